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


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config, items):
    """Tests that share a module's fixture run on one worker (pytest-xdist's ``--dist
    loadgroup``, in pyproject.toml), so that the fixture runs once (the diagnosis
    catalogue of tests/diagnose/test_diagnose.py, the dashboard's server); every other
    test goes to whichever worker is free: the long diagnoses of one file are shared
    by both, and neither waits alone at the end on a file the other could have split."""
    for item in items:
        info = getattr(item, "_fixtureinfo", None)
        defs = info.name2fixturedefs.values() if info is not None else ()
        if any(d.scope in ("module", "class", "package") for ds in defs for d in ds):
            item.add_marker(pytest.mark.xdist_group(item.nodeid.split("::")[0]))
