"""The one reader of a recorded drive (fielddiag.drive) on real HDF5 sessions.

Sessions are written with :func:`fielddiag.session.write_session` (the writer every import
and the simulator use). Arrays are compared exactly where the reader only copies, and to
1e-12 relative where it multiplies by a unit factor (one rounding of a float64 product).
"""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from fielddiag import sim
from fielddiag.channels import CORNERS, ChannelSpec, Gap, SessionMetadata
from fielddiag.cli import main as cli_main
from fielddiag.diagnose.engine import read_drive
from fielddiag.drive import CornerDrive, find_channel, read_accel_channel, read_corner_drive
from fielddiag.errors import (
    ChannelNotFoundError,
    FieldDiagError,
    InsufficientDataError,
    SessionError,
)
from fielddiag.identify import read_recording
from fielddiag.identify.greybox import GreyBoxData
from fielddiag.session import write_session
from fielddiag.units import GRAVITY_MPS2

FS = 200.0
N = 2000  # 10 s


def _signals(n: int = N, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return GRAVITY_MPS2 + rng.normal(0, 2.0, n), GRAVITY_MPS2 + rng.normal(0, 0.5, n)


def _write(path, wheel, body, *, units=("m/s2", "m/s2"), roles=("wheel", "body"),
           time_s=None, added_mass_kg=0.0, gaps=(), vehicle="test car"):
    chans = [ChannelSpec("wheel_z", unit=units[0], role=roles[0]),
             ChannelSpec("body_z", unit=units[1], role=roles[1])]
    return write_session(path, SessionMetadata(vehicle=vehicle, added_mass_kg=added_mass_kg),
                         chans, np.column_stack([wheel, body]), sample_rate_hz=FS,
                         time_s=time_s, gaps=gaps)


# ------------------------------------------------------------------------------ units
def test_g_mg_and_mps2_channels_give_the_same_drive(tmp_path):
    wheel, body = _signals()
    ref = read_corner_drive(_write(tmp_path / "si.h5", wheel, body))
    in_g = read_corner_drive(_write(tmp_path / "g.h5", wheel / GRAVITY_MPS2,
                                    body / GRAVITY_MPS2, units=("g", "g")))
    mixed = read_corner_drive(_write(tmp_path / "mixed.h5", wheel / (1e-3 * GRAVITY_MPS2),
                                     body, units=("mg", "m/s^2")))
    np.testing.assert_array_equal(ref.wheel_accel_mps2, wheel)
    np.testing.assert_array_equal(ref.body_accel_mps2, body)
    for d in (in_g, mixed):
        np.testing.assert_allclose(d.wheel_accel_mps2, wheel, rtol=1e-12, atol=0)
        np.testing.assert_allclose(d.body_accel_mps2, body, rtol=1e-12, atol=0)
    # an accelerometer at rest reads +g: the mean of the converted reading is ~9.81 m/s^2
    assert np.mean(in_g.wheel_accel_mps2) == pytest.approx(GRAVITY_MPS2, abs=4 * 2.0 / N**0.5)


def test_a_channel_that_is_not_an_acceleration_is_refused(tmp_path):
    wheel, body = _signals()
    p = _write(tmp_path / "v.h5", wheel, body, units=("V", "m/s2"))
    with pytest.raises(FieldDiagError, match="'wheel_z' is in 'V', not an acceleration"):
        read_corner_drive(p)


# ------------------------------------------------------------------- time base, gaps
def test_gaps_in_time_stamps_give_pieces_and_the_real_times(tmp_path):
    wheel, body = _signals()
    t = 5.0 + np.arange(N) / FS
    t[1200:] += 0.5  # 100 samples' worth of time lost after sample 1199
    d = read_corner_drive(_write(tmp_path / "gap.h5", wheel, body, time_s=t))
    assert d.pieces == [(0, 1200), (1200, N)] and d.piece_list() == d.pieces
    assert d.sample_rate_hz == pytest.approx(FS, rel=1e-9)
    assert d.start_s == 5.0 and d.n == N and d.duration_s == pytest.approx(N / FS)
    np.testing.assert_array_equal(d.time_s, t)
    # continuous recordings are one piece
    c = read_corner_drive(_write(tmp_path / "ok.h5", wheel, body, time_s=5.0 + np.arange(N) / FS))
    assert c.pieces is None and c.piece_list() == [(0, N)]


def test_the_rate_of_steered_time_stamps_is_the_devices(tmp_path):
    """A recorder's host-clock mapping slews (here +1.5e-3 for 70 % of the time, then
    back) while it steers towards its clock fit: the median step is 0.15 % short, the
    rate over the drive is the device's."""
    wheel, body = _signals()
    slope = np.where(np.arange(N) < 0.7 * N, 1.5e-3, -3.5e-3)  # net offset change 0
    t = 5.0 + np.cumsum(np.r_[0.0, (1.0 + slope[1:]) / FS])
    assert 1.0 / np.median(np.diff(t)) == pytest.approx(FS / 1.0015, rel=1e-6)
    d = read_corner_drive(_write(tmp_path / "steered.h5", wheel, body, time_s=t))
    assert d.pieces is None
    assert d.sample_rate_hz == pytest.approx(FS, rel=1e-5)


def test_a_gap_recorded_on_a_uniform_time_base_cuts_the_pieces(tmp_path):
    wheel, body = _signals()
    p = _write(tmp_path / "u.h5", wheel, body, gaps=[Gap(4.0, 4.5, 100, "usb")])
    d = read_corner_drive(p)
    assert d.pieces == [(0, 800), (800, N)]
    assert d.timestamps_s is None
    np.testing.assert_allclose(d.time_s, np.arange(N) / FS, rtol=0, atol=1e-12)


def test_require_continuous_refuses_gaps_with_where_and_what_to_do(tmp_path):
    wheel, body = _signals()
    t = np.arange(N) / FS
    t[1200:] += 0.5
    p = _write(tmp_path / "gap.h5", wheel, body, time_s=t)
    with pytest.raises(InsufficientDataError) as exc:
        read_drive(p, "before")
    msg = str(exc.value)
    # the last sample before the gap is at 5.995 s, the first after it at 6.5 s
    assert re.match(r"gap\.h5 has gaps in its time base \(the first between (5\.99|6\.00) "
                    r"and 6\.50 s\)", msg), msg
    assert "diagnose needs a continuous recording (export the longest gap-free stretch)" in msg
    with pytest.raises(InsufficientDataError, match="--start/--end"):
        GreyBoxData.from_session(p)
    # the stretch before the gap is continuous: the fit takes it
    d = read_corner_drive(p, end_s=5.5, require_continuous=True)
    assert d.n == 1100 and d.pieces is None


def test_irregular_time_stamps_are_refused(tmp_path):
    wheel, body = _signals()
    t = np.arange(N) / FS + np.random.default_rng(3).uniform(0, 0.2 / FS, N)  # 6 % jitter
    p = _write(tmp_path / "jitter.h5", wheel, body, time_s=np.sort(t))
    with pytest.raises(SessionError, match=r"irregular time stamps \(jitter \d+ % of the sample "
                                           "period\\); identify needs a uniformly sampled"):
        read_recording(p, "before")


def test_start_and_end_select_a_stretch(tmp_path):
    wheel, body = _signals()
    uni = read_corner_drive(_write(tmp_path / "u.h5", wheel, body), start_s=2.0, end_s=5.0)
    assert uni.n == 600 and uni.start_s == pytest.approx(2.0, abs=1e-12)
    np.testing.assert_array_equal(uni.wheel_accel_mps2, wheel[400:1000])
    np.testing.assert_array_equal(uni.body_accel_mps2, body[400:1000])
    np.testing.assert_allclose(uni.time_s, np.arange(400, 1000) / FS, atol=1e-12)
    t = 1.0 + np.arange(N) / FS
    ts = read_corner_drive(_write(tmp_path / "t.h5", wheel, body, time_s=t), start_s=2.0,
                           end_s=5.0)
    assert ts.n == 600 and ts.start_s == pytest.approx(2.0, abs=1e-9)
    np.testing.assert_array_equal(ts.body_accel_mps2, body[200:800])
    np.testing.assert_array_equal(ts.time_s, t[200:800])
    with pytest.raises(InsufficientDataError, match="holds no samples between 20.0 and 30.0 s"):
        read_corner_drive(tmp_path / "u.h5", start_s=20.0, end_s=30.0)


def test_added_mass_label_and_header(tmp_path):
    wheel, body = _signals()
    p = _write(tmp_path / "after.h5", wheel, body, added_mass_kg=60.0, vehicle="car 7")
    d = read_corner_drive(p, label="after")
    assert (d.added_mass_kg, d.label, d.name, d.path) == (60.0, "after", "after.h5", str(p))
    assert (d.vehicle, d.wheel_channel, d.body_channel, d.corner) == (
        "car 7", "wheel_z", "body_z", None)
    assert read_corner_drive(p, added_mass_kg=0.0).added_mass_kg == 0.0
    assert read_drive(p, "drive", 0.0).added_mass_kg == 0.0
    assert read_drive(p, "after").added_mass_kg == 60.0


# ------------------------------------------------------------------------- channels
def test_missing_and_duplicate_roles_say_where_to_mount_the_sensor(tmp_path):
    wheel, body = _signals()
    p = write_session(tmp_path / "body_only.h5", SessionMetadata(),
                      [ChannelSpec("body_z", role="body")], body[:, None], sample_rate_hz=FS)
    with pytest.raises(ChannelNotFoundError) as exc:
        read_recording(p, "before")
    msg = str(exc.value)
    assert msg.startswith("body_only.h5 has no wheel channel (role 'wheel'; channels: "
                          "body_z (body)). identify needs exactly one wheel-side")
    assert "accelerometer on the wheel carrier or hub, below the spring" in msg
    two = write_session(tmp_path / "two.h5", SessionMetadata(),
                        [ChannelSpec("wheel_z", role="wheel"), ChannelSpec("body_z", role="body"),
                         ChannelSpec("body_y", role="body")],
                        np.column_stack([wheel, body, body]), sample_rate_hz=FS)
    with pytest.raises(ChannelNotFoundError, match="two.h5 has several body channel") as exc:
        read_drive(two, "drive")
    assert "diagnose needs" in str(exc.value)


def test_corner_roles_of_a_full_vehicle_session(tmp_path):
    rng = np.random.default_rng(5)
    data = {c: (rng.normal(size=N), rng.normal(size=N)) for c in CORNERS}
    chans, cols = [], []
    for c in CORNERS:
        chans += [ChannelSpec(f"hub_{c}", unit="g", role=f"wheel_{c}"),
                  ChannelSpec(f"top_{c}", unit="m/s2", role=f"body_{c}")]
        cols += list(data[c])
    p = write_session(tmp_path / "car.h5", SessionMetadata(vehicle="car"), chans,
                      np.column_stack(cols), sample_rate_hz=FS)
    for c in CORNERS:
        d = read_corner_drive(p, corner=c)
        assert (d.corner, d.wheel_channel, d.body_channel) == (c, f"hub_{c}", f"top_{c}")
        np.testing.assert_allclose(d.wheel_accel_mps2, data[c][0] * GRAVITY_MPS2, rtol=1e-15)
        np.testing.assert_array_equal(d.body_accel_mps2, data[c][1])
    with pytest.raises(ChannelNotFoundError, match="give the corner \\(fl, fr, rl, rr\\)"):
        read_corner_drive(p)
    with pytest.raises(FieldDiagError, match="corner 'lf' is not a corner; give one of fl"):
        read_corner_drive(p, corner="lf")
    # a single-corner session has no corner roles
    wheel, body = _signals()
    with pytest.raises(ChannelNotFoundError, match="no wheel_rr channel .* of the rr corner"):
        read_corner_drive(_write(tmp_path / "one.h5", wheel, body), corner="rr")


def test_find_channel_on_a_live_channel_list():
    chans = [ChannelSpec("b", role="body"), ChannelSpec("x"), ChannelSpec("w", role="wheel")]
    assert find_channel(chans, "wheel").name == "w"
    with pytest.raises(ChannelNotFoundError, match="the recorder has no wheel channel"):
        find_channel(chans[:2], "wheel", source="the recorder")


# ------------------------------------------------------------------------ consumers
def test_every_consumer_reads_the_same_arrays(tmp_path):
    wheel, body = _signals(4000)
    si = _write(tmp_path / "si.h5", wheel, body, added_mass_kg=30.0)
    g = _write(tmp_path / "g.h5", wheel / GRAVITY_MPS2, body / GRAVITY_MPS2, units=("g", "g"),
               added_mass_kg=30.0)
    a, b, c = read_drive(si, "after"), read_recording(g, "after"), read_corner_drive(si)
    assert isinstance(a, CornerDrive) and isinstance(b, CornerDrive)
    np.testing.assert_array_equal(a.wheel_accel_mps2, c.wheel_accel_mps2)
    np.testing.assert_allclose(b.wheel_accel_mps2, a.wheel_accel_mps2, rtol=1e-12)
    np.testing.assert_allclose(b.body_accel_mps2, a.body_accel_mps2, rtol=1e-12)
    fa, fb = GreyBoxData.from_session(si), GreyBoxData.from_session(g)
    assert fa.added_mass_kg == fb.added_mass_kg == 30.0 and fa.band_hz == fb.band_hz
    scale = np.max(np.abs(fa.wheel_disp_m))
    np.testing.assert_allclose(fb.wheel_disp_m, fa.wheel_disp_m, rtol=0, atol=1e-9 * scale)
    t, acc, ch = read_accel_channel(g, "body")
    assert ch.name == "body_z"
    np.testing.assert_allclose(acc, body, rtol=1e-12)
    np.testing.assert_allclose(t, np.arange(4000) / FS, atol=1e-12)


@pytest.fixture(scope="module")
def sim_pair(tmp_path_factory):
    """A simulated before/after pair (60 kg added), in m/s^2 and with channels in g."""
    d = tmp_path_factory.mktemp("drive_units")
    sensor = sim.SensorModel(output_rate_hz=200.0, snr_db=30.0)
    b, a = sim.simulate_pair(sim.QuarterCarParams(), added_mass_kg=60.0, seed=11,
                             duration_s=60.0, road_class="C", sensor=sensor)
    paths = {}
    for name, drv, units in (("b_si", b, ("m/s2", "m/s2")), ("a_si", a, ("m/s2", "m/s2")),
                             ("b_g", b, ("g", "m/s2")), ("a_g", a, ("m/s2", "g"))):
        w, y = drv.wheel_accel_mps2, drv.body_accel_mps2
        w = w / GRAVITY_MPS2 if units[0] == "g" else w
        y = y / GRAVITY_MPS2 if units[1] == "g" else y
        paths[name] = _write(d / f"{name}.h5", w, y, units=units, vehicle="simulated car",
                             added_mass_kg=drv.added_mass_kg)
    return d, paths


def test_identify_gives_the_same_answer_for_channels_in_g(sim_pair, capsys):
    """``fielddiag identify`` on a pair in m/s^2 and on the same pair with one channel of each
    drive in g (the wheel before, the body after): every number of the result agrees."""
    d, p = sim_pair
    out = {}
    for tag in ("si", "g"):
        js = d / f"identify_{tag}.json"
        assert cli_main(["identify", str(p[f"b_{tag}"]), str(p[f"a_{tag}"]), "--added-mass",
                         "60", "--json", str(js)]) == 0
        out[tag] = json.loads(js.read_text())
    capsys.readouterr()
    si, g = out["si"], out["g"]
    assert si["sprung_mass_kg"]["value"] == pytest.approx(380.0, rel=0.05)
    for key in ("sprung_mass_kg", "suspension_stiffness_n_per_m", "suspension_damping_ns_per_m",
                "body_natural_frequency_hz", "damping_ratio"):
        for part in ("value", "std"):
            assert g[key][part] == pytest.approx(si[key][part], rel=1e-6), key
    for ts, tg in zip(si["transmissibility"], g["transmissibility"], strict=True):
        assert tg["noise"]["wheel_rms_mps2"] == pytest.approx(ts["noise"]["wheel_rms_mps2"],
                                                              rel=1e-6)
        assert tg["noise"]["body_rms_mps2"] == pytest.approx(ts["noise"]["body_rms_mps2"],
                                                             rel=1e-6)
    for rs, rg in zip(si["restoring_force"], g["restoring_force"], strict=True):
        assert rg["stiffness_n_per_m"]["value"] == pytest.approx(
            rs["stiffness_n_per_m"]["value"], rel=1e-6)


def test_ride_reads_a_body_channel_in_g_as_m_per_s2(sim_pair, capsys):
    d, p = sim_pair
    rms = []
    for name in ("a_si", "a_g"):
        js = d / f"ride_{name}.json"
        assert cli_main(["ride", str(p[name]), "--json", str(js)]) == 0
        rms.append(json.loads(js.read_text())["rms_mps2"])
    capsys.readouterr()
    assert rms[1] == pytest.approx(rms[0], rel=1e-9)
    assert 0.05 < rms[0] < 5.0  # m/s^2 of a car body on a class C road, not g
