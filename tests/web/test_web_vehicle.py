"""The full-vehicle diagnosis page in a real headless Chromium against ``fielddiag serve``:
the car seen from above coloured by finding, the per-corner and body tables, the held-out
fit. Screenshot: tests/screenshots/20-full-vehicle-diagnosis.png."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from _vehicle_helpers import write_with_a_gap
from test_web_browser import chart_series, clean_page, js_errors, shot, text_of, wait_until
from web_helpers import LiveServer

from fielddiag.catalog import result_path
from fielddiag.effects import CoulombFriction
from fielddiag.vehicle import random_vehicle, read_vehicle_recording, simulate_vehicle
from fielddiag.vehicle.diagnose import diagnose_vehicle
from fielddiag.vehicle.writer import write_vehicle_session

RESIDUAL_RMS_JS = """
const el = document.querySelector(arguments[0]);
if (!el) return null;
const comp = getElement(el.id.slice(1));
if (!comp || !comp.chart) return null;
const o = comp.chart.getOption();
if (!o || !o.series || !o.series.length || !(o.series[0].data || []).length) return null;
return o.series.map(s => [s.name, Math.sqrt(s.data.reduce((a, p) => a + p[1] * p[1], 0)
                                            / s.data.length)]);"""

WHEELS_JS = """return Array.from(document.querySelectorAll('.fd-wheel')).map(
    el => [el.getAttribute('data-corner'), el.getAttribute('data-status'),
           el.getAttribute('fill')]);"""


@pytest.fixture
def vehicle_root(tmp_path: Path) -> Path:
    """A folder with a diagnosed full-vehicle pair: worn rear-left damper, front-left
    strut friction."""
    car = random_vehicle(21)
    car = car.with_corner("rl", damping_ns_per_m=0.7 * car.corner("rr").damping_ns_per_m)
    eff = {"fl": [CoulombFriction(friction_force_n=80.0)]}
    at = (1.8, -0.2)
    folder = tmp_path / "root" / "car"
    folder.mkdir(parents=True)
    b = simulate_vehicle(car, duration_s=45.0, seed=1, effects=eff)
    a = simulate_vehicle(car, duration_s=45.0, seed=2, effects=eff, added_mass_kg=150.0,
                         added_mass_at_m=at)
    # the 'before' drive lost a second while recording: read back, the longest stretch
    pb = write_with_a_gap(b, folder / "before.h5", (2.0, 3.0), vehicle_name="test car")
    pa = write_vehicle_session(a, folder / "after.h5", vehicle_name="test car")
    rb = read_vehicle_recording(pb)
    out = {"session_paths": [pb.name, pa.name],
           **diagnose_vehicle(rb, read_vehicle_recording(pa), 150.0, at).to_dict()}
    for p in (pb, pa):
        result_path(p, "diagnose").write_text(json.dumps(out), encoding="utf-8")
    return tmp_path / "root"


def test_full_vehicle_diagnosis_page(browser, vehicle_root: Path) -> None:
    server = LiveServer(vehicle_root)
    try:
        with clean_page(browser) as d:
            d.set_window_size(1400, 1300)
            d.get(server.url + "/diagnose?session=car%2Fbefore.h5")
            wait_until(lambda: "Missing physics found at a corner" in text_of(d), timeout_s=60,
                       what="full-vehicle verdict")
            wheels = {c: (s, fill) for c, s, fill in d.execute_script(WHEELS_JS)}
            assert {c: s for c, (s, _) in wheels.items()} == {
                "fl": "effect", "fr": "ok", "rl": "mismatch", "rr": "ok"}
            assert wheels["fl"][1] != wheels["rl"][1] != wheels["fr"][1]
            body = text_of(d)
            # per-corner table: the finding in its row, values with std
            row = d.find_element("xpath", "//tr[td[normalize-space(.)='rl']]")
            cells = [c.text for c in row.find_elements("tag name", "td")]
            assert cells[3] == "damping x0.70" and "±" in cells[2]
            row = d.find_element("xpath", "//tr[td[normalize-space(.)='fl']]")
            assert row.find_elements("tag name", "td")[3].text == "coulomb friction"
            assert "sprung mass" in body and "pitch inertia (about the CoG)" in body
            assert "dry friction of about" in body and "30 % lower than at rr" in body
            warning = d.find_element("css selector", ".fd-vehicle-warning").text
            (note,) = read_vehicle_recording(vehicle_root / "car" / "before.h5").notes
            assert warning == f"⚠ {note}" and "stretch, 3.0-45.0 s" in warning
            charts = d.find_elements("css selector", ".fd-vehicle-fit-chart")
            assert len(charts) == 2  # held-out traces of both drives
            series = wait_until(lambda: chart_series(d, ".fd-vehicle-fit-chart"),
                                what="fit chart")
            assert [n for n, _, _ in series] == ["recorded", "linear model", "with the findings"]
            assert all(k > 100 for _, k, _ in series)
            # what each model leaves of the held-out data: the findings leave less
            rms = wait_until(lambda: d.execute_script(RESIDUAL_RMS_JS,
                                                      ".fd-vehicle-residual-chart"),
                             what="residual chart")
            assert [n for n, _ in rms] == ["left by the linear model", "left with the findings"]
            out = json.loads(result_path(vehicle_root / "car" / "before.h5",
                                         "diagnose").read_text())
            ratio = out["augmented"]["nrmse_validation"] / out["baseline"]["nrmse_validation"]
            assert ratio < 0.7  # friction and a worn damper: the findings fit much better
            # the chart shows the first drive's held-out part: its rms ratio is the drives'
            assert rms[1][1] / rms[0][1] == pytest.approx(ratio, rel=0.5)
            shot(d, "20-full-vehicle-diagnosis")
            assert not js_errors(d)
    finally:
        server.stop()
