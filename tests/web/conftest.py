"""Fixtures of the dashboard tests: a sessions folder, a simulated user, a real server.

* ``sessions_root``: a folder with two short simulated drives (before/after 60 kg) made
  by the simulator and written by :func:`fielddiag.simio.drive_to_session`.
* ``dashboard_user``: nicegui's simulated :class:`~nicegui.testing.User`, connected to the
  dashboard app set up by :func:`fielddiag.web.app.setup_app` (pages, middleware, routes),
  in nicegui's isolated test context (``nicegui_reset_globals``). Async tests run on
  anyio's pytest plugin (``@pytest.mark.anyio``). Like nicegui's ``user`` fixture, it
  fails a test that logged an ERROR record (a handler or timer that raised).
* ``live_server``: ``fielddiag serve`` started as a real subprocess on a free port.
* ``browser``: headless Chromium through Selenium (Debian's chromium + chromium-driver);
  the tests that need it are skipped when it is missing.
"""

from __future__ import annotations

import shutil
from collections.abc import AsyncIterator, Iterator
from pathlib import Path

import pytest
from web_helpers import (
    CHROME_FLAGS,
    SCREENSHOT_DIR,
    LiveServer,
    chromium_available,
    dashboard_user_for,
    fail_on_error_records,
    make_pair,
)


@pytest.fixture(scope="session")
def pair_template(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Simulated once per test run; copied per test."""
    root = tmp_path_factory.mktemp("template")
    make_pair(root / "car-a")
    return root


@pytest.fixture
def sessions_root(tmp_path: Path, pair_template: Path) -> Path:
    root = tmp_path / "root"
    shutil.copytree(pair_template, root)
    return root


@pytest.fixture
def anyio_backend() -> str:
    return "asyncio"


@pytest.fixture
def dashboard_user_factory(caplog: pytest.LogCaptureFixture) -> Iterator:
    """``dashboard_user_for``: an async context manager giving a User for any config; the
    test fails on ERROR log records."""
    yield dashboard_user_for
    fail_on_error_records(caplog)


@pytest.fixture
async def dashboard_user(sessions_root: Path, caplog: pytest.LogCaptureFixture
                         ) -> AsyncIterator:
    """nicegui's User on the dashboard of ``sessions_root``; the test fails on ERROR log
    records (as with nicegui's own ``user`` fixture)."""
    from fielddiag.web.app import DashboardConfig

    async with dashboard_user_for(DashboardConfig(root=sessions_root)) as user:
        yield user
    fail_on_error_records(caplog)


@pytest.fixture
def live_server(sessions_root: Path) -> Iterator[LiveServer]:
    server = LiveServer(sessions_root)
    try:
        yield server
    finally:
        server.stop()


@pytest.fixture(scope="session")
def browser():
    if not chromium_available():
        pytest.skip("chromium and chromium-driver are not installed (apt-get install chromium "
                    "chromium-driver; .ci/run does it)")
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    opts = webdriver.ChromeOptions()
    for flag in CHROME_FLAGS:
        opts.add_argument(flag)
    opts.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    driver = webdriver.Chrome(service=Service(shutil.which("chromedriver")), options=opts)
    driver.set_page_load_timeout(30)
    SCREENSHOT_DIR.mkdir(parents=True, exist_ok=True)
    try:
        yield driver
    finally:
        driver.quit()
