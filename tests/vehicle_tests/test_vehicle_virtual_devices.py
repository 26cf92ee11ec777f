"""The full-vehicle virtual devices a technician runs as separate processes:
``fielddiag virtual-daq --full-vehicle`` on a pseudo-terminal and ``fielddiag virtual-ecu
--full-vehicle`` on an emulated SLCAN adapter, started with the same seed, recorded by
``fielddiag record`` with the arguments their hints print, each its own process.

The session is checked against the drive :func:`fielddiag.virtual_streams.
full_vehicle_stream` simulates for that seed: the eight accelerometers sample for sample
(to the DAQ's rounding), the ECU's speed and accelerations in step with them. One
recording of 6 s (about 15 s with the devices' start-up).
"""

from __future__ import annotations

import json
import shlex
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fielddiag.cli import main
from fielddiag.commands._virtual_vehicle import write_vehicle_file
from fielddiag.errors import FieldDiagError
from fielddiag.session import SessionReader
from fielddiag.units import GRAVITY_MPS2
from fielddiag.vehicle import VehicleParams, read_vehicle_recording
from fielddiag.vehicle.corner_map import VIRTUAL_DAQ_MAP
from fielddiag.virtual_streams import full_vehicle_stream

SEED, DRIVE_S, RATE_HZ, RECORD_S = 3, 12.0, 500.0, 6.0
ADDED_MASS_KG, ADDED_AT_M = 100.0, (1.5, 0.25)
#: The options that make the two devices play one car and one drive.
SAME_DRIVE = [
    "--full-vehicle",
    "--seed",
    str(SEED),
    "--duration",
    f"{DRIVE_S:g}",
    "--added-mass",
    f"{ADDED_MASS_KG:g}",
    "--added-mass-at",
    "1.5,0.25",
]
#: The virtual ECU's SPEED: 0.01 km/h per bit.
SPEED_LSB_MPS = 0.01 / 3.6
#: The virtual ECU sends each acceleration as its mean over 10 ms (5 DAQ samples).
ACCEL_MEAN_SAMPLES = 5


def _fielddiag(*args: str) -> list[str]:
    return [sys.executable, "-m", "fielddiag.cli", *args]


def _start(*args: str) -> subprocess.Popen:
    return subprocess.Popen(
        _fielddiag(*args), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )


def _hint_words(proc: subprocess.Popen, starts: str) -> list[str]:
    """The first stderr line of ``proc`` that starts with ``starts``, split as a shell does."""
    seen = []
    for line in proc.stderr:
        if line.startswith(starts):
            return shlex.split(line)
        seen.append(line)
    raise AssertionError(f"no hint line starting with {starts!r}: {''.join(seen)}")


def _stop(proc: subprocess.Popen) -> str:
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=20)
    assert proc.returncode == 0, err
    return out


def _record_both(session: Path) -> tuple[dict, list[str]]:
    """Start the two devices, record them with the hinted arguments; the DAQ's account of
    what it did and the record command."""
    daq = _start("virtual-daq", *SAME_DRIVE)
    ecu = _start("virtual-ecu", *SAME_DRIVE)
    try:
        assert "VDAQ" in daq.stdout.readline() and "slcan" in ecu.stdout.readline()
        record = _hint_words(daq, "fielddiag record")
        can_args = _hint_words(ecu, "--can")
        assert record[-2:] == ["-o", "drive.h5"]
        command = [
            *record[2:-2],
            *can_args,
            "-o",
            str(session),
            "--duration",
            f"{RECORD_S:g}",
            "--quiet",
        ]
        proc = subprocess.run(
            _fielddiag("record", *command), capture_output=True, text=True, timeout=60
        )
        assert proc.returncode == 0, proc.stderr
        assert ", 0 lost, 0 CRC errors, 0 gaps" in proc.stderr, proc.stderr
    finally:
        daq_out = _stop(daq)
        _stop(ecu)
    return json.loads(daq_out.strip().splitlines()[-1]), command


def _best_lag(recorded: np.ndarray, simulated: np.ndarray, max_lag: int) -> tuple[int, float]:
    """The shift (samples) of ``simulated`` that correlates best with ``recorded``, and the
    correlation there."""
    core = recorded[max_lag : recorded.size - max_lag]
    corr = [
        np.corrcoef(core, simulated[max_lag + k : recorded.size - max_lag + k])[0, 1]
        for k in range(-max_lag, max_lag + 1)
    ]
    best = int(np.argmax(corr))
    return best - max_lag, float(corr[best])


def test_full_vehicle_virtual_daq_and_ecu_record_one_simulated_drive(tmp_path):
    session = tmp_path / "drive.h5"
    device, command = _record_both(session)
    # the hint's record command: the corner map in the stream's order, the vehicle file the
    # DAQ wrote, the added mass and where it sits
    roles = [command[i + 1] for i, w in enumerate(command) if w == "--role"]
    assert roles == [f"{r}={i}" for i, r in VIRTUAL_DAQ_MAP.items()]
    assert command[command.index("--added-mass-at") + 1] == "1.5,0.25"

    truth = full_vehicle_stream(
        drive_s=DRIVE_S,
        sample_rate_hz=RATE_HZ,
        added_mass_kg=ADDED_MASS_KG,
        seed=SEED,
        with_daq=True,
        added_mass_at_m=ADDED_AT_M,
    ).drive
    rec = read_vehicle_recording(session)
    with SessionReader(session) as s:
        channels, counters, meta = s.channels, s.counters, s.metadata
        signal_roles = {x.name: x.role for x in s.signals}
        wheel_speed = s.signal_on_daq_time("WHEEL_SPEED_FL")
    assert [(c.name, c.role) for c in channels] == [(r, r) for r in VIRTUAL_DAQ_MAP.values()]
    assert counters["frames_lost"] == 0 and counters["can_decode_errors"] == 0
    assert 0 <= device["frames_made"] - counters["frames_received"] <= 30  # before the stop
    # the session's vehicle metadata: the default car, the added mass and its position
    assert meta.vehicle == "virtual_car" and meta.extra["full_vehicle"] is True
    assert rec.geometry == VehicleParams().geometry == truth.geometry
    assert (rec.added_mass_kg, rec.added_mass_at_m) == (ADDED_MASS_KG, ADDED_AT_M)
    n = rec.n
    assert (RECORD_S - 0.1) * RATE_HZ <= n <= (RECORD_S + 0.15) * RATE_HZ
    # the accelerometers read gravity (up positive) and are the simulated drive's from its
    # first sample on, to the DAQ's rounding (int32 over the range the stream chose)
    assert rec.body_accel_mps2.mean(axis=1) == pytest.approx([GRAVITY_MPS2] * 4, abs=0.05)
    lsb = channels[0].scale
    for got, want in (
        (rec.wheel_accel_mps2, truth.wheel_accel_mps2),
        (rec.body_accel_mps2, truth.body_accel_mps2),
    ):
        assert np.abs(got - want[:, :n]).max() <= 0.5 * lsb * (1 + 1e-9)
    assert np.std(rec.wheel_accel_mps2) > 3 * np.std(rec.body_accel_mps2) > 0.3  # rough road

    # the ECU's signals under their roles, from the same drive
    assert signal_roles["vehicle_speed"] == "speed"
    assert (signal_roles["accel_long"], signal_roles["accel_lat"]) == ("accel_long", "accel_lat")
    assert np.abs(rec.speed_mps - truth.speed_mps[:n]).max() <= SPEED_LSB_MPS  # cruising
    assert np.abs(wheel_speed[100:] / truth.speed_mps[100:n] - 1).max() < 0.01
    # the accelerations are the drive's (noise included: 0.05 m/s^2), sent as 10 ms means
    # and in step with the DAQ: the ECU's drive starts when the recorder opens the bus
    other = full_vehicle_stream(
        drive_s=DRIVE_S, sample_rate_hz=RATE_HZ, added_mass_kg=0.0, seed=SEED + 1, with_daq=True
    )
    box = np.ones(ACCEL_MEAN_SAMPLES) / ACCEL_MEAN_SAMPLES
    for role, k in (("accel_long", 0), ("accel_lat", 1)):
        got = rec.signal_or_zero(role)
        lag, corr = _best_lag(got, np.convolve(truth.signal_or_zero(role), box, "same"), 100)
        assert abs(lag) <= 50 and corr > 0.6, (role, lag, corr)
        assert abs(got.mean() - truth.signal_or_zero(role)[:n].mean()) < 0.005
        assert abs(np.corrcoef(got, other.accel_mps2[k][:n])[0, 1]) < 0.15  # not any drive


def test_full_vehicle_virtual_devices_refuse_bad_options(tmp_path, capsys):
    proc = subprocess.run(
        _fielddiag("virtual-daq", "--full-vehicle", "--channels", "3"),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 1 and proc.stdout == ""
    assert "--channels is for the quarter car" in proc.stderr
    assert proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr
    for args, expect in (
        (["virtual-ecu", "--full-vehicle", "--speed-kmh", "50"], "--speed-kmh is a constant"),
        (["virtual-ecu", "--rate", "500"], "--rate is for --full-vehicle"),
        (
            ["virtual-daq", "--added-mass", "50", "--added-mass-at", "1,0"],
            "--added-mass-at is for --full-vehicle",
        ),
        (["virtual-ecu", "--full-vehicle", "--added-mass-at", "1,0"], "give --added-mass KG too"),
        (
            ["virtual-daq", "--write-vehicle-file", str(tmp_path / "car.json")],
            "--write-vehicle-file is for --full-vehicle",
        ),
        (
            ["virtual-daq", "--full-vehicle", "--duration", "12", "--full-scale-g", "2"],
            "--full-scale-g 2: the simulated hub accelerations need 16 g",
        ),
        (
            ["virtual-ecu", "--full-vehicle", "--added-mass", "80"],
            "80 kg added to a full vehicle: say where it sits",
        ),
    ):
        assert main(args) == 1, args
        err = capsys.readouterr().err
        assert expect in err and err.count("\n") == 1, err


def test_the_vehicle_file_is_written_once_and_never_replaced(tmp_path):
    geometry = VehicleParams().geometry
    path = write_vehicle_file(geometry, None, str(tmp_path))
    assert path == tmp_path / "virtual_car.json"
    assert json.loads(path.read_text()) == json.loads(geometry.to_json())
    assert write_vehicle_file(geometry, str(path), "unused") == path  # the same car: kept
    path.write_text('{"wheelbase_m": 2.0}')
    with pytest.raises(FieldDiagError, match="exists and holds something else"):
        write_vehicle_file(geometry, str(path), "unused")
    assert path.read_text() == '{"wheelbase_m": 2.0}'
