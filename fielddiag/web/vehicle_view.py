"""Dashboard view of a full-vehicle result: the car seen from above with each corner
coloured by its finding, the per-corner parameters, the body, and the held-out fit.

Pages only: everything shown comes from the JSON of
:func:`fielddiag.vehicle.diagnose.diagnose_vehicle` / :func:`identify_vehicle`.
"""

from __future__ import annotations

import html
from collections.abc import Mapping
from typing import Any

from nicegui import ui

from fielddiag.web.charts import xy_options
from fielddiag.web.layout import warning_labels

__all__ = ["car_svg", "corner_status", "is_full_vehicle_result", "render_vehicle_diagnosis",
           "render_vehicle_identification"]

CORNERS = ("fl", "fr", "rl", "rr")
#: Corner colours: fine, physics found (an effect), left/right mismatch (the weak corner).
COLOURS = {"ok": "#2e7d32", "effect": "#c62828", "mismatch": "#ef6c00"}
_BODY_KEYS = (("sprung_mass_kg", "sprung mass", "kg"),
              ("cog_behind_front_axle_m", "CoG behind the front axle", "m"),
              ("cog_left_of_centre_m", "CoG left of centre", "m"),
              ("pitch_inertia_kgm2", "pitch inertia (about the CoG)", "kg m²"),
              ("roll_inertia_kgm2", "roll inertia (about the CoG)", "kg m²"),
              ("anti_roll_stiffness_front_n_per_m", "anti-roll bar front", "N/m"),
              ("anti_roll_stiffness_rear_n_per_m", "anti-roll bar rear", "N/m"))


def is_full_vehicle_result(result: Any) -> bool:
    """True for the JSON of a full-vehicle identification or diagnosis."""
    return isinstance(result, Mapping) and (
        result.get("mode") == "full_vehicle" or isinstance(result.get("corners"), Mapping)
        and "pitch_inertia_kgm2" in result)


def corner_status(result: Mapping[str, Any]) -> dict[str, tuple[str, str]]:
    """Per corner: status (``ok``, ``effect``, ``mismatch``) and a short text.

    An effect wins over a mismatch at the same corner; an axle-wide effect marks both of
    the axle's corners.
    """
    out = {c: ("ok", "no finding") for c in CORNERS}
    for f in result.get("findings") or []:
        if not isinstance(f, Mapping):
            continue
        eff = str(f.get("effect", ""))
        if eff == "left_right_mismatch":
            c = f.get("corner")
            p = f.get("parameters") or {}
            if c in out and out[c][0] == "ok":
                out[c] = ("mismatch", f"{p.get('quantity', '')} x{float(p.get('ratio', 0)):.2f}")
            continue
        where = [f["corner"]] if f.get("corner") in out else (
            ["fl", "fr"] if f.get("axle") == "front" else
            ["rl", "rr"] if f.get("axle") == "rear" else [])
        for c in where:
            out[c] = ("effect", eff.replace("_", " "))
    return out


def car_svg(result: Mapping[str, Any], width_px: int = 320) -> str:
    """The car seen from above (front at the top, its left on the left), the wheels
    coloured by :func:`corner_status`.

    Returns
    -------
    str
        An ``<svg>`` element.
    """
    geo = result.get("vehicle") if isinstance(result.get("vehicle"), Mapping) else {}
    wb = float(geo.get("wheelbase_m", 2.7))
    tf = float(geo.get("track_front_m", 1.55))
    tr = float(geo.get("track_rear_m", 1.55))
    status = corner_status(result)
    scale = 120.0  # px per metre
    w = max(tf, tr) * scale + 330
    h = wb * scale + 160
    cx, top = w / 2, 80.0
    pos = {"fl": (cx + tf / 2 * scale * -1, top), "fr": (cx + tf / 2 * scale, top),
           "rl": (cx - tr / 2 * scale, top + wb * scale), "rr": (cx + tr / 2 * scale,
                                                                top + wb * scale)}
    parts = [f'<svg xmlns="http://www.w3.org/2000/svg" viewBox="0 0 {w:.0f} {h:.0f}" '
             f'width="{width_px}" class="fd-car" role="img" aria-label="car seen from above">',
             f'<rect x="{cx - max(tf, tr) / 2 * scale + 10:.0f}" y="{top - 55:.0f}" '
             f'width="{max(tf, tr) * scale - 20:.0f}" height="{wb * scale + 110:.0f}" rx="40" '
             'fill="#eceff1" stroke="#607d8b" stroke-width="3"/>',
             f'<text x="{cx:.0f}" y="{top - 62:.0f}" text-anchor="middle" font-size="16" '
             'fill="#455a64">front</text>']
    for c in CORNERS:
        x, y = pos[c]
        kind, text = status[c]
        colour = COLOURS[kind]
        left = c[1] == "l"
        tx = x - 24 if left else x + 24
        parts.append(f'<rect x="{x - 14:.0f}" y="{y - 32:.0f}" width="28" height="64" rx="6" '
                     f'fill="{colour}" data-corner="{c}" data-status="{kind}" '
                     f'class="fd-wheel"/>')
        parts.append(f'<text x="{tx:.0f}" y="{y - 6:.0f}" text-anchor="'
                     f'{"end" if left else "start"}" font-size="18" font-weight="bold" '
                     f'fill="{colour}">{c}</text>')
        parts.append(f'<text x="{tx:.0f}" y="{y + 16:.0f}" text-anchor="'
                     f'{"end" if left else "start"}" font-size="13" fill="#263238">'
                     f'{html.escape(text)}</text>')
    parts.append("</svg>")
    return "".join(parts)


def _pm(e: Any, digits: int = 4) -> str:
    if not isinstance(e, Mapping):
        return "-"
    v, s = e.get("value"), e.get("std")
    try:
        return f"{float(v):.{digits}g} ± {float(s):.2g}"
    except (TypeError, ValueError):
        return "-"


def _corner_table(model: Mapping[str, Any], status: Mapping[str, tuple[str, str]]) -> None:
    corners = model.get("corners") or {}
    rows = []
    for c in CORNERS:
        d = corners.get(c) or {}
        rows.append({"corner": c, "k": _pm(d.get("stiffness_n_per_m")),
                     "c": _pm(d.get("damping_ns_per_m")),
                     "finding": status.get(c, ("ok", ""))[1]})
    ui.table(columns=[{"name": "corner", "label": "corner", "field": "corner", "align": "left"},
                      {"name": "k", "label": "stiffness [N/m]", "field": "k"},
                      {"name": "c", "label": "damping [N s/m]", "field": "c"},
                      {"name": "finding", "label": "finding", "field": "finding"}],
             rows=rows, row_key="corner").props("dense flat bordered").classes(
        "max-w-3xl").mark("corner-table")


def _body_table(model: Mapping[str, Any]) -> None:
    rows = [{"q": label, "v": _pm(model.get(key)), "u": unit}
            for key, label, unit in _BODY_KEYS if key in model]
    ui.table(columns=[{"name": "q", "label": "body", "field": "q", "align": "left"},
                      {"name": "v", "label": "value ± std", "field": "v"},
                      {"name": "u", "label": "unit", "field": "u", "align": "left"}],
             rows=rows, row_key="q").props("dense flat bordered").classes(
        "max-w-3xl").mark("body-table")


def render_vehicle_identification(result: Mapping[str, Any]) -> None:
    """Body, corners, anti-roll bars with standard deviations; cross-validation NRMSE."""
    ui.label("Full vehicle: identified parameters (± 1 std)").classes(
        "text-base font-semibold mt-2")
    warning_labels(result, "vehicle-warning", "fd-vehicle-warning")
    with ui.row().classes("w-full items-start gap-6"):
        ui.html(car_svg(result), sanitize=False).mark("car-svg")
        with ui.column():
            _body_table(result)
            _corner_table(result, corner_status(result))
    cv = result.get("cross_validation") or []
    if cv:
        text = ", ".join(f"{c.get('session')}: NRMSE {float(c.get('nrmse', 0)):.3f}"
                         for c in cv if isinstance(c, Mapping))
        ui.label("Cross-validation (body accelerations simulated from the hub motion): "
                 + text).classes("text-sm").mark("cross-validation")


def render_vehicle_diagnosis(result: Mapping[str, Any]) -> None:
    """Verdict, the car from above coloured by finding, findings, per-corner and body
    tables, the held-out fit and the cross-validation."""
    from fielddiag.web.results_view import _finding_card

    verdict = str(result.get("verdict", ""))
    words = {"missing_physics": "Missing physics found at a corner",
             "left_right_mismatch": "Left/right mismatch found",
             "adequate": "The linear full-vehicle model is adequate; the axles are balanced"}
    ui.label(words.get(verdict, verdict)).classes(
        "text-lg font-semibold " + ("text-positive" if verdict == "adequate" else
                                    "text-negative")).mark("diagnosis-verdict")
    warning_labels(result, "vehicle-warning", "fd-vehicle-warning")
    status = corner_status(result)
    model = result.get("augmented_model") or result.get("linear_model") or {}
    with ui.row().classes("w-full items-start gap-6"):
        ui.html(car_svg(result), sanitize=False).mark("car-svg")
        with ui.column().classes("grow"):
            ui.label("Findings").classes("text-base font-semibold")
            findings = [f for f in result.get("findings") or [] if isinstance(f, Mapping)]
            for f in findings:
                place = f.get("corner") or f"{f.get('axle')} axle"
                ui.label(f"{place}:").classes("text-sm font-semibold")
                _finding_card(f)
            if not findings:
                ui.label("No finding.").classes("text-gray-600")
    ui.label("Corners (model with the findings, ± 1 std)").classes("text-base font-semibold")
    _corner_table(model, status)
    ui.label("Body").classes("text-base font-semibold")
    _body_table(model)
    b, a = result.get("baseline") or {}, result.get("augmented") or {}
    try:
        ui.label(f"Held-out NRMSE of the body accelerations ({result.get('holdout', '')}): "
                 f"linear {float(b['nrmse_validation']):.4f}, with the findings "
                 f"{float(a['nrmse_validation']):.4f}").classes("text-sm").mark("fit-metrics")
    except (KeyError, TypeError, ValueError):
        pass
    for cv in result.get("cross_validation") or []:
        if isinstance(cv, Mapping):
            ui.label(f"Cross-validation {cv.get('session')}: NRMSE linear "
                     f"{float(cv.get('nrmse_linear', 0)):.4f}, with the findings "
                     f"{float(cv.get('nrmse_augmented', 0)):.4f}").classes("text-sm").mark(
                "cross-validation")
    for tr in result.get("fit") or []:
        if not isinstance(tr, Mapping) or not tr.get("time_s"):
            continue
        series = [{"name": "recorded", "x": tr["time_s"], "y": tr["recorded"]},
                  {"name": "linear model", "x": tr["time_s"], "y": tr["simulated_linear"],
                   "dashed": True},
                  {"name": "with the findings", "x": tr["time_s"],
                   "y": tr["simulated_augmented"]}]
        ui.echart(xy_options(series, x_name="time [s]",
                             y_name="mean body acceleration [m/s²]",
                             title=f"Held-out data: {tr.get('session', '')}", zoom=True)
                  ).classes("w-full h-72 fd-vehicle-fit-chart").mark("vehicle-fit-chart")
        # the traces overlap where the fit is good: what each model leaves shows the gain
        rec = tr["recorded"]
        left = [{"name": name, "x": tr["time_s"], "y": [r - m for r, m in zip(rec, tr[key],
                                                                             strict=False)]}
                for name, key in (("left by the linear model", "simulated_linear"),
                                  ("left with the findings", "simulated_augmented"))]
        ui.echart(xy_options(left, x_name="time [s]", y_name="recorded - model [m/s²]",
                             title=f"What each model leaves: {tr.get('session', '')}",
                             zoom=True)
                  ).classes("w-full h-56 fd-vehicle-residual-chart").mark(
            "vehicle-residual-chart")
