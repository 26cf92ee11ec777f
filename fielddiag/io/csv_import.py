"""Import a CSV file (one row per sample, a header row) into a session.

Columns are mapped to roles with ``--role ROLE=COLUMN``. Known roles: ``wheel``, ``body``
(accelerations), ``speed`` (vehicle speed, stored as a signal), and for rig tests
``force``, ``displacement``, ``acceleration``. Any other role name keeps that column as a
channel of that name with role ``other``.

Every problem is reported as one :class:`~fielddiag.errors.ImportFormatError` naming the
file, the row or column and what to do; nothing is written unless the whole file is good.
"""

from __future__ import annotations

import csv
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fielddiag.channels import ChannelSpec, SessionMetadata, SignalSpec
from fielddiag.errors import ImportFormatError
from fielddiag.session import write_session

G_MPS2 = 9.80665

ACCEL_UNITS = {"m/s2": 1.0, "m/s^2": 1.0, "mps2": 1.0, "g": G_MPS2}
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6}
SPEED_UNITS = {"m/s": 1.0, "km/h": 1 / 3.6, "mph": 0.44704}

#: role -> (unit stored, kind of quantity)
KNOWN_ROLES = {
    "wheel": ("m/s2", "accel"),
    "body": ("m/s2", "accel"),
    "acceleration": ("m/s2", "accel"),
    "force": ("N", "plain"),
    "displacement": ("m", "plain"),
    "speed": ("m/s", "speed"),
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
    name = path.name
    try:
        fh = open(path, newline="", encoding="utf-8-sig")
    except FileNotFoundError:
        raise ImportFormatError(f"{path}: no such file") from None
    except OSError as exc:
        raise ImportFormatError(f"{path}: cannot read it ({exc.strerror})") from None
    with fh:
        header_line = fh.readline()
        if not header_line.strip():
            raise ImportFormatError(
                f"{name}: the file is empty; it needs a header row and at least two data rows"
            )
        delim = delimiter or _sniff_delimiter(header_line)
        header = [h.strip() for h in next(csv.reader([header_line], delimiter=delim))]
        missing = [c for c in columns if c not in header]
        if missing:
            raise ImportFormatError(
                f"{name}: no column {', '.join(repr(m) for m in missing)}; the header has "
                f"{', '.join(repr(h) for h in header)}. Check the --role/--time column names"
            )
        dup = {h for h in header if header.count(h) > 1 and h in columns}
        if dup:
            raise ImportFormatError(
                f"{name}: column {sorted(dup)[0]!r} appears twice in the header"
            )
        index = [header.index(c) for c in columns]
        values: list[list[float]] = [[] for _ in columns]
        reader = csv.reader(fh, delimiter=delim)
        for row_no, row in enumerate(reader, start=2):
            if not row or all(not cell.strip() for cell in row):
                continue
            if len(row) < len(header):
                raise ImportFormatError(
                    f"{name} row {row_no}: {len(row)} fields, the header has {len(header)}; "
                    "fix or delete that row"
                )
            for k, i in enumerate(index):
                cell = row[i].strip()
                try:
                    v = float(cell)
                except ValueError:
                    raise ImportFormatError(
                        f"{name} row {row_no}, column {columns[k]!r}: {cell!r} is not a number; "
                        "fix or delete that row"
                    ) from None
                if not math.isfinite(v):
                    raise ImportFormatError(
                        f"{name} row {row_no}, column {columns[k]!r}: {cell!r} is not a finite "
                        "number; fill the gap or cut the file there"
                    )
                values[k].append(v)
    n = len(values[0]) if values else 0
    if n < 2:
        raise ImportFormatError(
            f"{name}: {n} data row{'s' if n != 1 else ''}; a session needs at least two samples"
        )
    return {c: np.asarray(v, dtype="f8") for c, v in zip(columns, values, strict=True)}


def _check_time(name: str, time_column: str, t: np.ndarray) -> None:
    dt = np.diff(t)
    bad = np.flatnonzero(dt <= 0)
    if bad.size:
        i = int(bad[0])
        kind = "repeats" if dt[i] == 0 else "goes backwards"
        raise ImportFormatError(
            f"{name} row {i + 3}, column {time_column!r}: time {kind} "
            f"({t[i]:g} then {t[i + 1]:g}); times must increase strictly; sort the file or "
            "remove duplicate rows"
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
        Missing column, bad number, non-monotonic or duplicate time, empty file, bad unit.
    SessionError
        The output exists and ``overwrite`` is False.
    """
    path = Path(path)
    if options.accel_unit not in ACCEL_UNITS:
        raise ImportFormatError(
            f"unknown acceleration unit {options.accel_unit!r}; use one of {', '.join(ACCEL_UNITS)}"
        )
    if options.time_unit not in TIME_UNITS:
        raise ImportFormatError(
            f"unknown time unit {options.time_unit!r}; use one of {', '.join(TIME_UNITS)}"
        )
    if options.speed_unit not in SPEED_UNITS:
        raise ImportFormatError(
            f"unknown speed unit {options.speed_unit!r}; use one of {', '.join(SPEED_UNITS)}"
        )
    if not options.roles:
        raise ImportFormatError(
            "say which columns to import with --role ROLE=COLUMN (e.g. --role wheel=acc_w "
            "--role body=acc_b)"
        )
    cols = [options.time_column, *options.roles.values()]
    if len(set(cols)) != len(cols):
        raise ImportFormatError("the same column is mapped twice (check --time and --role)")
    data = read_csv_columns(path, cols, options.delimiter)
    t = data[options.time_column] * TIME_UNITS[options.time_unit]
    _check_time(path.name, options.time_column, t)
    rate_hz = 1.0 / float(np.median(np.diff(t)))

    channels: list[ChannelSpec] = []
    columns: list[np.ndarray] = []
    signals: dict[SignalSpec, tuple[np.ndarray, np.ndarray]] = {}
    for role, col in options.roles.items():
        values = data[col]
        unit, kind = KNOWN_ROLES.get(role, ("", "plain"))
        if kind == "speed":
            spec = SignalSpec("vehicle_speed", unit="m/s", source="csv", message=col, role="speed")
            signals[spec] = (t, values * SPEED_UNITS[options.speed_unit])
            continue
        if kind == "accel":
            values = values * ACCEL_UNITS[options.accel_unit]
        if role in KNOWN_ROLES:
            name = {"wheel": "wheel_z", "body": "body_z"}.get(role, role)
            channels.append(ChannelSpec(name, unit=unit, role=role, sensor=f"csv:{col}"))
        else:
            channels.append(ChannelSpec(role, unit="", role="other", sensor=f"csv:{col}"))
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
