"""One unit of batch work: identify (and diagnose) one before/after pair, in a worker.

:func:`process_pair` is what the cluster runs. It receives only paths and numbers (never
an open file: h5py objects cannot travel between processes), opens the sessions itself,
and writes each result as JSON beside the *before* session through a temporary file and
a rename, so a result file is either complete or absent. It never raises for a problem
of the data: the outcome says what failed and why, so one bad pair cannot stop a batch.

Whether a result is up to date is decided by a *fingerprint* of its inputs (size and
modification time of both sessions, the added mass, the step, the software version),
stored in the result's ``provenance`` and in the catalog.
"""

from __future__ import annotations

import hashlib
import json
import os
import socket
import time
import traceback
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from fielddiag.batch.discover import Pair

STEPS = ("identify", "diagnose")

__all__ = [
    "STEPS",
    "SUMMARISERS",
    "PairJob",
    "PairOutcome",
    "StepOutcome",
    "fingerprint",
    "make_job",
    "pair_result_path",
    "process_pair",
]


def pair_result_path(pair: Pair, step: str, *, before_shared: bool = False) -> Path:
    """Where a pair's ``step`` result is stored: ``<before stem>.<step>.json`` beside the
    before session (where the dashboard looks), or ``<before stem>.<step>+<after stem>.json``
    when that before drive is the reference of several after drives."""
    b = Path(pair.before)
    if before_shared:
        return b.with_name(f"{b.stem}.{step}+{Path(pair.after).stem}.json")
    return b.with_name(f"{b.stem}.{step}.json")


def fingerprint(pair: Pair, step: str) -> str:
    """Hash of what a ``step`` result of ``pair`` depends on (see module doc)."""
    from fielddiag import __version__

    parts: list[Any] = [step, round(float(pair.added_mass_kg), 9), __version__]
    for p in (pair.before, pair.after):
        st = os.stat(p)
        parts.append([Path(p).name, st.st_size, st.st_mtime_ns])
    return hashlib.sha1(json.dumps(parts).encode()).hexdigest()[:16]


@dataclass(frozen=True)
class PairJob:
    """Everything a worker needs for one pair: plain strings and numbers only."""

    before: str
    after: str
    added_mass_kg: float
    steps: tuple[str, ...]
    outputs: dict[str, str]  # step -> result file
    fingerprints: dict[str, str]  # step -> fingerprint
    vehicle: str = ""
    corner: str = ""


def make_job(pair: Pair, steps: Sequence[str], *, before_shared: bool = False) -> PairJob:
    """The job for ``pair`` running ``steps`` (a subset of :data:`STEPS`)."""
    steps = tuple(s for s in STEPS if s in steps)
    return PairJob(
        str(pair.before), str(pair.after), float(pair.added_mass_kg), steps,
        {s: str(pair_result_path(pair, s, before_shared=before_shared)) for s in steps},
        {s: fingerprint(pair, s) for s in steps}, pair.vehicle, pair.corner)


@dataclass
class StepOutcome:
    """How one step of a pair went: ``status`` is ``done``, ``skipped`` or ``failed``."""

    step: str
    status: str
    message: str = ""
    output: str = ""
    summary: dict[str, Any] = field(default_factory=dict)
    wall_s: float = 0.0
    fingerprint: str = ""
    detail: str = ""  # the traceback of an unexpected error (kept in the catalog)


@dataclass
class PairOutcome:
    """How a pair went, step by step, and where it ran."""

    before: str
    after: str
    added_mass_kg: float
    vehicle: str
    corner: str
    steps: list[StepOutcome]
    worker: str = ""
    wall_s: float = 0.0

    @property
    def status(self) -> str:
        """``failed`` if any step failed, else ``skipped`` if all were, else ``done``."""
        states = {s.status for s in self.steps}
        if "failed" in states:
            return "failed"
        return "skipped" if states == {"skipped"} else "done"

    @property
    def message(self) -> str:
        return "; ".join(f"{s.step}: {s.message}" for s in self.steps if s.status == "failed")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def _write_json_atomically(path: Path, data: dict[str, Any]) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "w", encoding="utf-8") as fh:
            json.dump(data, fh, indent=1, allow_nan=False)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def summarise_identify(data: dict[str, Any]) -> dict[str, Any]:
    """The catalog's summary of an identification result (as JSON)."""
    out: dict[str, Any] = {}
    for key, name in (("sprung_mass_kg", "sprung_mass"), ("suspension_stiffness_n_per_m",
                      "stiffness"), ("suspension_damping_ns_per_m", "damping")):
        est = data.get(key) or {}
        unit = key.rsplit("_", 1)[-1] if name == "sprung_mass" else key.split("_", 2)[-1]
        out[f"{name}_{unit}"] = est.get("value")
        out[f"{name}_std_{unit}"] = est.get("std")
    return out


def summarise_diagnose(data: dict[str, Any]) -> dict[str, Any]:
    """The catalog's summary of a diagnosis result (as JSON)."""
    out: dict[str, Any] = {
        "verdict": data.get("verdict", ""),
        "findings": [f.get("effect", "") + (f"@{f.get('corner') or f.get('axle')}"
                                            if data.get("mode") == "full_vehicle" else "")
                     for f in data.get("findings", [])],
        "warnings": [w.get("kind", "") for w in data.get("warnings", [])],
    }
    aug, std = data.get("augmented_model") or {}, data.get("augmented_model_std") or {}
    if out["findings"] and "sprung_mass_kg" in aug:  # the linear part refitted with them
        out["corrected"] = {
            f"{name}_{unit}": aug.get(key) for key, name, unit in _CORRECTED}
        out["corrected"].update({
            f"{name}_std_{unit}": std.get(key) for key, name, unit in _CORRECTED})
    return out


_CORRECTED = (("sprung_mass_kg", "sprung_mass", "kg"),
              ("suspension_stiffness_n_per_m", "stiffness", "n_per_m"),
              ("suspension_damping_ns_per_m", "damping", "ns_per_m"))


def _vehicle_pair(job: PairJob):
    """The pair as full-vehicle recordings, or None for single-corner sessions."""
    from fielddiag.vehicle.recording import is_full_vehicle_session, read_vehicle_recording

    if not (is_full_vehicle_session(job.before) and is_full_vehicle_session(job.after)):
        return None
    return (read_vehicle_recording(job.before, label="before"),
            read_vehicle_recording(job.after, label="after"))


def _identify(job: PairJob) -> dict[str, Any]:
    vehicle = _vehicle_pair(job)
    if vehicle is not None:  # the added mass's place from the after session's metadata
        from fielddiag.vehicle.identify import identify_vehicle

        return {"mode": "full_vehicle", **identify_vehicle(
            *vehicle, added_mass_kg=job.added_mass_kg).to_dict()}
    from fielddiag.identify import identify_sessions

    return identify_sessions(job.before, job.after, added_mass_kg=job.added_mass_kg).to_dict()


def _diagnose(job: PairJob) -> dict[str, Any]:
    vehicle = _vehicle_pair(job)
    if vehicle is not None:
        from fielddiag.vehicle.diagnose import diagnose_vehicle

        return diagnose_vehicle(*vehicle, added_mass_kg=job.added_mass_kg).to_dict()
    from fielddiag.diagnose.engine import diagnose_sessions

    return diagnose_sessions([job.before, job.after], added_mass_kg=job.added_mass_kg).to_dict()


SUMMARISERS = {"identify": summarise_identify, "diagnose": summarise_diagnose}
_RUNNERS = {"identify": _identify, "diagnose": _diagnose}


def _run_step(job: PairJob, step: str) -> StepOutcome:
    from fielddiag.errors import FieldDiagError
    from fielddiag.threads import thread_budget

    out = Path(job.outputs[step])
    t0 = time.perf_counter()
    try:
        # the cluster runs one job per worker process and core: its fits stay on one
        # thread (fielddiag.threads)
        with thread_budget(1):
            data = _RUNNERS[step](job)
        summary = SUMMARISERS[step](data)
        data["provenance"] = {
            "fingerprint": job.fingerprints[step],
            "before": Path(job.before).name,
            "after": Path(job.after).name,
            "added_mass_kg": job.added_mass_kg,
            "step": step,
            "made_by": "fielddiag reprocess",
        }
        _write_json_atomically(out, data)
        return StepOutcome(step, "done", output=str(out), summary=summary,
                           wall_s=time.perf_counter() - t0,
                           fingerprint=job.fingerprints[step])
    except FieldDiagError as exc:
        msg = str(exc)
        detail = ""
    except OSError as exc:
        msg = f"{exc.strerror or exc}" + (f": {exc.filename}" if exc.filename else "")
        detail = traceback.format_exc()
    except Exception as exc:  # a corrupt file or a bug: this pair fails, never the batch
        msg = f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__
        detail = traceback.format_exc()
    return StepOutcome(step, "failed", message=msg, detail=detail,
                       wall_s=time.perf_counter() - t0)


def process_pair(job: PairJob) -> PairOutcome:
    """Run the job's steps on one pair (in a worker process); never raises for bad data."""
    t0 = time.perf_counter()
    steps = [_run_step(job, step) for step in job.steps]
    return PairOutcome(job.before, job.after, job.added_mass_kg, job.vehicle, job.corner,
                       steps, worker=f"{socket.gethostname()}:{os.getpid()}",
                       wall_s=time.perf_counter() - t0)
