"""The command line as a user meets it: help, simulate, info, demo, errors."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from fielddiag.cli import main
from fielddiag.session import SessionReader


def _cli(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "fielddiag.cli", *args], capture_output=True,
                          text=True, cwd=cwd)


def test_help_lists_commands():
    proc = _cli("--help")
    assert proc.returncode == 0
    for cmd in ("demo", "simulate", "import", "info"):
        assert cmd in proc.stdout


def test_simulate_then_info_json(tmp_path, capsys):
    out = tmp_path / "s.h5"
    assert main(["simulate", "-o", str(out), "--duration", "20", "--added-mass", "40",
                 "--effect", "bump_stop", "--param", "gap_m=0.03", "--param",
                 "stiffness_n_per_m=1e5", "--seed", "7", "--rate", "200"]) == 0
    capsys.readouterr()
    assert main(["info", str(out), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["samples"] == 4000 and info["sample_rate_hz"] == 200.0
    assert info["metadata"]["added_mass_kg"] == 40.0
    assert {c["role"] for c in info["channels"]} == {"wheel", "body"}
    recipe = info["metadata"]["extra"]["simulation"]
    assert recipe["effects"] == [
        {"name": "bump_stop", "params": {"gap_m": 0.03, "stiffness_n_per_m": 1e5}}
    ]
    assert recipe["seed"] == 7
    with SessionReader(out) as s:
        # accelerometers read a + g: the mean of the body channel is g within the noise
        assert abs(np.mean(s.read_role("body")) - 9.80665) < 0.05


def test_errors_are_one_line_exit_1(tmp_path):
    cases = [
        (("info", str(tmp_path / "none.h5")), "does not exist"),
        (("simulate", "-o", str(tmp_path / "x.h5"), "--effect", "bogus"), "unknown effect"),
        (("simulate", "-o", str(tmp_path / "x.h5"), "--car", "wings=2"), "unknown car parameter"),
    ]
    procs = [subprocess.Popen([sys.executable, "-m", "fielddiag.cli", *args],  # at once
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for args, _ in cases]
    for proc, (_, message) in zip(procs, cases, strict=True):
        _, stderr = proc.communicate(timeout=120)
        assert proc.returncode == 1, stderr
        assert "Traceback" not in stderr and message in stderr
        assert len(stderr.strip().splitlines()) == 1


def _check_demo_results(demo: Path) -> None:
    """What a demo run leaves: both drives recorded through the virtual devices, identified
    and diagnosed, results beside each drive, where the dashboard finds them."""
    (run,) = sorted(demo.iterdir())
    with SessionReader(run / "before.h5") as b, SessionReader(run / "after.h5") as a:
        assert b.metadata.added_mass_kg == 0.0 and a.metadata.added_mass_kg == 60.0
        assert b.counters["frames_lost"] == 0 and b.counters["frames_received"] > 0
        assert b.duration_s == pytest.approx(32.0, abs=1.5)
        assert {s.name for s in b.signals} >= {"vehicle_speed"}
    ident = json.loads((run / "before.identify.json").read_text())
    assert ident["sprung_mass_kg"]["value"] > 0 and ident["sprung_mass_kg"]["std"] > 0
    diag = json.loads((run / "before.diagnose.json").read_text())
    assert diag["verdict"] in ("adequate", "missing_physics")
    assert (run / "plots" / "transmissibility.png").exists()
    # the dashboard the demo serves finds both drives processed, with the demo's results
    from fielddiag.catalog import Catalog

    listed = {s.path: s.processed for s in Catalog(demo).scan()}
    for drive in ("before", "after"):
        assert listed[f"{run.name}/{drive}.h5"] == {
            "diagnose": f"{run.name}/{drive}.diagnose.json",
            "identify": f"{run.name}/{drive}.identify.json"}
        beside = json.loads((run / f"{drive}.identify.json").read_text())
        assert beside["sprung_mass_kg"] == ident["sprung_mass_kg"]
        beside = json.loads((run / f"{drive}.diagnose.json").read_text())
        assert beside["verdict"] == diag["verdict"] and beside["findings"] == diag["findings"]
        assert beside["session_paths"] == ["before.h5", "after.h5"]


def test_demo_records_identifies_diagnoses_and_serves(tmp_path):
    """The README's main job, ``fielddiag demo`` with the shortest drives it accepts
    (recorded through the virtual devices in real time): it identifies and diagnoses the
    pair, and ends by serving the dashboard at the address it prints. One run for both
    (a demo takes a minute); ``--no-serve`` is the demo .ci/run runs first."""
    import socket
    import threading

    import httpx

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    env = {k: v for k, v in os.environ.items() if not k.startswith(("PYTEST_", "NICEGUI_"))}
    proc = subprocess.Popen(
        [sys.executable, "-m", "fielddiag.cli", "demo", "--out", str(tmp_path / "demo"),
         "--duration", "32", "--port", str(port)],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    lines: list[str] = []
    served = threading.Event()

    def read() -> None:
        for line in proc.stdout:
            lines.append(line)
            if "fielddiag dashboard for" in line:
                served.set()

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    try:
        assert served.wait(150), "".join(lines)
        (line,) = [x for x in lines if "fielddiag dashboard for" in x]
        url = line.split(" at ", 1)[1].split()[0]
        assert url == f"http://127.0.0.1:{port}/"
        for _ in range(100):  # the address is printed just before the server listens
            try:
                r = httpx.get(url, timeout=5)
                break
            except httpx.TransportError:
                time.sleep(0.1)
        else:
            raise AssertionError(f"{url} does not answer: {''.join(lines)}")
        assert r.status_code == 200 and "fielddiag" in r.text
        assert "4/4 serving the dashboard" in "".join(lines)
    finally:
        proc.terminate()
        try:
            proc.wait(15)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)
        reader.join(5)
    _check_demo_results(tmp_path / "demo")
