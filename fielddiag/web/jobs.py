"""Long work (identification, diagnosis, imports) run off the event loop, with progress.

A :class:`Job` runs a function in a worker thread and exposes its progress (a fraction
and a message), its result or its error; pages poll it with a timer, so the page stays
responsive and a job keeps running when the person navigates away and comes back.
The numerics called from here release the GIL in their compiled/numpy parts, so a thread
is enough to keep the dashboard fluid; nothing here computes anything itself.
"""

from __future__ import annotations

import inspect
import logging
import threading
import time
import uuid
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

from fielddiag.errors import FieldDiagError

__all__ = ["Job", "JobRunner", "Progress"]

log = logging.getLogger("fielddiag.web")


@dataclass
class Progress:
    """Progress of a job: a fraction in [0, 1] and what it is doing."""

    fraction: float = 0.0
    message: str = "waiting"


@dataclass
class Job:
    """One unit of long work and its state (``queued``, ``running``, ``done``, ``failed``)."""

    id: str
    kind: str
    title: str
    params: dict[str, Any] = field(default_factory=dict)
    state: str = "queued"
    progress: Progress = field(default_factory=Progress)
    result: Any = None
    error: str = ""
    started_unix_s: float = 0.0
    finished_unix_s: float = 0.0
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def report(self, fraction: float | None = None, message: str | None = None) -> None:
        """Progress callback handed to the work function (thread-safe)."""
        with self._lock:
            if fraction is not None:
                self.progress.fraction = float(min(1.0, max(0.0, fraction)))
            if message is not None:
                self.progress.message = str(message)

    @property
    def finished(self) -> bool:
        return self.state in ("done", "failed")

    @property
    def elapsed_s(self) -> float:
        if not self.started_unix_s:
            return 0.0
        end = self.finished_unix_s or time.time()
        return end - self.started_unix_s


def _accepts_progress(fn: Callable) -> str | None:
    """Name of the progress keyword ``fn`` accepts (``progress`` / ``on_progress``), if any."""
    try:
        params = inspect.signature(fn).parameters
    except (TypeError, ValueError):
        return None
    for name in ("progress", "on_progress", "progress_callback"):
        if name in params:
            return name
    return None


class JobRunner:
    """Runs jobs in a small thread pool and keeps the recent ones for the pages.

    Parameters
    ----------
    workers : int
        Jobs run at the same time (the rest queue).
    keep : int
        Finished jobs remembered.
    """

    def __init__(self, workers: int = 1, keep: int = 50) -> None:
        self._pool = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="fielddiag-job")
        self._jobs: dict[str, Job] = {}
        self._keep = keep
        self._lock = threading.Lock()

    def submit(
        self, kind: str, title: str, fn: Callable[..., Any], /, *args: Any, **kwargs: Any
    ) -> Job:
        """Start ``fn(*args, **kwargs)`` in the background and return its Job at once.

        If ``fn`` takes a ``progress`` (or ``on_progress``) keyword, it is given
        ``job.report(fraction, message)``.
        """
        job = Job(id=uuid.uuid4().hex[:12], kind=kind, title=title, params=dict(kwargs))
        name = _accepts_progress(fn)
        if name is not None and name not in kwargs:
            kwargs[name] = job.report

        def work() -> None:
            job.state = "running"
            job.started_unix_s = time.time()
            job.report(0.0, "started")
            try:
                job.result = fn(*args, **kwargs)
                job.report(1.0, "done")
                job.state = "done"
            except FieldDiagError as exc:
                job.error = str(exc)
                job.state = "failed"
            except Exception as exc:  # a bug: shown with its type, logged with the traceback
                job.error = f"{type(exc).__name__}: {exc}"
                job.state = "failed"
                log.error("%s failed", title, exc_info=exc)
            finally:
                job.finished_unix_s = time.time()

        with self._lock:
            self._jobs[job.id] = job
            finished = [j for j in self._jobs.values() if j.finished]
            for old in finished[: max(0, len(finished) - self._keep)]:
                self._jobs.pop(old.id, None)
        self._pool.submit(work)
        return job

    def get(self, job_id: str) -> Job | None:
        with self._lock:
            return self._jobs.get(job_id)

    def jobs(self, kind: str | None = None) -> list[Job]:
        """Jobs, newest first."""
        with self._lock:
            out = [j for j in self._jobs.values() if kind is None or j.kind == kind]
        return sorted(out, key=lambda j: j.started_unix_s or time.time(), reverse=True)

    def shutdown(self) -> None:
        self._pool.shutdown(wait=False, cancel_futures=True)
