"""Run batch jobs on dask.distributed: a local cluster by default, or an existing one.

The local cluster has process workers with one thread each: h5py serialises every call
in a process behind one lock, and the numerics hold the GIL in places, so processes are
what scale. Workers receive paths (:class:`~fielddiag.batch.task.PairJob`) and open the
files themselves; on a remote cluster the session files must be visible to the workers
at the same paths (a shared folder) and fielddiag must be installed on them.

A worker that dies (killed, out of memory, a crash in a library on a corrupt file) makes
its pair fail with that reason; the pair is retried once on another worker first, since a
worker can also die for reasons unrelated to the pair it holds. Ctrl-C cancels what is
left; every result already finished is kept (see ``reprocess``: it records as it goes).
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from fielddiag.batch.task import PairJob, PairOutcome, StepOutcome, process_pair
from fielddiag.errors import FieldDiagError

__all__ = ["ClusterInfo", "run_jobs", "start_client"]

#: how many worker deaths a pair may be involved in before it is failed (dask's default
#: is 3): one retry on another worker
ALLOWED_WORKER_DEATHS = 1


@dataclass(frozen=True)
class ClusterInfo:
    """Where the jobs ran: ``address`` and the number of worker processes and threads."""

    address: str
    n_workers: int
    threads: int
    local: bool


def start_client(scheduler: str | None = None, workers: int | None = None):
    """A dask Client on an existing scheduler (``tcp://host:port``) or a new local cluster.

    Returns
    -------
    client, info : distributed.Client, ClusterInfo
        Close the client (and its local cluster) with ``client.close()`` /
        ``client.cluster.close()``, or use :func:`run_jobs`, which does.

    Raises
    ------
    FieldDiagError
        The scheduler cannot be reached, or ``workers`` is not a positive number.
    """
    import dask
    from distributed import Client, LocalCluster

    if scheduler:
        try:
            _probe(scheduler)
            client = Client(scheduler, timeout="10s")
        except (OSError, TimeoutError, ValueError) as exc:
            raise FieldDiagError(
                f"cannot reach the dask scheduler at {scheduler}: {exc}. Start one with "
                "`dask scheduler` and workers with `dask worker ADDRESS --nthreads 1`, or "
                "leave out --scheduler to run on this machine") from exc
        info = client.scheduler_info()
        ws = info.get("workers", {})
        return client, ClusterInfo(scheduler, len(ws),
                                   sum(int(w.get("nthreads", 1)) for w in ws.values()), False)
    n = workers if workers is not None else (os.cpu_count() or 1)
    if n < 1:
        raise FieldDiagError(f"--workers must be at least 1 (got {n})")
    # read when the (in-process) scheduler starts; a remote scheduler keeps its own setting
    with dask.config.set({"distributed.scheduler.allowed-failures": ALLOWED_WORKER_DEATHS}):
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                               dashboard_address=None, silence_logs=logging.ERROR)
    client = Client(cluster)
    return client, ClusterInfo(cluster.scheduler_address, n, n, True)


def _probe(address: str) -> None:
    """Fail at once on a refused TCP connection (dask would keep retrying until its timeout)."""
    import socket
    from urllib.parse import urlsplit

    parts = urlsplit(address if "://" in address else f"tcp://{address}")
    if parts.scheme not in ("tcp", "tls") or not parts.hostname or not parts.port:
        if parts.scheme in ("tcp", "tls"):
            raise ValueError("give the address as tcp://HOST:PORT")
        return  # other transports (inproc, ucx): let dask handle them
    with socket.create_connection((parts.hostname, parts.port), timeout=5.0):
        pass


def _failed(job: PairJob, message: str) -> PairOutcome:
    return PairOutcome(job.before, job.after, job.added_mass_kg, job.vehicle, job.corner,
                       [StepOutcome(s, "failed", message=message) for s in job.steps])


def _worker_death_message(exc: BaseException) -> str:
    return ("the worker processing this pair died (killed, out of memory, or crashed "
            f"reading a corrupt session); {exc}")


def run_jobs(
    jobs: Sequence[PairJob],
    *,
    scheduler: str | None = None,
    workers: int | None = None,
    on_done: Callable[[PairOutcome], None] | None = None,
    on_start: Callable[[ClusterInfo], None] | None = None,
    task: Callable[[PairJob], PairOutcome] = process_pair,
) -> list[PairOutcome]:
    """Run ``jobs`` on a cluster and return their outcomes in the order they finished.

    Parameters
    ----------
    jobs : sequence of PairJob
    scheduler, workers
        See :func:`start_client`.
    on_done : callable or None
        Called with each outcome as it arrives (to record it and draw progress).
    on_start : callable or None
        Called once the cluster is up, with its :class:`ClusterInfo`.
    task : callable
        The function a worker runs per job (the benchmark swaps in a no-op to measure the
        scheduler's own overhead).
    """
    if not jobs:
        return []
    from distributed import as_completed
    from distributed.client import FutureCancelledError

    try:
        from distributed.scheduler import KilledWorker
    except ImportError:  # older layout
        from distributed import KilledWorker  # type: ignore[no-redef]

    client, info = start_client(scheduler, workers)
    outcomes: list[PairOutcome] = []
    try:
        if on_start is not None:
            on_start(info)
        keys = [f"fielddiag-pair-{i}-{'-'.join(j.fingerprints.values())}"
                for i, j in enumerate(jobs)]
        futures = client.map(task, list(jobs), key=keys, pure=False)
        job_of = {f.key: j for f, j in zip(futures, jobs, strict=True)}
        for fut in as_completed(futures):
            job = job_of[fut.key]
            try:
                outcome = fut.result()
            except KilledWorker as exc:
                outcome = _failed(job, _worker_death_message(exc))
            except FutureCancelledError as exc:
                outcome = _failed(job, f"cancelled: {exc}")
            except Exception as exc:  # noqa: BLE001 - e.g. the task could not be unpickled
                outcome = _failed(job, f"{type(exc).__name__}: {exc}")
            outcomes.append(outcome)
            if on_done is not None:
                on_done(outcome)
            fut.release()
    finally:
        cluster = client.cluster if info.local else None
        client.close()
        if cluster is not None:
            cluster.close()
    return outcomes
