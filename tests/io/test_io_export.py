"""`fielddiag export` to CSV and MDF4 through the real command line, and round trips back."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fielddiag.channels import ChannelSpec, SessionMetadata, SignalSpec
from fielddiag.cli import main
from fielddiag.errors import ImportFormatError
from fielddiag.io.csv_export import export_csv, import_exported_csv
from fielddiag.io.formats import detect_format, import_file
from fielddiag.session import (
    CAN_FLAG_EXTENDED,
    CAN_FLAG_RX,
    CAN_FRAME_DTYPE,
    SessionReader,
    SessionWriter,
)

G = 9.80665


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "fielddiag.cli", *args], capture_output=True,
                          text=True)


@pytest.fixture
def session(tmp_path) -> Path:
    """A recorded-like session: int16 wheel with calibration, float body, CAN speed, frames."""
    rng = np.random.default_rng(11)
    path = tmp_path / "drive.h5"
    n = 12_000
    t_frames = np.sort(rng.uniform(0, 24, 300))
    frames = np.zeros(t_frames.size, dtype=CAN_FRAME_DTYPE)
    frames["time_s"] = t_frames
    frames["arbitration_id"] = 0xB4
    frames["arbitration_id"][::10] = 0x18FEF100
    frames["flags"] = CAN_FLAG_RX
    frames["flags"][::10] |= CAN_FLAG_EXTENDED
    frames["dlc"] = 8
    frames["dlc"][1::10] = 3
    frames["data"][:, :8] = rng.integers(0, 256, (t_frames.size, 8))
    frames["data"][1::10, 3:] = 0
    with SessionWriter(
        path, SessionMetadata(vehicle="Camry", corner="front-left", added_mass_kg=40.0,
                              t0_unix_s=1700000000.5),
        [ChannelSpec("wheel_z", role="wheel", dtype="int16", scale=G / 2048, offset=-0.01),
         ChannelSpec("body_z", role="body", dtype="float32")],
        sample_rate_hz=500.0, time_base="uniform",
        signals=[SignalSpec("vehicle_speed", "m/s", "can", "SPEED", "speed"),
                 SignalSpec("one", "V", "can", "X")],
        store_can_frames=True, atomic=True,
    ) as w:
        w.append_daq({"wheel_z": rng.integers(-4000, 4000, n).astype("i2"),
                      "body_z": (G + rng.normal(0, 0.4, n)).astype("f4")})
        ts = np.sort(rng.uniform(0, 24, 990))
        w.append_signal("vehicle_speed", ts, rng.uniform(5, 25, ts.size) / 3.0)
        w.append_signal("one", [1.5], [12.25])
        w.append_can_frames(frames)
        w.add_event(2.25, "pothole")
        w.set_counters(frames_lost=2, can_frames_received=300)
    return path


def test_csv_export_files_are_plain_csv(session, tmp_path):
    out = tmp_path / "out.csv"
    proc = _cli("export", str(session), "-o", str(out))
    assert proc.returncode == 0, proc.stderr
    written = [Path(line.removeprefix("wrote ")) for line in proc.stdout.splitlines()]
    assert {p.name for p in written} == {"out.csv", "out.fielddiag.json",
                                         "out.signal.vehicle_speed.csv", "out.signal.one.csv",
                                         "out.can_frames.csv"}
    with open(out, newline="") as fh:
        rows = list(csv.reader(fh))
    assert rows[0] == ["time_s", "wheel_z", "body_z"] and len(rows) == 12_001
    with SessionReader(session) as s:
        wheel = s.read("wheel_z")
        body = s.read("body_z")
        t = s.time_s()
    data = np.array(rows[1:], dtype="f8")  # float() of repr gives the float back exactly
    np.testing.assert_array_equal(data[:, 0], t)
    np.testing.assert_array_equal(data[:, 1], wheel)
    np.testing.assert_array_equal(data[:, 2], body)
    manifest = json.loads((tmp_path / "out.fielddiag.json").read_text())
    assert [c["unit"] for c in manifest["channels"]] == ["m/s2", "m/s2"]
    assert manifest["channels"][0]["source_calibration"]["dtype"] == "int16"
    sig = np.loadtxt(tmp_path / "out.signal.vehicle_speed.csv", delimiter=",", skiprows=1)
    assert sig.shape == (990, 2)


def test_csv_round_trip_keeps_every_sample_and_unit(session, tmp_path):
    out = tmp_path / "out.csv"
    export_csv(session, out)
    assert detect_format(out) == "fielddiag-csv"
    back = tmp_path / "back.h5"
    import_file(out, back)
    with SessionReader(session) as x, SessionReader(back) as y:
        assert y.time_base == "uniform" and y.sample_rate_hz == x.sample_rate_hz
        np.testing.assert_array_equal(x.time_s(), y.time_s())
        for c in x.channels:
            d = y.channel(c.name)
            assert (d.unit, d.role, d.axis) == (c.unit, c.role, c.axis)
            np.testing.assert_array_equal(x.read(c.name), y.read(d.name))
        assert x.signals == y.signals
        for s in x.signals:
            for u, v in zip(x.signal(s.name), y.signal(s.name), strict=True):
                np.testing.assert_array_equal(u, v)
        for k in CAN_FRAME_DTYPE.names:
            np.testing.assert_array_equal(x.can_frames()[k], y.can_frames()[k])
        assert x.events == y.events and x.counters == y.counters
        assert y.metadata.added_mass_kg == 40.0 and y.metadata.t0_unix_s == 1700000000.5
        assert y.metadata.extra["import_format"] == "fielddiag-csv"


def test_mdf_export_through_the_cli_round_trips(session, tmp_path):
    pytest.importorskip("asammdf", reason="asammdf is not installed (pip install "
                        "'fielddiag[mdf]')")
    out = tmp_path / "out.mf4"
    assert main(["export", str(session), "-o", str(out)]) == 0
    back = tmp_path / "back.h5"
    import_file(out, back)
    with SessionReader(session) as x, SessionReader(back) as y:
        assert x.channels == y.channels  # raw dtype and calibration too
        for c in x.channels:
            np.testing.assert_array_equal(x.read_raw(c.name), y.read_raw(c.name))
        for s in x.signals:
            assert y.signal_spec(s.name) == s
            for u, v in zip(x.signal(s.name), y.signal(s.name), strict=True):
                np.testing.assert_array_equal(u, v)
        assert x.can_frames().tobytes() == y.can_frames().tobytes()
    other = tmp_path / "other.bin"
    assert main(["export", str(session), "-o", str(other), "--format", "mdf4"]) == 0
    assert other.read_bytes()[:8] == b"MDF     "


def test_export_never_overwrites_and_errors_are_one_line(session, tmp_path):
    out = tmp_path / "out.csv"
    export_csv(session, out)
    before = out.read_bytes()
    for args, message in [
        (("export", str(session), "-o", str(out)), "already exists"),
        (("export", str(session), "-o", str(tmp_path / "x.xyz")), "cannot tell the export format"),
        (("export", str(tmp_path / "none.h5"), "-o", str(tmp_path / "n.csv")), "does not exist"),
        (("export", str(session), "-o", str(tmp_path / "no" / "x.csv")), "does not exist"),
    ]:
        proc = _cli(*args)
        assert proc.returncode == 1, proc.stderr
        assert "Traceback" not in proc.stderr and message in proc.stderr
        assert len(proc.stderr.strip().splitlines()) == 1
    assert out.read_bytes() == before
    assert not [p for p in tmp_path.iterdir() if "partial" in p.name]
    assert main(["export", str(session), "-o", str(out), "--overwrite"]) == 0


def test_broken_exports_fail_cleanly(session, tmp_path):
    out = tmp_path / "out.csv"
    export_csv(session, out)
    (tmp_path / "out.signal.one.csv").unlink()
    with pytest.raises(ImportFormatError, match="out.signal.one.csv .*missing beside out.csv"):
        import_exported_csv(out, tmp_path / "x.h5")
    export_csv(session, out, overwrite=True)
    lines = out.read_text().splitlines()
    lines[7] = lines[7].replace(",", ",oops", 1)
    out.write_text("\n".join(lines) + "\n")
    with pytest.raises(ImportFormatError, match="out.csv row 8, column 'wheel_z'"):
        import_file(out, tmp_path / "x.h5")
    assert not (tmp_path / "x.h5").exists()
    # without its manifest the CSV is an ordinary CSV, imported with roles
    (tmp_path / "out.fielddiag.json").unlink()
    export_csv(session, tmp_path / "plain.csv")
    (tmp_path / "plain.fielddiag.json").unlink()
    assert detect_format(tmp_path / "plain.csv") == "csv"
    import_file(tmp_path / "plain.csv", tmp_path / "p.h5", roles=["wheel=wheel_z",
                "body=body_z"], time_column="time_s")
    with SessionReader(session) as x, SessionReader(tmp_path / "p.h5") as y:
        np.testing.assert_array_equal(x.read("body_z"), y.read_role("body"))
