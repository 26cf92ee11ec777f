"""The CLI on truncated sessions (issue 14): one line, exit 1, the rest of a batch goes on.

Real subprocesses of ``python -m fielddiag.cli`` with a time limit each, so a hang fails
the test instead of hanging it (a 2000-byte cut of a session hung the reader for 15
minutes and more before the guard).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fielddiag.channels import ChannelSpec, SessionMetadata
from fielddiag.cli import main
from fielddiag.session import write_session
from fielddiag.sim import QuarterCarParams, simulate_pair
from fielddiag.simio import drive_to_session

CAR = QuarterCarParams()  # body 380 kg


def _cli(*args: str, timeout_s: float = 60.0) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "fielddiag.cli", *args], capture_output=True,
                          text=True, timeout=timeout_s)


@pytest.fixture
def small_session(tmp_path) -> Path:
    x = np.column_stack([np.sin(np.arange(3000) / 10.0), np.cos(np.arange(3000) / 10.0)])
    return write_session(tmp_path / "good.h5", SessionMetadata(vehicle="van", corner="fl"),
                         [ChannelSpec("wheel_z", role="wheel"),
                          ChannelSpec("body_z", role="body")], x, sample_rate_hz=500.0)


def _expected(cut: Path, n_bytes: int, whole: bytes) -> str:
    return (f"fielddiag info: error: {cut} is not a complete fielddiag session (truncated at "
            f"{n_bytes} of {len(whole)} bytes): copy it again from the original\n")


def test_info_on_a_truncated_session_is_one_line_and_exit_1(tmp_path, small_session, capsys):
    whole = small_session.read_bytes()
    cut = tmp_path / "truncated.h5"
    cut.write_bytes(whole[:2000])
    r = _cli("info", str(cut), timeout_s=60.0)  # a real process: it hung before
    assert r.returncode == 1 and r.stdout == "", r
    assert r.stderr == _expected(cut, 2000, whole)
    for n_bytes in (500, 1000, 4000, 8000):
        cut.write_bytes(whole[:n_bytes])
        for extra in ([], ["--json"]):
            assert main(["info", str(cut), *extra]) == 1
            out, err = capsys.readouterr()
            assert out == "" and err == _expected(cut, n_bytes, whole)


def test_info_on_a_good_session_and_on_no_session(tmp_path, small_session, capsys):
    assert main(["info", str(small_session), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["samples"] == 3000 and info["duration_s"] == pytest.approx(6.0)
    for bad, why in ((tmp_path, "is a folder"), (tmp_path / "nope.h5", "does not exist")):
        assert main(["info", str(bad)]) == 1
        out, err = capsys.readouterr()
        assert out == "" and len(err.splitlines()) == 1 and why in err, err


def test_reprocess_goes_on_past_a_truncated_session(tmp_path):
    root = tmp_path / "fleet"
    (root / "car-a").mkdir(parents=True)
    before, after = simulate_pair(CAR, added_mass_kg=60.0, seed=21, duration_s=40.0)
    b = drive_to_session(before, root / "car-a" / "before.h5", vehicle="car-a")
    drive_to_session(after, root / "car-a" / "after.h5", vehicle="car-a")
    whole = b.read_bytes()
    (root / "truncated.h5").write_bytes(whole[:2000])
    r = _cli("reprocess", str(root), "--workers", "1", "--steps", "identify", timeout_s=240.0)
    # documented: exit status 1 when anything failed; an unreadable session counts
    assert r.returncode == 1, r.stdout + r.stderr
    assert "Traceback" not in r.stdout + r.stderr
    assert "1 pair under" in r.stdout and "1 unreadable" in r.stdout
    assert (f"truncated.h5: cannot read the session header: {(root / 'truncated.h5').resolve()}"
            f" is not a complete fielddiag session (truncated at 2000 of {len(whole)} "
            "bytes)") in r.stdout
    assert "1 processed, 0 up to date, 1 failed" in r.stdout
    result = json.loads((root / "car-a" / "before.identify.json").read_text())
    m = result["sprung_mass_kg"]["value"]
    assert abs(m - CAR.body_mass_kg) / CAR.body_mass_kg < 0.05, m
