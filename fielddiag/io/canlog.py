"""Import a CAN log (.log candump, .asc, .blf, .trc, python-can .csv...) decoded with a DBC.

The log is read with python-can's :class:`can.LogReader` (the file suffix picks the
reader), every frame is kept in the session (``/can_frames``, so it can be decoded again
later with another DBC), and the signals the user names are decoded with cantools and
stored as vehicle signals on their own time stamps.

Signals are named ``SIGNAL`` or ``MESSAGE.SIGNAL``. Without names, the vehicle speed and
the wheel speeds are looked up in the DBC by their usual names (``SPEED``,
``VEHICLE_SPEED``, ``WheelBasedVehicleSpeed``, ``WHEEL_SPEED_FL``...); the vehicle speed
gets the role ``speed``. Values are converted to SI (km/h and mph to m/s, deg to rad,
deg/s and rpm to rad/s, g to m/s2); other units are kept as the DBC states them.

Time: the session's time zero is the first frame of the log; ``t0_unix_s`` is that
frame's wall-clock time when the log carries one (candump logs do).

The frame decoding here works on arrays of :data:`fielddiag.session.CAN_FRAME_DTYPE`, so
:mod:`fielddiag.io.mdf` decodes ASAM MDF4 bus logging with the very same code.
"""

from __future__ import annotations

import difflib
import math
import os
import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fielddiag.channels import SessionMetadata, SignalSpec
from fielddiag.errors import ImportFormatError
from fielddiag.session import (
    CAN_DATA_BYTES,
    CAN_FLAG_BRS,
    CAN_FLAG_ERROR,
    CAN_FLAG_ESI,
    CAN_FLAG_EXTENDED,
    CAN_FLAG_FD,
    CAN_FLAG_REMOTE,
    CAN_FLAG_RX,
    CAN_FRAME_DTYPE,
    safe_name,
)

G_MPS2 = 9.80665

#: Suffixes python-can's LogReader understands (the suffix selects the reader).
CAN_LOG_SUFFIXES = (".asc", ".blf", ".csv", ".db", ".log", ".mf4", ".trc", ".txt")

#: unit (lower case, as DBC files write it) -> (factor to SI, SI unit)
_UNIT_TO_SI: dict[str, tuple[float, str]] = {
    "km/h": (1 / 3.6, "m/s"),
    "kph": (1 / 3.6, "m/s"),
    "kmh": (1 / 3.6, "m/s"),
    "km/hr": (1 / 3.6, "m/s"),
    "mph": (0.44704, "m/s"),
    "m/s": (1.0, "m/s"),
    "deg": (math.pi / 180, "rad"),
    "degree": (math.pi / 180, "rad"),
    "degrees": (math.pi / 180, "rad"),
    "°": (math.pi / 180, "rad"),
    "deg/s": (math.pi / 180, "rad/s"),
    "deg/sec": (math.pi / 180, "rad/s"),
    "°/s": (math.pi / 180, "rad/s"),
    "rpm": (2 * math.pi / 60, "rad/s"),
    "1/min": (2 * math.pi / 60, "rad/s"),
    "g": (G_MPS2, "m/s2"),
    "m/s2": (1.0, "m/s2"),
    "m/s^2": (1.0, "m/s2"),
    "m/s²": (1.0, "m/s2"),
    "m/s/s": (1.0, "m/s2"),
    "mps2": (1.0, "m/s2"),
}

#: Normalised names (lower case, letters and digits only) of a vehicle speed signal, in
#: order of preference.
VEHICLE_SPEED_NAMES = (
    "vehiclespeed",
    "speed",
    "vehspeed",
    "vehspd",
    "vspd",
    "vehiclespd",
    "wheelbasedvehiclespeed",
)
_WHEEL_SPEED_RE = re.compile(r"(wheelspeed|wheelspd|whlspd|whlspeed)")
_SPEED_UNITS = {"km/h", "kph", "kmh", "km/hr", "mph", "m/s"}


def si_unit(unit: str | None) -> tuple[float, str]:
    """Factor and SI unit for ``unit`` (``("km/h") -> (1/3.6, "m/s")``); unknown: kept."""
    key = (unit or "").strip()
    return _UNIT_TO_SI.get(key.lower(), (1.0, key))


def _norm(name: str) -> str:
    return re.sub(r"[^a-z0-9]", "", name.lower())


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
    """Load DBC (or KCD/SYM/ARXML) files with cantools, ``strict=False``."""
    import cantools

    loaded = []
    for f in files:
        if not f.path.is_file():
            raise ImportFormatError(
                f"DBC file {f.path} not found; pass the database that describes this bus with "
                "--dbc FILE"
            )
        try:
            db = cantools.database.load_file(str(f.path), strict=False)
        except Exception as exc:  # cantools raises many types for bad files
            raise ImportFormatError(
                f"{f.path.name}: not a readable CAN database ({exc}); pass a .dbc, .kcd, .sym "
                "or .arxml file with --dbc"
            ) from None
        loaded.append((f, db))
    return loaded


# ---------------------------------------------------------------------------- frames
def _dlc_to_length(dlc: int, fd: bool) -> int:
    """Payload length of a frame (python-can stores the byte count as dlc)."""
    return min(int(dlc), CAN_DATA_BYTES) if fd else min(int(dlc), 8)


def frame_payload(frame: np.void | np.ndarray) -> bytes:
    """The payload bytes of one stored frame."""
    fd = bool(int(frame["flags"]) & CAN_FLAG_FD)
    return bytes(frame["data"][: _dlc_to_length(int(frame["dlc"]), fd)])


def messages_to_frames(messages: Iterable, source: str) -> tuple[np.ndarray, dict[int, str]]:
    """python-can messages -> (frames with source time stamps, bus index -> bus name).

    Bus indices come from the channel names (``can1`` -> 1, an int channel is itself);
    names without a number, or clashing numbers, get the next free index.
    """
    from can.util import channel2int

    times: list[float] = []
    ids: list[int] = []
    buses: list[int] = []
    flags: list[int] = []
    dlcs: list[int] = []
    payloads: list[bytes] = []
    bus_index: dict[object, int] = {}
    bus_names: dict[int, str] = {}
    pad = b"\0" * CAN_DATA_BYTES
    try:
        for msg in messages:
            ch = msg.channel
            idx = bus_index.get(ch)
            if idx is None:
                guess = channel2int(ch) if ch is not None else 0
                if guess is None or guess in bus_names or not 0 <= guess <= 255:
                    guess = next(i for i in range(256) if i not in bus_names)
                idx = bus_index[ch] = guess
                bus_names[idx] = "" if ch is None else str(ch)
            f = 0
            if msg.is_extended_id:
                f |= CAN_FLAG_EXTENDED
            if msg.is_remote_frame:
                f |= CAN_FLAG_REMOTE
            if msg.is_error_frame:
                f |= CAN_FLAG_ERROR
            if msg.is_fd:
                f |= CAN_FLAG_FD
            if msg.bitrate_switch:
                f |= CAN_FLAG_BRS
            if msg.error_state_indicator:
                f |= CAN_FLAG_ESI
            if msg.is_rx:
                f |= CAN_FLAG_RX
            data = bytes(msg.data or b"")
            times.append(float(msg.timestamp))
            ids.append(int(msg.arbitration_id))
            buses.append(idx)
            flags.append(f)
            dlcs.append(int(msg.dlc))
            payloads.append((data + pad)[:CAN_DATA_BYTES])
    except ImportFormatError:
        raise
    except Exception as exc:  # python-can raises ValueError, IndexError, struct.error...
        raise ImportFormatError(
            f"{source}: unreadable CAN log after {len(times)} frames ({type(exc).__name__}: "
            f"{exc}); the file is corrupt or not in the format its suffix says"
        ) from None
    frames = np.zeros(len(times), dtype=CAN_FRAME_DTYPE)
    if times:
        frames["time_s"] = times
        frames["arbitration_id"] = ids
        frames["bus"] = buses
        frames["flags"] = flags
        frames["dlc"] = dlcs
        frames["data"] = np.frombuffer(b"".join(payloads), dtype="u1").reshape(
            -1, CAN_DATA_BYTES
        )
    return frames, bus_names


def read_can_log(path: str | os.PathLike) -> tuple[np.ndarray, dict[int, str]]:
    """Every frame of a CAN log file (time stamps as in the file) and the bus names."""
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
    try:
        frames, buses = messages_to_frames(reader, path.name)
    finally:
        try:
            reader.stop()
        except Exception:  # noqa: BLE001 - closing a broken reader must not hide the cause
            pass
    if frames.size == 0:
        raise ImportFormatError(f"{path.name}: no CAN frames in the file")
    return frames, buses


# ---------------------------------------------------------------------------- signals
@dataclass(frozen=True)
class SignalChoice:
    """One signal to decode: where it is defined and how it is stored."""

    session_name: str
    dbc_index: int
    message: object  # cantools Message
    signal: object  # cantools Signal
    role: str = "other"


def _bus_allowed(dbc: DbcFile, bus_idx: int, bus_names: Mapping[int, str]) -> bool:
    if dbc.bus is None:
        return True
    return dbc.bus in (bus_names.get(bus_idx, ""), str(bus_idx))


def _frames_of(
    frames: np.ndarray, message, dbc: DbcFile, bus_names: Mapping[int, str]
) -> np.ndarray:
    """Indices of the data frames that carry ``message`` on the buses ``dbc`` covers."""
    ext = (frames["flags"] & CAN_FLAG_EXTENDED) != 0
    bad = (frames["flags"] & (CAN_FLAG_REMOTE | CAN_FLAG_ERROR)) != 0
    sel = (frames["arbitration_id"] == message.frame_id) & (ext == bool(message.is_extended_frame))
    sel &= ~bad
    if dbc.bus is not None:
        ok = np.array([_bus_allowed(dbc, int(b), bus_names) for b in range(256)])
        sel &= ok[frames["bus"]]
    return np.flatnonzero(sel)


def _present(frames: np.ndarray, message, dbc: DbcFile, bus_names) -> bool:
    return _frames_of(frames, message, dbc, bus_names).size > 0


def resolve_signals(
    dbcs: Sequence[tuple[DbcFile, object]],
    names: Sequence[str] | None,
    frames: np.ndarray,
    bus_names: Mapping[int, str],
    source: str,
) -> list[SignalChoice]:
    """Find the signals to decode (named, or the default speed signals) in the DBCs."""
    found: list[tuple[int, object, object]] = []  # (dbc index, message, signal)
    index: dict[str, list[tuple[int, object, object]]] = {}
    for di, (_f, db) in enumerate(dbcs):
        for m in db.messages:
            for s in m.signals:
                entry = (di, m, s)
                index.setdefault(s.name, []).append(entry)
                index.setdefault(f"{m.name}.{s.name}", []).append(entry)
    if names:
        for name in names:
            hits = index.get(name)
            if not hits:
                close = difflib.get_close_matches(name, list(index), n=5)
                hint = f"; did you mean {', '.join(close)}?" if close else ""
                dbc_names = ", ".join(f.path.name for f, _ in dbcs)
                raise ImportFormatError(
                    f"signal {name!r} is not in {dbc_names}{hint} Name it as SIGNAL or "
                    "MESSAGE.SIGNAL as the DBC spells it"
                )
            if len(hits) > 1:
                live = [h for h in hits if _present(frames, h[1], dbcs[h[0]][0], bus_names)]
                hits = live if len(live) == 1 else hits
            if len(hits) > 1:
                where = ", ".join(f"{m.name}.{s.name}" for _, m, s in hits)
                raise ImportFormatError(
                    f"signal {name!r} is defined in several messages ({where}); name it as "
                    "MESSAGE.SIGNAL"
                )
            found.append(hits[0])
    else:
        found = _default_signals(dbcs, frames, bus_names)
        if not found:
            raise ImportFormatError(
                f"{source}: no vehicle speed or wheel speed signal of the DBC occurs in the log; "
                "name the signals to import with --signal NAME (SIGNAL or MESSAGE.SIGNAL)"
            )
    # vehicle speed role: the first default pick, or a named signal that looks like one
    speed_key = None
    for di, m, s in found:
        if _norm(s.name) in VEHICLE_SPEED_NAMES and (s.unit or "").lower() in _SPEED_UNITS:
            speed_key = (di, m.name, s.name)
            break
    choices: list[SignalChoice] = []
    seen: set[tuple[int, str, str]] = set()
    short_count: dict[str, int] = {}
    for _di, _m, s in found:
        short_count[s.name] = short_count.get(s.name, 0) + 1
    for di, m, s in found:
        key = (di, m.name, s.name)
        if key in seen:
            continue
        seen.add(key)
        session_name = s.name if short_count[s.name] == 1 else f"{m.name}.{s.name}"
        session_name = safe_name(session_name)
        role = "speed" if key == speed_key else "other"
        choices.append(SignalChoice(session_name, di, m, s, role))
    return choices


def _default_signals(dbcs, frames, bus_names) -> list[tuple[int, object, object]]:
    speed: list[tuple[int, int, object, object]] = []
    wheels: list[tuple[int, object, object]] = []
    for di, (f, db) in enumerate(dbcs):
        for m in db.messages:
            speed_sigs = [s for s in m.signals if (s.unit or "").lower() in _SPEED_UNITS]
            if not speed_sigs or not _present(frames, m, f, bus_names):
                continue
            for s in speed_sigs:
                n = _norm(s.name)
                if n in VEHICLE_SPEED_NAMES:
                    speed.append((VEHICLE_SPEED_NAMES.index(n), di, m, s))
                elif _WHEEL_SPEED_RE.search(n):
                    wheels.append((di, m, s))
    out: list[tuple[int, object, object]] = []
    if speed:
        _, di, m, s = min(speed, key=lambda x: x[0])
        out.append((di, m, s))
    wheels.sort(key=lambda x: x[2].name)
    return out + wheels


def decode_signals(
    frames: np.ndarray,
    dbcs: Sequence[tuple[DbcFile, object]],
    choices: Sequence[SignalChoice],
    bus_names: Mapping[int, str],
    source: str,
) -> tuple[dict[SignalSpec, tuple[np.ndarray, np.ndarray]], int]:
    """Decode the chosen signals from ``frames``; returns ({spec: (t, value_si)}, errors).

    Frames that fail to decode (wrong length, bad multiplexer) are counted and skipped.
    """
    by_message: dict[tuple[int, str], list[SignalChoice]] = {}
    for c in choices:
        by_message.setdefault((c.dbc_index, c.message.name), []).append(c)
    out: dict[SignalSpec, tuple[np.ndarray, np.ndarray]] = {}
    errors = 0
    for (di, _mname), group in by_message.items():
        dbc = dbcs[di][0]
        message = group[0].message
        idx = _frames_of(frames, message, dbc, bus_names)
        if idx.size == 0:
            raise ImportFormatError(
                f"{source}: message {message.name} (0x{message.frame_id:X}) of "
                f"{dbc.path.name} never occurs in the log; check that the DBC describes this "
                "car and bus"
            )
        buses = np.unique(frames["bus"][idx])
        if buses.size > 1 and dbc.bus is None:
            names = ", ".join(bus_names.get(int(b), str(b)) or str(b) for b in buses)
            raise ImportFormatError(
                f"{source}: message {message.name} (0x{message.frame_id:X}) occurs on several "
                f"buses ({names}); bind the DBC to one bus with --dbc BUS={dbc.path}"
            )
        t_list: list[float] = []
        vals: dict[str, list[float]] = {c.signal.name: [] for c in group}
        times: dict[str, list[float]] = {c.signal.name: [] for c in group}
        for i in idx:
            fr = frames[i]
            try:
                decoded = message.decode(
                    frame_payload(fr), decode_choices=False, scaling=True, allow_truncated=False
                )
            except Exception:  # cantools DecodeError and friends
                errors += 1
                continue
            t = float(fr["time_s"])
            t_list.append(t)
            for c in group:
                v = decoded.get(c.signal.name)
                if v is None:  # multiplexed signal absent from this frame
                    continue
                times[c.signal.name].append(t)
                vals[c.signal.name].append(float(v))
        for c in group:
            factor, unit = si_unit(c.signal.unit)
            t = np.asarray(times[c.signal.name], dtype="f8")
            v = np.asarray(vals[c.signal.name], dtype="f8") * factor
            spec = SignalSpec(
                c.session_name, unit=unit, source="can", message=message.name, role=c.role
            )
            out[spec] = (t, v)
    return out, errors


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
    dbcs = load_dbcs(files)
    choices = resolve_signals(dbcs, list(signals or []), frames, bus_names, source)
    decoded, errors = decode_signals(frames, dbcs, choices, bus_names, source)
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
    signals : names to decode (``SIGNAL`` or ``MESSAGE.SIGNAL``); default: vehicle speed
        and wheel speeds found in the DBC
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
        Unreadable or empty log, missing DBC, signal not in the DBC, message never in the log.
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
