"""The import formats: a registry from format name to importer, and detection from the file.

Like python-can's interface registry, every format is a name mapped to ``"module:function"``
and the module is imported only when that format is used, so a missing optional
dependency (asammdf for MDF4) only matters to the files that need it.

Every importer has the signature ``importer(path, out_path, *, metadata, overwrite,
**options) -> Path`` and writes the session atomically (nothing is left behind when it
fails). :data:`FORMATS` lists each format with the options it takes; the command line
collects them with :func:`options_from_args`.

Examples
--------
>>> fmt = detect_format("drive.log")                       # 'canlog'
>>> import_file("drive.log", "drive.h5", dbc=["car.dbc"], signals=["SPEED"])
"""

from __future__ import annotations

import csv
import dataclasses
import importlib
import importlib.util
import os
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from fielddiag.channels import ChannelSpec, Event, Gap, SessionMetadata, SignalSpec
from fielddiag.errors import ImportFormatError
from fielddiag.session import SessionWriter


@dataclass(frozen=True)
class ImportOption:
    """An option an importer takes.

    Parameters
    ----------
    name : keyword the importer function takes
    cli : the command-line flag that carries it (``--dbc``)
    dest : attribute of the argparse namespace holding it
    help : one line for ``--help``
    repeatable : the flag may be given several times (a list)
    """

    name: str
    cli: str
    dest: str
    help: str
    repeatable: bool = False


@dataclass(frozen=True)
class ImportFormat:
    """One import format: its name, importer, options and how to recognise its files."""

    name: str
    description: str
    importer: str  # "module:function", imported lazily
    options: tuple[ImportOption, ...] = ()
    suffixes: tuple[str, ...] = ()
    aliases: tuple[str, ...] = ()
    requires: str | None = None  # optional package the importer needs

    def load(self):
        """The importer function (imports its module now)."""
        module, _, func = self.importer.partition(":")
        return getattr(importlib.import_module(module), func)


_ROLE = ImportOption(
    "roles", "--role", "role", "map a column/channel to a role, ROLE=NAME", repeatable=True
)
_DBC = ImportOption(
    "dbc", "--dbc", "dbc", "DBC file to decode CAN frames (BUS=FILE binds it to one bus)",
    repeatable=True,
)
_SIGNAL = ImportOption(
    "signals", "--signal", "signal",
    "CAN signal to decode, SIGNAL or MESSAGE.SIGNAL (default: vehicle and wheel speeds)",
    repeatable=True,
)

_VEHICLE_IMU_MODULE = "fielddiag.io.vehicle_imu"


def _vehicle_imu_available() -> bool:
    try:
        return importlib.util.find_spec(_VEHICLE_IMU_MODULE) is not None
    except (ImportError, ValueError):
        return False


def _build_formats() -> dict[str, ImportFormat]:
    formats = [
        ImportFormat(
            "csv",
            "CSV, one row per sample with a header; columns mapped to roles with --role",
            "fielddiag.io.formats:_import_generic_csv",
            (
                _ROLE,
                ImportOption("time_column", "--time", "time_column", "column holding time"),
                ImportOption("time_unit", "--time-unit", "time_unit", "s, ms or us"),
                ImportOption("accel_unit", "--accel-unit", "accel_unit", "m/s2 or g"),
                ImportOption("speed_unit", "--speed-unit", "speed_unit", "m/s, km/h or mph"),
            ),
            (".csv", ".txt", ".tsv"),
        ),
        ImportFormat(
            "fielddiag-csv",
            "CSV written by `fielddiag export` (with its .fielddiag.json manifest)",
            "fielddiag.io.csv_export:import_exported_csv",
            (),
            (".csv",),
        ),
        ImportFormat(
            "pvs",
            "PVS dataset (Menegazzo & von Wangenheim): dataset_gps_mpu_<side>.csv or its folder",
            "fielddiag.io.pvs:import_pvs",
            (
                ImportOption("side", "--side", "side", "PVS: left or right sensor network"),
                ImportOption(
                    "vertical_axis", "--vertical-axis", "vertical_axis",
                    "PVS: accelerometer axis that is vertical: x, y, z or auto",
                ),
            ),
            (".csv",),
        ),
        ImportFormat(
            "canlog",
            "CAN log (candump .log, .asc, .blf, .trc, python-can .csv) decoded with a DBC",
            "fielddiag.io.canlog:import_can_log",
            (_DBC, _SIGNAL),
            (".log", ".asc", ".blf", ".trc"),
            aliases=("can", "candump", "asc", "blf", "trc"),
        ),
        ImportFormat(
            "mdf",
            "ASAM MDF4 (.mf4): channels, and CAN bus logging decoded with a DBC",
            "fielddiag.io.mdf:import_mdf",
            (
                _DBC,
                _SIGNAL,
                _ROLE,
                ImportOption(
                    "channels", "--channel", "channel",
                    "MDF channel to import (default: all numeric channels)", repeatable=True,
                ),
            ),
            (".mf4", ".mdf", ".dat"),
            aliases=("mdf4", "mf4"),
            requires="asammdf",
        ),
    ]
    if _vehicle_imu_available():
        formats.append(
            ImportFormat(
                "comma2k19",
                "comma2k19 RAV4 drive: body IMU, CAN speeds and GNSS CSVs merged in one session",
                "fielddiag.io.formats:_import_comma2k19",
                (),
                (".csv",),
            )
        )
    return {f.name: f for f in formats}


#: Format name -> :class:`ImportFormat` (with its options), in detection order.
FORMATS: dict[str, ImportFormat] = _build_formats()


def get_format(name: str) -> ImportFormat:
    """The format called ``name`` (or one of its aliases)."""
    key = name.strip().lower()
    for f in FORMATS.values():
        if key == f.name or key in f.aliases:
            return f
    raise ImportFormatError(f"unknown format {name!r}; known: {', '.join(FORMATS)}")


# ---------------------------------------------------------------------------- detection
_CANDUMP_RE = re.compile(rb"^\s*\(\s*\d+(\.\d+)?\s*\)\s+\S+\s+[0-9A-Fa-f]{1,8}#")
PVS_REQUIRED = ("timestamp", "acc_z_below_suspension", "acc_z_above_suspension")
_PYTHON_CAN_CSV = ("timestamp", "arbitration_id", "extended", "remote", "error", "dlc", "data")
_COMMA2K19_COLUMNS = ("acc_down_mps2", "speed_mps", "wheel_fl_mps", "latitude_deg")


def _header_fields(head: bytes) -> list[str]:
    line = head.split(b"\n", 1)[0].decode("utf-8-sig", errors="replace").strip()
    counts = {d: line.count(d) for d in (",", ";", "\t")}
    delim = max(counts, key=counts.get)
    try:
        return [h.strip() for h in next(csv.reader([line], delimiter=delim or ","), [])]
    except csv.Error:  # not a CSV header (binary data): the importer says what is wrong
        return []


def manifest_path(csv_path: Path) -> Path:
    """The manifest that ``fielddiag export`` writes beside ``drive.csv``."""
    return csv_path.with_name(csv_path.stem + ".fielddiag.json")


def detect_format(path: str | os.PathLike) -> str:
    """The format of ``path``, from its contents first and its name second.

    Raises
    ------
    ImportFormatError
        The file does not exist or looks like none of the known formats.
    """
    p = Path(path)
    if not p.exists():
        raise ImportFormatError(f"{p}: no such file")
    if p.is_dir():
        names = {c.name for c in p.iterdir()}
        if names & {"dataset_gps_mpu_left.csv", "dataset_mpu_left.csv"}:
            return "pvs"
        if "comma2k19" in FORMATS:
            for c in sorted(p.glob("*.csv")):
                with open(c, "rb") as fh:
                    fields = _header_fields(fh.read(4096))
                if "t_boot_s" in fields and set(fields) & set(_COMMA2K19_COLUMNS):
                    return "comma2k19"
        raise ImportFormatError(
            f"{p} is a folder that holds neither a PVS dataset nor a known recording; pass a file"
        )
    try:
        with open(p, "rb") as fh:
            head = fh.read(4096)
    except OSError as exc:
        raise ImportFormatError(f"{p}: cannot read it ({exc.strerror})") from None
    suffix = p.suffix.lower()
    if head.startswith((b"MDF     ", b"UnFinMF ")):
        return "mdf"
    if head.startswith(b"LOGG") or suffix in (".blf", ".asc", ".trc"):
        return "canlog"
    first = next((ln for ln in head.splitlines() if ln.strip()), b"")
    if _CANDUMP_RE.match(first):
        return "canlog"
    if suffix in (".csv", ".txt", ".tsv"):
        fields = _header_fields(head)
        if suffix == ".csv" and manifest_path(p).is_file():
            return "fielddiag-csv"
        if all(c in fields for c in PVS_REQUIRED):
            return "pvs"
        if "comma2k19" in FORMATS and "t_boot_s" in fields and (
            set(fields) & set(_COMMA2K19_COLUMNS)
        ):
            return "comma2k19"
        if tuple(fields[: len(_PYTHON_CAN_CSV)]) == _PYTHON_CAN_CSV:
            return "canlog"
        return "csv"
    if suffix in (".mf4", ".mdf"):
        raise ImportFormatError(f"{p.name}: not an MDF file (no MDF header); is it corrupt? "
                                "Export it again from the logger, or give --format if it is "
                                "another format")
    known = sorted({s for f in FORMATS.values() for s in f.suffixes})
    raise ImportFormatError(
        f"cannot tell the format of {p.name} from its name or contents (known endings: "
        f"{', '.join(known)}); pass --format ({', '.join(FORMATS)})"
    )


# ---------------------------------------------------------------------------- importing
def import_file(
    path: str | os.PathLike,
    out_path: str | os.PathLike,
    *,
    format: str | None = None,  # noqa: A002 - the CLI calls it --format
    metadata: SessionMetadata | None = None,
    overwrite: bool = False,
    **options: Any,
) -> Path:
    """Import ``path`` into the session ``out_path`` with the importer of its format.

    Parameters
    ----------
    format : str, optional
        Format name or alias (see :data:`FORMATS`); default :func:`detect_format`.
    metadata : SessionMetadata, optional
        Root attributes from the user (vehicle, corner, added mass...). Formats that carry
        their own metadata (a fielddiag export) keep theirs where the user left a default.
    options :
        The format's options (see ``FORMATS[name].options``). Options set to None or an
        empty list are ignored; an option the format does not take is an error.

    Returns
    -------
    Path
        The session written.
    """
    fmt = get_format(format) if format else get_format(detect_format(path))
    names = {o.name for o in fmt.options}
    given = {k: v for k, v in options.items() if v is not None and v != [] and v != ()}
    unknown = sorted(set(given) - names)
    if unknown:
        flags = {o.name: o.cli for f in FORMATS.values() for o in f.options}
        raise ImportFormatError(
            f"{', '.join(flags.get(u, u) for u in unknown)} does not apply to format "
            f"{fmt.name!r}; it takes {', '.join(o.cli for o in fmt.options) or 'no options'}"
        )
    if fmt.requires and importlib.util.find_spec(fmt.requires) is None:
        from fielddiag.errors import FieldDiagError

        raise FieldDiagError(
            f"format {fmt.name} needs the package {fmt.requires}: "
            f"pip install 'fielddiag[{'mdf' if fmt.name == 'mdf' else fmt.requires}]'"
        )
    importer = fmt.load()
    return Path(
        importer(
            Path(path),
            out_path,
            metadata=metadata or SessionMetadata(),
            overwrite=overwrite,
            **given,
        )
    )


def options_from_args(format_name: str, args: Any) -> dict[str, Any]:
    """Import options set on an argparse namespace (found by ``dest``), for ``import_file``.

    The options of ``format_name`` are returned, and so is any other format's option the
    user set (not None, not empty), so that :func:`import_file` can say it does not apply
    instead of ignoring it. Give options that belong to one format a default of None.
    """
    fmt = get_format(format_name)
    out: dict[str, Any] = {}
    for f in [fmt, *FORMATS.values()]:
        for o in f.options:
            value = getattr(args, o.dest, None)
            if o.name not in out and value is not None and value != []:
                out[o.name] = value
    return out


# ---------------------------------------------------------------------------- helpers
def merged_metadata(
    metadata: SessionMetadata | None, extra: Mapping[str, Any], **fields: Any
) -> SessionMetadata:
    """A copy of ``metadata`` with ``extra`` merged in and ``fields`` set where it has defaults.

    The caller's object is not modified.
    """
    meta = dataclasses.replace(metadata) if metadata else SessionMetadata()
    defaults = SessionMetadata()
    for k, v in fields.items():
        if getattr(meta, k) == getattr(defaults, k):
            setattr(meta, k, v)
    meta.extra = {**(metadata.extra if metadata else {}), **dict(extra)}
    return meta


def overlay_metadata(stored: SessionMetadata, user: SessionMetadata | None) -> SessionMetadata:
    """``stored`` metadata (from a file) with every field the user set (not default) on top."""
    meta = dataclasses.replace(stored, extra=dict(stored.extra))
    if user is None:
        return meta
    defaults = SessionMetadata()
    for f in dataclasses.fields(SessionMetadata):
        value = getattr(user, f.name)
        if f.name == "extra":
            meta.extra.update(value)
        elif value != getattr(defaults, f.name):
            setattr(meta, f.name, value)
    return meta


def write_imported_session(
    out_path: str | os.PathLike,
    metadata: SessionMetadata,
    *,
    channels: Iterable[ChannelSpec] = (),
    samples: Mapping[str, np.ndarray] | np.ndarray | None = None,
    daq_time_s: np.ndarray | None = None,
    sample_rate_hz: float,
    t0_s: float = 0.0,
    signals: Mapping[SignalSpec, tuple[np.ndarray, np.ndarray]] | None = None,
    can_frames: np.ndarray | None = None,
    events: Iterable[Event] = (),
    gaps: Iterable[Gap] = (),
    counters: Mapping[str, int] | None = None,
    overwrite: bool = False,
) -> Path:
    """Write a whole imported session atomically (a failure leaves nothing behind).

    ``daq_time_s`` None means a uniform time base ``t0_s + i / sample_rate_hz``. Raw
    samples are given per channel (a mapping keeps each channel's dtype).
    """
    channels = list(channels)
    signals = dict(signals or {})
    with SessionWriter(
        out_path,
        metadata,
        channels,
        sample_rate_hz=sample_rate_hz,
        time_base="uniform" if daq_time_s is None else "timestamps",
        t0_s=t0_s,
        signals=list(signals),
        store_can_frames=can_frames is not None,
        overwrite=overwrite,
        atomic=True,
        flush_interval_s=3600.0,
    ) as w:
        if channels and samples is not None:
            w.append_daq(samples, daq_time_s)
        for spec, (t, v) in signals.items():
            w.append_signal(spec.name, t, v)
        if can_frames is not None and can_frames.size:
            w.append_can_frames(can_frames)
        for e in events:
            w.add_event(e.time_s, e.label)
        for g in gaps:
            w.add_gap(g.start_s, g.end_s, g.samples_lost, g.cause)
        if counters:
            w.set_counters(**counters)
    return Path(out_path)


def read_csv_numeric(
    path: Path, columns: list[str], delimiter: str = ","
) -> dict[str, np.ndarray]:
    """Named float columns of a CSV file, read fast by numpy.

    Every value parses exactly (shortest-repr floats come back bit for bit). On any
    problem the file is read again by :func:`fielddiag.io.csv_import.read_csv_columns`,
    which raises an :class:`ImportFormatError` naming the row and column.
    """
    from fielddiag.io.csv_import import read_csv_columns

    try:
        with open(path, encoding="utf-8-sig") as fh:
            header = [h.strip() for h in next(csv.reader([fh.readline()], delimiter=delimiter))]
    except (OSError, StopIteration, UnicodeDecodeError, csv.Error):
        header = []  # read_csv_columns says what is wrong
    if header and all(c in header for c in columns):
        idx = [header.index(c) for c in columns]
        try:
            data = np.loadtxt(
                path, delimiter=delimiter, skiprows=1, usecols=idx, dtype="f8", ndmin=2,
                encoding="utf-8-sig",
            )
            if data.shape[0] >= 2 and np.isfinite(data).all():
                return {c: np.ascontiguousarray(data[:, k]) for k, c in enumerate(columns)}
        except ValueError:
            pass
    return read_csv_columns(path, columns, delimiter)


# ---------------------------------------------------------------------------- adapters
def _import_generic_csv(
    path: Path,
    out_path: str | os.PathLike,
    *,
    metadata: SessionMetadata,
    overwrite: bool = False,
    roles: Mapping[str, str] | Iterable[str] | None = None,
    time_column: str | None = None,
    time_unit: str = "s",
    accel_unit: str = "m/s2",
    speed_unit: str = "m/s",
) -> Path:
    from fielddiag.io.csv_import import CsvImportOptions, import_csv, parse_role_args

    if not time_column:
        raise ImportFormatError("say which column holds the time with --time COLUMN")
    role_map = dict(roles) if isinstance(roles, Mapping) else parse_role_args(list(roles or []))
    options = CsvImportOptions(
        roles=role_map,
        time_column=time_column,
        time_unit=time_unit,
        accel_unit=accel_unit,
        speed_unit=speed_unit,
    )
    meta = dataclasses.replace(metadata, extra=dict(metadata.extra))
    return import_csv(path, out_path, options, meta, overwrite=overwrite)


def _comma2k19_files(path: Path) -> dict[str, Path]:
    """The IMU, CAN speed and GNSS CSVs of a comma2k19 excerpt, found by their headers.

    ``path`` is one of them or their folder; with several segments in a folder, the file
    whose name shares the longest prefix with ``path`` wins.
    """
    folder = path if path.is_dir() else path.parent
    kinds = {"imu": "acc_down_mps2", "speed": "wheel_fl_mps", "gnss": "latitude_deg"}
    found: dict[str, list[Path]] = {k: [] for k in kinds}
    for c in sorted(folder.glob("*.csv")):
        with open(c, "rb") as fh:
            fields = _header_fields(fh.read(4096))
        if "t_boot_s" not in fields:
            continue
        for kind, column in kinds.items():
            if column in fields:
                found[kind].append(c)

    def shared(c: Path) -> int:
        return len(os.path.commonprefix([c.name, path.name])) if path.is_file() else 0

    return {k: max(v, key=shared) for k, v in found.items() if v}


def _import_comma2k19(
    path: Path,
    out_path: str | os.PathLike,
    *,
    metadata: SessionMetadata,
    overwrite: bool = False,
) -> Path:
    """Hand the three comma2k19 CSVs to fielddiag.io.vehicle_imu (imported at call time).

    GNSS is merged in when its CSV is beside the IMU one. The vehicle name is passed on;
    the other metadata fields are set by that importer.
    """
    try:
        module = importlib.import_module(_VEHICLE_IMU_MODULE)
    except ModuleNotFoundError as exc:
        if exc.name != _VEHICLE_IMU_MODULE:
            raise
        raise ImportFormatError(
            f"{path.name}: the comma2k19 importer is not part of this fielddiag; import the "
            "CSV with --format csv and --role/--time instead"
        ) from None
    files = _comma2k19_files(Path(path))
    if "imu" not in files:
        raise ImportFormatError(
            f"{path.name}: no comma2k19 IMU CSV (with t_boot_s and acc_down_mps2) beside it; "
            "import the IMU file together with its CAN speed and GNSS files"
        )
    kwargs: dict[str, Any] = {
        "gnss_csv": files.get("gnss"),
        "overwrite": overwrite,
        "metadata": metadata,
    }
    if metadata.vehicle:
        kwargs["vehicle"] = metadata.vehicle
    return Path(module.import_vehicle_imu(files["imu"], files.get("speed"), out_path, **kwargs))
