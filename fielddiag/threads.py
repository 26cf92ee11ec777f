"""Independent numeric work on threads: the compiled kernels and LAPACK release the GIL.

A diagnosis fits every effect of the library to the same drives, and those fits do not
depend on each other; inside one fit, the drives (sessions) are simulated independently.
Both run on a few threads of the one process (no copies of the drives, no second import of
the compiled kernels), each with a one-threaded BLAS (:mod:`fielddiag.blas`).

A *thread budget* says how many threads the work may use: :func:`thread_budget` sets it
for a block (``diagnose_drives(workers=...)`` does), ``$FIELDDIAG_THREADS`` sets the
default, else one per usable CPU. :func:`map_threads` shares its budget among its tasks,
so nested parallel work (fits on threads, each simulating its sessions on threads) never
uses more threads than the budget. Where the caller already runs one job per core
(``fielddiag reprocess``, the randomized benchmark) it sets a budget of 1 and everything
runs in order on the calling thread.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from contextvars import ContextVar
from typing import TypeVar

T = TypeVar("T")
R = TypeVar("R")

__all__ = ["THREADS_ENV", "default_threads", "map_threads", "thread_budget", "usable_cpus"]

#: Environment variable: the default thread budget (like ``OMP_NUM_THREADS``); unset, one
#: thread per usable CPU.
THREADS_ENV = "FIELDDIAG_THREADS"

_BUDGET: ContextVar[int | None] = ContextVar("fielddiag_thread_budget", default=None)


def usable_cpus() -> int:
    """The CPUs this process may run on (its affinity mask where the OS has one)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - macOS, Windows
        return max(1, os.cpu_count() or 1)


def default_threads() -> int:
    """The thread budget where nobody set one: ``$FIELDDIAG_THREADS``, else one per usable
    CPU (a value that is not a positive whole number is ignored)."""
    try:
        return max(1, int(os.environ[THREADS_ENV]))
    except (KeyError, ValueError):
        return usable_cpus()


def current_budget() -> int:
    """The threads the work running here may use (:func:`thread_budget`)."""
    budget = _BUDGET.get()
    return default_threads() if budget is None else budget


@contextlib.contextmanager
def thread_budget(threads: int | None) -> Iterator[int]:
    """Run the block with a budget of ``threads`` (None: :func:`default_threads`)."""
    n = default_threads() if threads is None else max(1, int(threads))
    token = _BUDGET.set(n)
    try:
        yield n
    finally:
        _BUDGET.reset(token)


def map_threads(fn: Callable[[T], R], items: Sequence[T], workers: int | None = None,
                cost: Callable[[T], float] | None = None) -> list[R]:
    """``[fn(x) for x in items]``, on up to ``workers`` threads.

    Parameters
    ----------
    fn : callable
        Called once per item; its exceptions propagate (the first in ``items`` order).
    items : sequence
        The independent tasks.
    workers : int or None
        Threads; None: the current budget (:func:`thread_budget`). With 1 (or a single
        item) the tasks run in order on the calling thread. Each task runs with an equal
        share of the budget (at least 1), for the parallel work it does itself.
    cost : callable or None
        A guess of each item's run time: the dearest are started first, so that one long
        task does not start last and run alone (longest processing time first).

    Returns
    -------
    list
        The results in the order of ``items``, whatever order they ran in.
    """
    items = list(items)
    budget = current_budget() if workers is None else max(1, int(workers))
    n = min(budget, len(items))
    if n <= 1:
        return [fn(x) for x in items]
    share = max(1, budget // n)

    def run(x: T) -> R:
        with thread_budget(share):
            return fn(x)

    order = sorted(range(len(items)), key=lambda i: -cost(items[i])) if cost else \
        range(len(items))
    with ThreadPoolExecutor(max_workers=n, thread_name_prefix="fielddiag") as pool:
        futures = {i: pool.submit(run, items[i]) for i in order}
        return [futures[i].result() for i in range(len(items))]
