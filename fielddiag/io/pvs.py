"""Import the PVS "Passive Vehicular Sensors" dataset (Menegazzo & von Wangenheim, 2020).

Layout (public, from the authors' pre-processing notebook, repository
``jefmenegazzo/MPU-9250-and-GPS-Raw-Data-Pre-Processing``): one folder per drive
(``PVS 1`` ... ``PVS 9``) holding, per side of the front axle (``left``, ``right``):

* ``dataset_gps_mpu_<side>.csv``: 100 Hz rows, ``timestamp`` (UNIX s, rounded to 0.01 s),
  then for the three MPU-9250 modules (``dashboard``, ``above_suspension`` on the body
  above the tyre, ``below_suspension`` on the control arm): ``acc_{x,y,z}_<pos>`` (m/s2,
  gravity included), ``gyro_{x,y,z}_<pos>`` (deg/s), ``mag_{x,y,z}_<pos>`` (uT, not below
  the suspension), ``temp_<pos>`` (degC), and the last GPS fix held on every row:
  ``timestamp_gps`` (UNIX s), ``latitude``, ``longitude``, ``speed`` (m/s, 1 Hz fixes).
* ``dataset_mpu_<side>.csv``: the same without the GPS columns (the speed is then taken
  from ``dataset_gps.csv``: ``timestamp``, ``speed_meters_per_second``...).
* ``dataset_labels.csv``: one-hot labels, one row per sensor row (``dirt_road``,
  ``cobblestone_road``, ``asphalt_road``, ``speed_bump_asphalt``, ``good_road_left``...).

What the session holds: ``wheel_z`` (role wheel) = the vertical axis of the module below
the suspension, ``body_z`` (role body) = the vertical axis of the module above it, both as
accelerometers read them (acceleration + g, up positive: an axis whose mean is negative,
i.e. mounted upside down, gets calibration scale -1; the raw values stay as recorded);
every other sensor column as a channel of its PVS name, role ``other``, in SI (gyro rad/s,
magnetometer T, temperature degC); the GPS fixes as signals ``vehicle_speed`` (role speed,
m/s), ``latitude_deg`` and ``longitude_deg`` at their own 1 Hz time stamps; and, when
``dataset_labels.csv`` is beside the file with as many rows, an event where each label
switches on (``speed_bump_asphalt``, ``cobblestone_road``...).

No PVS file could be brought onto the development machine; the importer is tested on a
synthetic file written in this exact layout.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from fielddiag.channels import ChannelSpec, Event, SessionMetadata, SignalSpec
from fielddiag.errors import ImportFormatError
from fielddiag.units import DEG_TO_RAD

POSITIONS = ("dashboard", "above_suspension", "below_suspension")

#: The columns of ``dataset_mpu_<side>.csv`` in file order.
MPU_COLUMNS = (
    "timestamp",
    *(f"acc_{a}_{p}" for p in POSITIONS for a in "xyz"),
    *(f"gyro_{a}_{p}" for p in POSITIONS for a in "xyz"),
    *(f"mag_{a}_{p}" for p in ("dashboard", "above_suspension") for a in "xyz"),
    *(f"temp_{p}" for p in POSITIONS),
)
#: The columns ``dataset_gps_mpu_<side>.csv`` adds after :data:`MPU_COLUMNS`.
GPS_COLUMNS = ("timestamp_gps", "latitude", "longitude", "speed")

_UNITS = {"acc": ("m/s2", 1.0), "gyro": ("rad/s", DEG_TO_RAD), "mag": ("T", 1e-6),
          "temp": ("degC", 1.0)}
_ROLE_OF = {"below_suspension": ("wheel", "wheel_z"), "above_suspension": ("body", "body_z")}


def _find_files(path: Path, side: str | None) -> tuple[Path, str]:
    """The sensor CSV to read and the side it belongs to."""
    if path.is_dir():
        side = side or "left"
        for name in (f"dataset_gps_mpu_{side}.csv", f"dataset_mpu_{side}.csv"):
            if (path / name).is_file():
                return path / name, side
        raise ImportFormatError(
            f"{path}: no dataset_gps_mpu_{side}.csv or dataset_mpu_{side}.csv in the folder; "
            "is it a PVS drive folder?"
        )
    if not path.is_file():
        raise ImportFormatError(f"{path}: no such file")
    name = path.stem.lower()
    file_side = "right" if name.endswith("right") else "left" if name.endswith("left") else None
    if side and file_side and side != file_side:
        raise ImportFormatError(
            f"{path.name} holds the {file_side} side, but --side {side} was given; pass the "
            f"dataset_gps_mpu_{side}.csv file or drop --side"
        )
    return path, side or file_side or "left"


#: A PVS header is a few hundred characters; a longer first line is not a PVS file.
_MAX_HEADER_CHARS = 100_000


def _header(path: Path) -> list[str]:
    """The column names of a PVS CSV file's first line, or a one-line error for a file
    that is not CSV text (binary data, no line break)."""
    try:
        with open(path, "rb") as fh:
            raw = fh.readline(_MAX_HEADER_CHARS + 1)
    except OSError as exc:
        raise ImportFormatError(f"{path}: cannot read it ({exc.strerror}); give a PVS "
                                "dataset_gps_mpu_*.csv file or its folder") from None
    if b"\0" in raw or len(raw) > _MAX_HEADER_CHARS:
        raise ImportFormatError(f"{path.name}: not a CSV text file; give a PVS "
                                "dataset_gps_mpu_*.csv file or its folder")
    text = raw.decode("utf-8-sig", errors="replace")
    return [h.strip() for h in text.strip().split(",")]


def _read(path: Path, columns: list[str]) -> dict[str, np.ndarray]:
    """Read named columns fast; a missing column is named with what a PVS file holds."""
    from fielddiag.io.formats import read_csv_numeric

    header = _header(path)
    missing = [c for c in columns if c not in header]
    if missing:
        raise ImportFormatError(
            f"{path.name}: no column {', '.join(repr(m) for m in missing)}; a PVS "
            f"dataset_gps_mpu file has {', '.join(MPU_COLUMNS[:4])}, ...; is it a PVS file?"
        )
    return read_csv_numeric(path, columns)


def _vertical_axis(data: dict[str, np.ndarray], pos: str, choice: str) -> str:
    if choice in ("x", "y", "z"):
        return choice
    if choice != "auto":
        raise ImportFormatError(f"--vertical-axis must be x, y, z or auto, not {choice!r}")
    means = {a: abs(float(np.mean(data[f"acc_{a}_{pos}"]))) for a in "xyz"}
    return max(means, key=means.get)  # gravity points along the vertical axis


def import_pvs(
    path: str | os.PathLike,
    out_path: str | os.PathLike,
    *,
    side: str | None = None,
    vertical_axis: str = "auto",
    metadata: SessionMetadata | None = None,
    overwrite: bool = False,
) -> Path:
    """Import one side of a PVS drive into a session.

    Parameters
    ----------
    path : a PVS drive folder, or its ``dataset_gps_mpu_<side>.csv`` / ``dataset_mpu_<side>.csv``
    side : ``left`` or ``right``; default from the file name (a folder: ``left``)
    vertical_axis : ``x``, ``y``, ``z`` or ``auto`` (the axis with the largest mean, i.e.
        gravity), chosen per module
    metadata : root attributes; ``corner`` defaults to ``front-<side>``

    Returns
    -------
    Path
        The session written.
    """
    from fielddiag.io.formats import merged_metadata, write_imported_session

    if side is not None and side not in ("left", "right"):
        raise ImportFormatError(f"--side must be left or right, not {side!r}")
    src, side = _find_files(Path(path), side)
    header = _header(src)
    has_gps = all(c in header for c in GPS_COLUMNS)
    sensor_cols = [c for c in MPU_COLUMNS[1:] if c in header]
    required = ["timestamp", *(f"acc_{a}_{p}" for p in _ROLE_OF for a in "xyz")]
    cols = list(dict.fromkeys(required + sensor_cols + (list(GPS_COLUMNS) if has_gps else [])))
    data = _read(src, cols)
    t_unix = data["timestamp"]
    dt = np.diff(t_unix)
    if np.any(dt <= 0):
        i = int(np.flatnonzero(dt <= 0)[0])
        raise ImportFormatError(
            f"{src.name} row {i + 3}: timestamp {t_unix[i + 1]!r} does not increase; the file "
            "is not a PVS sensor file as published (sorted, 100 Hz)"
        )
    t0 = float(t_unix[0])
    n = t_unix.size
    rate_hz = (n - 1) / float(t_unix[-1] - t0)
    uniform = bool(np.max(np.abs(dt - 1.0 / rate_hz)) < 1e-4)

    channels: list[ChannelSpec] = []
    samples: dict[str, np.ndarray] = {}
    chosen_axes: dict[str, str] = {}
    for pos, (role, name) in _ROLE_OF.items():
        axis = _vertical_axis(data, pos, vertical_axis)
        col = f"acc_{axis}_{pos}"
        chosen_axes[pos] = axis
        flip = float(np.mean(data[col])) < 0
        sensor = f"MPU-9250 {pos.replace('_', ' ')} ({side}), PVS column {col}"
        if flip:
            sensor += ", sign flipped so up is positive"
        channels.append(
            ChannelSpec(name, unit="m/s2", role=role, axis="z", sensor=sensor,
                        scale=-1.0 if flip else 1.0)
        )
        samples[name] = data[col]
    used = {f"acc_{chosen_axes[p]}_{p}" for p in _ROLE_OF}
    for col in sensor_cols:
        if col in used:
            continue
        kind = col.split("_", 1)[0]
        unit, factor = _UNITS[kind]
        axis = col.split("_")[1] if kind != "temp" else ""
        channels.append(
            ChannelSpec(col, unit=unit, role="other", axis=axis if axis in "xyz" else "",
                        sensor=f"MPU-9250 ({side}), PVS column {col}", scale=factor)
        )
        samples[col] = data[col]

    signals = _gps_signals(src, data if has_gps else None, t0)
    events = _label_events(src, side, n, t_unix - t0)
    meta = merged_metadata(
        metadata,
        {
            "imported_from": src.name,
            "import_format": "pvs",
            "source_time_of_first_sample_s": t0,
            "pvs_side": side,
            "pvs_vertical_axis": chosen_axes,
        },
        corner=f"front-{side}",
        t0_unix_s=t0,
    )
    return write_imported_session(
        out_path,
        meta,
        channels=channels,
        samples=samples,
        daq_time_s=None if uniform else t_unix - t0,
        sample_rate_hz=rate_hz,
        signals=signals,
        events=events,
        overwrite=overwrite,
    )


def _gps_signals(
    src: Path, data: dict[str, np.ndarray] | None, t0: float
) -> dict[SignalSpec, tuple[np.ndarray, np.ndarray]]:
    """The GPS fixes (not the 100 Hz rows that repeat them) as signals on session time."""
    if data is not None:
        t_fix = data["timestamp_gps"]
        keep = np.concatenate([[True], np.diff(t_fix) != 0])
        t = t_fix[keep]
        speed, lat, lon = data["speed"][keep], data["latitude"][keep], data["longitude"][keep]
        message = "dataset_gps_mpu (fix held on every row)"
    else:
        gps = src.with_name("dataset_gps.csv")
        if not gps.is_file():
            return {}
        cols = _read(gps, ["timestamp", "speed_meters_per_second", "latitude", "longitude"])
        t, speed = cols["timestamp"], cols["speed_meters_per_second"]
        lat, lon = cols["latitude"], cols["longitude"]
        message = "dataset_gps.csv"
    order = np.argsort(t, kind="stable")
    t = t[order]
    unique = np.concatenate([[True], np.diff(t) > 0])
    t = t[unique] - t0
    take = order[unique]
    return {
        SignalSpec("vehicle_speed", unit="m/s", source="gnss", message=message, role="speed"):
            (t, speed[take]),
        SignalSpec("latitude_deg", unit="deg", source="gnss", message=message): (t, lat[take]),
        SignalSpec("longitude_deg", unit="deg", source="gnss", message=message): (t, lon[take]),
    }


def _label_events(src: Path, side: str, n: int, t: np.ndarray) -> list[Event]:
    """An event where each one-hot label of ``dataset_labels.csv`` switches on."""
    labels_path = src.with_name("dataset_labels.csv")
    if not labels_path.is_file():
        return []
    header = _header(labels_path)
    other = "right" if side == "left" else "left"
    cols = [h for h in header if h and not h.endswith(f"_{other}") and h != "no_speed_bump"]
    if not cols:
        return []
    data = _read(labels_path, cols)
    if data[cols[0]].size != n:
        return []  # not the labels of this file
    events: list[Event] = []
    for c in cols:
        if not np.isin(data[c], (0.0, 1.0)).all():
            continue  # not a one-hot label column (a time stamp, a count...)
        on = data[c] > 0.5
        starts = np.flatnonzero(on & ~np.concatenate([[False], on[:-1]]))
        events.extend(Event(float(t[i]), c) for i in starts)
    events.sort(key=lambda e: e.time_s)
    return events
