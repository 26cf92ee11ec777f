"""Helpers of the dashboard tests (a module with a name of its own: both tests/ and
tests/web/ have a conftest.py, so tests import these from here, not from ``conftest``)."""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
import socket
import subprocess
import sys
import time
from collections.abc import AsyncIterator
from pathlib import Path

import httpx

SCREENSHOT_DIR = Path(__file__).resolve().parents[1] / "screenshots"
CHROME_FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-dev-shm-usage",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
    "--window-size=1400,1000",
)


def make_pair(folder: Path, *, duration_s: float = 40.0, added_mass_kg: float = 60.0,
              rate_hz: float = 200.0) -> tuple[Path, Path]:
    """A before/after pair of simulated drives in ``folder``."""
    from fielddiag import sim
    from fielddiag.simio import drive_to_session

    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for label, mass, seed in (("before", 0.0, 11), ("after", added_mass_kg, 12)):
        drive = sim.simulate(
            duration_s=duration_s,
            added_mass_kg=mass,
            seed=seed,
            sensor=sim.SensorModel(output_rate_hz=rate_hz, snr_db=40.0),
        )
        out.append(drive_to_session(drive, folder / f"{label}.h5", vehicle="test car",
                                    corner="front-left"))
    return out[0], out[1]


#: The friction drive runs at constant speed over one speed bump, in the part of the drive
#: the diagnosis holds out (the last 30 %), so the residual stands out in a time window.
FRICTION_SPEED_MPS = 12.0
FRICTION_BUMP_AT_S = 33.0


def friction_session(folder: Path, friction_n: float = 150.0) -> Path:
    """A 40 s simulated drive whose strut has dry friction (the linear model misses it),
    over a speed bump at :data:`FRICTION_BUMP_AT_S` (where the misfit stands out)."""
    from fielddiag import sim
    from fielddiag.sim.road import SpeedBump, SpeedProfile
    from fielddiag.simio import drive_to_session

    drive = sim.simulate(
        duration_s=40.0, seed=21, sensor=sim.SensorModel(output_rate_hz=200.0, snr_db=40.0),
        speed=SpeedProfile.constant(FRICTION_SPEED_MPS, 40.0),
        road_events=[SpeedBump(FRICTION_SPEED_MPS * FRICTION_BUMP_AT_S, height_m=0.08)],
        effects=(sim.make_effect("coulomb_friction", friction_force_n=friction_n),))
    folder.mkdir(parents=True, exist_ok=True)
    return drive_to_session(drive, folder / "friction.h5", vehicle="sticky car")


def short_session(folder: Path, duration_s: float) -> Path:
    """A short simulated drive ``short-<duration>s.h5`` (for lists that sort by duration)."""
    from fielddiag import sim
    from fielddiag.simio import drive_to_session

    drive = sim.simulate(duration_s=duration_s, seed=31,
                         sensor=sim.SensorModel(output_rate_hz=100.0, snr_db=40.0))
    folder.mkdir(parents=True, exist_ok=True)
    return drive_to_session(drive, folder / f"short-{duration_s:g}s.h5", vehicle="short car")


def error_records(caplog) -> list[logging.LogRecord]:
    """ERROR (and worse) log records of a test's call phase."""
    return [r for r in caplog.get_records("call") if r.levelno >= logging.ERROR]


def fail_on_error_records(caplog) -> None:
    """Fail the test on ERROR log records, as nicegui's own ``user`` fixture does (an
    exception in a handler or a timer is logged by nicegui, not raised into the test)."""
    import pytest

    errors = error_records(caplog)
    if errors:
        pytest.fail("There were unexpected ERROR logs:\n" + "\n".join(
            f"{r.name}: {r.getMessage()}" + (f"\n{r.exc_text}" if r.exc_text else "")
            for r in errors), pytrace=False)


@contextlib.asynccontextmanager
async def dashboard_user_for(config) -> AsyncIterator:
    """nicegui's User on the dashboard configured by ``config`` (a DashboardConfig).

    A copy of nicegui's ``user_simulation`` for an app set up by a function instead of a
    main file; the fixtures that use it fail the test on ERROR log records afterwards
    (:func:`fail_on_error_records`), like nicegui's ``user`` fixture.
    """
    from nicegui import core, ui
    from nicegui.functions.download import download
    from nicegui.functions.navigate import Navigate
    from nicegui.functions.notify import notify
    from nicegui.testing.general import nicegui_reset_globals, prepare_simulation
    from nicegui.testing.user import User

    from fielddiag.web.app import setup_app

    with nicegui_reset_globals():
        os.environ["NICEGUI_USER_SIMULATION"] = "true"
        try:
            root_fn = setup_app(config)
            prepare_simulation()
            ui.run(root_fn, storage_secret="test secret")
            async with core.app.router.lifespan_context(core.app):
                async with httpx.AsyncClient(
                    transport=httpx.ASGITransport(core.app), base_url="http://127.0.0.1"
                ) as client:
                    user = User(client)
                    user.state = root_fn.state  # the DashboardState, for assertions
                    yield user
        finally:
            os.environ.pop("NICEGUI_USER_SIMULATION", None)
            ui.navigate = Navigate()
            ui.notify = notify
            ui.download = download


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def server_env() -> dict[str, str]:
    """Environment of a server subprocess: without pytest's and nicegui's test markers
    (nicegui changes its behaviour when it believes it runs under pytest)."""
    env = {k: v for k, v in os.environ.items()
           if not k.startswith(("PYTEST_", "NICEGUI_"))}
    env["PYTHONUNBUFFERED"] = "1"
    return env


class LiveServer:
    """``fielddiag serve`` in a subprocess."""

    def __init__(self, root: Path, *args: str, host: str = "127.0.0.1") -> None:
        self.port = free_port()
        self.host = host
        self.root = root
        self.log = root.parent / f"serve-{self.port}.log"
        self._log_fh = open(self.log, "w")
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "fielddiag.cli", "serve", "--root", str(root), "--host",
             host, "--port", str(self.port), *args],
            stdout=self._log_fh, stderr=subprocess.STDOUT, env=server_env(),
        )
        self.url = f"http://127.0.0.1:{self.port}"
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"server exited: {self.log.read_text()}")
            try:
                with socket.create_connection(("127.0.0.1", self.port), timeout=0.2):
                    break
            except OSError:
                time.sleep(0.1)
        else:
            self.stop()
            raise RuntimeError(f"server did not start: {self.log.read_text()}")

    def output(self) -> str:
        return self.log.read_text()

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
        self._log_fh.close()


def chromium_available() -> bool:
    return bool(shutil.which("chromedriver")) and bool(
        shutil.which("chromium") or shutil.which("chromium-browser")
        or shutil.which("google-chrome")
    )


