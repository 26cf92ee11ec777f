"""CAN log import on the real comma2k19 RAV4 log (candump) decoded with the opendbc DBC.

Reference values come from the data README (decoded independently by its authors and
cross-checked against comma's processed arrays) and from comma's own processed CAN speeds
in vehicle_imu/comma2k19_rav4_seg40_can_speed.csv (6 decimals).
"""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import can
import cantools
import numpy as np
import pytest
from _real_data import shared_data

from drivers.can_decode import frame_payload
from fielddiag.errors import DbcError, ImportFormatError
from fielddiag.io.canlog import import_can_log
from fielddiag.io.formats import import_file
from fielddiag.session import CAN_FLAG_EXTENDED, SessionReader

DATA = shared_data()
LOG = DATA / "can" / "comma2k19_rav4_2018-08-02_seg40.log"
PT_DBC = DATA / "can" / "toyota_new_mc_pt_generated.dbc"
ADAS_DBC = DATA / "can" / "toyota_adas.dbc"
CAN_SPEED_CSV = DATA / "vehicle_imu" / "comma2k19_rav4_seg40_can_speed.csv"
KMH = 1 / 3.6

pytestmark = pytest.mark.skipif(not LOG.is_file(), reason="real CAN log not available")


@pytest.fixture(scope="module")
def rav4(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("rav4") / "rav4.h5"
    import_file(LOG, out, dbc=[str(PT_DBC)])  # format detected from the contents
    return out


def test_default_signals_are_speed_and_wheel_speeds_in_si(rav4):
    with SessionReader(rav4) as s:
        names = {sig.name for sig in s.signals}
        assert names == {"SPEED", "WHEEL_SPEED_FL", "WHEEL_SPEED_FR", "WHEEL_SPEED_RL",
                         "WHEEL_SPEED_RR"}
        speed = s.signal_for_role("speed")
        assert speed.name == "SPEED" and speed.unit == "m/s" and speed.source == "can"
        t, v = s.signal("SPEED")
        # README: SPEED 29.38 to 73.05 km/h at 41 Hz over 59.99 s; resolution 0.01 km/h
        assert v.min() == pytest.approx(29.38 * KMH, abs=0.005 * KMH)
        assert v.max() == pytest.approx(73.05 * KMH, abs=0.005 * KMH)
        assert t.size / (t[-1] - t[0]) == pytest.approx(41.45, abs=0.3)
        assert 0 <= t[0] < 0.05 and t[-1] == pytest.approx(59.98, abs=0.05)
        _, fl = s.signal("WHEEL_SPEED_FL")
        assert fl.min() == pytest.approx(28.83 * KMH, abs=0.005 * KMH)
        assert fl.max() == pytest.approx(71.77 * KMH, abs=0.005 * KMH)
        assert s.signal_spec("WHEEL_SPEED_FL").message == "WHEEL_SPEEDS"
        assert s.n_samples == 0  # a CAN log has no DAQ channels


def test_wheel_speeds_match_commas_processed_values(rav4):
    ref = np.loadtxt(CAN_SPEED_CSV, delimiter=",", skiprows=1)
    t_utc, fl_ref, rr_ref = ref[:, 1], ref[:, 3], ref[:, 6]
    with SessionReader(rav4) as s:
        t, fl = s.signal("WHEEL_SPEED_FL")
        _, rr = s.signal("WHEEL_SPEED_RR")
        t0 = s.metadata.t0_unix_s
    assert fl.size == fl_ref.size == 4974
    # the CSV keeps 6 decimals: values agree to its rounding, times to its 1 us rounding
    assert np.max(np.abs(fl - fl_ref)) < 1e-6
    assert np.max(np.abs(rr - rr_ref)) < 1e-6
    assert np.max(np.abs(t + t0 - t_utc)) < 2e-5


def test_every_frame_is_kept_and_decodes_again(rav4):
    with SessionReader(rav4) as s:
        frames = s.can_frames()
        counters = s.counters
        md = s.metadata
    # README: 98,800 frames, 53,800 on can0 and 45,000 on can1, duration 59.99 s
    assert frames.size == 98_800 == counters["can_frames_received"]
    assert counters["can_decode_errors"] == 0
    assert md.extra["can_buses"] == {"0": "can0", "1": "can1"}
    assert np.sum(frames["bus"] == 0) == 53_800 and np.sum(frames["bus"] == 1) == 45_000
    assert md.t0_unix_s == pytest.approx(1533226488.230547, abs=1e-6)
    assert frames["time_s"][-1] == pytest.approx(59.99, abs=0.01)
    assert not np.any(frames["flags"] & CAN_FLAG_EXTENDED)
    # decode the stored raw frames again with cantools directly: the same speeds
    db = cantools.database.load_file(str(PT_DBC), strict=False)
    msg = db.get_message_by_name("SPEED")
    sel = frames[(frames["arbitration_id"] == msg.frame_id) & (frames["bus"] == 0)]
    again = np.array([msg.decode(frame_payload(f))["SPEED"] for f in sel]) * KMH
    with SessionReader(rav4) as s:
        _, v = s.signal("SPEED")
    np.testing.assert_array_equal(again, v)


def test_named_signals_in_si_and_ambiguity(tmp_path):
    out = tmp_path / "k.h5"
    import_can_log(LOG, out, dbc=[PT_DBC], signals=[
        "SPEED", "KINEMATICS.ACCEL_X", "YAW_RATE", "STEER_ANGLE_SENSOR.STEER_ANGLE", "RPM"])
    with SessionReader(out) as s:
        units = {sig.name: sig.unit for sig in s.signals}
        assert units == {"SPEED": "m/s", "ACCEL_X": "m/s2", "YAW_RATE": "rad/s",
                         "STEER_ANGLE": "rad", "RPM": "rad/s"}
        _, ax = s.signal("ACCEL_X")
        _, yaw = s.signal("YAW_RATE")
        _, steer = s.signal("STEER_ANGLE")
        _, rpm = s.signal("RPM")
    # README ranges: ACCEL_X -3.88..2.33 m/s2, YAW_RATE -2.27..0.42 deg/s,
    # STEER_ANGLE -4.5..3.0 deg, RPM 955..2544
    assert (ax.min(), ax.max()) == pytest.approx((-3.88, 2.33), abs=0.006)
    assert (yaw.min(), yaw.max()) == pytest.approx(
        (math.radians(-2.27), math.radians(0.42)), abs=math.radians(0.006))
    assert (steer.min(), steer.max()) == pytest.approx(
        (math.radians(-4.5), math.radians(3.0)), abs=math.radians(0.01))
    assert (rpm.min(), rpm.max()) == pytest.approx(
        (955 * 2 * math.pi / 60, 2544 * 2 * math.pi / 60), rel=2e-3)
    with pytest.raises(DbcError, match="STEER_ANGLE_SENSOR.STEER_ANGLE"):
        import_can_log(LOG, tmp_path / "amb.h5", dbc=[PT_DBC], signals=["STEER_ANGLE"])
    assert not (tmp_path / "amb.h5").exists()


def test_radar_bus_decoded_with_a_dbc_bound_to_it(tmp_path):
    out = tmp_path / "radar.h5"
    import_can_log(LOG, out, dbc=[PT_DBC, f"can1={ADAS_DBC}"],
                   signals=["SPEED", "TRACK_A_0.LONG_DIST"])
    with SessionReader(out) as s:
        t, d = s.signal("LONG_DIST")
        assert s.signal_spec("LONG_DIST").unit == "m"
        assert s.metadata.extra["dbc_files"] == [PT_DBC.name, f"can1={ADAS_DBC.name}"]
    assert (t.size - 1) / (t[-1] - t[0]) == pytest.approx(20.0, rel=0.02)  # 20 Hz per track
    assert np.all((d >= 0) & (d < 330))


@pytest.mark.parametrize("suffix,writer", [(".asc", can.ASCWriter), (".blf", can.BLFWriter)])
def test_other_log_formats_decode_the_same(tmp_path, suffix, writer):
    """The first 6000 frames rewritten as ASC/BLF by python-can decode to the same SPEED."""
    msgs = list(itertools.islice(can.LogReader(str(LOG)), 6000))
    src = tmp_path / f"part{suffix}"
    with writer(str(src)) as w:
        for m in msgs:
            w.on_message_received(m)
    with open(tmp_path / "part.log", "w") as fh:
        for m in msgs:
            fh.write(f"({m.timestamp:.6f}) {m.channel} {m.arbitration_id:03X}#{m.data.hex()}\n")
    a, b = tmp_path / "a.h5", tmp_path / "b.h5"
    import_file(src, a, dbc=[str(PT_DBC)], signals=["SPEED"])
    import_file(tmp_path / "part.log", b, dbc=[str(PT_DBC)], signals=["SPEED"])
    with SessionReader(a) as x, SessionReader(b) as y:
        ta, va = x.signal("SPEED")
        tb, vb = y.signal("SPEED")
        assert x.can_frames().size == 6000
    assert va.size > 100
    np.testing.assert_array_equal(va, vb)
    np.testing.assert_allclose(ta, tb, atol=2e-6)  # ASC/BLF keep time to 1 us / 10 ns


def _assert_nothing_left(folder: Path):
    assert [p.name for p in folder.iterdir() if p.suffix == ".h5" or "partial" in p.name] == []


def test_user_errors_are_clear_and_leave_nothing(tmp_path):
    out = tmp_path / "x.h5"
    cases = [
        (dict(dbc=[tmp_path / "none.dbc"]), DbcError, "DBC file .*none.dbc not found"),
        (dict(dbc=None), ImportFormatError, "needs a DBC file"),
        (dict(dbc=[PT_DBC], signals=["SPEEED"]), DbcError, "not in .*did you mean SPEED"),
        (dict(dbc=[f"can0={ADAS_DBC}"], signals=["TRACK_A_0.LONG_DIST"]), ImportFormatError,
         r"TRACK_A_0 \(0x210\) of toyota_adas.dbc never occurs in the log"),
        # 0x224 is BRAKE_MODULE on the powertrain bus and something else on the radar bus
        (dict(dbc=[PT_DBC], signals=["BRAKE_MODULE.BRAKE_PRESSURE"]), ImportFormatError,
         "occurs on several buses \\(can0, can1\\); bind the DBC to one bus with --dbc BUS="),
    ]
    for kwargs, error, message in cases:
        with pytest.raises(error, match=message):
            import_can_log(LOG, out, **kwargs)
        _assert_nothing_left(tmp_path)
    bad_dbc = tmp_path / "bad.dbc"
    bad_dbc.write_text("this is not a DBC\n")
    with pytest.raises(DbcError, match="not a readable CAN database"):
        import_can_log(LOG, out, dbc=[bad_dbc])
    corrupt = tmp_path / "corrupt.log"
    corrupt.write_text("(1533226488.230547) can0 0B4#000000001D0B7A5E\n(garbage here\n")
    with pytest.raises(ImportFormatError, match="corrupt.log: unreadable CAN log after 1 frames"):
        import_can_log(corrupt, out, dbc=[PT_DBC])
    empty = tmp_path / "empty.log"
    empty.write_text("")
    with pytest.raises(ImportFormatError, match="no CAN frames"):
        import_can_log(empty, out, dbc=[PT_DBC])
    only_radar = tmp_path / "radar_only.log"
    with open(LOG) as fh, open(only_radar, "w") as o:
        o.writelines(ln for ln in itertools.islice(fh, 5000) if " can1 " in ln)
    with pytest.raises(ImportFormatError, match="no vehicle speed or wheel speed"):
        import_can_log(only_radar, out, dbc=[PT_DBC])
    _assert_nothing_left(tmp_path)
