"""Keep BLAS on one thread inside the numerics.

The fits solve many small, tall least-squares problems (a few parameters by thousands of
samples). A multi-threaded BLAS (OpenBLAS spawns one thread per core) gains nothing on
them and loses much when the cores are busy: on this 2-core machine a diagnosis took
10.2 s with one BLAS thread and 16.8 s (and 3x the CPU) with two. Parallelism belongs one
level up (``fielddiag reprocess`` runs one pair per worker process).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import ParamSpec, TypeVar

from threadpoolctl import threadpool_limits

P = ParamSpec("P")
R = TypeVar("R")

__all__ = ["single_threaded_blas"]


def single_threaded_blas(fn: Callable[P, R]) -> Callable[P, R]:
    """Run ``fn`` with BLAS limited to one thread (restored afterwards)."""

    @functools.wraps(fn)
    def wrapper(*args: P.args, **kwargs: P.kwargs) -> R:
        with threadpool_limits(limits=1, user_api="blas"):
            return fn(*args, **kwargs)

    return wrapper
