"""The virtual-drive harness: virtual DAQ on a real pty + virtual ECU on python-can's
virtual bus, read by the real drivers into a real session (fielddiag demo and the
dashboard's live page both record through it).

Every test streams for a few seconds in real time.
"""

from __future__ import annotations

import io
import os
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from drivers.virtual import simulated_accelerations, to_counts
from fielddiag.channels import SessionMetadata
from fielddiag.console import StatusPrinter, format_status
from fielddiag.errors import DeviceError, FieldDiagError
from fielddiag.session import SessionReader
from fielddiag.virtual_drive import VirtualDrive, record_virtual_drive

FULL_SCALE_MPS2 = 16 * 9.80665  # the virtual DAQ's full scale (int32 counts)


def _raw(s: SessionReader) -> np.ndarray:
    return np.column_stack([s.read_raw(c.name) for c in s.channels])


def test_record_virtual_drive_is_the_simulated_drive(tmp_path):
    path = tmp_path / "after.h5"
    statuses = []
    out = record_virtual_drive(
        path,
        duration_s=3.0,
        added_mass_kg=50.0,
        seed=7,
        vehicle="demo car",
        corner="rear-left",
        rate_hz=500.0,
        progress=statuses.append,
    )
    assert out == path and statuses and statuses[-1]["state"] == "stopped"
    signals, drive = simulated_accelerations(
        5.0, sample_rate_hz=500.0, n_channels=2, added_mass_kg=50.0, seed=7
    )
    counts = to_counts(signals, 16 * 9.80665, 2)
    with SessionReader(path) as s:
        md = s.metadata
        assert (md.vehicle, md.corner, md.added_mass_kg) == ("demo car", "rear-left", 50.0)
        assert md.extra["simulation"]["added_mass_kg"] == 50.0
        assert [(c.name, c.role) for c in s.channels] == [("wheel_z", "wheel"), ("body_z", "body")]
        raw = _raw(s)
        assert s.counters["frames_lost"] == 0 and 2.5 * 500 < len(raw) <= 3.2 * 500
        # the device streams the drive from its first sample on: the session holds it exactly
        assert np.array_equal(raw, counts[: len(raw)])
        # the body sensor reads g on average (the car stands on its springs)
        assert np.mean(s.read_role("body")) == pytest.approx(9.80665, abs=0.05)
        t_v, v = s.signal(s.signal_for_role("speed").name)
        # CAN speed = the simulated speed at the same session time (ECU started with the DAQ)
        truth = np.interp(t_v, drive.vehicle_speed_time_s, drive.vehicle_speed_mps)
        assert np.max(np.abs(v - truth)) < 0.3
        assert {x.name for x in s.signals} >= {"vehicle_speed", "WHEEL_SPEED_FL"}
    assert os.path.getsize(path) > 0


def test_live_status_shows_the_online_estimate_and_the_whole_advice(tmp_path):
    """A virtual drive with the on-line estimator attached: the status holds estimates,
    information bits and advice, and the console shows them, the advice never cut."""
    statuses = []
    record_virtual_drive(tmp_path / "online.h5", duration_s=5.0, seed=3, online=True,
                         progress=statuses.append)
    online = statuses[-1]["online"]
    assert online["updates"] > 1000  # the estimator saw the drive (500 Hz, 2 s to settle)
    params = {p["label"]: p for p in online["parameters"]}
    assert set(params) == {"stiffness", "damping"}
    # default car: K2 = 24 kN/m, C2 = 1.8 kN s/m on 380 kg
    assert params["stiffness"]["value"] == pytest.approx(24e3 / 380, rel=0.05)
    assert params["damping"]["value"] == pytest.approx(1800 / 380, rel=0.10)
    for p in params.values():
        assert p["information_bits"] > 3.0  # prior std 100 %: 3 bits = ±12 %
        assert p["rel_std_pct"] == pytest.approx(100 * p["std"] / abs(p["value"]))
    advice = online["advice"]
    assert isinstance(advice, str) and len(advice) > 20
    # a log: one full line per update with the estimates and the whole advice
    log = io.StringIO()
    StatusPrinter(log, terminal=False).show(statuses[-1])
    line = log.getvalue()
    assert line.count("\n") == 1 and line.startswith(format_status(statuses[-1]))
    assert line.rstrip("\n").endswith("advice: " + advice)
    k = params["stiffness"]
    assert (f"stiffness {k['value']:.3g} N/m/kg" in line
            and f"{k['information_bits']:.1f} bit" in line)
    # a narrow terminal: redrawn in place, wrapped (never wider than the screen), all there
    term = io.StringIO()
    printer = StatusPrinter(term, terminal=True, width=60)
    printer.show(statuses[-2])
    printer.show(statuses[-1])
    printer.finish()
    first, second = term.getvalue().split("\r")[1:]
    rows = second.removeprefix(f"\x1b[{first.count(chr(10))}A\x1b[J").rstrip("\n").split("\n")
    assert max(len(r) for r in rows) <= 59
    assert " ".join(r.strip() for r in rows).endswith("advice: " + advice)


def test_a_pulled_cable_and_a_corrupting_link_lose_nothing_received(tmp_path):
    """1e-3 byte corruption and a 1 s pulled cable: every frame the host received whole is
    stored bit for bit, in order; every frame missing is counted as lost, the corrupted
    ones among them; the recording goes on after the cable is back."""
    path = tmp_path / "faulty.h5"
    statuses: list[dict] = []
    run = VirtualDrive(path, drive_s=8.0, seed=5, sample_rate_hz=500.0,
                       metadata=SessionMetadata(vehicle="faulty car"),
                       faults={"corrupt_rate": 1e-3, "disconnect_at_s": 1.0,
                               "disconnect_for_s": 1.0}).start()
    final = run.record_for(4.5, progress=statuses.append)
    assert run.error is None and final["state"] == "stopped"
    assert any(not st["connected"] for st in statuses)  # the outage was seen live
    dev = run.daq_device
    n = dev.samples_per_frame
    frame_of = {dev.truth(q).tobytes(): q for q in range(dev.seq + 1)}
    with SessionReader(path) as s:
        raw = _raw(s)
        counters = s.counters
        labels = [e.label for e in s.events]
        lost_in_gaps = sum(g.samples_lost for g in s.gaps)
    assert raw.shape[0] % n == 0
    seqs = [frame_of.get(raw[i:i + n].tobytes()) for i in range(0, raw.shape[0], n)]
    assert None not in seqs and np.all(np.diff(seqs) > 0)  # stored bit for bit, in order
    missing = set(range(seqs[0], seqs[-1] + 1)) - set(seqs)
    assert counters["frames_received"] == len(seqs)
    assert counters["frames_lost"] == len(missing) >= 1.0 * 500.0 / n  # the outage: 1 s
    assert counters["samples_lost"] == lost_in_gaps == len(missing) * n
    damaged = {q for q in dev.stats.corrupted_seqs if seqs[0] <= q <= seqs[-1]}
    assert damaged and damaged <= missing
    assert counters["reconnects"] == 1
    assert "DAQ disconnected" in labels and any("reconnected" in x for x in labels)
    # the recording went on after the outage (1 s to 2 s): frames up to the end
    assert (seqs[-1] - seqs[0] + 1) * n / 500.0 > 4.0
    # 4.5 s of data were asked for: the outage made the recording longer, not shorter
    assert raw.shape[0] >= 4.5 * 500.0 and final["elapsed_s"] > 5.0


def test_a_looped_drive_repeats_on_the_daq_and_the_ecu(tmp_path):
    """The dashboard's mode: a 2 s drive looped for 4.5 s. The DAQ sends the drive again
    at its end; the ECU sends the speed of the session time modulo the drive length."""
    path = tmp_path / "looped.h5"
    rate = 200.0
    run = VirtualDrive(path, drive_s=2.0, loop=True, seed=9, sample_rate_hz=rate,
                       include_recipe=False).start()
    final = run.record_for(4.5)
    assert run.error is None and final["state"] == "stopped"
    signals, drive = simulated_accelerations(2.0, sample_rate_hz=rate, seed=9)
    counts = to_counts(signals, FULL_SCALE_MPS2, 2)
    m = counts.shape[0]
    with SessionReader(path) as s:
        raw = _raw(s)
        t_v, v = s.signal("vehicle_speed")
        extra = s.metadata.extra
        assert s.counters["frames_lost"] == 0
    assert raw.shape[0] > 2.0 * m  # more than two passes of the drive
    # the device streams the drive from its first sample, again and again
    assert np.array_equal(raw, counts[np.arange(raw.shape[0]) % m])
    period = drive.vehicle_speed_time_s[-1]
    truth = np.interp(t_v % period, drive.vehicle_speed_time_s, drive.vehicle_speed_mps)
    assert t_v[-1] > 1.5 * period and np.max(np.abs(v - truth)) < 0.3  # 0.01 km/h steps
    assert extra["virtual_drive"] == {"seed": 9, "rate_hz": rate, "drive_s": 2.0,
                                      "loop": True}
    assert "simulation" not in extra


def test_the_ecu_alone_records_the_speed_and_says_why_there_is_no_estimate(tmp_path):
    path = tmp_path / "can-only.h5"
    run = VirtualDrive(path, drive_s=10.0, virtual_daq=False, seed=4, online=True).start()
    final = run.record_for(2.0)
    assert final["state"] == "stopped"
    assert final["online_error"] == "no DAQ: nothing to estimate from"
    with SessionReader(path) as s:
        assert s.channels == [] and s.n_samples == 0
        t_v, v = s.signal("vehicle_speed")
        assert {x.name for x in s.signals} == {"vehicle_speed", "WHEEL_SPEED_FL",
                                               "WHEEL_SPEED_FR", "WHEEL_SPEED_RL",
                                               "WHEEL_SPEED_RR"}
    # the SPEED message is sent at 41 Hz for the ~2 s recorded
    assert 41 * 1.5 < len(v) < 41 * 2.6 and np.all(np.diff(t_v) > 0)


def test_stop_is_safe_from_several_threads_and_stops_the_devices(tmp_path):
    run = VirtualDrive(tmp_path / "stop.h5", drive_s=10.0, seed=1).start()
    link = run.daq_device.path
    assert os.path.exists(link) and run.running
    run.recorder.wait(1.0)  # a second of data, then stopped from three threads at once
    finals: list[dict] = []
    threads = [threading.Thread(target=lambda: finals.append(run.stop())) for _ in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(20.0)
    assert len(finals) == 3 and all(f is finals[0] for f in finals)
    assert finals[0]["state"] == "stopped" and not run.running
    assert not os.path.exists(link)  # the pty and its link are gone
    assert not run.ecu_device._thread.is_alive()
    assert run.stop() is finals[0]  # and once more later
    with SessionReader(tmp_path / "stop.h5") as s:
        assert s.closed_cleanly
        # what the host received is stored: the counters count the samples in the file
        spf = run.daq_device.samples_per_frame
        assert s.counters["frames_received"] * spf == s.n_samples >= 0.8 * 500


def test_a_failed_start_stops_what_it_started(tmp_path):
    run = VirtualDrive(tmp_path / "no-such-folder" / "x.h5", drive_s=10.0, seed=2)
    with pytest.raises(FieldDiagError):
        run.start()
    assert run.daq_device is not None and not os.path.exists(run.daq_device.path)
    assert not run.ecu_device._thread  # never started
    assert run.stop() == {} and not run.running


def test_refuses_nothing_to_record_and_faults_without_the_virtual_daq(tmp_path):
    with pytest.raises(DeviceError, match="choose a DAQ and/or a CAN source"):
        VirtualDrive(tmp_path / "x.h5", drive_s=5.0, virtual_daq=False, virtual_ecu=False)
    with pytest.raises(DeviceError, match="faults are injected by the virtual DAQ"):
        VirtualDrive(tmp_path / "x.h5", drive_s=5.0, virtual_daq=False,
                     faults={"corrupt_rate": 1e-3})
    with pytest.raises(TypeError, match="'duration'"):
        VirtualDrive(tmp_path / "x.h5", drive_s=5.0, duration=3.0)  # type: ignore[call-arg]


def test_record_virtual_on_the_command_line(tmp_path):
    """``fielddiag record --virtual`` records the simulated car through the same harness:
    the session is the drive simulated with the added mass, bit for bit, and the on-line
    estimate is per unit of the loaded mass (24 kN/m on 380 + 50 kg)."""
    path = tmp_path / "cli.h5"
    proc = subprocess.run(
        [sys.executable, "-m", "fielddiag.cli", "record", "--virtual", "-o", str(path),
         "--duration", "3", "--added-mass", "50", "--seed", "7", "--vehicle", "cli car"],
        capture_output=True, text=True, timeout=180)
    assert proc.returncode == 0, proc.stderr
    assert "stopped after" in proc.stderr and ", 0 lost," in proc.stderr
    signals, _ = simulated_accelerations(5.0, sample_rate_hz=500.0, added_mass_kg=50.0,
                                         seed=7)
    counts = to_counts(signals, FULL_SCALE_MPS2, 2)
    with SessionReader(path) as s:
        raw = _raw(s)
        assert s.metadata.vehicle == "cli car" and s.metadata.added_mass_kg == 50.0
        assert s.metadata.extra["virtual_drive"]["loop"] is False
        assert "vehicle_speed" in {x.name for x in s.signals}
    assert 2.5 * 500 < len(raw) <= 3.2 * 500 and np.array_equal(raw, counts[: len(raw)])
    stiffness = next(line for line in proc.stderr.splitlines() if line.startswith("on-line"))
    value = float(stiffness.split("stiffness ")[1].split(" N/m/kg")[0])
    assert value == pytest.approx(24e3 / 430.0, rel=0.05)


def test_record_virtual_refuses_real_sources_too(tmp_path):
    proc = subprocess.run(
        [sys.executable, "-m", "fielddiag.cli", "record", "--virtual", "--daq",
         "serial:///dev/ttyUSB0", "-o", str(tmp_path / "x.h5")],
        capture_output=True, text=True, timeout=60)
    assert proc.returncode == 1 and "Traceback" not in proc.stderr
    assert "--virtual records the virtual DAQ and ECU: give it without --daq" in proc.stderr
    assert not (tmp_path / "x.h5").exists()


def test_record_virtual_without_a_duration_loops_until_ctrl_c(tmp_path):
    path = tmp_path / "looped-cli.h5"
    proc = subprocess.Popen(
        [sys.executable, "-m", "fielddiag.cli", "record", "--virtual", "-o", str(path),
         "--quiet", "--no-online"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        n = 0
        while time.monotonic() < deadline and n < 1000:  # 2 s of samples on disk
            time.sleep(0.2)
            if path.exists():
                try:
                    with SessionReader(path) as s:
                        n = s.n_samples
                except FieldDiagError:  # not readable yet
                    pass
        assert n >= 1000, "the recording did not start"
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    with SessionReader(path) as s:
        assert s.closed_cleanly and s.metadata.extra["virtual_drive"]["loop"] is True
        assert s.metadata.extra["virtual_drive"]["drive_s"] == pytest.approx(120.0)
        # 100 frames/s of 5 samples at 500 Hz: what was received is stored
        assert s.counters["frames_received"] * 5 == s.n_samples >= 1000
        assert s.counters["frames_lost"] == 0
