"""CSV import through the real command line: good files round-trip, bad ones fail cleanly."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from fielddiag.cli import main
from fielddiag.session import SessionReader


def _write(path, text):
    path.write_text(text)
    return path


def _good_csv(path, n=500, rate=200.0, g_units=False):
    t = np.arange(n) / rate
    w = np.sin(2 * np.pi * 3 * t)
    b = 0.5 * np.cos(2 * np.pi * 1.2 * t)
    v = 10 + t
    rows = ["time,acc_wheel,acc_body,speed_kmh,temp"]
    for i in range(n):
        rows.append(f"{t[i]:.6f},{w[i]:.9f},{b[i]:.9f},{v[i] * 3.6:.6f},{20 + i % 3}")
    path.write_text("\n".join(rows) + "\n")
    return t, w, b, v


def test_import_round_trip_with_units(tmp_path, capsys):
    src = tmp_path / "drive.csv"
    t, w, b, v = _good_csv(src)
    out = tmp_path / "s.h5"
    rc = main(
        [
            "import",
            str(src),
            "-o",
            str(out),
            "--role",
            "wheel=acc_wheel",
            "--role",
            "body=acc_body",
            "--role",
            "speed=speed_kmh",
            "--role",
            "temp=temp",
            "--time",
            "time",
            "--accel-unit",
            "g",
            "--speed-unit",
            "km/h",
            "--added-mass",
            "35",
            "--vehicle",
            "Camry",
            "--corner",
            "rear-left",
        ]
    )
    assert rc == 0
    with SessionReader(out) as s:
        assert s.metadata.added_mass_kg == 35.0 and s.metadata.corner == "rear-left"
        assert s.sample_rate_hz == pytest.approx(200.0, rel=1e-6)
        np.testing.assert_allclose(s.read_role("wheel"), w * 9.80665, rtol=1e-9, atol=1e-8)
        np.testing.assert_allclose(s.read_role("body"), b * 9.80665, rtol=1e-9, atol=1e-8)
        np.testing.assert_allclose(s.time_s(), t, atol=1e-9)
        ts, vs = s.signal(s.signal_for_role("speed").name)
        np.testing.assert_allclose(vs, v, rtol=1e-6)
        assert s.channel("temp").role == "other"
        assert s.channel("wheel_z").unit == "m/s2"


BAD_CASES = {
    "missing column": (
        "time,a,b\n0,1,2\n0.1,1,2\n",
        ["--role", "wheel=a", "--role", "body=zz"],
        "no column 'zz'",
    ),
    "time backwards": (
        "time,a,b\n0,1,2\n0.2,1,2\n0.1,1,2\n",
        None,
        "row 4, column 'time': time goes backwards",
    ),
    "duplicate time": (
        "time,a,b\n0,1,2\n0.1,1,2\n0.1,1,2\n",
        None,
        "row 4, column 'time': time repeats",
    ),
    "nan": (
        "time,a,b\n0,1,2\n0.1,nan,2\n0.2,1,2\n",
        None,
        "row 3, column 'a': 'nan' is not a finite",
    ),
    "text": (
        "time,a,b\n0,1,2\n0.1,1,abc\n0.2,1,2\n",
        None,
        "row 3, column 'b': 'abc' is not a number",
    ),
    "empty file": ("", None, "the file is empty"),
    "header only": ("time,a,b\n", None, "0 data rows"),
    "short row": ("time,a,b\n0,1,2\n0.1,1\n", None, "row 3: 2 fields"),
}


@pytest.mark.parametrize("case", sorted(BAD_CASES))
def test_bad_input_one_clear_line_exit_1_nothing_written(tmp_path, case):
    text, roles, message = BAD_CASES[case]
    src = _write(tmp_path / "bad.csv", text)
    out = tmp_path / "out.h5"
    roles = roles or ["--role", "wheel=a", "--role", "body=b"]
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "fielddiag.cli",
            "import",
            str(src),
            "-o",
            str(out),
            "--time",
            "time",
            *roles,
        ],
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 1
    assert "Traceback" not in proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert message in lines[0] and "bad.csv" in lines[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.csv"]  # no partial session


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--accel-unit", "furlongs"], "unknown acceleration unit 'furlongs'"),
        (["--time-unit", "days"], "unknown time unit 'days'"),
        (["--role", "wheel"], "write it as ROLE=COLUMN"),
    ],
)
def test_bad_options(tmp_path, capsys, extra, message):
    src = tmp_path / "d.csv"
    _good_csv(src, n=10)
    rc = main(
        [
            "import",
            str(src),
            "-o",
            str(tmp_path / "o.h5"),
            "--time",
            "time",
            "--role",
            "body=acc_body",
            *extra,
        ]
    )
    assert rc == 1
    assert message in capsys.readouterr().err
    assert not (tmp_path / "o.h5").exists()


def test_existing_session_not_overwritten(tmp_path, capsys):
    src = tmp_path / "d.csv"
    _good_csv(src, n=10)
    out = tmp_path / "o.h5"
    args = ["import", str(src), "-o", str(out), "--time", "time", "--role", "body=acc_body"]
    assert main(args) == 0
    before = out.read_bytes()
    assert main(args) == 1
    assert "already exists" in capsys.readouterr().err
    assert out.read_bytes() == before
    assert main([*args, "--overwrite"]) == 0
