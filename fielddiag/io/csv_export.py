"""Export a session as CSV files, and import such an export back exactly.

Layout chosen: **signals as separate files**, not resampled. Resampling a 40 Hz CAN speed
onto a 1 kHz DAQ axis would invent samples and lose the real ones, so every time series
keeps its own time stamps. ``fielddiag export drive.h5 -o drive.csv`` writes:

``drive.csv``
    ``time_s`` then one column per DAQ channel, calibrated (physical units), one row per
    sample.
``drive.signal.<name>.csv``
    one file per vehicle signal: ``time_s,<name>``.
``drive.can_frames.csv``
    when the session holds raw CAN frames: ``time_s,bus,arbitration_id,flags,dlc,data``
    (identifier and payload in hex, flags as in the session format).
``drive.fielddiag.json``
    the manifest: metadata, time base, each channel's unit, role, axis, sensor and original
    calibration, each signal's unit, source, message and role, events, gaps, counters.

Numbers are written with Python's shortest round-trip representation (``repr``), so a
value read back is the same float64. Any spreadsheet or pandas reads the CSV files alone;
``fielddiag import drive.csv`` finds the manifest beside it and restores the session with
every sample, unit and role (DAQ channels come back calibrated, as float64 with scale 1).
"""

from __future__ import annotations

import json
import os
import secrets
from collections.abc import Iterable
from dataclasses import fields
from pathlib import Path
from typing import Any

import numpy as np

from fielddiag.channels import ChannelSpec, Event, Gap, SessionMetadata, SignalSpec
from fielddiag.errors import ImportFormatError
from fielddiag.outputs import check_target, os_error
from fielddiag.session import CAN_DATA_BYTES, CAN_FLAG_FD, CAN_FRAME_DTYPE, SessionReader

MANIFEST_FORMAT = "fielddiag-csv"
_ROWS_PER_CHUNK = 50_000


def export_paths(out_path: str | os.PathLike, session: SessionReader) -> dict[str, Path]:
    """Every file an export of ``session`` to ``out_path`` writes (key -> path)."""
    out = Path(out_path)
    stem = out.stem
    paths = {"data": out, "manifest": out.with_name(f"{stem}.fielddiag.json")}
    for s in session.signals:
        paths[f"signal:{s.name}"] = out.with_name(f"{stem}.signal.{s.name}.csv")
    if session.has_can_frames:
        paths["can_frames"] = out.with_name(f"{stem}.can_frames.csv")
    return paths


def _write_rows(fh, columns: list[np.ndarray]) -> None:
    n = columns[0].size if columns else 0
    for i0 in range(0, n, _ROWS_PER_CHUNK):
        block = np.column_stack([c[i0 : i0 + _ROWS_PER_CHUNK] for c in columns]).tolist()
        fh.write("".join(",".join(map(repr, row)) + "\n" for row in block))


def _frame_lines(frames: np.ndarray) -> Iterable[str]:
    for f in frames:
        fd = bool(int(f["flags"]) & CAN_FLAG_FD)
        n = min(int(f["dlc"]), CAN_DATA_BYTES if fd else 8)
        yield (
            f"{float(f['time_s'])!r},{int(f['bus'])},{int(f['arbitration_id']):X},"
            f"{int(f['flags'])},{int(f['dlc'])},{bytes(f['data'][:n]).hex().upper()}\n"
        )


def export_csv(
    session_path: str | os.PathLike, out_path: str | os.PathLike, *, overwrite: bool = False
) -> list[Path]:
    """Write a session as CSV files plus a manifest (see the module description).

    Every file is written beside its target under a hidden name and moved into place only
    when all of them are complete.

    Returns
    -------
    list of Path
        The files written, the data file first.

    Raises
    ------
    SessionError
        A target exists and ``overwrite`` is False, or the folder does not exist.
    """
    out_path = Path(out_path)
    check_target(out_path, overwrite=overwrite)
    with SessionReader(session_path) as s:
        paths = export_paths(out_path, s)
        for p in paths.values():  # every file: regular, replaced only with overwrite
            check_target(p, overwrite=overwrite)
        token = secrets.token_hex(4)
        tmp = {k: p.with_name(f".{p.name}.tmp-{token}") for k, p in paths.items()}
        try:
            manifest = _write_all(s, paths, tmp)
            with open(tmp["manifest"], "w", encoding="utf-8") as fh:
                json.dump(manifest, fh, indent=1)
            for key, p in paths.items():
                os.replace(tmp[key], p)
        except OSError as exc:
            raise os_error(out_path, exc) from None
        finally:
            for t in tmp.values():
                t.unlink(missing_ok=True)
    return [paths["data"], *[p for k, p in paths.items() if k != "data"]]


def _write_all(s: SessionReader, paths: dict[str, Path], tmp: dict[str, Path]) -> dict:
    n = s.n_samples
    with open(tmp["data"], "w", encoding="utf-8", newline="") as fh:
        fh.write(",".join(["time_s", *(c.name for c in s.channels)]) + "\n")
        for i0 in range(0, n, _ROWS_PER_CHUNK * 4):
            i1 = min(n, i0 + _ROWS_PER_CHUNK * 4)
            t = s.time_at(i0, i1)
            cols = [t] + [
                s.read_raw(c.name, i0, i1).astype("f8") * c.scale + c.offset
                if (c.scale, c.offset) != (1.0, 0.0)
                else s.read_raw(c.name, i0, i1).astype("f8")
                for c in s.channels
            ]
            _write_rows(fh, cols)
    signals = []
    for spec in s.signals:
        key = f"signal:{spec.name}"
        t, v = s.signal(spec.name)
        with open(tmp[key], "w", encoding="utf-8", newline="") as fh:
            fh.write(f"time_s,{spec.name}\n")
            _write_rows(fh, [np.asarray(t, dtype="f8"), np.asarray(v, dtype="f8")])
        signals.append({**spec.to_dict(), "file": paths[key].name, "samples": int(t.size)})
    frames_file = None
    if "can_frames" in paths:
        with open(tmp["can_frames"], "w", encoding="utf-8", newline="") as fh:
            fh.write("time_s,bus,arbitration_id,flags,dlc,data\n")
            fh.writelines(_frame_lines(s.can_frames()))
        frames_file = paths["can_frames"].name
    return {
        "format": MANIFEST_FORMAT,
        "version": 1,
        "session": s.path.name,
        "data_file": paths["data"].name,
        "samples": n,
        "metadata": s.metadata.to_dict(),
        "time_base": s.time_base,
        "sample_rate_hz": s.sample_rate_hz,
        "t0_s": s.start_s if s.time_base == "uniform" else 0.0,
        "channels": [
            {
                **c.to_dict(),
                "scale": 1.0,
                "offset": 0.0,
                "dtype": "float64",
                "source_calibration": {"scale": c.scale, "offset": c.offset, "dtype": c.dtype},
            }
            for c in s.channels
        ],
        "signals": signals,
        "can_frames_file": frames_file,
        "events": [[e.time_s, e.label] for e in s.events],
        "gaps": [[g.start_s, g.end_s, g.samples_lost, g.cause] for g in s.gaps],
        "counters": s.counters,
    }


# ============================================================================ import
def _load_manifest(path: Path) -> tuple[dict[str, Any], Path]:
    from fielddiag.io.formats import manifest_path

    mpath = manifest_path(path)
    if not mpath.is_file():
        raise ImportFormatError(
            f"{path.name}: no {mpath.name} beside it; import the CSV with --format csv and "
            "--role/--time instead"
        )
    try:
        doc = json.loads(mpath.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise ImportFormatError(f"{mpath.name}: not a readable manifest ({exc})") from None
    if doc.get("format") != MANIFEST_FORMAT:
        raise ImportFormatError(f"{mpath.name}: not a fielddiag CSV manifest")
    return doc, mpath


def _read_frames(path: Path) -> np.ndarray:
    rows = []
    with open(path, encoding="utf-8") as fh:
        header = fh.readline().strip()
        if header != "time_s,bus,arbitration_id,flags,dlc,data":
            raise ImportFormatError(f"{path.name}: unexpected header {header!r}")
        for row_no, line in enumerate(fh, start=2):
            if not line.strip():
                continue
            try:
                t, bus, ident, flags, dlc, data = line.strip().split(",")
                payload = bytes.fromhex(data)
                rows.append((float(t), int(ident, 16), int(bus), int(flags), int(dlc), payload))
            except ValueError:
                raise ImportFormatError(
                    f"{path.name} row {row_no}: not a CAN frame ({line.strip()[:60]!r}); fix or "
                    "delete that row"
                ) from None
    frames = np.zeros(len(rows), dtype=CAN_FRAME_DTYPE)
    for i, (t, ident, bus, flags, dlc, payload) in enumerate(rows):
        frames[i]["time_s"] = t
        frames[i]["arbitration_id"] = ident
        frames[i]["bus"] = bus
        frames[i]["flags"] = flags
        frames[i]["dlc"] = dlc
        frames[i]["data"][: len(payload)] = np.frombuffer(payload[:CAN_DATA_BYTES], dtype="u1")
    return frames


def import_exported_csv(
    path: str | os.PathLike,
    out_path: str | os.PathLike,
    *,
    metadata: SessionMetadata | None = None,
    overwrite: bool = False,
) -> Path:
    """Import a CSV export (``drive.csv`` with ``drive.fielddiag.json`` beside it).

    The user's metadata fields override the exported ones wherever they are set.

    Raises
    ------
    ImportFormatError
        No or broken manifest, a missing file or column, a bad number.
    """
    from fielddiag.io.formats import overlay_metadata, read_csv_numeric, write_imported_session

    path = Path(path)
    doc, _mpath = _load_manifest(path)
    md_fields = {f.name for f in fields(SessionMetadata)}
    stored = SessionMetadata(**{k: v for k, v in doc["metadata"].items() if k in md_fields})
    meta = overlay_metadata(stored, metadata)
    meta.extra = {**meta.extra, "imported_from": path.name, "import_format": "fielddiag-csv"}
    spec_fields = {f.name for f in fields(ChannelSpec)}
    channels = [ChannelSpec(**{k: v for k, v in c.items() if k in spec_fields})
                for c in doc["channels"]]
    samples = None
    daq_time = None
    t0_s = float(doc.get("t0_s", 0.0))
    rate = float(doc["sample_rate_hz"])
    if channels:
        data = read_csv_numeric(path, ["time_s", *(c.name for c in channels)])
        daq_time = data["time_s"]
        samples = {c.name: data[c.name] for c in channels}
        if doc["time_base"] == "uniform":
            expected = t0_s + np.arange(daq_time.size, dtype="f8") / rate
            tol = 1e-9 * max(1.0, abs(float(expected[-1])))
            if np.allclose(daq_time, expected, rtol=0, atol=tol):
                daq_time = None
    signals: dict[SignalSpec, tuple[np.ndarray, np.ndarray]] = {}
    sig_fields = {f.name for f in fields(SignalSpec)}
    for entry in doc["signals"]:
        spec = SignalSpec(**{k: v for k, v in entry.items() if k in sig_fields})
        file = path.with_name(entry["file"])
        if not file.is_file():
            raise ImportFormatError(
                f"{file.name} (signal {spec.name}) is missing beside {path.name}; copy all the "
                "files of the export together"
            )
        if int(entry.get("samples", 2)) < 2:
            signals[spec] = _read_short(file, spec.name)
        else:
            cols = read_csv_numeric(file, ["time_s", spec.name])
            signals[spec] = (cols["time_s"], cols[spec.name])
    frames = None
    if doc.get("can_frames_file"):
        file = path.with_name(doc["can_frames_file"])
        if not file.is_file():
            raise ImportFormatError(f"{file.name} is missing beside {path.name}")
        frames = _read_frames(file)
    return write_imported_session(
        out_path,
        meta,
        channels=channels,
        samples=samples,
        daq_time_s=daq_time,
        sample_rate_hz=rate,
        t0_s=t0_s,
        signals=signals,
        can_frames=frames,
        events=[Event(float(t), str(lbl)) for t, lbl in doc.get("events", [])],
        gaps=[Gap(float(a), float(b), int(n), str(c)) for a, b, n, c in doc.get("gaps", [])],
        counters={k: int(v) for k, v in doc.get("counters", {}).items()},
        overwrite=overwrite,
    )


def _read_short(file: Path, name: str) -> tuple[np.ndarray, np.ndarray]:
    """A signal file with zero or one row (the generic reader wants two)."""
    lines = [ln for ln in file.read_text(encoding="utf-8").splitlines()[1:] if ln.strip()]
    try:
        pairs = [tuple(float(x) for x in ln.split(",")) for ln in lines]
    except ValueError:
        raise ImportFormatError(f"{file.name}: not a number in signal {name}") from None
    t = np.array([p[0] for p in pairs], dtype="f8")
    v = np.array([p[1] for p in pairs], dtype="f8")
    return t, v
