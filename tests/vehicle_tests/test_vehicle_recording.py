"""Recording a full vehicle: eight accelerometers on one DAQ (a real pseudo-terminal read by
the serial driver), speed and the car's accelerations on CAN (python-can's virtual bus,
decoded with the DBC), into a session ``read_vehicle_recording`` reads.

The recordings stream in real time: 6 s and 3 s, plus one DAQ handshake for the errors.
"""

from __future__ import annotations

import json
import signal
import uuid

import can
import numpy as np
import pytest
from _daq_helpers import SchedulingDelay

from drivers.virtual import (
    FULL_SCALE_RANGES_G,
    VIRTUAL_ECU_DBC,
    VirtualDAQ,
    VirtualECU,
    full_scale_for,
)
from fielddiag.channels import SessionMetadata
from fielddiag.cli import main
from fielddiag.session import SessionReader
from fielddiag.units import GRAVITY_MPS2
from fielddiag.vehicle import (
    VehicleParams,
    braking,
    is_full_vehicle_session,
    read_vehicle_recording,
    simulate_vehicle,
)
from fielddiag.vehicle.corner_map import VIRTUAL_DAQ_MAP, daq_columns, parse_channel_map
from fielddiag.virtual_drive import VirtualDrive

RATE_HZ = 500.0
#: Samples a recording of ``d`` seconds holds lie within (d - 0.1 s, d + 0.3 s) x rate: the
#: first frame arrives a frame (10 ms) after START and the driver batches 20 ms into a block,
#: and the stop comes up to one poll of the command (0.1 s) after the duration, later on a
#: loaded machine (6.16 s once, with the suite's diagnoses on both cores).
EARLY_S, LATE_S = 0.1, 0.3
#: The virtual ECU's SPEED: 41 Hz, 0.01 km/h per bit.
SPEED_PERIOD_S, SPEED_LSB_MPS = 1 / 41.0, 0.01 / 3.6


@pytest.fixture(autouse=True)
def _restore_signal_handlers():
    """``fielddiag record`` run in-process installs SIGINT/SIGTERM handlers; put them back."""
    saved = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    yield
    for s, h in saved.items():
        signal.signal(s, h)


def _braking_drive(seconds: float, seed: int, **kw):
    """The default car braking 1 s after the start (22 -> 6 m/s at about 5 m/s^2), then
    accelerating: steps of the longitudinal acceleration to check the CAN timing on."""
    return simulate_vehicle(VehicleParams(), manoeuvre=braking(seconds, seed, cruise_s=1.0),
                            duration_s=seconds, seed=seed, **kw)


def test_a_full_vehicle_virtual_drive_is_the_simulated_drive(tmp_path):
    drive = _braking_drive(8.0, 4, added_mass_kg=120.0, added_mass_at_m=(1.6, -0.2))
    path = tmp_path / "fv.h5"
    with SchedulingDelay() as delay:
        run = VirtualDrive(path, drive_s=8.0, drive=drive,
                           metadata=SessionMetadata(vehicle="virtual car")).start()
        run.record_for(6.0)
        run.stop_or_raise()
    assert is_full_vehicle_session(path)
    rec = read_vehicle_recording(path)
    with SessionReader(path) as s:
        channels, counters = s.channels, s.counters
        roles = {x.role: x.name for x in s.signals}
        extra = s.metadata.extra
    # the device announces wheel/body; the driver's channel map names the corners
    assert [(c.name, c.role) for c in channels] == [(r, r) for r in VIRTUAL_DAQ_MAP.values()]
    assert counters["frames_lost"] == 0 and counters["samples_lost"] == 0
    assert counters["crc_errors"] == 0 and counters["can_decode_errors"] == 0
    assert (roles["speed"], roles["accel_long"], roles["accel_lat"]) == (
        "vehicle_speed", "accel_long", "accel_lat")
    assert rec.geometry == drive.geometry and rec.added_mass_kg == 120.0
    assert rec.added_mass_at_m == (1.6, -0.2) and extra["full_vehicle"] is True
    assert {x["url"].split(":")[0] for x in extra["sources"]} == {"serial", "can"}
    n = rec.n
    assert (6.0 - EARLY_S) * RATE_HZ <= n <= (6.0 + LATE_S) * RATE_HZ
    # the range: the smallest with 25 % headroom over the largest reading (no clipping)
    lsb = channels[0].scale
    readings = np.vstack([drive.wheel_accel_mps2, drive.body_accel_mps2])
    assert lsb * 2**31 == pytest.approx(full_scale_for(readings), rel=1e-12)
    assert 1.25 * np.abs(readings).max() <= lsb * 2**31
    # every sample is the drive's reading from its first sample on, to the DAQ's rounding
    err = max(np.abs(rec.wheel_accel_mps2 - drive.wheel_accel_mps2[:, :n]).max(),
              np.abs(rec.body_accel_mps2 - drive.body_accel_mps2[:, :n]).max())
    assert err <= 0.5 * lsb * (1 + 1e-9)
    # CAN, played in step with the DAQ: speed sampled at 41 Hz and interpolated onto the DAQ
    # samples; piecewise linear, so off only near a change of acceleration da, by at most
    # da T / 4 (da <= 6 m/s^2, T = 1/41 s: 0.037 m/s), plus half an LSB and 2 ms of timing
    # and how late this machine woke a sending or reading thread meanwhile (a frame is
    # stamped when it arrives: 3 ms late once under four busy processes)
    dv = np.abs(rec.speed_mps - drive.speed_mps[:n])
    timing_s = 0.002 + delay.max_s
    assert dv.max() <= 6.0 * SPEED_PERIOD_S / 4 + SPEED_LSB_MPS / 2 + 6.0 * timing_s
    # accelerations: 100 Hz means over 10 ms, interpolated; over 0.5 s blocks they carry the
    # drive's (noise included) but for a step da moved across a block edge by at most half
    # a period plus the timing (5 + 5 ms): da * 10 ms / 0.5 s = 0.12 m/s^2
    k = n // 250
    for role in ("accel_long", "accel_lat"):
        blocks = [x[: k * 250].reshape(k, 250).mean(axis=1)
                  for x in (rec.signal_or_zero(role), drive.signal_or_zero(role)[:n])]
        assert np.abs(blocks[0] - blocks[1]).max() <= 6.0 * 0.010 / 0.5
    assert np.mean(drive.accel_long_mps2[750:2000]) < -4.0  # the drive did brake hard


def _write_vehicle_file(tmp_path, geometry) -> str:
    path = tmp_path / "car.json"
    path.write_text(geometry.to_json())
    return str(path)


def test_record_a_daq_with_a_corner_map_and_the_cars_signals_by_role(tmp_path):
    """``fielddiag record --daq URL --role ... --vehicle-file --can URL --signal ALIAS=...``
    on a 9-channel DAQ whose sensors are wired in another order than the virtual DAQ's,
    channel 4 unused; the ECU on a python-can virtual bus, decoded with a DBC file."""
    drive = _braking_drive(6.0, 5)
    order = ["body_rr", "wheel_fl", "body_fl", "wheel_rr", None, "wheel_rl", "body_fr",
             "wheel_fr", "body_rl"]
    cols = {r: daq_columns(drive.wheel_accel_mps2, drive.body_accel_mps2)[:, i]
            for i, r in VIRTUAL_DAQ_MAP.items()}
    noise = np.random.default_rng(0).normal(0.0, 0.1, drive.n)
    signals = np.column_stack([cols[r] if r else noise for r in order])
    daq = VirtualDAQ(signals, sample_rate_hz=RATE_HZ, roles=["other"] * 9, loop=False,
                     full_scale_mps2=full_scale_for(signals),
                     link_name=f"ttyVDAQ{uuid.uuid4().hex[:6]}").start()
    channel = f"fielddiag-test-{uuid.uuid4().hex[:8]}"
    bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    ecu = VirtualECU(bus, drive.time_s, drive.speed_mps,
                     accel_mps2=(drive.accel_long_mps2, drive.accel_lat_mps2),
                     time_fn=lambda: daq.data_time_s() or 0.0).start()
    dbc = tmp_path / "vecu.dbc"
    dbc.write_text(VIRTUAL_ECU_DBC)
    out = tmp_path / "after.h5"
    try:
        rc = main(["record", "--daq", f"serial://{daq.path}", "--vehicle-file",
                   _write_vehicle_file(tmp_path, drive.geometry),
                   *[a for i, r in enumerate(order) if r for a in ("--role", f"{r}={i}")],
                   "--can", f"can://virtual/{channel}?dbc={dbc}",
                   "--signal", "vehicle_speed=SPEED.SPEED",
                   "--signal", "accel_long=KINEMATICS.ACCEL_X",
                   "--signal", "accel_lat=KINEMATICS.ACCEL_Y",
                   "--added-mass", "150", "--added-mass-at", "1.9,0.3",
                   "-o", str(out), "--duration", "3", "--quiet"])
    finally:
        ecu.stop()
        bus.shutdown()
        daq.stop()
    assert rc == 0
    rec = read_vehicle_recording(out)
    with SessionReader(out) as s:
        assert [c.role for c in s.channels] == [r or "other" for r in order]
        assert s.channels[4].name == "ch4" and s.counters["frames_lost"] == 0
        assert s.metadata.vehicle == "car" and s.metadata.added_mass_kg == 150.0
    assert rec.added_mass_at_m == (1.9, 0.3) and rec.geometry == drive.geometry
    n = rec.n
    assert (3.0 - EARLY_S) * RATE_HZ <= n <= (3.0 + LATE_S) * RATE_HZ
    lsb = full_scale_for(signals) / 2**31
    assert np.abs(rec.wheel_accel_mps2 - drive.wheel_accel_mps2[:, :n]).max() <= 0.5 * lsb * (
        1 + 1e-9)
    assert np.abs(rec.body_accel_mps2 - drive.body_accel_mps2[:, :n]).max() <= 0.5 * lsb * (
        1 + 1e-9)
    # the signals decoded under their roles: the car's speed (22 m/s before braking) and its
    # accelerations (about 0 while cruising, braking from 1 s on)
    assert rec.speed_mps[:400] == pytest.approx(22.0, abs=0.01)
    assert np.mean(rec.accel_long_mps2[:400]) == pytest.approx(0.0, abs=0.02)
    assert np.mean(rec.accel_long_mps2[750:1400]) < -4.0
    assert np.std(rec.accel_lat_mps2) < 0.06  # noise of 0.05 m/s^2, no steering


def test_record_virtual_full_vehicle_on_the_command_line(tmp_path, capsys):
    path = tmp_path / "virtual.h5"
    rc = main(["record", "--virtual", "--full-vehicle", "--added-mass", "100",
               "--added-mass-at", "1.5,0.25", "--seed", "3", "-o", str(path),
               "--duration", "3", "--quiet"])
    assert rc == 0
    assert ", 0 lost," in capsys.readouterr().err
    rec = read_vehicle_recording(path)
    truth = simulate_vehicle(VehicleParams(), duration_s=5.0, seed=3, added_mass_kg=100.0,
                             added_mass_at_m=(1.5, 0.25))
    assert (rec.added_mass_kg, rec.added_mass_at_m) == (100.0, (1.5, 0.25))
    assert rec.geometry == VehicleParams().geometry
    n = rec.n
    assert (3.0 - EARLY_S) * RATE_HZ <= n <= (3.0 + LATE_S) * RATE_HZ
    with SessionReader(path) as s:
        lsb = s.channels[0].scale
        sim = s.metadata.extra["simulation"]
    assert sim["seed"] == 3 and sim["manoeuvre"] == "rough_road"
    assert np.abs(rec.body_accel_mps2 - truth.body_accel_mps2[:, :n]).max() <= 0.5 * lsb * (
        1 + 1e-9)
    assert rec.speed_mps is not None and rec.accel_long_mps2 is not None


@pytest.fixture
def daq8():
    """An 8-channel virtual DAQ (for the errors found when the device tells its channels)."""
    dev = VirtualDAQ(np.zeros((1000, 8)), sample_rate_hz=RATE_HZ,
                     link_name=f"ttyVDAQ{uuid.uuid4().hex[:6]}").start()
    yield dev
    dev.stop()


_MAP = [a for i, r in VIRTUAL_DAQ_MAP.items() for a in ("--role", f"{r}={i}")]


@pytest.mark.parametrize("args, expect", [
    (["--role", "whel_rl=0"], "--role whel_rl: unknown role; did you mean wheel_rl?"),
    (["--role", "wheel_fl"], "--role 'wheel_fl': write it as ROLE=CHANNEL"),
    (["--role", "wheel_fl=left"], "the channel is the DAQ channel number"),
    (_MAP[:-2], "needs all eight corner sensors; missing body_rr"),
    ([*_MAP[:-2], "--role", "wheel_fl=7"], "--role wheel_fl is given twice"),
    ([*_MAP[:-2], "--role", "body_rr=0"], "channel 0 is mapped twice (wheel_fl and body_rr)"),
    ([*_MAP, "--role", "wheel=8"], "--role wheel is a single-corner role"),
    (["--role", "speed=3"], "speed is a CAN signal, not a DAQ channel; give it with "
                            "--signal vehicle_speed=MESSAGE.SIGNAL"),
    (_MAP, "needs the vehicle file: give --vehicle-file"),
    ([*_MAP, "--vehicle-file", "{BAD_JSON}"], "bad.json is not valid JSON"),
    ([*_MAP, "--vehicle-file", "{NO_TRACK}"], "missing ['track_rear_m']"),
    ([*_MAP, "--vehicle-file", "{CAR}", "--added-mass", "150"],
     "--added-mass 150 on a full vehicle: say where it sits with --added-mass-at"),
    (["--vehicle-file", "{CAR}"], "--vehicle-file is for a full-vehicle recording"),
    (["--added-mass", "50", "--added-mass-at", "1,0"],
     "--added-mass-at is for a full-vehicle recording"),
    ([*_MAP, "--vehicle-file", "{CAR}", "--added-mass-at", "1,0"],
     "--added-mass-at says where the added mass sits: give --added-mass KG too"),
    ([*_MAP[:-2], "--role", "body_rr=8", "--vehicle-file", "{CAR}"],
     "channel 8 (body_rr) is not on the device: it has 8 channels, numbered 0 to 7"),
])
def test_corner_map_errors_are_one_line(tmp_path, capsys, daq8, args, expect):
    car = _write_vehicle_file(tmp_path, VehicleParams().geometry)
    bad = tmp_path / "bad.json"
    bad.write_text("{wheelbase_m: 2.7")
    no_track = tmp_path / "no_track.json"
    d = json.loads(VehicleParams().geometry.to_json())
    del d["track_rear_m"]
    no_track.write_text(json.dumps(d))
    subs = {"{CAR}": car, "{BAD_JSON}": str(bad), "{NO_TRACK}": str(no_track)}
    out = tmp_path / "s.h5"
    rc = main(["record", "--daq", f"serial://{daq8.path}", *[subs.get(a, a) for a in args],
               "-o", str(out), "--duration", "1", "--quiet"])
    err = capsys.readouterr().err
    assert rc == 1 and expect in err, err
    assert err.count("\n") == 1 and "Traceback" not in err and not out.exists()


def test_virtual_full_vehicle_errors(tmp_path, capsys):
    for args, expect in (
            (["--full-vehicle", "--added-mass", "80"], "--added-mass 80 on a full vehicle"),
            (["--full-vehicle", "--role", "wheel_fl=0"], "--virtual records the virtual DAQ "
                                                         "with its own channels")):
        rc = main(["record", "--virtual", *args, "-o", str(tmp_path / "v.h5"),
                   "--duration", "1"])
        err = capsys.readouterr().err
        assert rc == 1 and expect in err and err.count("\n") == 1
    rc = main(["record", "--full-vehicle", "--daq", "serial:///dev/null", "-o",
               str(tmp_path / "v.h5")])
    assert rc == 1 and "--full-vehicle is for --virtual" in capsys.readouterr().err


def test_full_scale_and_channel_map_helpers():
    g = GRAVITY_MPS2
    # 25 % headroom: 6.3 g fits 8 g, 6.5 g needs 16 g; beyond 128 g nothing fits
    assert full_scale_for(np.array([0.5, -6.3 * g])) == 8 * g
    assert full_scale_for(np.array([6.5 * g])) == 16 * g
    with pytest.raises(ValueError, match="exceed the largest range"):
        full_scale_for(np.array([FULL_SCALE_RANGES_G[-1] * g]))
    assert parse_channel_map(["wheel=ch3", "body=CH0"]) == {0: "body", 3: "wheel"}
    wheel, body = np.arange(8.0).reshape(2, 4, 1)
    assert daq_columns(wheel, body)[0].tolist() == [0, 4, 1, 5, 2, 6, 3, 7]


def test_a_drive_with_gaps_is_read_as_its_longest_gap_free_stretch_and_says_so(tmp_path):
    """Frames lost while recording (a starved host, a cable pulled for a moment) leave gaps
    in the time base; the whole-car analysis needs every corner without a jump in time, so
    it keeps the longest gap-free stretch and tells the user which, rather than refusing the
    drive."""
    from fielddiag.channels import ChannelSpec, Gap, SessionMetadata, SignalSpec
    from fielddiag.errors import InsufficientDataError
    from fielddiag.session import write_session
    from fielddiag.vehicle.identify import VehicleIdentifyConfig, prepare_drive
    from fielddiag.vehicle.recording import SIGNAL_NAMES, full_vehicle_extra

    drive = simulate_vehicle(VehicleParams(), duration_s=12.0, seed=8)
    n, fs = drive.n, drive.sample_rate_hz
    # two gaps: 0.2 s lost at 3 s, 0.1 s at 4 s; the longest stretch is from 4.1 s on
    keep = np.ones(n, bool)
    keep[int(3.0 * fs):int(3.2 * fs)] = False
    keep[int(4.0 * fs):int(4.1 * fs)] = False
    t = drive.time_s[keep]
    samples = np.vstack([drive.wheel_accel_mps2, drive.body_accel_mps2]).T[keep]
    channels = [ChannelSpec(f"{k}_{c}", unit="m/s2", role=f"{k}_{c}")
                for k in ("wheel", "body") for c in ("fl", "fr", "rl", "rr")]
    signals = {SignalSpec(SIGNAL_NAMES["speed"], unit="m/s", role="speed"):
               (drive.time_s, drive.speed_mps)}
    path = write_session(
        tmp_path / "gappy.h5", SessionMetadata(extra=full_vehicle_extra(drive.geometry)),
        channels, samples, sample_rate_hz=fs, time_s=t,
        signals=signals, gaps=[Gap(3.0, 3.2, int(0.2 * fs), "frames lost"),
                               Gap(4.0, 4.1, int(0.1 * fs), "frames lost")])
    rec = read_vehicle_recording(path)
    start = int(4.1 * fs)
    assert rec.n == n - start
    np.testing.assert_allclose(rec.wheel_accel_mps2, drive.wheel_accel_mps2[:, start:],
                               rtol=0, atol=1e-9)
    np.testing.assert_allclose(rec.body_accel_mps2, drive.body_accel_mps2[:, start:],
                               rtol=0, atol=1e-9)
    np.testing.assert_allclose(rec.speed_mps, drive.speed_mps[start:], rtol=0, atol=1e-6)
    assert rec.sample_rate_hz == pytest.approx(fs, rel=1e-9)
    assert rec.start_s == pytest.approx(4.1, abs=1e-9)  # times told count from the session start
    (note,) = rec.notes
    assert note == ("gappy.h5 has 2 gaps in its time base; the whole-car analysis uses its "
                    "longest gap-free stretch, 4.1-12.0 s (68 % of the samples)")
    # too short once cut: the refusal says why the drive is shorter than recorded
    with pytest.raises(InsufficientDataError, match=r"gappy.h5 lasts 7.9 s \(gappy.h5 has 2 gap"):
        prepare_drive(rec, VehicleIdentifyConfig())
