"""ASAM MDF4 (.mf4) import and export with asammdf.

Export (:func:`export_mdf`) writes one session as an MDF 4.10 file (standard blocks only;
tested with asammdf and python-can's MF4 reader):

* channel group ``fielddiag DAQ``: every DAQ channel with its name, unit and a comment
  (``role=wheel; axis=z; sensor=...``), stored raw in the recorder's dtype with the
  calibration as a linear conversion (physical = raw * scale + offset), on one master
  time channel (session time, s);
* one channel group per vehicle signal (``signal vehicle_speed``...) on its own time base;
* the raw CAN frames as ASAM bus logging (``CAN_DataFrame``/``CAN_ErrorFrame``/
  ``CAN_RemoteFrame`` groups, the layout python-can's MF4Writer and CANedge use);
* the header start time = the session's ``t0_unix_s`` (1970-01-01 when unknown), author =
  operator, subject = vehicle; and an embedded attachment ``fielddiag_session.json`` with
  what MDF has no field for (roles, metadata, events, gaps, counters), so that
  :func:`import_mdf` restores the session exactly.

Import (:func:`import_mdf`):

* a file written by :func:`export_mdf` comes back as the same session (every raw sample,
  dtype, calibration, unit, time stamp, signal, frame, event, gap and counter);
* any other MDF4: ``roles`` maps roles to channel names (``wheel=AccZ_FL``); DAQ channels
  (every role but ``speed``) must share one channel group; the other numeric channels
  become signals on their own time bases (``channels`` limits which). Without roles, the
  channel group with the most samples becomes the DAQ channels (role ``other``);
* CAN bus logging (``CAN_DataFrame`` groups) is kept as raw frames and decoded with the
  DBC files given (``dbc``), by the same decoder as CAN logs (:mod:`fielddiag.io.canlog`),
  so a signal decodes to the same values and units from either.

asammdf is an optional dependency: ``pip install 'fielddiag[mdf]'``.
"""

from __future__ import annotations

import gc
import importlib.util
import json
import math
import os
import sys
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import fields
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from drivers.can_decode import FD_LENGTHS, payload_lengths
from fielddiag.channels import ChannelSpec, Event, Gap, SessionMetadata, SignalSpec
from fielddiag.errors import FieldDiagError, ImportFormatError
from fielddiag.outputs import atomic_file
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
    SessionReader,
    unique_name,
)
from fielddiag.units import to_si

MANIFEST_NAME = "fielddiag_session.json"
MANIFEST_FORMAT = "fielddiag-mdf"
DAQ_GROUP_NAME = "fielddiag DAQ"
_CHUNK = 1 << 20

#: Record layouts of ASAM MDF4 CAN bus logging (as python-can's MF4Writer writes them).
CAN_DATA_DTYPE = np.dtype(
    [
        ("CAN_DataFrame.BusChannel", "<u1"),
        ("CAN_DataFrame.ID", "<u4"),
        ("CAN_DataFrame.IDE", "<u1"),
        ("CAN_DataFrame.DLC", "<u1"),
        ("CAN_DataFrame.DataLength", "<u1"),
        ("CAN_DataFrame.DataBytes", "(64,)u1"),
        ("CAN_DataFrame.Dir", "<u1"),
        ("CAN_DataFrame.EDL", "<u1"),
        ("CAN_DataFrame.BRS", "<u1"),
        ("CAN_DataFrame.ESI", "<u1"),
    ]
)
CAN_ERROR_DTYPE = np.dtype(
    [(n.replace("DataFrame", "ErrorFrame"), CAN_DATA_DTYPE.fields[n][0]) for n in
     CAN_DATA_DTYPE.names]
)
CAN_REMOTE_DTYPE = np.dtype(
    [
        ("CAN_RemoteFrame.BusChannel", "<u1"),
        ("CAN_RemoteFrame.ID", "<u4"),
        ("CAN_RemoteFrame.IDE", "<u1"),
        ("CAN_RemoteFrame.DLC", "<u1"),
        ("CAN_RemoteFrame.DataLength", "<u1"),
        ("CAN_RemoteFrame.Dir", "<u1"),
    ]
)
_BUS_KINDS = ("CAN_DataFrame", "CAN_ErrorFrame", "CAN_RemoteFrame")


def asammdf_available() -> bool:
    """True when asammdf can be imported."""
    return importlib.util.find_spec("asammdf") is not None


def require_asammdf() -> None:
    """Raise a FieldDiagError that says how to install asammdf if it is missing."""
    if not asammdf_available():
        raise FieldDiagError(
            "MDF4 files need the asammdf package, which is not installed: "
            "pip install 'fielddiag[mdf]' (or pip install asammdf)"
        )


# ============================================================================ export
def _channel_comment(c: ChannelSpec) -> str:
    return f"role={c.role}; axis={c.axis}; sensor={c.sensor}"


def _frames_to_bus_records(frames: np.ndarray) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """Session CAN frames -> [(kind, timestamps, MDF records)] for each kind present."""
    out = []
    flags = frames["flags"]
    is_err = (flags & CAN_FLAG_ERROR) != 0
    is_rtr = ((flags & CAN_FLAG_REMOTE) != 0) & ~is_err
    is_data = ~is_err & ~is_rtr
    for kind, sel, dtype in (
        ("CAN_DataFrame", is_data, CAN_DATA_DTYPE),
        ("CAN_ErrorFrame", is_err, CAN_ERROR_DTYPE),
        ("CAN_RemoteFrame", is_rtr, CAN_REMOTE_DTYPE),
    ):
        f = frames[sel]
        if f.size == 0:
            continue
        rec = np.zeros(f.size, dtype=dtype)
        rec[f"{kind}.BusChannel"] = f["bus"]
        rec[f"{kind}.ID"] = f["arbitration_id"]
        rec[f"{kind}.IDE"] = (f["flags"] & CAN_FLAG_EXTENDED) != 0
        fd = (f["flags"] & CAN_FLAG_FD) != 0
        # the session stores the byte count; MDF (like the bus) the 4-bit DLC code for CAN FD
        length = payload_lengths(f)
        rec[f"{kind}.DLC"] = np.where(fd, np.searchsorted(FD_LENGTHS, length), f["dlc"])
        rec[f"{kind}.DataLength"] = length
        rec[f"{kind}.Dir"] = np.where((f["flags"] & CAN_FLAG_RX) != 0, 0, 1)
        if kind != "CAN_RemoteFrame":
            rec[f"{kind}.DataBytes"] = f["data"]
            rec[f"{kind}.EDL"] = fd
            rec[f"{kind}.BRS"] = (f["flags"] & CAN_FLAG_BRS) != 0
            rec[f"{kind}.ESI"] = (f["flags"] & CAN_FLAG_ESI) != 0
        out.append((kind, np.ascontiguousarray(f["time_s"], dtype="f8"), rec))
    return out


def export_mdf(
    session_path: str | os.PathLike, out_path: str | os.PathLike, *, overwrite: bool = False
) -> Path:
    """Write a session as an MDF4 file (written beside, then moved into place).

    Parameters
    ----------
    session_path : the session (.h5)
    out_path : the MDF file to write (``.mf4``)
    overwrite : replace ``out_path`` if it exists

    Returns
    -------
    Path
        ``out_path``.

    Raises
    ------
    FieldDiagError
        asammdf is not installed.
    SessionError
        The session is unreadable, or ``out_path`` exists and ``overwrite`` is False.
    """
    require_asammdf()
    from asammdf import MDF, Signal
    from asammdf.blocks.v4_blocks import SourceInformation
    from asammdf.blocks.v4_constants import BUS_TYPE_CAN, SOURCE_BUS

    out_path = Path(out_path)
    with atomic_file(out_path, overwrite=overwrite) as tmp, \
            SessionReader(session_path) as s:
        md = s.metadata
        mdf = MDF(version="4.10")
        try:
            mdf.header.start_time = datetime.fromtimestamp(float(md.t0_unix_s or 0.0), UTC)
            mdf.header.author = md.operator
            mdf.header.subject = md.vehicle
            mdf.header.comment = (
                f"fielddiag session {s.path.name}: vehicle {md.vehicle or '-'}, corner "
                f"{md.corner or '-'}, added mass {md.added_mass_kg:g} kg. {md.notes}".strip()
            )
            manifest: dict[str, Any] = {
                "format": MANIFEST_FORMAT,
                "version": 1,
                "session": s.path.name,
                "metadata": md.to_dict(),
                "time_base": s.time_base,
                "sample_rate_hz": s.sample_rate_hz,
                "t0_s": s.start_s if s.time_base == "uniform" else 0.0,
                "channels": [c.to_dict() for c in s.channels],
                "signals": [],
                "can_groups": [],
                "events": [[e.time_s, e.label] for e in s.events],
                "gaps": [[g.start_s, g.end_s, g.samples_lost, g.cause] for g in s.gaps],
                "counters": s.counters,
            }
            group = 0
            n = s.n_samples
            if s.channels and n:
                for i0 in range(0, n, _CHUNK):
                    i1 = min(n, i0 + _CHUNK)
                    t = np.ascontiguousarray(s.time_at(i0, i1), dtype="f8")
                    raws = [s.read_raw(c.name, i0, i1) for c in s.channels]
                    if i0 == 0:
                        sigs = [
                            Signal(
                                raw, t, name=c.name, unit=c.unit, comment=_channel_comment(c),
                                conversion=(
                                    {"a": c.scale, "b": c.offset}
                                    if (c.scale, c.offset) != (1.0, 0.0) else None
                                ),
                            )
                            for c, raw in zip(s.channels, raws, strict=True)
                        ]
                        mdf.append(sigs, acq_name=DAQ_GROUP_NAME, comment="DAQ channels")
                    else:
                        mdf.extend(group, [(t, None)] + [(r, None) for r in raws])
                manifest["daq_group"] = group
                group += 1
            for spec in s.signals:
                t, v = s.signal(spec.name)
                mdf.append(
                    Signal(
                        np.ascontiguousarray(v, dtype="f8"), np.ascontiguousarray(t, dtype="f8"),
                        name=spec.name, unit=spec.unit,
                        comment=f"source={spec.source}; message={spec.message}; role={spec.role}",
                    ),
                    acq_name=f"signal {spec.name}",
                    comment=f"vehicle signal {spec.name}",
                )
                manifest["signals"].append({**spec.to_dict(), "group": group})
                group += 1
            frames = s.can_frames() if s.has_can_frames else None
            manifest["has_can_frames"] = frames is not None
            if frames is not None:
                for kind, t, rec in _frames_to_bus_records(frames):
                    mdf.append(
                        Signal(rec, t, name=kind, source=SourceInformation(
                            source_type=SOURCE_BUS, bus_type=BUS_TYPE_CAN)),
                        acq_name="CAN bus logging",
                        comment=f"raw CAN frames ({kind})",
                    )
                    manifest["can_groups"].append(group)
                    group += 1
            data = json.dumps(manifest, indent=1).encode()
            mdf.attach(data, file_name=MANIFEST_NAME, comment="fielddiag session description",
                       mime="application/json", embedded=True)
            written = Path(mdf.save(tmp, overwrite=True, compression=2))
            if written != tmp:  # asammdf may have changed the name
                os.replace(written, tmp)
        finally:
            mdf.close()
    return out_path


# ============================================================================ import
def _open_mdf(path: Path):
    from asammdf import MDF

    if not path.is_file():
        raise ImportFormatError(f"{path}: no such file")
    error = None
    # When MDF() fails half-way, asammdf's MDF4.__del__ raises on the half-built object.
    # Free that object here, quietly, rather than at some later garbage collection.
    hook = sys.unraisablehook
    sys.unraisablehook = lambda _unraisable: None
    try:
        try:
            mdf = MDF(str(path))
        except Exception as exc:  # asammdf raises MdfException, struct.error, ValueError...
            error = f"{type(exc).__name__}: {exc}"
        if error is not None:
            gc.collect()
    finally:
        sys.unraisablehook = hook
    if error is not None:
        raise ImportFormatError(
            f"{path.name}: not a readable MDF file ({' '.join(str(error).split())}); is it "
            "corrupt or cut short? "
            "Export it again from the logger"
        )
    if int(str(mdf.version).split(".")[0]) < 4:
        mdf.close()
        raise ImportFormatError(
            f"{path.name} is MDF {mdf.version}; convert it to MDF4 first (asammdf: "
            "MDF(path).convert('4.10').save(...))"
        )
    return mdf


def _manifest(mdf) -> dict | None:
    for i, att in enumerate(getattr(mdf, "attachments", [])):
        if str(getattr(att, "file_name", "")).endswith(MANIFEST_NAME):
            try:
                data = mdf.extract_attachment(i)[0]
                doc = json.loads(bytes(data).decode())
            except Exception:  # noqa: BLE001 - a broken manifest means: generic MDF
                return None
            return doc if doc.get("format") == MANIFEST_FORMAT else None
    return None


def _is_bus_group(group) -> str | None:
    names = {c.name for c in group.channels}
    for kind in _BUS_KINDS:
        if kind in names:
            return kind
    return None


def _start_unix_s(mdf) -> float:
    try:
        return float(mdf.header.start_time.timestamp())
    except (AttributeError, ValueError, OSError):
        return 0.0


def _read_bus_frames(mdf, source: str) -> np.ndarray:
    """Every CAN frame of the bus-logging groups, as CAN_FRAME_DTYPE (MDF time)."""
    parts: list[np.ndarray] = []
    for gi, group in enumerate(mdf.groups):
        kind = _is_bus_group(group)
        if kind is None or group.channel_group.cycles_nr == 0:
            continue
        try:
            sig = mdf.get(kind, gi, raw=False)
        except Exception as exc:  # noqa: BLE001
            raise ImportFormatError(
                f"{source}: bus logging group {gi} is unreadable ({exc}); is the file corrupt?"
            ) from None
        rec = sig.samples
        names = rec.dtype.names or ()

        def field(name: str, rec=rec, names=names, kind=kind):
            key = f"{kind}.{name}"
            return rec[key] if key in names else None

        n = rec.shape[0]
        f = np.zeros(n, dtype=CAN_FRAME_DTYPE)
        f["time_s"] = sig.timestamps
        ident = field("ID")
        ident = np.zeros(n, dtype="u8") if ident is None else ident.astype("u8")
        f["arbitration_id"] = ident & 0x1FFFFFFF
        ide = field("IDE")
        ext = (ident & 0x80000000) != 0 if ide is None else ide.astype(bool)
        bus = field("BusChannel")
        if bus is not None:
            f["bus"] = bus
        flags = np.where(ext, CAN_FLAG_EXTENDED, 0)
        if kind == "CAN_ErrorFrame":
            flags |= CAN_FLAG_ERROR
        if kind == "CAN_RemoteFrame":
            flags |= CAN_FLAG_REMOTE
        for name, bit in (("EDL", CAN_FLAG_FD), ("BRS", CAN_FLAG_BRS), ("ESI", CAN_FLAG_ESI)):
            v = field(name)
            if v is not None:
                flags |= np.where(v.astype(bool), bit, 0)
        direction = field("Dir")
        if direction is None:
            flags |= CAN_FLAG_RX
        elif direction.dtype.kind == "S":
            flags |= np.where(direction == b"Rx", CAN_FLAG_RX, 0)
        else:
            flags |= np.where(direction == 0, CAN_FLAG_RX, 0)
        f["flags"] = flags
        length = field("DataLength")
        dlc = field("DLC")
        fd = (flags & CAN_FLAG_FD) != 0
        if dlc is not None:
            dlc = dlc.astype("i8")
            # MDF stores the 4-bit DLC code; the session stores the byte count for CAN FD
            f["dlc"] = np.where(fd, FD_LENGTHS[np.clip(dlc, 0, 15)], dlc)
        elif length is not None:
            f["dlc"] = length
        data = field("DataBytes")
        if data is not None:
            if data.dtype == object:
                for i, row in enumerate(data):
                    b = bytes(row)[:CAN_DATA_BYTES]
                    f["data"][i, : len(b)] = np.frombuffer(b, dtype="u1")
            else:
                arr = np.asarray(data, dtype="u1").reshape(n, -1)[:, :CAN_DATA_BYTES]
                f["data"][:, : arr.shape[1]] = arr
            if length is not None:  # bytes past the frame's length are not part of it
                cols = np.arange(CAN_DATA_BYTES)
                f["data"][cols[None, :] >= length.astype("i8")[:, None]] = 0
        parts.append(f)
    if not parts:
        return np.zeros(0, dtype=CAN_FRAME_DTYPE)
    frames = np.concatenate(parts)
    return frames[np.argsort(frames["time_s"], kind="stable")]


def _linear(conversion) -> tuple[float, float] | None:
    """(scale, offset) of an identity or linear conversion, None for anything else."""
    if conversion is None:
        return 1.0, 0.0
    ctype = int(getattr(conversion, "conversion_type", -1))
    if ctype == 0:
        return 1.0, 0.0
    if ctype == 1:
        return float(conversion.a), float(conversion.b)
    return None


def _numeric_channels(mdf, gi: int) -> list[tuple[int, str]]:
    master = mdf.masters_db.get(gi)
    out = []
    for ci, ch in enumerate(mdf.groups[gi].channels):
        if ci == master or "." in ch.name and ch.name.split(".")[0] in _BUS_KINDS:
            continue
        out.append((ci, ch.name))
    return out


class _Channel:
    """One channel read from an MDF group: raw samples, calibration, unit, comment."""

    def __init__(self, sig, phys_sig=None) -> None:
        self.name: str = sig.name
        self.unit: str = sig.unit or ""
        self.comment: str = sig.comment or ""
        self.timestamps = np.asarray(sig.timestamps, dtype="f8")
        lin = _linear(sig.conversion)
        if lin is not None and sig.samples.dtype.kind in "iuf" and sig.samples.ndim == 1:
            self.raw = sig.samples
            self.scale, self.offset = lin
        else:
            self.raw = np.asarray(phys_sig.samples, dtype="f8") if phys_sig else None
            self.scale, self.offset = 1.0, 0.0

    @property
    def physical(self) -> np.ndarray:
        return self.raw.astype("f8") * self.scale + self.offset


def _read_group(mdf, gi: int, wanted: Iterable[tuple[int, str]]) -> list[_Channel]:
    wanted = list(wanted)
    if not wanted:
        return []
    raw = mdf.select([(None, gi, ci) for ci, _ in wanted], raw=True)
    out: list[_Channel] = []
    for (ci, _name), sig in zip(wanted, raw, strict=True):
        samples = sig.samples
        if samples.dtype.names or samples.ndim != 1:
            continue  # structures and arrays are not time series of one number
        ch = _Channel(sig)
        if ch.raw is None:
            try:
                phys = mdf.get(group=gi, index=ci, raw=False)
            except Exception:  # noqa: BLE001 - a text table channel and the like
                continue
            if phys.samples.dtype.kind not in "iuf":
                continue
            ch = _Channel(sig, phys)
        if ch.raw is not None and ch.raw.dtype.kind in "iuf":
            out.append(ch)
    return out


def import_mdf(
    path: str | os.PathLike,
    out_path: str | os.PathLike,
    *,
    dbc: Sequence[str | os.PathLike] | str | os.PathLike | None = None,
    signals: Sequence[str] | None = None,
    roles: Mapping[str, str] | Sequence[str] | None = None,
    channels: Sequence[str] | None = None,
    metadata: SessionMetadata | None = None,
    overwrite: bool = False,
) -> Path:
    """Import an MDF4 file into a session (see the module description for the mapping).

    Parameters
    ----------
    path : the .mf4 file
    out_path : session file to write (atomically)
    dbc : DBC file(s) to decode CAN bus logging (``BUS=FILE`` binds one to a bus)
    signals : CAN signals to decode (default with a DBC: vehicle and wheel speeds)
    roles : role -> channel name (``{"wheel": "AccZ_FL"}`` or ``["wheel=AccZ_FL"]``)
    channels : MDF channels to import besides the role channels (default: all numeric)
    metadata : root attributes from the user; they override a fielddiag file's own
        wherever the user set them

    Raises
    ------
    ImportFormatError
        Unreadable file, unknown channel, role channels in different groups, CAN bus
        logging without a DBC and nothing else to import.
    FieldDiagError
        asammdf is not installed.
    """
    require_asammdf()
    from fielddiag.io.csv_import import check_role_names, parse_role_args

    path = Path(path)
    role_map = dict(roles) if isinstance(roles, Mapping) else parse_role_args(list(roles or []))
    check_role_names(path.name, role_map)
    if signals and not dbc:
        raise ImportFormatError("--signal decodes CAN bus logging: pass the DBC with --dbc FILE")
    mdf = _open_mdf(path)
    try:
        frames = _read_bus_frames(mdf, path.name)
        manifest = _manifest(mdf)
        if manifest is not None and not role_map and not channels:
            plan = _plan_fielddiag(mdf, manifest, path, metadata)
        else:
            first = float(frames["time_s"][0]) if frames.size else None
            plan = _plan_generic(mdf, path, role_map, channels, metadata, bool(dbc), first)
    finally:
        mdf.close()
    if dbc:
        from fielddiag.io.canlog import decode_frames_to_signals

        if frames.size == 0:
            raise ImportFormatError(
                f"{path.name} holds no CAN bus logging (CAN_DataFrame channels) to decode with "
                "--dbc; drop --dbc/--signal"
            )
        bus_names = {int(b): str(int(b)) for b in np.unique(frames["bus"])}
        decoded, errors, files = decode_frames_to_signals(
            frames, bus_names, dbc, signals, path.name
        )
        taken = {s.name for s in plan["signals"]}
        for spec, (t, v) in decoded.items():
            if spec.name in taken:
                raise ImportFormatError(
                    f"{path.name}: decoded signal {spec.name} has the name of a channel already "
                    "in the file; pick other signals with --signal"
                )
            plan["signals"][spec] = (t - plan["shift_s"], v)
        counters = dict(plan.get("counters") or {})
        counters["can_decode_errors"] = counters.get("can_decode_errors", 0) + errors
        plan["counters"] = counters
        plan["metadata"].extra["dbc_files"] = [
            f"{f.bus}={f.path.name}" if f.bus else f.path.name for f in files
        ]
    if frames.size:
        frames["time_s"] -= plan["shift_s"]
        counters = dict(plan.get("counters") or {})
        counters.setdefault("can_frames_received", int(frames.size))
        plan["counters"] = counters
    elif plan["manifest_frames"]:
        frames = np.zeros(0, dtype=CAN_FRAME_DTYPE)
    else:
        frames = None
    if not plan["channels"] and not plan["signals"] and frames is None:
        raise ImportFormatError(f"{path.name}: no numeric channel to import")
    if not plan["channels"] and not plan["signals"] and not dbc:
        raise ImportFormatError(
            f"{path.name} holds only CAN bus logging; pass --dbc FILE to decode its signals "
            "(the raw frames are kept too)"
        )
    from fielddiag.io.canlog import fastest_rate_hz
    from fielddiag.io.formats import write_imported_session

    rate = plan["sample_rate_hz"] or fastest_rate_hz(plan["signals"])
    return write_imported_session(
        out_path,
        plan["metadata"],
        channels=plan["channels"],
        samples=plan["samples"],
        daq_time_s=plan["daq_time_s"],
        sample_rate_hz=rate,
        t0_s=plan["t0_s"],
        signals=plan["signals"],
        can_frames=frames,
        events=plan["events"],
        gaps=plan["gaps"],
        counters=plan.get("counters"),
        overwrite=overwrite,
    )


def _plan_fielddiag(mdf, manifest: dict, path: Path, user: SessionMetadata | None) -> dict:
    """What to write for a file made by :func:`export_mdf`: the session as it was."""
    from fielddiag.io.formats import overlay_metadata

    md_fields = {f.name for f in fields(SessionMetadata)}
    stored = SessionMetadata(**{k: v for k, v in manifest["metadata"].items() if k in md_fields})
    meta = overlay_metadata(stored, user)
    meta.extra = {**meta.extra, "imported_from": path.name, "import_format": "mdf"}
    channels: list[ChannelSpec] = []
    samples: dict[str, np.ndarray] = {}
    daq_time = None
    spec_fields = {f.name for f in fields(ChannelSpec)}
    if manifest["channels"]:
        gi = int(manifest["daq_group"])
        specs = [ChannelSpec(**{k: v for k, v in c.items() if k in spec_fields})
                 for c in manifest["channels"]]
        by_name = {ch.name: ci for ci, ch in enumerate(mdf.groups[gi].channels)}
        missing = [c.name for c in specs if c.name not in by_name]
        if missing:
            raise ImportFormatError(
                f"{path.name}: channel {missing[0]} of its fielddiag description is not in the "
                "file; it was edited after export. Import it with --role to map channels"
            )
        read = _read_group(mdf, gi, [(by_name[c.name], c.name) for c in specs])
        if len(read) != len(specs):
            raise ImportFormatError(
                f"{path.name}: a DAQ channel of its fielddiag description is no longer a "
                "numeric time series; it was edited after export. Import it with --role"
            )
        for c, ch in zip(specs, read, strict=True):
            lin = (ch.scale, ch.offset)
            channels.append(ChannelSpec(**{**c.to_dict(), "unit": ch.unit,
                                           "scale": lin[0], "offset": lin[1],
                                           "dtype": _dtype_name(ch.raw.dtype)}))
            samples[c.name] = ch.raw
        daq_time = read[0].timestamps if read else None
    t0_s = float(manifest.get("t0_s", 0.0))
    rate = float(manifest["sample_rate_hz"])
    if daq_time is not None and manifest["time_base"] == "uniform":
        expected = t0_s + np.arange(daq_time.size, dtype="f8") / rate
        if np.allclose(daq_time, expected, rtol=0, atol=1e-9 * max(1.0, abs(expected[-1]))):
            daq_time = None  # the session's own uniform time base, exactly as it was
    signals: dict[SignalSpec, tuple[np.ndarray, np.ndarray]] = {}
    sig_fields = {f.name for f in fields(SignalSpec)}
    for entry in manifest["signals"]:
        spec = SignalSpec(**{k: v for k, v in entry.items() if k in sig_fields})
        sig = mdf.get(spec.name, int(entry["group"]), raw=False)
        signals[SignalSpec(**{**spec.to_dict(), "unit": sig.unit or spec.unit})] = (
            np.asarray(sig.timestamps, dtype="f8"), np.asarray(sig.samples, dtype="f8"))
    counters = {k: int(v) for k, v in manifest.get("counters", {}).items()}
    return {
        "metadata": meta,
        "channels": channels,
        "samples": samples if channels else None,
        "daq_time_s": daq_time,
        "sample_rate_hz": rate,
        "t0_s": t0_s,
        "signals": signals,
        "events": [Event(float(t), str(lbl)) for t, lbl in manifest.get("events", [])],
        "gaps": [
            Gap(float(a), float(b), int(n), str(c)) for a, b, n, c in manifest.get("gaps", [])
        ],
        "counters": counters,
        "shift_s": 0.0,
        "manifest_frames": bool(manifest.get("has_can_frames")),
    }


def _dtype_name(dtype: np.dtype) -> str:
    return dtype.name if dtype.byteorder in ("=", "|", "<") else dtype.str


_DAQ_NAME = {"wheel": "wheel_z", "body": "body_z"}


def _plan_generic(
    mdf, path: Path, roles: dict[str, str], only: Sequence[str] | None,
    user: SessionMetadata | None, has_dbc: bool, first_frame_s: float | None,
) -> dict:
    """Channels of any MDF4 file: role channels and one group as DAQ, the rest as signals."""
    from fielddiag.io.csv_import import KNOWN_ROLES
    from fielddiag.io.formats import merged_metadata

    data_groups = [gi for gi, g in enumerate(mdf.groups)
                   if _is_bus_group(g) is None and g.channel_group.cycles_nr > 0]
    every: list[tuple[int, int, str]] = [
        (gi, ci, name) for gi in data_groups for ci, name in _numeric_channels(mdf, gi)
    ]

    def locate(name: str, what: str) -> tuple[int, int, str]:
        hits = [e for e in every if e[2] == name]
        if not hits:
            import difflib

            close = difflib.get_close_matches(name, sorted({e[2] for e in every}), n=5)
            hint = f"; did you mean {', '.join(close)}?" if close else ""
            raise ImportFormatError(f"{path.name}: no channel {name!r} ({what}){hint}")
        if len(hits) > 1:
            raise ImportFormatError(
                f"{path.name}: channel {name!r} is in several channel groups "
                f"({', '.join(str(g) for g, _, _ in hits)}); rename it in the file or pick "
                "another"
            )
        return hits[0]

    daq_roles = {r: c for r, c in roles.items() if r != "speed"}
    role_pos = {r: locate(c, f"--role {r}") for r, c in daq_roles.items()}
    speed_channel = roles.get("speed")
    speed_pos = locate(speed_channel, "--role speed") if speed_channel else None
    groups_of_roles = {gi for gi, _, _ in role_pos.values()}
    if len(groups_of_roles) > 1:
        raise ImportFormatError(
            f"{path.name}: the DAQ role channels are in different channel groups (different "
            "time bases); map only channels recorded together to wheel/body roles"
        )
    wanted = [locate(name, "--channel") for name in only] if only else list(every)
    wanted = [e for e in wanted if e != speed_pos]
    if groups_of_roles:
        daq_group = next(iter(groups_of_roles))
    elif wanted:
        counts = {gi: mdf.groups[gi].channel_group.cycles_nr for gi, _, _ in wanted}
        daq_group = max(counts, key=counts.get)
    else:
        daq_group = None

    channels: list[ChannelSpec] = []
    samples: dict[str, np.ndarray] = {}
    signals: dict[SignalSpec, tuple[np.ndarray, np.ndarray]] = {}
    daq_time = None
    used_names: set[str] = set()

    def unique(name: str) -> str:
        return unique_name(name, used_names)

    role_of = {(gi, ci): r for r, (gi, ci, _n) in role_pos.items()}
    if daq_group is not None:
        members = sorted({(ci, n) for gi, ci, n in [*wanted, *role_pos.values()]
                          if gi == daq_group})
        read = _read_group(mdf, daq_group, members)
        read_names = {ch.name for ch in read}
        for r, (_gi, _ci, n) in role_pos.items():
            if n not in read_names:
                raise ImportFormatError(
                    f"{path.name}: channel {n!r} for --role {r} is not a numeric time series"
                )
        for (ci, _n), ch in zip([m for m in members if m[1] in read_names], read, strict=True):
            factor, unit = to_si(ch.unit)
            role = role_of.get((daq_group, ci), "other")
            if role == "other":
                name, spec_role = ch.name, "other"
            elif role in KNOWN_ROLES:
                name, spec_role = _DAQ_NAME.get(role, role), role
            else:
                name, spec_role = role, "other"
            channels.append(ChannelSpec(
                unique(name), unit=unit, role=spec_role, axis="z" if role in _DAQ_NAME else "",
                sensor=f"mdf:{ch.name}" + (f" ({ch.comment})" if ch.comment else ""),
                scale=ch.scale * factor, offset=ch.offset * factor,
                dtype=_dtype_name(ch.raw.dtype)))
            samples[channels[-1].name] = ch.raw
            daq_time = ch.timestamps
    if speed_pos is not None:
        gi, ci, _n = speed_pos
        read = _read_group(mdf, gi, [(ci, speed_channel)])
        if not read:
            raise ImportFormatError(f"{path.name}: channel {speed_channel!r} is not numeric")
        ch = read[0]
        factor, unit = to_si(ch.unit or "m/s")
        signals[SignalSpec(unique("vehicle_speed"), unit=unit, source="mdf",
                           message=speed_channel, role="speed")] = (
            ch.timestamps, ch.physical * factor)
    by_group: dict[int, list[tuple[int, str]]] = {}
    for gi, ci, name in wanted:
        if gi != daq_group:
            by_group.setdefault(gi, []).append((ci, name))
    for gi, members in sorted(by_group.items()):
        acq = mdf.groups[gi].channel_group.acq_name or f"group {gi}"
        for ch in _read_group(mdf, gi, sorted(members)):
            factor, unit = to_si(ch.unit)
            signals[SignalSpec(unique(ch.name), unit=unit, source="mdf", message=str(acq))] = (
                ch.timestamps, ch.physical * factor)
    starts = [float(t[0]) for t, _ in signals.values() if t.size]
    if daq_time is not None and daq_time.size:
        starts.append(float(daq_time[0]))
    if first_frame_s is not None:
        starts.append(first_frame_s)
    shift = min(starts) if starts else 0.0
    if daq_time is not None:
        daq_time = daq_time - shift
        if daq_time.size > 1 and np.any(np.diff(daq_time) <= 0):
            raise ImportFormatError(
                f"{path.name}: the time stamps of channel group {daq_group} do not increase"
            )
    signals = {s: (t - shift, v) for s, (t, v) in signals.items()}
    n = 0 if daq_time is None else daq_time.size
    rate = (n - 1) / float(daq_time[-1] - daq_time[0]) if n > 1 else 0.0
    start = _start_unix_s(mdf)
    meta = merged_metadata(
        user,
        {"imported_from": path.name, "import_format": "mdf",
         "source_time_of_first_sample_s": shift},
        t0_unix_s=start + shift if start > 0 else 0.0,
    )
    return {
        "metadata": meta,
        "channels": channels,
        "samples": samples if channels else None,
        "daq_time_s": daq_time if channels else None,
        "sample_rate_hz": rate if math.isfinite(rate) and rate > 0 else 0.0,
        "t0_s": 0.0,
        "signals": signals,
        "events": [],
        "gaps": [],
        "counters": {},
        "shift_s": shift,
        "manifest_frames": False,
    }
