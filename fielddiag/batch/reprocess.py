"""Reprocess a fleet's sessions: find, pair, skip what is up to date, run, record.

:func:`plan` decides what to do without running anything (``--dry-run`` prints it);
:func:`reprocess` runs the plan on a cluster and records every outcome in the catalog as
it arrives, so an interrupted batch resumes where it stopped.
"""

from __future__ import annotations

import json
import os
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

from fielddiag.batch.discover import (
    Pairing,
    find_sessions,
    pair_sessions,
    read_headers,
)
from fielddiag.batch.runner import ClusterInfo, run_jobs
from fielddiag.batch.store import CATALOG_NAME, BatchCatalog
from fielddiag.batch.task import (
    STEPS,
    SUMMARISERS,
    PairJob,
    PairOutcome,
    StepOutcome,
    make_job,
)
from fielddiag.errors import FieldDiagError

__all__ = ["BatchPlan", "BatchReport", "plan", "reprocess"]


@dataclass
class BatchPlan:
    """What a batch will do: the jobs to run, the pairs already up to date, what is left out."""

    root: Path
    catalog_path: Path
    pairing: Pairing
    jobs: list[PairJob] = field(default_factory=list)
    up_to_date: list[PairOutcome] = field(default_factory=list)


@dataclass
class BatchReport:
    """What a batch did."""

    plan: BatchPlan
    outcomes: list[PairOutcome]
    cluster: ClusterInfo | None
    wall_s: float

    @property
    def n_failed(self) -> int:
        return sum(o.status == "failed" for o in self.outcomes) + len(self.plan.pairing.unreadable)


def _input_folder(item: str | os.PathLike) -> Path:
    """The folder an input names: itself, a file's folder, or a glob's fixed prefix."""
    import glob

    text = os.fspath(item)
    if glob.has_magic(text):
        fixed = []
        for part in Path(text).parts:
            if glob.has_magic(part):
                break
            fixed.append(part)
        p = Path(*fixed) if fixed else Path.cwd()
    else:
        p = Path(text)
    p = p.resolve()
    return p if p.is_dir() else p.parent


def _common_folder(inputs: Sequence[str | os.PathLike]) -> Path:
    """The folder the batch is about (the catalog goes there): the common folder of the
    inputs, so ``reprocess fleet/`` keeps its catalog in ``fleet/`` where the dashboard
    serving ``fleet/`` finds it."""
    return Path(os.path.commonpath([str(_input_folder(i)) for i in inputs]))


def _stored_result(step: str, output: str) -> tuple[str | None, dict]:
    """(fingerprint, catalog summary) of a result file (None, {} if unreadable)."""
    try:
        with open(output, encoding="utf-8") as fh:
            data = json.load(fh)
        return str(data["provenance"]["fingerprint"]), SUMMARISERS[step](data)
    except (OSError, ValueError, KeyError, TypeError):
        return None, {}


def plan(
    inputs: Sequence[str | os.PathLike],
    *,
    steps: Sequence[str] = STEPS,
    force: bool = False,
    manifest: str | os.PathLike | None = None,
    catalog_path: str | os.PathLike | None = None,
    max_apart_h: float = 24.0,
) -> BatchPlan:
    """Find and pair the sessions named by ``inputs`` and decide what needs running.

    A step of a pair is up to date (skipped) when its result file exists and carries the
    fingerprint of the current inputs (the catalog is consulted first, the file itself
    if the catalog has no row), unless ``force``.

    Raises
    ------
    FieldDiagError
        An input names nothing, no session is found, a manifest is malformed, or a step
        is unknown.
    """
    unknown = [s for s in steps if s not in STEPS]
    if unknown or not steps:
        raise FieldDiagError(f"unknown step {unknown[0] if unknown else '(none)'!r}; "
                             f"choose from {', '.join(STEPS)}")
    sessions, manifests = find_sessions(inputs)
    if manifest is not None:
        if not Path(manifest).is_file():
            raise FieldDiagError(f"manifest {manifest} does not exist")
        manifests = sorted({*manifests, Path(manifest).resolve()})
    if not sessions:
        raise FieldDiagError(f"no session files (.h5) found in {', '.join(map(str, inputs))}")
    root = _common_folder(inputs)
    catalog_file = (Path(catalog_path) if catalog_path else root / CATALOG_NAME).resolve()
    # read only: a dry run leaves no catalog behind
    known = (BatchCatalog(catalog_file, readonly=True).done_steps()
             if catalog_file.is_file() else {})
    pairing = pair_sessions(read_headers(sessions), manifests, max_apart_h=max_apart_h)
    result = BatchPlan(root, catalog_file, pairing)
    shared = Counter(p.before for p in pairing.pairs)
    for pair in pairing.pairs:
        job = make_job(pair, steps, before_shared=shared[pair.before] > 1)
        todo, done = [], []
        for step in job.steps:
            out, fp = job.outputs[step], job.fingerprints[step]
            if force or not Path(out).is_file():
                todo.append(step)
                continue
            stored_fp, summary = known.get((job.before, job.after, step), (None, None))
            if stored_fp != fp:  # not in the catalog (or lost): the result file decides
                stored_fp, summary = _stored_result(step, out)
            if stored_fp != fp:
                todo.append(step)
                continue
            done.append(StepOutcome(step, "skipped", message="up to date", output=out,
                                    summary=summary, fingerprint=fp))
        if todo:
            result.jobs.append(replace(job, steps=tuple(todo),
                                       outputs={s: job.outputs[s] for s in todo},
                                       fingerprints={s: job.fingerprints[s] for s in todo}))
        if done:
            result.up_to_date.append(PairOutcome(job.before, job.after, job.added_mass_kg,
                                                 job.vehicle, job.corner, done))
    return result


def reprocess(
    batch: BatchPlan,
    *,
    scheduler: str | None = None,
    workers: int | None = None,
    on_done: Callable[[PairOutcome], None] | None = None,
    on_start: Callable[[ClusterInfo], None] | None = None,
) -> BatchReport:
    """Run a plan; every outcome is stored in the catalog the moment it arrives."""
    import time

    catalog = BatchCatalog(batch.catalog_path)
    for outcome in batch.up_to_date:
        catalog.record(outcome)
    t0 = time.perf_counter()
    cluster: list[ClusterInfo] = []

    def started(info: ClusterInfo) -> None:
        cluster.append(info)
        if on_start is not None:
            on_start(info)

    def finished(outcome: PairOutcome) -> None:
        catalog.record(outcome)
        if on_done is not None:
            on_done(outcome)

    outcomes = run_jobs(batch.jobs, scheduler=scheduler, workers=workers, on_done=finished,
                        on_start=started)
    merged = _merge(batch.up_to_date, outcomes)
    return BatchReport(batch, merged, cluster[0] if cluster else None,
                       time.perf_counter() - t0)


def _merge(up_to_date: list[PairOutcome], ran: list[PairOutcome]) -> list[PairOutcome]:
    """One outcome per pair: the steps that ran plus the steps skipped as up to date."""
    by_pair = {(o.before, o.after): o for o in up_to_date}
    out = []
    for o in ran:
        skipped = by_pair.pop((o.before, o.after), None)
        if skipped is not None:
            o = replace(o, steps=sorted([*skipped.steps, *o.steps],
                                        key=lambda s: STEPS.index(s.step)))
        out.append(o)
    out.extend(by_pair.values())
    return sorted(out, key=lambda o: (o.before, o.after))
