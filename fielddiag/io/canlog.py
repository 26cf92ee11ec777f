"""Import a CAN log (.log candump, .asc, .blf, .trc, python-can .csv...) decoded with a DBC.

The log is read with python-can's :class:`can.LogReader` (the file suffix picks the
reader), every frame is kept in the session (``/can_frames``, so it can be decoded again
later with another DBC), and the signals the user names are decoded with cantools and
stored as vehicle signals on their own time stamps.

Signals are named ``SIGNAL``, ``MESSAGE.SIGNAL`` or ``ALIAS=MESSAGE.SIGNAL``. Without
names, the vehicle speed and the wheel speeds are looked up in the DBC by their usual
names (``SPEED``, ``VEHICLE_SPEED``, ``WheelBasedVehicleSpeed``, ``WHEEL_SPEED_FL``...);
the vehicle speed gets the role ``speed``. Decoding, units (SI), CAN FD lengths and
names are those of :mod:`drivers.can_decode`, the decoder of live recording too: a log
imported here and the same frames recorded live give the same stored signals.

Time: the session's time zero is the first frame of the log; ``t0_unix_s`` is that
frame's wall-clock time when the log carries one (candump logs do).

The decoding works on arrays of :data:`fielddiag.session.CAN_FRAME_DTYPE`, so
:mod:`fielddiag.io.mdf` decodes ASAM MDF4 bus logging with the very same code.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from drivers.can_decode import (
    BusTable,
    CanDecoder,
    Dbc,
    buses_named,
    default_signals,
    frames_of,
    load_dbc,
    messages_to_frames,
    presence,
    resolve_signals,
)
from fielddiag.channels import SessionMetadata, SignalSpec
from fielddiag.errors import ImportFormatError

#: Suffixes python-can's LogReader understands (the suffix selects the reader).
CAN_LOG_SUFFIXES = (".asc", ".blf", ".csv", ".db", ".log", ".mf4", ".trc", ".txt")


# ---------------------------------------------------------------------------- DBC files
@dataclass(frozen=True)
class DbcFile:
    """A DBC file, optionally bound to one bus (``can1=radar.dbc``)."""

    path: Path
    bus: str | None = None


def parse_dbc_args(items: Iterable[str | os.PathLike | DbcFile] | str | None) -> list[DbcFile]:
    """``["pt.dbc", "can1=radar.dbc"]`` -> :class:`DbcFile` list (``BUS=FILE`` binds a bus)."""
    if items is None:
        return []
    if isinstance(items, str | os.PathLike | DbcFile):
        items = [items]
    out: list[DbcFile] = []
    for item in items:
        if isinstance(item, DbcFile):
            out.append(item)
            continue
        text = os.fspath(item)
        bus, sep, file = text.partition("=")
        if sep and bus and "/" not in bus and "\\" not in bus and file:
            out.append(DbcFile(Path(file), bus.strip()))
        else:
            out.append(DbcFile(Path(text)))
    return out


def load_dbcs(files: Sequence[DbcFile]) -> list[tuple[DbcFile, object]]:
    """Load DBC (or KCD/SYM/ARXML) files with cantools (:func:`drivers.can_decode.load_dbc`)."""
    return [(f, load_dbc(f.path)) for f in files]


# ---------------------------------------------------------------------------- frames
def read_can_log(path: str | os.PathLike) -> tuple[np.ndarray, dict[int, str]]:
    """Every frame of a CAN log file (time stamps as in the file) and the bus names.

    Bus indices follow :data:`drivers.can_decode.BUS_RULE` (``can1`` -> 1).
    """
    import can

    path = Path(path)
    if not path.is_file():
        raise ImportFormatError(f"{path}: no such file")
    suffix = path.suffix.lower()
    if suffix not in CAN_LOG_SUFFIXES:
        raise ImportFormatError(
            f"{path.name}: python-can reads CAN logs ending in {', '.join(CAN_LOG_SUFFIXES)}; "
            "rename the file to the suffix of its format"
        )
    try:
        reader = can.LogReader(str(path))
    except Exception as exc:
        raise ImportFormatError(f"{path.name}: cannot open it as a CAN log ({exc})") from None
    msgs: list = []
    table = BusTable()
    try:
        for msg in reader:
            msgs.append(msg)
        frames = messages_to_frames(
            msgs, [float(m.timestamp) for m in msgs], [table.index(m.channel) for m in msgs]
        )
    except Exception as exc:  # python-can raises ValueError, IndexError, struct.error...
        raise ImportFormatError(
            f"{path.name}: unreadable CAN log after {len(msgs)} frames ({type(exc).__name__}: "
            f"{exc}); the file is corrupt or not in the format its suffix says"
        ) from None
    finally:
        try:
            reader.stop()
        except Exception:  # noqa: BLE001 - closing a broken reader must not hide the cause
            pass
    if frames.size == 0:
        raise ImportFormatError(f"{path.name}: no CAN frames in the file")
    return frames, table.names


# ---------------------------------------------------------------------------- signals
def decode_signals(
    frames: np.ndarray,
    dbcs: Sequence[Dbc],
    signals: Sequence[str] | None,
    bus_names: Mapping[int, str],
    source: str,
) -> tuple[dict[SignalSpec, tuple[np.ndarray, np.ndarray]], int]:
    """Choose the signals (named, or the default speeds) and decode them from ``frames``.

    Returns ``({spec: (time_s, value_si)}, decode errors)``; every chosen signal has an
    entry, in the order chosen.

    Raises
    ------
    ImportFormatError
        No default signal occurs, a chosen message never occurs in the log, or occurs on
        several buses while its DBC is bound to none.
    DbcError
        A signal name is not in the DBCs, or is ambiguous.
    """
    present = presence(frames)
    if signals:
        choices = resolve_signals(dbcs, signals, present=present)
    else:
        choices = default_signals(dbcs, present)
        if not choices:
            raise ImportFormatError(
                f"{source}: no vehicle speed or wheel speed signal of the DBC occurs in the "
                "log; name the signals to import with --signal NAME (SIGNAL or MESSAGE.SIGNAL)"
            )
    for c in choices:
        idx = frames_of(frames, c.message, c.dbc.buses)
        m = c.message
        if idx.size == 0:
            raise ImportFormatError(
                f"{source}: message {m.name} (0x{m.frame_id:X}) of {c.dbc.label} never occurs "
                "in the log; check that the DBC describes this car and bus"
            )
        buses = np.unique(frames["bus"][idx])
        if buses.size > 1 and c.dbc.buses is None:
            names = ", ".join(bus_names.get(int(b), str(b)) or str(b) for b in buses)
            raise ImportFormatError(
                f"{source}: message {m.name} (0x{m.frame_id:X}) occurs on several buses "
                f"({names}); bind the DBC to one bus with --dbc BUS={c.dbc.label}"
            )
    dec = CanDecoder(choices)
    got = dec.decode(frames)
    empty = (np.zeros(0, dtype="f8"), np.zeros(0, dtype="f8"))
    return {c.spec: got.get(c.name, empty) for c in choices}, dec.errors


# ---------------------------------------------------------------------------- import
def decode_frames_to_signals(
    frames: np.ndarray,
    bus_names: Mapping[int, str],
    dbc: Iterable[str | os.PathLike | DbcFile] | str | os.PathLike | None,
    signals: Sequence[str] | None,
    source: str,
) -> tuple[dict[SignalSpec, tuple[np.ndarray, np.ndarray]], int, list[DbcFile]]:
    """DBC files + signal names + frames -> decoded signals, decode errors, DBC files used."""
    files = parse_dbc_args(dbc)
    if not files:
        raise ImportFormatError(
            f"{source}: CAN frames need a DBC file to decode; pass --dbc FILE (BUS=FILE binds "
            "it to one bus, e.g. can0=powertrain.dbc)"
        )
    dbcs = [
        Dbc(db, f.path.name, buses_named(f.bus, bus_names)) for f, db in load_dbcs(files)
    ]
    decoded, errors = decode_signals(frames, dbcs, list(signals or []), bus_names, source)
    return decoded, errors, files


def import_can_log(
    path: str | os.PathLike,
    out_path: str | os.PathLike,
    *,
    dbc: Iterable[str | os.PathLike | DbcFile] | str | os.PathLike | None = None,
    signals: Sequence[str] | None = None,
    metadata: SessionMetadata | None = None,
    overwrite: bool = False,
) -> Path:
    """Import a CAN log into a session: decoded signals plus every raw frame.

    Parameters
    ----------
    path : path of the log (``.log`` candump, ``.asc``, ``.blf``, ``.trc``, ``.csv``...)
    out_path : session file to write (atomically)
    dbc : one DBC file or several; ``BUS=FILE`` binds a DBC to one bus (``can1=adas.dbc``)
    signals : names to decode (``SIGNAL``, ``MESSAGE.SIGNAL`` or ``ALIAS=MESSAGE.SIGNAL``);
        default: vehicle speed and wheel speeds found in the DBC
    metadata : root attributes; ``extra`` gets how the import was made
    overwrite : replace ``out_path`` if it exists

    Returns
    -------
    Path
        The session written. It has no DAQ channels; its ``sample_rate_hz`` is the rate of
        the fastest decoded signal (nominal only).

    Raises
    ------
    ImportFormatError
        Unreadable or empty log, no DBC given, message never in the log.
    DbcError
        DBC missing or unreadable, signal not in the DBC or ambiguous.
    """
    from fielddiag.io.formats import merged_metadata, write_imported_session

    path = Path(path)
    if not path.is_file():
        raise ImportFormatError(f"{path}: no such file")
    files = parse_dbc_args(dbc)
    if not files:  # fail before reading a large log
        raise ImportFormatError(
            f"{path.name}: a CAN log needs a DBC file to decode; pass --dbc FILE"
        )
    load_dbcs(files)
    frames, bus_names = read_can_log(path)
    t_first = float(frames["time_s"].min())
    decoded, errors, files = decode_frames_to_signals(frames, bus_names, files, signals, path.name)
    frames["time_s"] -= t_first
    signals_rel = {spec: (t - t_first, v) for spec, (t, v) in decoded.items()}
    meta = merged_metadata(
        metadata,
        {
            "imported_from": path.name,
            "import_format": "canlog",
            "source_time_of_first_sample_s": t_first,
            "dbc_files": [f"{f.bus}={f.path.name}" if f.bus else f.path.name for f in files],
            "can_buses": {str(k): v for k, v in sorted(bus_names.items())},
        },
        t0_unix_s=t_first if t_first > 946684800.0 else 0.0,
    )
    return write_imported_session(
        out_path,
        meta,
        sample_rate_hz=fastest_rate_hz(signals_rel),
        signals=signals_rel,
        can_frames=frames,
        counters={"can_frames_received": int(frames.size), "can_decode_errors": errors},
        overwrite=overwrite,
    )


def fastest_rate_hz(signals: Mapping[SignalSpec, tuple[np.ndarray, np.ndarray]]) -> float:
    """Median sample rate of the fastest signal (1.0 if none has two samples)."""
    best = 0.0
    for t, _v in signals.values():
        if t.size > 1:
            dt = np.diff(t)
            dt = dt[dt > 0]
            if dt.size:
                best = max(best, 1.0 / float(np.median(dt)))
    return best if best > 0 else 1.0
