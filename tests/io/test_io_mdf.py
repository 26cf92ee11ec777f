"""MDF4: export a session, open it with asammdf and python-can, import it back exactly;
import third-party MDF4 (channels with roles and units, CAN bus logging with a DBC)."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest

from fielddiag.channels import ChannelSpec, SessionMetadata, SignalSpec
from fielddiag.errors import FieldDiagError, ImportFormatError, SessionError
from fielddiag.io.formats import detect_format, import_file
from fielddiag.session import (
    CAN_FLAG_BRS,
    CAN_FLAG_ERROR,
    CAN_FLAG_EXTENDED,
    CAN_FLAG_FD,
    CAN_FLAG_REMOTE,
    CAN_FLAG_RX,
    CAN_FRAME_DTYPE,
    SessionReader,
    SessionWriter,
)

asammdf = pytest.importorskip(
    "asammdf", reason="asammdf is not installed (pip install 'fielddiag[mdf]')"
)
from asammdf import MDF, Signal  # noqa: E402

from fielddiag.io.mdf import export_mdf, import_mdf  # noqa: E402

DATA = Path("/work/shared/data/can")
LOG = DATA / "comma2k19_rav4_2018-08-02_seg40.log"
PT_DBC = DATA / "toyota_new_mc_pt_generated.dbc"
G = 9.80665


def make_frames(rng: np.random.Generator) -> np.ndarray:
    """Classic, extended, CAN FD (byte count 12 and 64), remote and error frames, 2 buses."""
    n = 400
    f = np.zeros(n, dtype=CAN_FRAME_DTYPE)
    f["time_s"] = np.sort(rng.uniform(0, 30, n))
    f["arbitration_id"] = rng.integers(0, 0x7FF, n)
    f["bus"] = rng.integers(0, 2, n)
    f["flags"] = CAN_FLAG_RX
    f["dlc"] = 8
    f["data"][:, :8] = rng.integers(0, 256, (n, 8))
    f["arbitration_id"][::7] = rng.integers(0x800, 0x1FFFFFFF, f[::7].size)
    f["flags"][::7] |= CAN_FLAG_EXTENDED
    f["flags"][3::50] = CAN_FLAG_FD | CAN_FLAG_BRS | CAN_FLAG_RX
    f["dlc"][3::50] = 12
    f["data"][3::50, :12] = 0xAB
    f["flags"][5::50] = CAN_FLAG_FD  # transmitted, not received
    f["dlc"][5::50] = 64
    f["data"][5::50, :] = 0xCD
    f["flags"][11::100] = CAN_FLAG_REMOTE | CAN_FLAG_RX
    f["data"][11::100] = 0
    f["flags"][13::100] = CAN_FLAG_ERROR | CAN_FLAG_RX
    f["dlc"][13::100] = 0
    f["data"][13::100] = 0
    return f


@pytest.fixture
def rich_session(tmp_path) -> Path:
    """int16 raw with calibration, float32, float64; signals (one empty); frames; events."""
    rng = np.random.default_rng(3)
    path = tmp_path / "drive.h5"
    n = 15_000
    meta = SessionMetadata(vehicle="Camry", corner="rear-left", operator="Ana",
                           added_mass_kg=35.0, notes="loaded", t0_unix_s=1700000000.125,
                           extra={"road": "B"})
    with SessionWriter(
        path, meta,
        [ChannelSpec("wheel_z", role="wheel", sensor="ADXL357 #12", dtype="int16",
                     scale=G / 1024, offset=0.02),
         ChannelSpec("body_z", role="body", sensor="ADXL357 #13", dtype="float32"),
         ChannelSpec("force", unit="N", role="force")],
        sample_rate_hz=500.0, time_base="uniform", t0_s=0.0,
        signals=[SignalSpec("vehicle_speed", "m/s", "can", "SPEED", "speed"),
                 SignalSpec("WHEEL_SPEED_FL", "m/s", "can", "WHEEL_SPEEDS"),
                 SignalSpec("battery", "V", "can", "BATT")],
        store_can_frames=True, atomic=True,
    ) as w:
        w.append_daq({"wheel_z": rng.integers(-3000, 3000, n).astype("i2"),
                      "body_z": (G + rng.normal(size=n)).astype("f4"),
                      "force": rng.normal(size=n) * 100})
        ts = np.sort(rng.uniform(0, 30, 1230))
        w.append_signal("vehicle_speed", ts, rng.uniform(8, 20, ts.size))
        ts = np.sort(rng.uniform(0, 30, 2490))
        w.append_signal("WHEEL_SPEED_FL", ts, rng.uniform(8, 20, ts.size))
        w.append_can_frames(make_frames(rng))
        w.add_event(3.5, "speed bump")
        w.add_gap(10.0, 10.1, 50, "usb stall")
        w.set_counters(frames_lost=3, can_frames_received=400)
    return path


def assert_same_session(a: Path, b: Path, *, raw: bool) -> None:
    with SessionReader(a) as x, SessionReader(b) as y:
        assert (x.time_base, x.sample_rate_hz, x.n_samples) == (
            y.time_base, y.sample_rate_hz, y.n_samples)
        np.testing.assert_array_equal(x.time_s(), y.time_s())
        for c in x.channels:
            d = y.channel(c.name)
            assert (d.unit, d.role, d.axis, d.sensor) == (c.unit, c.role, c.axis, c.sensor)
            if raw:
                assert d == c  # dtype and calibration too
                rx, ry = x.read_raw(c.name), y.read_raw(c.name)
                assert rx.dtype == ry.dtype
                np.testing.assert_array_equal(rx, ry)
            np.testing.assert_array_equal(x.read(c.name), y.read(c.name))
        assert x.signals == y.signals
        for s in x.signals:
            for u, v in zip(x.signal(s.name), y.signal(s.name), strict=True):
                np.testing.assert_array_equal(u, v)
        fx, fy = x.can_frames(), y.can_frames()
        assert fx.size == fy.size
        for k in CAN_FRAME_DTYPE.names:
            np.testing.assert_array_equal(fx[k], fy[k], err_msg=k)
        assert x.events == y.events and x.gaps == y.gaps and x.counters == y.counters
        mx, my = x.metadata, y.metadata
        for k in ("vehicle", "corner", "operator", "added_mass_kg", "notes", "t0_unix_s"):
            assert getattr(mx, k) == getattr(my, k), k
        assert mx.extra.items() <= my.extra.items()


def test_export_opens_in_asammdf_with_names_units_and_groups(rich_session, tmp_path):
    out = tmp_path / "drive.mf4"
    export_mdf(rich_session, out)
    assert detect_format(out) == "mdf"
    with MDF(out) as mdf:
        assert mdf.header.start_time.timestamp() == pytest.approx(1700000000.125, abs=1e-6)
        wheel = mdf.get("wheel_z")
        assert wheel.unit == "m/s2" and "role=wheel" in wheel.comment
        assert "ADXL357 #12" in wheel.comment
        with SessionReader(rich_session) as s:
            np.testing.assert_allclose(wheel.samples, s.read("wheel_z"), rtol=1e-12)
            np.testing.assert_array_equal(wheel.timestamps, s.time_s())
            t, v = s.signal("vehicle_speed")
        speed = mdf.get("vehicle_speed")
        assert speed.unit == "m/s" and "role=speed" in speed.comment
        np.testing.assert_array_equal(speed.timestamps, t)  # its own time base
        assert mdf.get("force").unit == "N"
        acq = [g.channel_group.acq_name for g in mdf.groups]
        assert acq[0] == "fielddiag DAQ"
        assert set(acq[1:4]) == {"signal vehicle_speed", "signal WHEEL_SPEED_FL",
                                 "signal battery"}
        names = {c.name for g in mdf.groups for c in g.channels}
        assert {"CAN_DataFrame", "CAN_ErrorFrame", "CAN_RemoteFrame"} <= names


def test_python_can_reads_the_exported_bus_logging(rich_session, tmp_path):
    import can

    out = tmp_path / "drive.mf4"
    export_mdf(rich_session, out)
    with SessionReader(rich_session) as s:
        frames = s.can_frames()
        t0 = s.metadata.t0_unix_s
    msgs = list(can.LogReader(str(out)))
    assert len(msgs) == frames.size
    data = frames[(frames["flags"] & (CAN_FLAG_ERROR | CAN_FLAG_REMOTE)) == 0]
    got = [m for m in msgs if not (m.is_error_frame or m.is_remote_frame)]
    assert len(got) == data.size
    for m, f in zip(got, data, strict=True):
        assert m.timestamp == pytest.approx(t0 + f["time_s"], abs=2e-6)
        assert m.arbitration_id == f["arbitration_id"] and m.channel == f["bus"]
        assert m.is_extended_id == bool(f["flags"] & CAN_FLAG_EXTENDED)
        assert m.is_fd == bool(f["flags"] & CAN_FLAG_FD)
        assert m.is_rx == bool(f["flags"] & CAN_FLAG_RX)
        assert bytes(m.data) == bytes(f["data"][: f["dlc"]])


def test_round_trip_keeps_every_sample_dtype_unit_and_frame(rich_session, tmp_path):
    out = tmp_path / "drive.mf4"
    export_mdf(rich_session, out)
    back = tmp_path / "back.h5"
    import_file(out, back, metadata=SessionMetadata(notes="loaded"))
    assert_same_session(rich_session, back, raw=True)
    # the user's metadata wins where given
    again = tmp_path / "again.h5"
    import_mdf(out, again, metadata=SessionMetadata(vehicle="Corolla"))
    with SessionReader(again) as s:
        assert s.metadata.vehicle == "Corolla" and s.metadata.corner == "rear-left"


def test_timestamps_session_round_trip(tmp_path):
    path = tmp_path / "ts.h5"
    t = np.cumsum(np.random.default_rng(1).uniform(0.0019, 0.0021, 5000))
    with SessionWriter(path, SessionMetadata(), [ChannelSpec("body_z", role="body")],
                       sample_rate_hz=500.0, atomic=True) as w:
        w.append_daq(np.sin(t)[:, None], t)
    export_mdf(path, tmp_path / "ts.mf4")
    import_mdf(tmp_path / "ts.mf4", tmp_path / "back.h5")
    assert_same_session(path, tmp_path / "back.h5", raw=True)


def test_third_party_mdf_with_roles_and_units(tmp_path):
    """A logger's file: int16 counts with a linear conversion in g, a km/h speed at 10 Hz."""
    src = tmp_path / "logger.mf4"
    rng = np.random.default_rng(5)
    t = 12.0 + np.arange(20_000) / 1000.0  # the logger started its clock earlier
    counts = rng.integers(-4000, 4000, t.size).astype("i2")
    body = G + rng.normal(0, 0.3, t.size)
    ts = 12.05 + np.arange(200) / 10.0
    kmh = rng.uniform(20, 60, ts.size)
    with MDF(version="4.10") as mdf:
        mdf.append([Signal(counts, t, name="AccZ_FL_wheel", unit="g",
                           conversion={"a": 1 / 2048, "b": 0.0}),
                    Signal(body, t, name="AccZ_FL_body", unit="m/s^2"),
                    Signal(body * 0, t, name="Temp", unit="degC")], acq_name="ADC")
        mdf.append([Signal(kmh, ts, name="VehSpd", unit="km/h")], acq_name="GPS")
        mdf.save(src, overwrite=True)
    out = tmp_path / "s.h5"
    import_file(src, out, roles=["wheel=AccZ_FL_wheel", "body=AccZ_FL_body", "speed=VehSpd"])
    with SessionReader(out) as s:
        w = s.channel("wheel_z")
        assert (w.role, w.unit, w.dtype) == ("wheel", "m/s2", "int16")
        np.testing.assert_array_equal(s.read_raw("wheel_z"), counts)
        np.testing.assert_allclose(s.read("wheel_z"), counts / 2048 * G, rtol=1e-12)
        np.testing.assert_array_equal(s.read("body_z"), body)
        assert s.channel("body_z").unit == "m/s2" and s.channel("Temp").role == "other"
        np.testing.assert_allclose(s.time_s(), t - 12.0, atol=1e-12)
        ts_s, v = s.signal(s.signal_for_role("speed").name)
        np.testing.assert_allclose(ts_s, ts - 12.0, atol=1e-12)
        np.testing.assert_allclose(v, kmh / 3.6, rtol=1e-12)
        assert s.signal_spec("vehicle_speed").unit == "m/s"
        assert s.metadata.extra["source_time_of_first_sample_s"] == 12.0
    # without roles: the biggest group is the DAQ, the rest are signals
    plain = tmp_path / "plain.h5"
    import_mdf(src, plain)
    with SessionReader(plain) as s:
        assert [c.name for c in s.channels] == ["AccZ_FL_wheel", "AccZ_FL_body", "Temp"]
        assert s.channel("AccZ_FL_wheel").unit == "m/s2"
        assert [x.name for x in s.signals] == ["VehSpd"]
    with pytest.raises(ImportFormatError, match="no channel 'AccZ_FL_whee'.*AccZ_FL_wheel"):
        import_mdf(src, tmp_path / "x.h5", roles={"wheel": "AccZ_FL_whee"})
    with pytest.raises(ImportFormatError, match="different channel groups"):
        import_mdf(src, tmp_path / "x.h5", roles={"wheel": "AccZ_FL_wheel", "body": "VehSpd"})
    assert not (tmp_path / "x.h5").exists()


@pytest.mark.skipif(not LOG.is_file(), reason="real CAN log not available")
def test_bus_logging_from_python_can_decodes_like_the_can_log(tmp_path):
    """6000 real frames written as MF4 bus logging by python-can, decoded with the DBC."""
    import can

    from fielddiag.io.canlog import import_can_log

    msgs = list(itertools.islice(can.LogReader(str(LOG)), 6000))
    mf4 = tmp_path / "bus.mf4"
    with can.MF4Writer(str(mf4)) as w:
        for m in msgs:
            w.on_message_received(m)
    part = tmp_path / "part.log"
    with open(LOG) as fh, open(part, "w") as o:
        o.writelines(itertools.islice(fh, 6000))
    assert detect_format(mf4) == "mdf"
    with pytest.raises(ImportFormatError, match="only CAN bus logging; pass --dbc"):
        import_file(mf4, tmp_path / "x.h5")
    a, b = tmp_path / "mdf.h5", tmp_path / "log.h5"
    import_file(mf4, a, dbc=[str(PT_DBC)])
    import_can_log(part, b, dbc=[PT_DBC])
    with SessionReader(a) as x, SessionReader(b) as y:
        assert [s.name for s in x.signals] == [s.name for s in y.signals]
        assert x.signal_for_role("speed").name == "SPEED"
        for s in y.signals:
            tx, vx = x.signal(s.name)
            ty, vy = y.signal(s.name)
            assert x.signal_spec(s.name).unit == "m/s"
            np.testing.assert_array_equal(vx, vy)
            np.testing.assert_allclose(tx, ty, atol=2e-6)
        assert x.can_frames().size == 6000
        np.testing.assert_array_equal(x.can_frames()["data"], y.can_frames()["data"])
        assert x.metadata.t0_unix_s == pytest.approx(y.metadata.t0_unix_s, abs=2e-6)


def test_corrupt_and_wrong_files(rich_session, tmp_path):
    out = tmp_path / "drive.mf4"
    export_mdf(rich_session, out)
    cut = tmp_path / "cut.mf4"
    cut.write_bytes(out.read_bytes()[: out.stat().st_size // 3])
    with pytest.raises(ImportFormatError, match="cut.mf4"):
        import_file(cut, tmp_path / "x.h5")
    fake = tmp_path / "fake.mf4"
    fake.write_bytes(b"not an mdf file at all" * 10)
    with pytest.raises(ImportFormatError, match="fake.mf4: not an MDF file"):
        import_file(fake, tmp_path / "x.h5")
    with pytest.raises(ImportFormatError, match="--signal decodes CAN bus logging"):
        import_mdf(out, tmp_path / "x.h5", signals=["SPEED"])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cut.mf4", "drive.h5", "drive.mf4",
                                                           "fake.mf4"]
    with pytest.raises(SessionError, match="already exists"):
        export_mdf(rich_session, out)


def test_missing_asammdf_is_a_clear_error(monkeypatch, tmp_path, rich_session):
    """Simulated absence (asammdf is installed here): find_spec reports it missing."""
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "asammdf" else real(name, *a))
    with pytest.raises(FieldDiagError, match=r"pip install 'fielddiag\[mdf\]'"):
        export_mdf(rich_session, tmp_path / "x.mf4")
    src = tmp_path / "y.mf4"
    src.write_bytes(b"MDF     4.10    ")
    with pytest.raises(FieldDiagError, match=r"pip install 'fielddiag\[mdf\]'"):
        import_file(src, tmp_path / "y.h5")
