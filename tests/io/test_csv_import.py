"""CSV import through the real command line: good files round-trip, bad ones fail cleanly."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from fielddiag.cli import main
from fielddiag.errors import ImportFormatError
from fielddiag.io.csv_import import CsvImportOptions, import_csv
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


ROLES_AB = ["--role", "wheel=a", "--role", "body=b"]

#: case -> (file text, options after --time time, the message's telling part)
BAD_CASES = {
    "missing column": (
        "time,a,b\n0,1,2\n0.1,1,2\n",
        ["--role", "wheel=a", "--role", "body=zz"],
        "no column 'zz'",
    ),
    "time backwards": (
        "time,a,b\n0,1,2\n0.2,1,2\n0.1,1,2\n",
        ROLES_AB,
        "row 4, column 'time': time goes backwards",
    ),
    "time backwards after blank lines": (
        # rows are file lines: the backward time is on line 6, the 3rd data row
        "time,a,b\n0,1,2\n\n0.2,1,2\n\n0.1,1,2\n",
        ROLES_AB,
        "row 6, column 'time': time goes backwards (0.2 then 0.1)",
    ),
    "duplicate time": (
        "time,a,b\n0,1,2\n0.1,1,2\n0.1,1,2\n",
        ROLES_AB,
        "row 4, column 'time': time repeats",
    ),
    "nan": (
        "time,a,b\n0,1,2\n0.1,nan,2\n0.2,1,2\n",
        ROLES_AB,
        "row 3, column 'a': 'nan' is not a finite",
    ),
    "text": (
        "time,a,b\n0,1,2\n0.1,1,abc\n0.2,1,2\n",
        ROLES_AB,
        "row 3, column 'b': 'abc' is not a number",
    ),
    "empty file": ("", ROLES_AB, "the file is empty"),
    "header only": ("time,a,b\n", ROLES_AB, "0 data rows"),
    "short row": ("time,a,b\n0,1,2\n0.1,1\n", ROLES_AB, "row 3: 2 fields, the header has 3"),
    "long row": (
        "time,a,b\n0,1,2\n0.1,1,2,7\n0.2,1,2\n",
        ROLES_AB,
        "row 3: 4 fields, the header has 3",
    ),
    "unknown acceleration unit": (
        "time,a,b\n0,1,2\n0.1,1,2\n",
        [*ROLES_AB, "--accel-unit", "furlongs"],
        "unknown acceleration unit 'furlongs'; use one of m/s2",
    ),
    "unknown time unit": (
        "time,a,b\n0,1,2\n0.1,1,2\n",
        [*ROLES_AB, "--time-unit", "days"],
        "unknown time unit 'days'; use one of s, ms, us",
    ),
    "unknown speed unit": (
        "time,a,b,v\n0,1,2,3\n0.1,1,2,3\n",
        [*ROLES_AB, "--role", "speed=v", "--speed-unit", "knots"],
        "unknown speed unit 'knots'; use one of m/s, km/h, mph",
    ),
    "misspelt role": (
        "time,a,b\n0,1,2\n0.1,1,2\n",
        ["--role", "whel=a", "--role", "body=b"],
        "--role whel=a: did you mean wheel?",
    ),
}


@pytest.mark.parametrize("case", sorted(BAD_CASES))
def test_bad_input_one_clear_line_exit_1_nothing_written(tmp_path, case):
    text, options, message = BAD_CASES[case]
    src = _write(tmp_path / "bad.csv", text)
    out = tmp_path / "out.h5"
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
            *options,
        ],
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 1
    assert "Traceback" not in proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert message in lines[0] and "bad.csv" in lines[0], lines[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.csv"]  # no partial session


@pytest.mark.parametrize(
    "text, message",
    [
        # blank lines (empty, spaces, only delimiters) count as lines, CRLF or LF
        ("time,a,b\n\n   \n0,1,2\n,,\n0.1,nan,2\n", "row 6, column 'a': 'nan'"),
        ("time,a,b\r\n\r\n0,1,2\r\n\r\n0.1,1,x\r\n", "row 5, column 'b': 'x'"),
        ("time,a,b\n0,1,2\n\n\n0.1,1\n", "row 5: 2 fields"),
        ("time,a,b\n0,1,2\n\n\n0.1,1,2,3\n", "row 5: 4 fields"),
        ("time,a,b\n\n0,1,2\n\n0.1,1,2\n\n\n0.1,1,2\n", "row 8, column 'time': time repeats"),
        # a quoted cell spanning two lines: later rows keep their file line
        ('time,a,b\n0,1,"2\n"\n0.1,1,2\n0.05,1,2\n', "row 5, column 'time': time goes back"),
    ],
)
def test_rows_are_named_by_their_line_in_the_file(tmp_path, text, message):
    src = _write(tmp_path / "lines.csv", text)
    options = CsvImportOptions(roles={"wheel": "a", "body": "b"}, time_column="time")
    with pytest.raises(ImportFormatError) as err:
        import_csv(src, tmp_path / "o.h5", options)
    assert str(err.value).startswith("lines.csv row ") and message in str(err.value)
    assert not (tmp_path / "o.h5").exists()


def test_other_columns_are_kept_under_their_own_names(tmp_path):
    src = tmp_path / "rig.csv"
    src.write_text(
        "time,acc_wheel,acc_body,wheel_z,ambient temp [C]\n"
        + "".join(f"{i / 100},{i},{-i},{2 * i},{20 + i / 8}\n" for i in range(50))
    )
    roles = {"wheel": "acc_wheel", "body": "acc_body", "other": "wheel_z", "t": "ambient temp [C]"}
    import_csv(src, tmp_path / "o.h5", CsvImportOptions(roles=roles, time_column="time"))
    with SessionReader(tmp_path / "o.h5") as s:
        by_name = {c.name: c for c in s.channels}
        assert list(by_name) == ["wheel_z", "body_z", "wheel_z_2", "ambient_temp__C_"]
        assert by_name["wheel_z"].role == "wheel" and by_name["wheel_z"].sensor == "csv:acc_wheel"
        assert (by_name["wheel_z_2"].role, by_name["wheel_z_2"].sensor) == ("other", "csv:wheel_z")
        assert by_name["ambient_temp__C_"].sensor == "csv:ambient temp [C]"
        assert s.read("wheel_z_2").tolist() == [2.0 * i for i in range(50)]
        assert s.read("ambient_temp__C_").tolist() == [20 + i / 8 for i in range(50)]
        assert s.read("body_z").tolist() == [-1.0 * i for i in range(50)]


def test_malformed_role_option(tmp_path, capsys):
    src = tmp_path / "d.csv"
    _good_csv(src, n=10)
    out = tmp_path / "o.h5"
    rc = main(["import", str(src), "-o", str(out), "--time", "time", "--role", "wheel"])
    assert rc == 1
    assert "--role 'wheel': write it as ROLE=COLUMN" in capsys.readouterr().err
    assert not out.exists()


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
