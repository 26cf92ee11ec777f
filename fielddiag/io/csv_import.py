"""Import a CSV file (one row per sample, a header row) into a session.

Columns are mapped to roles with ``--role ROLE=COLUMN``. Known roles: ``wheel``, ``body``
(accelerations), ``speed`` (vehicle speed, stored as a signal), and for rig tests
``force``, ``displacement``, ``acceleration``. Any other ``NAME=COLUMN`` (``other=temp``,
``t1=temp``) keeps that column as a channel named after the column itself, with role
``other``; ``NAME`` only has to be unique. A ``NAME`` that looks like a misspelt role
(``whel``) is an error suggesting the role.

Every problem is reported as one :class:`~fielddiag.errors.ImportFormatError` naming the
file, the row or column and what to do; nothing is written unless the whole file is good.
Rows are numbered as lines of the file (the header is row 1), blank lines included, so
the number is the line an editor shows.
"""

from __future__ import annotations

import csv
import difflib
import math
import os
from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fielddiag.channels import CORNERS, ChannelSpec, SessionMetadata, SignalSpec
from fielddiag.errors import ImportFormatError
from fielddiag.session import unique_name, write_session
from fielddiag.units import QUANTITIES, factor_to_si

#: Bytes looked at for NUL bytes (a binary file); a header longer than this many characters
#: is not a CSV header (a 50 MB line of garbage would otherwise be split into columns).
_SNIFF_BYTES = 64 * 1024
_MAX_HEADER_CHARS = 1_000_000

#: role -> (unit stored, kind of quantity)
KNOWN_ROLES = {
    "wheel": ("m/s2", "accel"),
    "body": ("m/s2", "accel"),
    "acceleration": ("m/s2", "accel"),
    "force": ("N", "plain"),
    "displacement": ("m", "plain"),
    "speed": ("m/s", "speed"),
    # full vehicle: the eight corner accelerometers and the car's accelerations (signals)
    **{f"{k}_{c}": ("m/s2", "accel") for k in ("wheel", "body") for c in CORNERS},
    "accel_long": ("m/s2", "accel_signal"),
    "accel_lat": ("m/s2", "accel_signal"),
}


@dataclass(frozen=True)
class CsvImportOptions:
    """How to read a CSV file.

    Parameters
    ----------
    roles : mapping role -> column name
        e.g. ``{"wheel": "acc_w", "body": "acc_b"}``.
    time_column : str
        Column holding the sample time.
    time_unit : {"s", "ms", "us"}
    accel_unit : {"m/s2", "g"}
        Unit of the acceleration columns (``g`` is converted to m/s2).
    speed_unit : {"m/s", "km/h", "mph"}
    delimiter : str or None
        None sniffs ``,``, ``;`` or tab from the header.
    """

    roles: Mapping[str, str]
    time_column: str
    time_unit: str = "s"
    accel_unit: str = "m/s2"
    speed_unit: str = "m/s"
    delimiter: str | None = None


def parse_role_args(items: list[str] | None) -> dict[str, str]:
    """Turn ``["wheel=acc_w", "body=acc_b"]`` into a dict, with clear errors."""
    roles: dict[str, str] = {}
    for item in items or []:
        role, sep, col = item.partition("=")
        role, col = role.strip(), col.strip()
        if not sep or not role or not col:
            raise ImportFormatError(f"--role {item!r}: write it as ROLE=COLUMN, e.g. wheel=acc_z")
        if role in roles:
            raise ImportFormatError(f"--role {role} is given twice")
        roles[role] = col
    return roles


def _sniff_delimiter(header: str) -> str:
    counts = {d: header.count(d) for d in (",", ";", "\t")}
    best = max(counts, key=counts.get)
    return best if counts[best] else ","


def read_csv_columns(
    path: Path, columns: list[str], delimiter: str | None = None
) -> dict[str, np.ndarray]:
    """Read the named columns of a CSV file as float64 arrays, with row-exact errors."""
    return read_csv_table(path, columns, delimiter)[0]


def read_csv_table(
    path: Path, columns: list[str], delimiter: str | None = None
) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """The named columns of a CSV file as float64 arrays, and the file line of every row.

    Returns
    -------
    columns : dict column name -> ndarray
    line_numbers : ndarray of int
        Line of the file each data row was read from (the header is line 1), for
        messages about a row found bad later (a time going backwards).

    Raises
    ------
    ImportFormatError
        No such file, empty file, missing or repeated column, a row with fewer or more
        fields than the header, a cell that is not a finite number, fewer than two rows.
    """
    name = path.name
    try:
        with open(path, "rb") as fh:
            head = fh.read(_SNIFF_BYTES)
    except FileNotFoundError:
        raise ImportFormatError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise ImportFormatError(f"{path} is a folder; give a CSV file") from None
    except OSError as exc:
        raise ImportFormatError(f"{path}: cannot read it ({exc.strerror})") from None
    if b"\0" in head:
        raise ImportFormatError(
            f"{name}: binary data, not CSV text; export the recording as CSV (a header row, "
            "then one row of numbers per sample) or give --format for its real format"
        )
    # UTF-8 (with or without a byte-order mark) first; files from older Windows tools are
    # often Latin-1 (a degree sign or an accent in the header), read as such rather than
    # refused: every byte is a Latin-1 character, and the numbers are ASCII either way
    try:
        return _read_table(path, columns, delimiter, "utf-8-sig")
    except UnicodeDecodeError:
        return _read_table(path, columns, delimiter, "latin-1")


def _read_table(
    path: Path, columns: list[str], delimiter: str | None, encoding: str
) -> tuple[dict[str, np.ndarray], np.ndarray]:
    name = path.name
    with open(path, newline="", encoding=encoding) as fh:
        header_line = fh.readline(_MAX_HEADER_CHARS + 1)
        if len(header_line) > _MAX_HEADER_CHARS:
            raise ImportFormatError(
                f"{name}: the first line is longer than {_MAX_HEADER_CHARS // 1000} kB with no "
                "line break; give a CSV file with a header row, then one row per sample"
            )
        if not header_line.strip():
            raise ImportFormatError(
                f"{name}: the file is empty; give a CSV file with a header row and at least "
                "two data rows"
            )
        delim = delimiter or _sniff_delimiter(header_line)
        try:
            header = [h.strip() for h in next(csv.reader([header_line], delimiter=delim))]
        except csv.Error as exc:
            raise ImportFormatError(f"{name} row 1: not a CSV header ({exc}); fix the first "
                                    "line") from None
        missing = [c for c in columns if c not in header]
        if missing:
            shown = ", ".join(repr(h) for h in header[:20])
            more = f" and {len(header) - 20} more" if len(header) > 20 else ""
            raise ImportFormatError(
                f"{name}: no column {', '.join(repr(m) for m in missing)}; the header has "
                f"{shown}{more}. Check the --role/--time column names"
            )
        counts = Counter(header)
        dup = {c for c in columns if counts[c] > 1}
        if dup:
            raise ImportFormatError(
                f"{name}: column {sorted(dup)[0]!r} appears twice in the header"
            )
        index = [header.index(c) for c in columns]
        values: list[list[float]] = [[] for _ in columns]
        lines: list[int] = []
        reader = csv.reader(fh, delimiter=delim)
        line_no = 1
        try:
            for row in reader:
                line_no = 1 + reader.line_num  # the header line was read before the reader
                if not row or all(not cell.strip() for cell in row):
                    continue
                if len(row) != len(header):
                    raise ImportFormatError(
                        f"{name} row {line_no}: {len(row)} fields, the header has "
                        f"{len(header)}; fix or delete that row"
                    )
                for k, i in enumerate(index):
                    values[k].append(_cell_value(name, line_no, columns[k], row[i]))
                lines.append(line_no)
        except csv.Error as exc:
            raise ImportFormatError(
                f"{name} row {1 + reader.line_num}: not a CSV row ({exc}); fix or delete "
                "that row"
            ) from None
    n = len(lines)
    if n < 2:
        raise ImportFormatError(
            f"{name}: {n} data row{'s' if n != 1 else ''}; a session needs at least two "
            "samples: give a file with a header row and two or more data rows"
        )
    data = {c: np.asarray(v, dtype="f8") for c, v in zip(columns, values, strict=True)}
    return data, np.asarray(lines, dtype="i8")


def _cell_value(name: str, line_no: int, column: str, text: str) -> float:
    cell = text.strip()
    try:
        v = float(cell)
    except ValueError:
        raise ImportFormatError(
            f"{name} row {line_no}, column {column!r}: {cell!r} is not a number; "
            "fix or delete that row"
        ) from None
    if not math.isfinite(v):
        raise ImportFormatError(
            f"{name} row {line_no}, column {column!r}: {cell!r} is not a finite "
            "number; fill the gap or cut the file there"
        )
    return v


def _check_time(name: str, time_column: str, t: np.ndarray, line_numbers: np.ndarray) -> None:
    dt = np.diff(t)
    bad = np.flatnonzero(dt <= 0)
    if bad.size:
        i = int(bad[0])
        kind = "repeats" if dt[i] == 0 else "goes backwards"
        raise ImportFormatError(
            f"{name} row {line_numbers[i + 1]}, column {time_column!r}: time {kind} "
            f"({t[i]:g} then {t[i + 1]:g}); times must increase strictly; sort the file or "
            "remove duplicate rows"
        )


def _check_units(name: str, options: CsvImportOptions) -> None:
    for what, unit in (
        ("acceleration", options.accel_unit),
        ("time", options.time_unit),
        ("speed", options.speed_unit),
    ):
        try:
            factor_to_si(unit, what)
        except KeyError:
            raise ImportFormatError(
                f"{name}: unknown {what} unit {unit!r}; use one of "
                f"{', '.join(QUANTITIES[what][0])}"
            ) from None


def check_role_names(name: str, roles: Mapping[str, str]) -> None:
    """A role name that is not a role but close to one is a typo, not an extra column."""
    for role, col in roles.items():
        if role in KNOWN_ROLES or role == "other":
            continue
        close = [r for r in KNOWN_ROLES if len(role) >= 3 and r.startswith(role)]
        close = close or difflib.get_close_matches(role, list(KNOWN_ROLES), n=1, cutoff=0.75)
        if close:
            raise ImportFormatError(
                f"{name}: --role {role}={col}: did you mean {close[0]}? The roles are "
                f"{', '.join(KNOWN_ROLES)}; to keep the column under its own name, write "
                f"--role other={col}"
            )


def import_csv(
    path: str | os.PathLike,
    out_path: str | os.PathLike,
    options: CsvImportOptions,
    metadata: SessionMetadata | None = None,
    *,
    overwrite: bool = False,
) -> Path:
    """Import ``path`` into the session ``out_path`` (written atomically).

    Returns
    -------
    Path
        The session written.

    Raises
    ------
    ImportFormatError
        Missing column, bad number, non-monotonic or duplicate time, empty file, bad unit,
        a row with the wrong number of fields, a misspelt role.
    SessionError
        The output exists and ``overwrite`` is False.
    """
    path = Path(path)
    _check_units(path.name, options)
    if not options.roles:
        raise ImportFormatError(
            "say which columns to import with --role ROLE=COLUMN (e.g. --role wheel=acc_w "
            "--role body=acc_b)"
        )
    check_role_names(path.name, options.roles)
    cols = [options.time_column, *options.roles.values()]
    if len(set(cols)) != len(cols):
        raise ImportFormatError("the same column is mapped twice (check --time and --role)")
    data, line_numbers = read_csv_table(path, cols, options.delimiter)
    t = data[options.time_column] * factor_to_si(options.time_unit, "time")
    _check_time(path.name, options.time_column, t, line_numbers)
    rate_hz = 1.0 / float(np.median(np.diff(t)))

    channels: list[ChannelSpec] = []
    columns: list[np.ndarray] = []
    signals: dict[SignalSpec, tuple[np.ndarray, np.ndarray]] = {}
    extras: list[tuple[str, np.ndarray]] = []  # columns kept under their own name
    for role, col in options.roles.items():
        values = data[col]
        unit, kind = KNOWN_ROLES.get(role, ("", "plain"))
        if kind == "speed":
            spec = SignalSpec("vehicle_speed", unit="m/s", source="csv", message=col, role="speed")
            signals[spec] = (t, values * factor_to_si(options.speed_unit, "speed"))
            continue
        if kind == "accel_signal":
            spec = SignalSpec(role, unit="m/s2", source="csv", message=col, role=role)
            signals[spec] = (t, values * factor_to_si(options.accel_unit, "acceleration"))
            continue
        if kind == "accel":
            values = values * factor_to_si(options.accel_unit, "acceleration")
        if role in KNOWN_ROLES:
            name = {"wheel": "wheel_z", "body": "body_z"}.get(role, role)
            channels.append(ChannelSpec(name, unit=unit, role=role, sensor=f"csv:{col}"))
        else:
            extras.append((col, values))
            continue
        columns.append(values)
    taken = {c.name for c in channels}
    for col, values in extras:  # after the role channels, whose names are fixed
        name = unique_name(col, taken, default="column")
        channels.append(ChannelSpec(name, unit="", role="other", sensor=f"csv:{col}"))
        columns.append(values)
    if not channels:
        raise ImportFormatError("no DAQ channel to import: map at least one column besides speed")
    meta = metadata or SessionMetadata()
    meta.extra = {
        **meta.extra,
        "imported_from": path.name,
        "import_format": "csv",
        "source_time_of_first_sample_s": float(t[0]),
    }
    return write_session(
        out_path,
        meta,
        channels,
        np.column_stack(columns),
        sample_rate_hz=rate_hz,
        time_s=t - t[0],
        signals=signals,
        overwrite=overwrite,
    )
