"""End to end in a real headless Chromium against ``fielddiag serve`` in a subprocess.

Screenshots go to tests/screenshots/ (ignored by git) for a person to look at.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from web_helpers import SCREENSHOT_DIR, friction_session

from fielddiag.catalog import result_path
from fielddiag.web.services import diagnosis_backend, recorder_backend

CHART_JS = """
const el = document.querySelector(arguments[0]);
if (!el) return null;
const comp = getElement(el.id.slice(1));
if (!comp || !comp.chart) return null;
const o = comp.chart.getOption();
if (!o || !o.series) return null;
return o.series.map(s => [s.name, (s.data || []).length,
                          (s.data && s.data.length) ? s.data[s.data.length - 1][0] : null]);
"""


_current_driver: list = []


def wait_until(fn: Callable[[], Any], timeout_s: float = 20.0, what: str = "") -> Any:
    deadline = time.monotonic() + timeout_s
    last: Any = None
    while time.monotonic() < deadline:
        try:
            last = fn()
        except Exception as exc:  # element not there yet, stale element...
            last = exc
        else:
            if last:
                return last
        time.sleep(0.05)
    if _current_driver:
        shot(_current_driver[0], f"failed-{what or 'wait'}".replace(" ", "-").replace("/", "-"))
    raise AssertionError(f"timed out waiting for {what or fn}: last {last!r}")


def text_of(driver) -> str:
    return driver.find_element("tag name", "body").text


def click_text(driver, text: str, tag: str = "*", exact: bool = True) -> None:
    cond = (f"normalize-space(.)={json.dumps(text)}" if exact
            else f"contains(normalize-space(.), {json.dumps(text)})")
    el = wait_until(lambda: driver.find_element("xpath", f"//{tag}[{cond}]"), what=text)
    driver.execute_script("arguments[0].scrollIntoView({block: 'center'});", el)
    el.click()


def shot(driver, name: str) -> Path:
    path = SCREENSHOT_DIR / f"{name}.png"
    driver.save_screenshot(str(path))
    return path


def js_errors(driver) -> list[dict]:
    return [e for e in driver.get_log("browser") if e.get("level") == "SEVERE"
            and "favicon" not in e.get("message", "")]


def chart_series(driver, selector: str):
    return driver.execute_script(CHART_JS, selector)


@pytest.fixture
def page(browser, live_server):
    """The browser, cleaned before and after a test (so that a page left open does not log
    connection errors while its server stops)."""
    browser.get("about:blank")
    browser.get_log("browser")
    _current_driver[:] = [browser]
    yield browser
    browser.get("about:blank")
    browser.get_log("browser")


def test_sessions_to_session_to_identification_to_diagnosis(page, live_server,
                                                             sessions_root: Path) -> None:
    d = page
    d.set_window_size(1400, 1000)
    d.get(live_server.url + "/")
    wait_until(lambda: "2 of 2 sessions" in text_of(d), what="session list")
    body = text_of(d)
    assert "car-a/before.h5" in body and "car-a/after.h5" in body and "test car" in body
    # sort by duration: a Quasar client-side sort on the column header
    click_text(d, "Duration", "th", exact=False)
    shot(d, "01-sessions")

    # to a session: the overview of every channel and the CAN speed
    click_text(d, "car-a/before.h5", "a")
    series = wait_until(lambda: (s := chart_series(d, ".fd-session-chart")) and len(s) == 3
                        and all(n > 0 for _, n, _ in s) and s, what="session chart")
    assert [name for name, _, _ in series] == ["wheel_z", "body_z", "vehicle_speed"]
    assert 1900 < series[0][1] <= 2002  # 8000 samples sent as ~2000 points
    assert "of 8000 samples per channel (min/max kept)" in text_of(d)
    shot(d, "02-session-overview")

    # zoom as the mouse wheel would: the server re-sends the window at full detail
    d.execute_script("""const el = document.querySelector('.fd-session-chart');
        getElement(el.id.slice(1)).chart.dispatchAction({type: 'dataZoom', start: 25, end: 30});""")
    wait_until(lambda: "10.000–12.000 s: all 400 samples" in text_of(d), what="zoomed status")
    series = chart_series(d, ".fd-session-chart")
    assert series[0][1] == 400 and 11.9 < series[0][2] < 12.0
    shot(d, "03-session-zoomed")

    # identification of the pair, in the background, then the results
    click_text(d, "Identification", "div")
    wait_until(lambda: "car-a/before.h5 has no identification result yet" in text_of(d),
               what="pair preselected")
    inputs = [i.get_attribute("value") for i in d.find_elements("css selector", "input")]
    assert any(v.startswith("car-a/before.h5") for v in inputs if v)
    assert any(v.startswith("car-a/after.h5") for v in inputs if v)
    click_text(d, "Run identification", "button", exact=False)
    wait_until(lambda: "sprung mass M2" in text_of(d), timeout_s=60, what="parameter table")
    row = d.find_element("xpath", "//tr[td[normalize-space(.)='sprung mass M2']]")
    cells = [c.text for c in row.find_elements("tag name", "td")]
    value, std = float(cells[1]), float(cells[2])
    assert abs(value - 380.0) < 4 * std and std < 19.0  # truth 380 kg, within 4 sigma
    tr = wait_until(lambda: chart_series(d, ".fd-transmissibility-chart"), what="T chart")
    assert [n for n, _, _ in tr][:4] == ["before", "before model", "after", "after model"]
    assert all(n > 10 for _, n, _ in tr)
    shot(d, "04-identification")
    surface = d.find_element("css selector", ".fd-surface-chart")
    d.execute_script("arguments[0].scrollIntoView({block: 'center'});", surface)
    time.sleep(0.3)
    shot(d, "04b-identification-surfaces")

    # diagnosis of a drive whose strut has dry friction, run from the page
    if not diagnosis_backend().available:
        click_text(d, "Diagnosis", "div")
        wait_until(lambda: "Diagnosis: not available yet" in text_of(d), what="panel")
        shot(d, "05-diagnosis")
        pytest.skip(diagnosis_backend().reason)
    friction_session(sessions_root / "car-b")
    d.get(live_server.url + "/diagnose?session=car-b%2Ffriction.h5")
    wait_until(lambda: "car-b/friction.h5 has not been diagnosed yet" in text_of(d),
               what="diagnosis page")
    click_text(d, "Run diagnosis", "button", exact=False)
    wait_until(lambda: "Missing physics found" in text_of(d), timeout_s=90, what="diagnosis")
    body = text_of(d)
    assert "coulomb friction" in body and "dry friction" in body
    stored = json.loads(result_path(sessions_root / "car-b" / "friction.h5",
                                    "diagnose").read_text())
    assert stored["findings"][0]["effect"] == "coulomb_friction"
    shot(d, "05-diagnosis")
    if d.find_elements("css selector", ".fd-windows-chart"):
        el = d.find_element("css selector", ".fd-windows-chart")
        d.execute_script("arguments[0].scrollIntoView({block: 'center'});", el)
        time.sleep(0.3)
        shot(d, "05b-diagnosis-windows")
    errors = js_errors(d)
    assert errors == [], errors


@pytest.mark.skipif(not recorder_backend().available, reason=recorder_backend().reason)
def test_live_recording_in_the_browser(page, live_server, sessions_root: Path) -> None:
    d = page
    d.set_window_size(1400, 1100)
    d.get(live_server.url + "/live")
    click_text(d, "Start", "button", exact=False)
    wait_until(lambda: (s := chart_series(d, ".fd-live-chart")) and len(s) == 3
               and s[0][1] > 50, timeout_s=30, what="live chart")
    time.sleep(3.0)  # steady state: past the start-up of the devices and the estimator
    # frames drawn per second, counted in the browser: renders (ECharts' "finished") that
    # show a new newest sample. The machine is shared, so the best of three 2 s windows.
    d.execute_script("""window.__frames = [];
        const el = document.querySelector('.fd-live-chart');
        const c = getElement(el.id.slice(1)).chart;
        c.on('finished', () => {
            const s = c.getOption().series[0].data;
            window.__frames.push([performance.now(), s[s.length - 1][0]]);
        });""")
    rates = []
    for _ in range(3):
        d.execute_script("window.__frames.length = 0;")
        time.sleep(2.0)
        frames = d.execute_script("return window.__frames")
        new = [f for i, f in enumerate(frames) if i == 0 or f[1] != frames[i - 1][1]]
        rates.append((len(new) - 1) / ((new[-1][0] - new[0][0]) / 1000.0))
        if rates[-1] >= 10.0:
            break
    assert max(rates) >= 10.0, f"frames/s drawn: {rates}"
    click_text(d, "Mark event", "button", exact=False)
    wait_until(lambda: "bump @" in text_of(d), what="event shown")
    shot(d, "06-live")
    click_text(d, "Stop", "button", exact=False)
    wait_until(lambda: "saved recordings/" in text_of(d) or "open recordings/" in text_of(d),
               what="saved")
    errors = js_errors(d)
    assert errors == [], errors
