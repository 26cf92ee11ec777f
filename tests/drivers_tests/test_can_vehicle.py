"""CAN driver: the real RAV4 log and DBC, other log formats, live python-can buses."""

from __future__ import annotations

import csv
import subprocess
import sys
import time
import uuid

import can
import numpy as np
import pytest
from _real_data import shared_data

from drivers import open_source
from drivers.base import SessionClock
from drivers.can_decode import load_dbc, resolve_signals
from drivers.can_vehicle import CanBusSource, decode_stored_frames, read_can_log
from drivers.virtual import VirtualECU
from fielddiag.channels import SessionMetadata
from fielddiag.errors import DbcError, DeviceError
from fielddiag.recorder import Recorder
from fielddiag.session import SessionReader

DATA = shared_data()
LOG = DATA / "can" / "comma2k19_rav4_2018-08-02_seg40.log"
DBC = DATA / "can" / "toyota_new_mc_pt_generated.dbc"
ADAS_DBC = DATA / "can" / "toyota_adas.dbc"
SPEED_CSV = DATA / "vehicle_imu" / "comma2k19_rav4_seg40_can_speed.csv"
KMH = 1 / 3.6

pytestmark = pytest.mark.skipif(not LOG.exists(), reason=f"real CAN data not found at {LOG}")


@pytest.fixture(scope="module")
def rav4():
    return read_can_log(
        LOG,
        DBC,
        ["vehicle_speed=SPEED.SPEED", "WHEEL_SPEED_FL", "WHEEL_SPEED_RR"],
        decode_channel="can0",
    )


def test_real_log_decodes_to_plausible_speeds(rav4):
    frames, sig, specs, errors = rav4
    assert errors == 0
    # every frame kept: 53,800 on the powertrain bus (can0), 45,000 on the radar bus (can1)
    assert len(frames) == 98_800
    assert np.bincount(frames["bus"]).tolist() == [53_800, 45_000]
    spec = {s.name: s for s in specs}
    assert spec["vehicle_speed"].role == "speed" and spec["vehicle_speed"].unit == "m/s"
    assert spec["WHEEL_SPEED_FL"].message == "WHEEL_SPEEDS"
    t, v = sig["vehicle_speed"]
    assert len(v) == 2487  # SPEED at 41 Hz for 60 s
    # the README's range of the decoded SPEED (0.01 km/h resolution)
    assert v.min() == pytest.approx(29.38 * KMH, abs=1e-6)
    assert v.max() == pytest.approx(73.05 * KMH, abs=1e-6)
    # its speed profile (README): 29 km/h at 0 s, 73 at 10 s, 51 at 35 s, 66 at 50 s
    for t_s, kmh in ((0.0, 29), (10, 73), (35, 51), (50, 66)):
        assert np.interp(t_s, t, v) / KMH == pytest.approx(kmh, abs=1.5)
    # a car does not jump: over any second the speed changes by less than 0.5 g * 1 s
    grid = np.arange(0.0, 60.0, 0.5)
    assert np.max(np.abs(np.interp(grid + 1.0, t, v) - np.interp(grid, t, v))) < 4.9
    # wheel speeds agree with the vehicle speed; speedometers read a few % high, never low
    tw, fl = sig["WHEEL_SPEED_FL"]
    ratio = np.interp(tw, t, v) / fl
    assert 1.0 < np.median(ratio) < 1.04 and np.all(np.abs(ratio - 1) < 0.06)


def test_wheel_speeds_match_comma_processed_values(rav4):
    """Independent check: comma2k19's own processed wheel speeds for the same frames."""
    _, sig, _, _ = rav4
    with open(SPEED_CSV) as fh:
        rows = list(csv.DictReader(fh))
    fl = np.array([float(r["wheel_fl_mps"]) for r in rows])
    rr = np.array([float(r["wheel_rr_mps"]) for r in rows])
    assert np.max(np.abs(sig["WHEEL_SPEED_FL"][1] - fl)) < 1e-5  # CSV has 6 decimals
    assert np.max(np.abs(sig["WHEEL_SPEED_RR"][1] - rr)) < 1e-5


@pytest.mark.parametrize("suffix", [".asc", ".blf", ".trc", ".csv"])
def test_other_log_formats_read_the_same(tmp_path, suffix):
    msgs = [m for _, m in zip(range(3000), can.LogReader(str(LOG)), strict=False)]
    path = tmp_path / f"excerpt{suffix}"
    with can.Logger(str(path)) as out:
        for m in msgs:
            out.on_message_received(m)
    frames, sig, _, errors = read_can_log(path, DBC, ["SPEED.SPEED"])
    ref, ref_sig, _, _ = read_can_log(LOG, DBC, ["SPEED.SPEED"])
    ref = ref[:3000]
    assert errors == 0 and len(frames) == 3000
    assert np.array_equal(frames["arbitration_id"], ref["arbitration_id"])
    assert np.array_equal(frames["data"][:, :8], ref["data"][:, :8])
    # time stamps relative to the first frame, to the format's resolution
    assert np.max(np.abs(frames["time_s"] - ref["time_s"])) < 2e-4
    n = len(sig["SPEED"][1])
    assert n > 0 and np.array_equal(sig["SPEED"][1], ref_sig["SPEED"][1][:n])


def test_signal_names_are_checked():
    db = load_dbc(DBC)
    (r,) = resolve_signals(db, ["speed_kmh=SPEED.SPEED"])
    assert (r.name, r.message.name, r.signal.name) == ("speed_kmh", "SPEED", "SPEED")
    with pytest.raises(DbcError, match="signal 'SPEEED' is not in the DBC; did you mean SPEED"):
        resolve_signals(db, ["SPEEED"])
    with pytest.raises(DbcError, match="in several messages"):
        resolve_signals(db, ["CHECKSUM"])
    with pytest.raises(DbcError, match="no signal 'X'"):
        resolve_signals(db, ["SPEED.X"])
    with pytest.raises(DbcError, match="named twice"):
        resolve_signals(db, ["a=SPEED.SPEED", "a=WHEEL_SPEEDS.WHEEL_SPEED_FL"])
    with pytest.raises(DbcError, match="DBC file /nonexistent.dbc not found"):
        load_dbc("/nonexistent.dbc")
    with pytest.raises(DeviceError, match="need a DBC"):
        open_source(f"canlog://{LOG}?signal=SPEED").open()


def test_live_virtual_bus_through_notifier():
    channel = f"test-{uuid.uuid4().hex[:8]}"
    tx = can.Bus(interface="virtual", channel=channel)
    sent: list[can.Message] = []
    ecu = VirtualECU(tx, np.array([0.0, 3.0]), np.array([10.0, 30.0]), dbc=DBC, on_send=sent.append)
    src = open_source(
        f"can://virtual/{channel}?dbc={DBC}&signal=vehicle_speed=SPEED.SPEED"
        "&signal=WHEEL_SPEED_FL&bus=2"
    )
    assert isinstance(src, CanBusSource)
    src.open()
    clock = SessionClock()
    src.start(clock)
    ecu.start()
    blocks = []
    end = time.monotonic() + 2.5
    while time.monotonic() < end:
        b = src.read(0.1)
        if b is not None:
            blocks.append(b)
    ecu.stop()
    time.sleep(0.2)
    while (b := src.read(0.05)) is not None:
        blocks.append(b)
    src.close()
    tx.shutdown()
    frames = np.concatenate([b.can_frames for b in blocks])
    assert len(frames) == len(sent) == src.counters()["can_frames_received"]
    assert np.all(frames["bus"] == 2)
    assert frames["arbitration_id"].tolist() == [m.arbitration_id for m in sent]
    assert all(bytes(f["data"][:8]) == bytes(m.data) for f, m in zip(frames, sent, strict=True))
    t = np.concatenate(
        [b.signals["vehicle_speed"][0] for b in blocks if "vehicle_speed" in b.signals]
    )
    v = np.concatenate(
        [b.signals["vehicle_speed"][1] for b in blocks if "vehicle_speed" in b.signals]
    )
    speed_db = load_dbc(DBC).get_message_by_name("SPEED")
    truth = [speed_db.decode(m.data)["SPEED"] * KMH for m in sent if m.arbitration_id == 0xB4]
    assert np.allclose(v, truth, atol=1e-9)
    # the ECU's ramp, 10 m/s + 20/3 m/s per second, sent at 41 Hz, on session time
    assert len(v) == pytest.approx(2.5 * 41, abs=6)
    slope, v0 = np.polyfit(t - t[0], v, 1)
    assert slope == pytest.approx(20.0 / 3.0, rel=0.05) and v0 == pytest.approx(10.0, abs=0.2)
    assert np.all(np.diff(t) > 0) and -0.1 < t[0] < 0.5


def test_virtual_ecu_in_another_process_over_slcan(tmp_path):
    proc = subprocess.Popen(
        [sys.executable, "-m", "fielddiag.cli", "virtual-ecu", "--speed-kmh", "54"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        url = proc.stdout.readline().strip()
        assert url.startswith("can://slcan//")
        src = open_source(url + "&signal=vehicle_speed=SPEED.SPEED")
        src.open()
        src.start(SessionClock())
        vals = []
        end = time.monotonic() + 1.5
        while time.monotonic() < end:
            b = src.read(0.1)
            if b is not None and b.signals:
                vals.append(b.signals["vehicle_speed"][1])
        src.close()
    finally:
        proc.terminate()
        proc.wait(10)
    v = np.concatenate(vals)
    assert len(v) == pytest.approx(1.5 * 41, abs=12)
    assert np.allclose(v, 54.0 * KMH, atol=0.01 * KMH)
    assert proc.returncode == 0


def test_recorded_frames_decode_again_with_another_dbc(tmp_path, rav4):
    path = tmp_path / "can_only.h5"
    src = open_source(f"canlog://{LOG}?rate=0&dbc={DBC}&signal=SPEED.SPEED&decode_channel=can0")
    rec = Recorder(path, [src], metadata=SessionMetadata(vehicle="RAV4"))
    rec.start()
    rec.wait(30.0)
    rec.stop()
    with SessionReader(path) as s:
        frames = s.can_frames()
        t, v = s.signal("SPEED")
        assert s.signal_spec("SPEED").role == "speed"
        assert s.counters["can_frames_received"] == 98_800
        assert "can0 -> 0" in s.metadata.extra["sources"][0]["bus_rule"]
    assert len(frames) == 98_800
    assert np.bincount(frames["bus"]).tolist() == [53_800, 45_000]
    ref_frames, ref_sig, _, _ = rav4
    assert np.array_equal(frames["data"], ref_frames["data"])
    assert np.array_equal(v, ref_sig["vehicle_speed"][1])
    # decode the stored raw frames later, with other signals
    specs, sig, errors = decode_stored_frames(
        frames, DBC, ["WHEEL_SPEED_RR", "yaw=KINEMATICS.YAW_RATE"], decode_channel=0
    )
    assert errors == 0
    assert np.array_equal(sig["WHEEL_SPEED_RR"][1], ref_sig["WHEEL_SPEED_RR"][1])
    yaw = np.degrees(sig["yaw"][1])
    assert {s.name: s.unit for s in specs}["yaw"] == "rad/s"  # stored in SI, as imported
    assert yaw.min() == pytest.approx(-2.27, abs=0.02) and yaw.max() == pytest.approx(
        0.42, abs=0.02
    )
    _check_radar_bus_decodes_with_the_adas_dbc(frames)


def _check_radar_bus_decodes_with_the_adas_dbc(frames: np.ndarray) -> None:
    """The stored frames of bus 1 (the radar bus) decoded with a DBC that was not used
    while recording: the status message and the 16 radar tracks, none failing."""
    tracks = range(16)
    wanted = ["STATUS_MSG.RADAR_STATUS"] + [
        f"{q}{k}=TRACK_A_{k}.{sig}"
        for k in tracks
        for q, sig in (
            ("dist", "LONG_DIST"),
            ("lat", "LAT_DIST"),
            ("rel", "REL_SPEED"),
            ("valid", "VALID"),
            ("count", "COUNTER"),
        )
    ]
    specs, sig, errors = decode_stored_frames(frames, ADAS_DBC, wanted, decode_channel=1)
    assert errors == 0
    units = {s.name: s.unit for s in specs}
    assert (units["dist0"], units["lat0"], units["rel0"]) == ("m", "m", "m/s")
    # message counts: STATUS_MSG (0x123) at 10 Hz, every TRACK_A_k (0x210 + k) at 20 Hz
    assert len(sig["RADAR_STATUS"][1]) == 600 and set(sig["RADAR_STATUS"][1]) == {1.0}
    for k in tracks:
        count = sig[f"count{k}"][1]
        assert len(count) == 1200
        # each track's rolling counter steps by exactly one: no frame lost, reordered
        # or decoded from the wrong bytes
        assert np.all(np.diff(count) % 256 == 1)
        t = sig[f"count{k}"][0]
        # the whole minute of the log, in order (where it starts on the session clock
        # depends on when the recorder started: a few ms, more on a busy machine)
        assert t[0] < 0.5 and t[-1] - t[0] > 59.8 and np.all(np.diff(t) > 0)
    # plausible radar targets: the tracks flagged valid, within the sensor's range
    valid = np.concatenate([sig[f"valid{k}"][1] == 1 for k in tracks])
    dist, lat, rel = (
        np.concatenate([sig[f"{q}{k}"][1] for k in tracks])[valid] for q in ("dist", "lat", "rel")
    )
    assert valid.sum() == 10_100
    assert dist.min() == pytest.approx(6.88, abs=1e-9) and dist.max() == pytest.approx(
        181.61, abs=1e-9
    )
    assert lat.min() == pytest.approx(-7.16, abs=1e-9) and lat.max() == pytest.approx(
        6.84, abs=1e-9
    )
    assert rel.min() == pytest.approx(-19.85, abs=1e-9) and rel.max() == pytest.approx(
        10.225, abs=1e-9
    )
    # the radar messages are not on the powertrain bus
    assert decode_stored_frames(frames, ADAS_DBC, wanted, decode_channel=0)[1:] == ({}, 0)
