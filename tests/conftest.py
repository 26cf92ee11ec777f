"""Shared fixtures."""

from __future__ import annotations

import os

import numpy as np
import pytest

from fielddiag.threads import THREADS_ENV


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(12345)


@pytest.fixture(autouse=True, scope="session")
def _one_fit_thread_per_test_process():
    """The suite runs in two processes on two cores (pytest-xdist), and the diagnosis
    tests diagnose in two more: each diagnosis fits on one thread, as ``fielddiag
    reprocess`` does (tests that compare threads with none say so explicitly)."""
    saved = os.environ.get(THREADS_ENV)
    os.environ[THREADS_ENV] = "1"
    yield
    if saved is None:
        os.environ.pop(THREADS_ENV, None)
    else:
        os.environ[THREADS_ENV] = saved
