"""A newcomer's dashboard, in a real headless Chromium against ``fielddiag serve``: a pair
stays a pair wherever it is opened, transmissibility of drives sampled at slightly
different rates shows both curves, a CAN-only session shows its real duration.

Screenshots go to tests/screenshots/ for a person to look at.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest
from test_web_browser import (
    chart_series,
    clean_page,
    click_text,
    js_errors,
    shot,
    shot_of,
    text_of,
    wait_until,
)
from web_helpers import LiveServer

from fielddiag.catalog import result_path
from fielddiag.web.services import diagnosis_backend


def _drive(folder: Path, name: str, *, mass_kg: float, seed: int, vehicle: str = "test car",
           rate_hz: float = 200.0, duration_s: float = 40.0) -> Path:
    from fielddiag import sim
    from fielddiag.simio import drive_to_session

    drive = sim.simulate(duration_s=duration_s, added_mass_kg=mass_kg, seed=seed,
                         sensor=sim.SensorModel(output_rate_hz=rate_hz, snr_db=40.0))
    folder.mkdir(parents=True, exist_ok=True)
    return drive_to_session(drive, folder / name, vehicle=vehicle, corner="front-left")


def _select_values(d) -> list[str]:
    return [v for v in (i.get_attribute("value")
                        for i in d.find_elements("css selector", "input")) if v]


@pytest.fixture
def page(browser):
    """The browser, clean (each test starts its own server)."""
    with clean_page(browser) as b:
        yield b


@pytest.fixture
def server_of():
    servers: list[LiveServer] = []

    def start(root: Path) -> LiveServer:
        servers.append(LiveServer(root))
        return servers[-1]

    yield start
    for s in servers:
        s.stop()


@pytest.fixture(scope="module")
def shared(tmp_path_factory, pair_template: Path):
    """One server for the identification tests (a server starts in ~5 s): its root holds
    the pair (car-a/) and each test's own folder of drives."""
    import shutil

    root = tmp_path_factory.mktemp("pairs-shared")
    shutil.copytree(pair_template, root, dirs_exist_ok=True)
    server = LiveServer(root)
    try:
        yield root, server
    finally:
        server.stop()


def test_identification_preselects_the_partner_by_vehicle_not_by_name(page, shared) -> None:
    """car-a holds its pair and, first by name, an 'after' drive of another car: the
    identification page pairs car-a/before.h5 with its own after drive."""
    sessions_root, server = shared
    _drive(sessions_root / "car-a", "a-other-car.h5", mass_kg=60.0, seed=5,
           vehicle="another car")
    d = page
    d.get(server.url + "/identify?before=car-a%2Fbefore.h5")
    wait_until(lambda: any(v.startswith("car-a/after.h5") for v in _select_values(d)),
               what="partner preselected")
    values = _select_values(d)
    assert any(v.startswith("car-a/before.h5") for v in values)
    assert not any(v.startswith("car-a/a-other-car.h5") for v in values)
    assert "60.0" in values  # the added mass, from the two drives' own metadata
    # opened from the after drive, the same pair
    d.get(server.url + "/identify?before=car-a%2Fafter.h5")
    wait_until(lambda: any(v.startswith("car-a/before.h5") for v in _select_values(d)),
               what="pair from the after drive")
    values = _select_values(d)
    assert [v.split()[0] for v in values if v.startswith("car-a/")] == [
        "car-a/before.h5", "car-a/after.h5"]
    shot(d, "10-identify-partner")
    assert js_errors(d) == []


def test_diagnosis_opened_from_a_session_keeps_the_pair(page, sessions_root: Path,
                                                        server_of) -> None:
    """Diagnose reached from a session page: the pair is preselected, and the page shows
    the result when the job ends. It used to stop updating: the session page had forked
    the session reader worker, which kept copies of the browser's keep-alive connections;
    closed by the server they stayed open, and the browser's request for the results'
    components waited in one of them forever (nicegui handles its messages in order, so
    every later update waited behind it)."""
    if not diagnosis_backend().available:
        pytest.skip(diagnosis_backend().reason)
    server = server_of(sessions_root)
    d = page
    d.get(server.url + "/session?path=car-a%2Fafter.h5")
    click_text(d, "Diagnose", "button", exact=False)
    wait_until(lambda: any(v.startswith("car-a/after.h5") for v in _select_values(d))
               and any(v.startswith("car-a/before.h5") for v in _select_values(d)),
               what="pair on the diagnosis page")
    values = _select_values(d)
    assert values[0].startswith("car-a/before.h5") and values[1].startswith("car-a/after.h5")
    assert "60.0" in values
    click_text(d, "Run diagnosis", "button", exact=False)
    wait_until(lambda: "diagnosis done" in text_of(d) or "Findings" in text_of(d),
               timeout_s=240, what="pair diagnosis")
    stored = json.loads(result_path(sessions_root / "car-a" / "before.h5",
                                    "diagnose").read_text())
    assert stored["session_paths"] == ["before.h5", "after.h5"]
    assert stored["mode"] == "pair"
    shot(d, "11-diagnosis-of-the-pair")
    # the before drive diagnosed alone (the second drive cleared): stored under a name of
    # its own, the pair's result stays as it was
    pair_result = result_path(sessions_root / "car-a" / "before.h5", "diagnose").read_bytes()
    clear = [b for b in d.find_elements("css selector", ".q-field__append .q-icon")
             if b.text == "cancel" and b.is_displayed()]
    assert clear, "the second drive's select has a clear button"
    clear[-1].click()
    wait_until(lambda: not any(v.startswith("car-a/after.h5") for v in _select_values(d)),
               what="second drive cleared")
    click_text(d, "Run diagnosis", "button", exact=False)
    single = result_path(sessions_root / "car-a" / "before.h5", "diagnose-single")
    wait_until(single.exists, timeout_s=240, what="one-drive diagnosis stored")
    assert json.loads(single.read_text())["mode"] == "single"
    assert result_path(sessions_root / "car-a" / "before.h5",
                       "diagnose").read_bytes() == pair_result
    assert js_errors(d) == []


def test_transmissibility_of_drives_at_500_and_500_001_hz_shows_both(page, shared) -> None:
    top, server = shared
    root = top / "rates"
    _drive(root, "before.h5", mass_kg=0.0, seed=11, rate_hz=500.0, duration_s=40.0,
           vehicle="rates car")
    _drive(root, "after.h5", mass_kg=60.0, seed=12, rate_hz=500.001, duration_s=40.0,
           vehicle="rates car")
    d = page
    d.get(server.url + "/identify?before=rates%2Fbefore.h5")
    wait_until(lambda: any(v.startswith("rates/after.h5") for v in _select_values(d)),
               what="pair preselected")
    click_text(d, "Run identification", "button", exact=False)
    wait_until(lambda: "sprung mass M2" in text_of(d), timeout_s=120, what="parameter table")
    tr = wait_until(lambda: chart_series(d, ".fd-transmissibility-chart"), what="T chart")
    names = [n for n, _, _ in tr]
    assert names[:4] == ["before", "before model", "after", "after model"]
    counts = dict((n, k) for n, k, _ in tr)
    assert counts["after"] == counts["before"] > 50  # both drawn on the one grid
    stored = json.loads(result_path(root / "before.h5", "identify").read_text())
    f_before, f_after = (np.array(t["freq_hz"]) for t in stored["transmissibility"])
    assert np.array_equal(f_before, f_after)
    shot_of(d, ".fd-transmissibility-chart", "12-transmissibility-500-vs-500.001-hz")
    assert js_errors(d) == []


def _can_only_session(path: Path, duration_s: float = 60.0) -> Path:
    """A session as a CAN log import writes it: vehicle signals only, no DAQ channel."""
    from fielddiag.channels import SessionMetadata, SignalSpec
    from fielddiag.session import SessionWriter

    t = np.arange(0.0, duration_s, 0.024)
    with SessionWriter(path, SessionMetadata(vehicle="can car"), [], sample_rate_hz=100.0,
                       signals=[SignalSpec("SPEED", "m/s", "can", "SPEED", "speed")]) as w:
        w.append_signal("SPEED", t + 5.0, 10.0 + np.sin(t))
    return path


def test_can_only_session_shows_its_real_duration(page, tmp_path: Path, server_of) -> None:
    root = tmp_path / "can"
    root.mkdir()
    _can_only_session(root / "can-only.h5")
    server = server_of(root)
    d = page
    d.get(server.url + "/")
    wait_until(lambda: "can-only.h5" in text_of(d), what="session list")
    assert "60.0 s" in text_of(d) or "1 min" in text_of(d)
    click_text(d, "can-only.h5", "a")
    # the layout comes first, the points just after it
    series = wait_until(lambda: (s := chart_series(d, ".fd-session-chart"))
                        and all(k > 0 for _, k, _ in s) and s, what="session chart")
    (name, n, last), = series
    assert name == "SPEED" and n > 100
    assert 64.0 < last <= 65.0  # the signal's own span: 5 s to 65 s
    time.sleep(0.3)
    shot(d, "13-can-only-session")
    assert js_errors(d) == []
