"""The commands a technician runs, end to end: ``fielddiag virtual-daq`` with faults,
``fielddiag ports``, ``fielddiag record`` and ``fielddiag info``, each its own process.

What the recording reports (frames lost, gaps, reconnects) is checked against what the
virtual DAQ says it did when it exits, an account kept independently of the recorder.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from pathlib import Path

RATE_HZ = 1000.0
FRAMES_PER_S = 100  # the virtual DAQ's default: RATE_HZ / 10 samples per frame
SAMPLES_PER_FRAME = int(RATE_HZ) // FRAMES_PER_S
OUTAGE_S = 2.0


def _fielddiag(*args: str) -> list[str]:
    return [sys.executable, "-m", "fielddiag.cli", *args]


def _json_of(*args: str) -> dict | list:
    proc = subprocess.run(_fielddiag(*args), capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout)


def _list_ports_then_record(port: str, session: Path) -> tuple[list, str]:
    """``fielddiag ports --json``, then ``fielddiag record`` for 6 s.

    (Listed before the recording: during it the cable is pulled, and a loaded machine
    could list the ports just while the link is gone.)
    Returns the ports listed and the recorder's last line (its summary)."""
    ports = _json_of("ports", "--json")
    record = subprocess.Popen(
        _fielddiag(
            "record",
            "--daq",
            f"serial://{port}",
            "-o",
            str(session),
            "--duration",
            "6",
            "--no-online",
            "--quiet",
        ),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        out, err = record.communicate(timeout=40)
    finally:
        if record.poll() is None:
            record.kill()
            record.wait()
    assert record.returncode == 0, err
    return ports, err.strip().splitlines()[-1]


def test_virtual_daq_with_faults_recorded_by_the_record_command(tmp_path):
    session = tmp_path / "S.h5"
    vdaq = subprocess.Popen(
        _fielddiag(
            "virtual-daq",
            "--rate",
            f"{RATE_HZ:g}",
            "--channels",
            "4",
            "--corrupt",
            "1e-3",
            "--garbage-every",
            "0.5",
            "--disconnect-at",
            "1.5",
            "--disconnect-for",
            f"{OUTAGE_S:g}",
            "--duration",
            "10",  # a 10 s simulated drive, looped
        ),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        port = vdaq.stdout.readline().strip()
        assert port.startswith("/") and "VDAQ" in port, vdaq.stderr.read()
        ports, summary = _list_ports_then_record(port, session)
    finally:
        vdaq.send_signal(signal.SIGINT)
        stats_out, vdaq_err = vdaq.communicate(timeout=20)
    assert vdaq.returncode == 0, vdaq_err
    device = json.loads(stats_out.strip().splitlines()[-1])  # what the device did

    # the pseudo-terminal of the running virtual DAQ is offered as a port
    listed = {p["device"]: p for p in ports}
    assert port in listed, f"{port} not in {sorted(listed)}"
    assert listed[port]["manufacturer"] == "fielddiag"
    assert "virtual DAQ" in listed[port]["description"]

    info = _json_of("info", "--json", str(session))
    c = info["counters"]
    assert info["closed_cleanly"] and info["sample_rate_hz"] == RATE_HZ
    assert f"{c['frames_received']} frames, {c['frames_lost']} lost" in summary, summary
    assert [ch["name"] for ch in info["channels"]] == ["wheel_z", "body_z", "ch2", "ch3"]
    # the cable was pulled once, and the recorder reconnected once
    assert device["disconnects"] == 1 and c["reconnects"] == 1
    # every frame the device made while recorded was received or counted lost: the few
    # it made before the first frame received (a damaged first frame) or after the last
    # (stopping) are the only ones unaccounted for
    unaccounted = device["frames_made"] - c["frames_received"] - c["frames_lost"]
    assert 0 <= unaccounted <= 0.3 * FRAMES_PER_S, (device, c)
    assert c["frames_received"] <= device["frames_written"]
    assert c["samples_lost"] == c["frames_lost"] * SAMPLES_PER_FRAME == info["samples_lost"]
    assert info["samples"] == c["frames_received"] * SAMPLES_PER_FRAME
    # the frames the device could not send during the outage are all counted lost, in
    # one gap caused by the disconnection
    not_sent = device["frames_dropped_outage"] + device["frames_lost_in_link"]
    assert not_sent >= OUTAGE_S * FRAMES_PER_S * 0.95
    assert c["frames_lost"] >= not_sent
    gaps = info["gaps"]
    assert sum(g["samples_lost"] for g in gaps) == c["samples_lost"]
    outage = [g for g in gaps if g["cause"] == "disconnected"]
    longest = max(outage, key=lambda g: g["samples_lost"])
    assert longest["samples_lost"] >= not_sent * SAMPLES_PER_FRAME
    # its length in session time is the device's time through the clock mapping, whose
    # rate stays within 2e-3 of the device's (fitted drift + slew)
    assert longest["end_s"] - longest["start_s"] >= OUTAGE_S * (1 - 2e-3)
    # the other losses are the frames the device damaged: dropped on their CRC, no more
    damaged_lost = c["frames_lost"] - sum(g["samples_lost"] for g in outage) // SAMPLES_PER_FRAME
    assert 0 < damaged_lost <= device["frames_corrupted"]
    # (and a frame the host had read part of when the cable was pulled: its head meets
    # the bytes sent after the reconnect and fails its CRC; counted lost in the link by
    # the device. Seen once in 2026-11-29's suite: 64 CRC errors for 63 damaged frames)
    assert 0 < c["crc_errors"] <= device["frames_corrupted"] + device["disconnects"]
    # frames the device itself dropped (its transmit buffer overflowed while nobody read
    # the port, around the reconnect) are the only ones called 'dropped by device'; the
    # frames that arrive with the INFO answer after the reconnect are kept, not dropped
    assert {"disconnected", "corrupted"} <= {g["cause"] for g in gaps}
    by_device = sum(g["samples_lost"] for g in gaps if g["cause"] == "dropped by device")
    assert by_device <= device["frames_dropped_overflow"] * SAMPLES_PER_FRAME, (gaps, device)
    assert c["bytes_discarded"] > 0
