"""The real RAV4 drive (comma2k19, /work/shared/data/vehicle_imu): import, body-only
analysis, and identify's refusal for want of a wheel-side accelerometer."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fielddiag.cli import main as cli_main
from fielddiag.dsp import GRAVITY_MPS2
from fielddiag.errors import ChannelNotFoundError, ImportFormatError
from fielddiag.identify import identify_sessions
from fielddiag.identify.ride import analyse_ride
from fielddiag.io.vehicle_imu import import_vehicle_imu
from fielddiag.session import SessionReader

DATA = Path("/work/shared/data/vehicle_imu")
IMU = DATA / "comma2k19_rav4_seg40_imu.csv"
SPEED = DATA / "comma2k19_rav4_seg40_can_speed.csv"
GNSS = DATA / "comma2k19_rav4_seg40_gnss_ublox.csv"

pytestmark = pytest.mark.skipif(not IMU.exists(), reason="shared real data not present")


@pytest.fixture(scope="module")
def rav4(tmp_path_factory) -> Path:
    return import_vehicle_imu(IMU, SPEED, tmp_path_factory.mktemp("rav4") / "rav4.h5",
                              gnss_csv=GNSS)


def test_import_keeps_time_stamps_and_makes_vertical_up_positive(rav4):
    with SessionReader(rav4) as s:
        assert s.time_base == "timestamps"
        assert s.n_samples == 6256  # every IMU row (README)
        body = s.channel_for_role("body")
        assert body.name == "body_z" and body.unit == "m/s2" and body.axis == "z"
        t, z = s.read_with_time("body_z")
        # specific force, up positive: +g on average on a level road (README: acc_down has
        # mean -9.661), i.e. within 2 % of g
        assert np.mean(z) == pytest.approx(9.661, abs=1e-3)
        assert abs(np.mean(z) - GRAVITY_MPS2) < 0.02 * GRAVITY_MPS2
        # the device's own time stamps, from 0, about 104.4 Hz (README), 60 s
        assert t[0] == 0.0 and t[-1] == pytest.approx(59.99, abs=0.02)
        assert s.sample_rate_hz == pytest.approx(104.4, abs=0.1)
        assert np.std(np.diff(t)) > 0  # irregular steps are kept as recorded
        ts, v = s.signal(s.signal_for_role("speed").name)
        # README: 28.7 to 71.4 km/h
        assert v.min() * 3.6 == pytest.approx(28.7, abs=0.1)
        assert v.max() * 3.6 == pytest.approx(71.4, abs=0.1)
        assert abs(ts[0]) < 0.05
        assert s.metadata.t0_unix_s == pytest.approx(1533226488.2257, abs=1e-3)
        assert {"wheel_speed_fl", "gnss_speed"} <= {sig.name for sig in s.signals}


def test_body_only_analysis_finds_body_modes_that_do_not_move_with_speed(rav4):
    with SessionReader(rav4) as s:
        t, z = s.read_with_time("body_z")
        ts, v = s.signal("vehicle_speed")
    a = analyse_ride(z, t, speed_time_s=ts, speed_mps=v)
    assert a.resampled and a.timing_jitter_fraction < 0.01
    freqs = [p.freq_hz for p in a.peaks]
    # a passenger car's body bounce/pitch modes lie at 1-2 Hz, its wheel hop at 10-15 Hz
    body = [f for f in freqs if 1.0 <= f <= 2.0]
    hop = [f for f in freqs if 10.0 <= f <= 15.0]
    assert body and hop
    # the body-mode peak, followed window by window, does not move with speed: its slope
    # is far below that of a wheel-rotation line, 1/(2 pi 0.35 m) = 0.45 Hz per m/s
    tr = min(a.tracks, key=lambda tr: abs(tr.mean_freq_hz - body[0]))
    assert abs(tr.slope_hz_per_mps) < 0.1
    assert abs(tr.slope_hz_per_mps) < 3 * tr.slope_std_hz_per_mps + 0.02
    # RMS vertical body acceleration of a highway drive: a few tenths of m/s2
    assert 0.1 < a.rms_mps2 < 1.5
    # body displacement in 0.5-16 Hz: millimetres, not metres (integration drift removed)
    assert 1e-3 < a.displacement_rms_m < 3e-2
    back = type(a).from_dict(a.to_dict())
    assert back.to_dict() == a.to_dict()


def test_identify_refuses_the_real_drive_naming_the_missing_wheel_channel(rav4, capsys):
    with pytest.raises(ChannelNotFoundError, match="no wheel channel") as exc:
        identify_sessions(rav4, rav4, added_mass_kg=50.0)
    assert "wheel carrier or hub" in str(exc.value)
    rc = cli_main(["identify", str(rav4), str(rav4), "--added-mass", "50"])
    assert rc == 1
    err = capsys.readouterr().err
    assert "wheel" in err and "body_z (body)" in err and "Traceback" not in err


def test_import_rejects_malformed_files(tmp_path):
    bad = tmp_path / "imu.csv"
    bad.write_text("t_boot_s,acc_down_mps2\n0.0,-9.8\n0.01,-9.8\n")
    with pytest.raises(ImportFormatError, match="lacks the column"):
        import_vehicle_imu(bad, None, tmp_path / "x.h5")
    rows = IMU.read_text().splitlines()[:5]
    rows[3], rows[2] = rows[2], rows[3]  # time goes backwards
    back = tmp_path / "back.csv"
    back.write_text("\n".join(rows) + "\n")
    with pytest.raises(ImportFormatError, match="does not increase"):
        import_vehicle_imu(back, None, tmp_path / "y.h5")
    with pytest.raises(ImportFormatError, match="does not exist"):
        import_vehicle_imu(tmp_path / "missing.csv", None, tmp_path / "z.h5")
    assert not (tmp_path / "x.h5").exists()
