"""Draw identification and diagnosis results (their ``to_dict()`` JSON) on a page.

The result objects belong to the pipeline; this module only looks up the arrays and
numbers a page shows, accepting the few spellings a result may use for them (so a page
keeps working while the result classes evolve), and says plainly what a result lacks.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np
from nicegui import ui

from fielddiag.diagnose.report import adequate_words
from fielddiag.dsp import spectrum_on_grid
from fielddiag.web.charts import (
    heatmap_options,
    region_box,
    spectrum_options,
    surface_options,
    xy_options,
)
from fielddiag.web.layout import warning_labels

__all__ = [
    "find",
    "mismatch_location",
    "mismatch_regions",
    "parameter_rows",
    "render_diagnosis",
    "render_identification",
]

#: Headline estimates of an identification result (``{"value", "std"}`` at top level).
KNOWN_ESTIMATES = {
    "sprung_mass_kg": ("sprung mass M2", "kg"),
    "suspension_stiffness_n_per_m": ("suspension stiffness K2", "N/m"),
    "suspension_damping_ns_per_m": ("suspension damping C2", "N s/m"),
    "coupling_stiffness_n_per_m": ("coupling stiffness K3", "N/m"),
    "body_natural_frequency_hz": ("body natural frequency", "Hz"),
    "damping_ratio": ("damping ratio", ""),
}


#: Colours of the simulations drawn over a recording.
FIT_COLOURS = {"linear model": "#d62728", "with findings": "#1f77b4"}

#: Readable names of the residual spectrum's curves.
PSD_LABELS = {"psd": "residual", "noise_psd": "noise floor"}


def find(d: Any, *paths: str) -> Any:
    """The first value found at one of the dotted ``paths`` in nested dicts, else None."""
    for path in paths:
        cur = d
        for part in path.split("."):
            if isinstance(cur, Mapping) and part in cur:
                cur = cur[part]
            else:
                cur = None
                break
        if cur is not None:
            return cur
    return None


def _arr(x: Any) -> np.ndarray | None:
    if x is None:
        return None
    try:
        a = np.asarray(x, dtype="f8")
    except (TypeError, ValueError):
        return None
    return a if a.ndim == 1 and a.size else None


def _fmt(v: Any, digits: int = 4) -> str:
    if v is None:
        return "-"
    try:
        f = float(v)
    except (TypeError, ValueError):
        return str(v)
    if not math.isfinite(f):
        return "-"
    if f == 0.0:
        return "0"
    text = f"{f:.{digits}g}"
    mag = math.floor(math.log10(abs(f)))
    if "e" in text and digits <= mag < 6:  # 2.401e+04 -> 24010: no exponent below 1e6
        text = f"{round(f, digits - 1 - mag):.0f}"
    return text


def parameter_rows(result: Mapping[str, Any]) -> list[dict[str, str]]:
    """Table rows (name, value, std, relative std, unit) of a result's parameters.

    Accepts ``parameters`` as a list of dicts (``name``/``label``, ``value``, ``std``,
    ``unit``, ``rel_std_pct``) or as a mapping name -> dict or name -> value.
    """
    rows: list[dict[str, str]] = []
    for key, (label, unit) in KNOWN_ESTIMATES.items():
        e = result.get(key) if isinstance(result, Mapping) else None
        if isinstance(e, Mapping) and "value" in e:
            value, std = e.get("value"), e.get("std")
            rel = None
            try:
                rel = 100.0 * float(std) / abs(float(value))
            except (TypeError, ValueError, ZeroDivisionError):
                rel = None
            note = ""
            if key == "coupling_stiffness_n_per_m" and result.get("k3_included") is False:
                note = "not significant: held at 0"
            rows.append({"name": label, "key": key, "value": _fmt(value), "std": _fmt(std, 2),
                         "rel_std_pct": _fmt(rel, 2), "unit": unit, "note": note})
    if rows:
        return rows
    params = find(result, "parameters", "params", "estimates", "fit.parameters")
    items: Iterable[tuple[str, Any]]
    if isinstance(params, Mapping):
        items = params.items()
    elif isinstance(params, list):
        items = [(str(p.get("name", p.get("key", i))), p) for i, p in enumerate(params)
                 if isinstance(p, Mapping)]
    else:
        return rows
    for name, p in items:
        if isinstance(p, Mapping):
            value, std = p.get("value"), p.get("std", p.get("std_dev", p.get("sigma")))
            rel = p.get("rel_std_pct")
            if rel is None and value not in (None, 0) and std is not None:
                try:
                    rel = 100.0 * float(std) / abs(float(value))
                except (TypeError, ValueError, ZeroDivisionError):
                    rel = None
            label = p.get("label") or name
            unit = p.get("unit", "")
            flags = [f for f, on in (("fixed", p.get("fixed")), ("at bound", p.get("at_bound")))
                     if on]
        else:
            value, std, rel, label, unit, flags = p, None, None, name, "", []
        rows.append({
            "name": str(label),
            "key": str(name),
            "value": _fmt(value),
            "std": _fmt(std, 2),
            "rel_std_pct": _fmt(rel, 2),
            "unit": str(unit),
            "note": ", ".join(flags),
        })
    return rows


def _parameter_table(result: Mapping[str, Any]) -> None:
    rows = parameter_rows(result)
    if not rows:
        ui.label("This result holds no parameter table.").classes("text-gray-600")
        return
    cols = [
        {"name": "name", "label": "parameter", "field": "name", "align": "left"},
        {"name": "value", "label": "value", "field": "value"},
        {"name": "std", "label": "std dev", "field": "std"},
        {"name": "rel_std_pct", "label": "± %", "field": "rel_std_pct"},
        {"name": "unit", "label": "unit", "field": "unit", "align": "left"},
        {"name": "note", "label": "", "field": "note", "align": "left"},
    ]
    ui.table(columns=cols, rows=rows, row_key="key").props("dense flat bordered").classes(
        "w-full max-w-3xl"
    ).mark("parameter-table")


def _magnitude(x: Any) -> np.ndarray | None:
    """|z| of a complex series ``{"re": [...], "im": [...]}`` or a plain magnitude list."""
    if isinstance(x, Mapping) and "re" in x and "im" in x:
        re, im = _arr(x["re"]), _arr(x["im"])
        if re is None or im is None or re.size != im.size:
            return None
        return np.hypot(re, im)
    return _arr(x)


def _transmissibility(result: Mapping[str, Any]) -> dict[str, Any] | None:
    """Frequency lines, |T| per session (estimate and model) and coherences."""
    tr = find(result, "transmissibility", "transfer", "spectra")
    curves: dict[str, np.ndarray] = {}
    coh: dict[str, np.ndarray] = {}
    freq = None
    if isinstance(tr, list):  # one entry per session (IdentificationResult)
        for item in tr:
            if not isinstance(item, Mapping):
                continue
            f = _arr(item.get("freq_hz"))
            if f is None:
                continue
            if freq is None:
                freq = f

            def on_grid(v: np.ndarray | None, f: np.ndarray = f,
                        grid: np.ndarray = freq) -> np.ndarray | None:
                # a result of drives on different grids (older files): the first drive's
                if v is None or v.size != f.size:
                    return None
                same = f.size == grid.size and np.array_equal(f, grid)
                return v if same else spectrum_on_grid(f, v, grid)

            label = str(item.get("label", f"session {len(coh) + 1}"))
            mag = on_grid(_magnitude(find(item, "hv", "h1", "magnitude")))
            if mag is not None:
                curves[label] = mag
            model = on_grid(_magnitude(item.get("model")))
            if model is not None:
                curves[f"{label} model"] = model
            c = on_grid(_arr(item.get("coherence")))
            if c is not None:
                coh[label] = c
    elif isinstance(tr, Mapping):
        freq = _arr(find(tr, "freq_hz", "frequency_hz", "f_hz"))
        if freq is None:
            return None
        for label in ("before", "after"):
            part = tr.get(label)
            if isinstance(part, Mapping):
                mag = _magnitude(find(part, "hv", "magnitude", "abs", "h1"))
                c = _arr(part.get("coherence"))
                model = _magnitude(part.get("model"))
            else:
                mag = _arr(find(tr, f"{label}_magnitude", f"{label}_abs"))
                c = _arr(find(tr, f"{label}_coherence"))
                model = _arr(find(tr, f"{label}_model_magnitude"))
            if mag is not None and mag.size == freq.size:
                curves[label] = mag
            if model is not None and model.size == freq.size:
                curves[f"{label} model"] = model
            if c is not None and c.size == freq.size:
                coh[label] = c
    if freq is None or not curves:
        return None
    band = result.get("band_hz") if isinstance(result, Mapping) else None
    band_hz = None
    if isinstance(band, Mapping) and band.get("low_hz") is not None:
        band_hz = (float(band["low_hz"]), float(band["high_hz"]))
    elif isinstance(band, list | tuple) and len(band) == 2:
        band_hz = (float(band[0]), float(band[1]))
    return {"freq_hz": freq, "curves": curves, "coherence": coh, "band_hz": band_hz}


def _grid_surfaces(result: Mapping[str, Any]) -> list[dict[str, Any]]:
    """Binned restoring-force surfaces (one per session) of an IdentificationResult."""
    out = []
    rf = result.get("restoring_force") if isinstance(result, Mapping) else None
    for item in rf if isinstance(rf, list) else []:
        if not isinstance(item, Mapping):
            continue
        r = _arr(item.get("r_centers_m"))
        v = _arr(item.get("rdot_centers_mps"))
        grid = item.get("force_per_mass_mps2")
        if r is None or v is None or not isinstance(grid, list) or len(grid) != r.size:
            continue
        out.append({"label": str(item.get("label", "")), "r": r, "rdot": v, "grid": grid,
                    "k": find(item, "stiffness_per_mass.value"),
                    "c": find(item, "damping_per_mass.value")})
    return out


def _surface(result: Mapping[str, Any]) -> dict[str, np.ndarray] | None:
    s = find(result, "restoring_force", "restoring_force_surface", "surface")
    if not isinstance(s, Mapping):
        return None
    r = _arr(find(s, "r_m", "extension_m", "r"))
    v = _arr(find(s, "rdot_mps", "rate_mps", "rdot"))
    f = _arr(find(s, "force_n_per_kg", "force_per_kg", "force_n", "force", "f"))
    if r is None or v is None or f is None or not (r.size == v.size == f.size):
        return None
    return {"r": r, "rdot": v, "force": f}


def _summary_text(result: Mapping[str, Any]) -> str:
    """The pipeline's own readable summary of an identification result, if it can make one."""
    text = find(result, "summary", "message")
    if isinstance(text, str):
        return text
    try:
        from fielddiag.identify.results import IdentificationResult

        return IdentificationResult.from_dict(dict(result)).summary()
    except Exception:  # an older/newer result layout: the tables below still show it
        return ""


def render_identification(result: Mapping[str, Any]) -> None:
    """Transmissibility before/after with coherence, restoring-force surface, parameters."""
    from fielddiag.web.vehicle_view import is_full_vehicle_result, render_vehicle_identification

    if is_full_vehicle_result(result):
        render_vehicle_identification(result)
        return
    ui.label("Parameters of the linear model (the diagnosis refits them with the physics it "
             "finds)").classes("text-base font-semibold mt-2")
    _parameter_table(result)
    warning_labels(result, "identify-warning")
    tr = _transmissibility(result)
    with ui.card().classes("w-full"):
        if tr is None:
            ui.label("No transmissibility in this result.").classes("text-gray-600")
        else:
            ui.echart(spectrum_options(
                tr["freq_hz"], tr["curves"], coherence=tr["coherence"],
                title="Transmissibility |X2/X1| before/after, with the model (dashed)",
                band_hz=tr["band_hz"], band_label="band used",
            )).classes("w-full h-[500px]").classes(
                "fd-transmissibility-chart").mark("transmissibility-chart")
    grids = _grid_surfaces(result)
    sf = _surface(result)
    with ui.row().classes("w-full gap-4 no-wrap"):
        for g in grids:
            with ui.card().classes("flex-1 min-w-0"):
                ui.label(f"Restoring force per unit mass, {g['label']}").classes(
                    "font-semibold text-sm")
                if g["k"] is not None and g["c"] is not None:
                    ui.label(f"plane fit: K2/M2 = {g['k']:.4g} 1/s², C2/M2 = {g['c']:.4g} 1/s"
                             ).classes("text-xs text-gray-600")
                ui.echart(heatmap_options(g["r"], g["rdot"], g["grid"], title="")).classes(
                    "w-full h-[420px]").classes("fd-surface-chart").mark("surface-chart")
        if not grids:
            with ui.card().classes("flex-1 min-w-0"):
                if sf is None:
                    ui.label("No restoring-force surface in this result.").classes(
                        "text-gray-600")
                else:
                    ui.echart(surface_options(sf["r"], sf["rdot"], sf["force"])).classes(
                        "w-full h-[420px]").classes("fd-surface-chart").mark("surface-chart")
    text = _summary_text(result)
    if text:
        with ui.expansion("Summary", icon="notes").classes("w-full"):
            ui.label(text).classes("text-xs whitespace-pre-wrap font-mono").mark(
                "identify-summary")


def _windows(x: Any) -> list[tuple[float, float]]:
    out = []
    if isinstance(x, list):
        for w in x:
            if isinstance(w, Mapping):
                a, b = find(w, "start_s", "t0_s", "start"), find(w, "end_s", "t1_s", "end")
            elif isinstance(w, list | tuple) and len(w) == 2:
                a, b = w
            else:
                continue
            try:
                out.append((float(a), float(b)))
            except (TypeError, ValueError):
                continue
    return out


def mismatch_location(result: Mapping[str, Any]) -> dict[str, Any]:
    """Where a diagnosis says the mismatch lives: time windows (per session label), the
    frequency band and the (r, rdot) region, gathered from the result and its findings."""
    windows: list[dict[str, Any]] = []
    band = find(result, "mismatch.band_hz", "excess_band_hz")
    region = find(result, "mismatch.region", "region")
    for w in find(result, "mismatch.windows", "windows") or []:
        windows.append(w if isinstance(w, Mapping) else {"start_s": w[0], "end_s": w[1]})
    findings = result.get("findings") if isinstance(result, Mapping) else None
    for f in findings if isinstance(findings, list) else []:
        where = f.get("where") if isinstance(f, Mapping) else None
        if not isinstance(where, Mapping):
            continue
        band = band or where.get("band_hz")
        region = region or where.get("region")
        for w in where.get("time_windows_s") or []:
            if w not in windows:
                windows.append(w)
    return {"windows": windows, "band_hz": band, "region": region}


def _region_text(region: Any) -> str:
    if not isinstance(region, Mapping):
        return ""
    box = region_box(region)
    if box is None:
        return ""
    (r0, r1), (v0, v1) = box
    if "r_m" in region:
        return f"travel {1e3 * r0:.0f}…{1e3 * r1:.0f} mm, rate {1e3 * v0:.0f}…{1e3 * v1:.0f} mm/s"
    return f"displacement {r0:.3g}…{r1:.3g}, velocity {v0:.3g}…{v1:.3g}"  # a rig's own units


def _finding_name(f: Mapping[str, Any]) -> str:
    return str(find(f, "label", "name", "effect") or "finding").replace("_", " ")


def mismatch_regions(result: Mapping[str, Any]) -> list[dict[str, Any]]:
    """Every located (r, rdot) region of a diagnosis, once each, named by the findings
    that point at it: ``[{"r_m": [lo, hi], "rdot_mps": [lo, hi], "name": ...}, ...]``.

    The region of the result itself (``mismatch.region``/``region``) comes first; the
    findings' ``where.region`` follow (the engine gives every finding of a model the
    same region, an ``unexplained`` finding one of its own).
    """
    found: list[tuple[Any, list[str], bool]] = []  # (box, names, in a rig's own units)

    def add(region: Any, name: str) -> None:
        box = region_box(region) if isinstance(region, Mapping) else None
        if box is None:
            return
        for seen_box, names, _rig in found:
            if seen_box == box:
                if name and name not in names:
                    names.append(name)
                return
        found.append((box, [name] if name else [], "r_m" not in region))

    add(find(result, "mismatch.region", "region"), "")
    findings = result.get("findings") if isinstance(result, Mapping) else None
    for f in findings if isinstance(findings, list) else []:
        where = f.get("where") if isinstance(f, Mapping) else None
        if isinstance(where, Mapping):
            add(where.get("region"), _finding_name(f))
    keys = {False: ("r_m", "rdot_mps"), True: ("displacement", "velocity")}
    return [{keys[rig][0]: list(r), keys[rig][1]: list(v), "name": " + ".join(names)
             or "mismatch"} for (r, v), names, rig in found]


def _finding_card(f: Mapping[str, Any]) -> None:
    name = _finding_name(f)
    conf = f.get("confidence")
    with ui.card().classes("w-full").mark("finding"):
        with ui.row().classes("items-center gap-2"):
            ui.label(name).classes("font-semibold")
            if isinstance(conf, int | float):
                ui.badge(f"confidence {conf:.2f}",
                         color="positive" if conf >= 0.8 else "warning")
        expl = find(f, "explanation", "why", "description")
        if expl:
            ui.label(str(expl)).classes("text-sm")
        shape = f.get("shape_description")
        if isinstance(shape, list) and shape:
            with ui.column().classes("gap-0").mark("finding-shape"):
                for line in shape:
                    ui.label(f"• {line}").classes("text-sm")
            gain = f.get("held_out_gain")
            if isinstance(gain, int | float):
                surface = f.get("force_surface")
                shape_name = ("the force with memory of each reversal"
                              if isinstance(surface, Mapping)
                              and surface.get("form") == "memory_of_reversals"
                              else "the force surface")
                what = (shape_name + " predicts {:.0f} % of the linear model's held-out "
                        "misfit" if isinstance(surface, Mapping) else
                        "a smooth model of this shape predicts {:.0f} % of the force left on "
                        "held-out data")
                ui.label(what.format(100 * gain)).classes("text-xs text-gray-600")
        params, stds = f.get("parameters"), f.get("std") or {}
        if isinstance(params, Mapping) and params:
            ui.label(", ".join(
                f"{k} = {_fmt(v)}" + (f" ± {_fmt(stds[k], 2)}" if k in stds else "")
                for k, v in params.items())).classes("text-sm font-mono")
        elif isinstance(params, list):
            rows = parameter_rows(f)
            ui.label(", ".join(f"{p['name']} = {p['value']} ± {p['std']} {p['unit']}"
                               for p in rows)).classes("text-sm font-mono")
        where = f.get("where") if isinstance(f.get("where"), Mapping) else {}
        bits = []
        if where.get("band_hz"):
            lo, hi = where["band_hz"]
            bits.append(f"band {lo:.2g}–{hi:.2g} Hz")
        wins = where.get("time_windows_s") or []
        if wins:
            bits.append("windows " + ", ".join(
                f"{w.get('session', '')} {w['start_s']:.1f}–{w['end_s']:.1f} s"
                for w in wins[:4] if isinstance(w, Mapping)))
        if _region_text(where.get("region")):
            bits.append(_region_text(where.get("region")))
        if bits:
            ui.label("where: " + "; ".join(bits)).classes("text-xs text-gray-600")


def _fit_series(result: Mapping[str, Any]) -> list[dict[str, Any]]:
    """Simulation-against-recording series: ``fit`` as one dict or a list per session."""
    fit = find(result, "fit", "comparison", "time_fit")
    items = fit if isinstance(fit, list) else [fit] if isinstance(fit, Mapping) else []
    out = []
    for item in items:
        t = _arr(find(item, "time_s", "t_s"))
        rec = _arr(find(item, "recorded", "measured", "recording"))
        if t is None or rec is None or rec.size != t.size:
            continue
        # the recording wide and pale underneath, the models thin on top of it
        series = [{"name": "recording", "x": t, "y": rec, "color": "#7f7f7f", "width": 4,
                   "opacity": 0.55}]
        for key, label in (("simulated_before", "linear model"),
                           ("simulated_linear", "linear model"),
                           ("simulated_after", "with findings"),
                           ("simulated_augmented", "with findings")):
            y = _arr(item.get(key))
            if y is not None and y.size == t.size and label not in [x["name"] for x in series]:
                series.append({"name": label, "x": t, "y": y, "width": 1.3,
                               "color": FIT_COLOURS[label], "dashed": label == "with findings"})
        # what each model misses (recording minus model), drawn under the fit: where the
        # traces overlap, the miss is invisible in the fit itself
        residuals = [{"name": f"residual, {x['name']}", "x": t, "y": rec - x["y"],
                      "width": 1.1, "color": x["color"], "dashed": x.get("dashed", False)}
                     for x in series[1:]]
        out.append({"session": str(item.get("session", item.get("label", ""))),
                    "series": series, "residuals": residuals})
    return out


def _fit_title(session: str, shaded: bool) -> str:
    """``before[28.0-40.0 s]`` -> 'Simulation against recording: before, held out
    28.0–40.0 s' (and what the shading means)."""
    m = re.fullmatch(r"(.*)\[([-\d.]+)-([-\d.]+) s\]", session)
    where = f"{m.group(1)}, held out {m.group(2)}–{m.group(3)} s" if m else session
    return ("Simulation against recording" + (f": {where}" if where else "")
            + (" (shaded: where the linear model misses)" if shaded else ""))


def _same_drive(window_session: Any, fit_session: str) -> bool:
    """Does a time window (labelled by drive: ``before``) belong to a fit series (labelled
    by drive and span: ``before[28.0-40.0 s]``)? A window without a label belongs to all."""
    if window_session in (None, ""):
        return True
    label = str(window_session)
    return fit_session == label or fit_session.startswith(label + "[")


def _linear_parameters_table(result: Mapping[str, Any]) -> None:
    """The linear part as the linear model alone fitted it and refitted with the findings
    (what the missing physics was hiding), when the result holds both."""
    from fielddiag.diagnose.report import data_problem_names, model_parameter

    alone, refit = result.get("linear_model"), result.get("augmented_model")
    if not (isinstance(alone, Mapping) and isinstance(refit, Mapping)) or not refit:
        return
    fixed = data_problem_names(result)
    findings = bool(result.get("findings")) and result.get("verdict") == "missing_physics"
    if not (findings or fixed):
        return
    alone_std = result.get("linear_model_std") or {}
    refit_std = result.get("augmented_model_std") or {}

    def pm(value: Any, std: Any) -> str:
        return f"{_fmt(value, 4)} ± {_fmt(std, 2) if std is not None else '?'}"

    rows = []
    for key, value in refit.items():
        name, unit = model_parameter(key)
        meaningful = result.get("linear_model_adequate", True)
        rows.append({"k": f"{name} [{unit}]" if unit else name,
                     "alone": pm(alone.get(key), alone_std.get(key)) if meaningful
                     else "not meaningful",
                     "refit": pm(value, refit_std.get(key))})
    what = " and ".join((["the findings"] if findings else [])
                        + [f"the {name} corrected" for name in fixed])
    ui.label("Linear part of the model: the linear model alone, fitted to the drives as "
             f"recorded, and refitted with {what}").classes("text-base font-semibold")
    ui.table(columns=[{"name": "k", "label": "parameter", "field": "k", "align": "left"},
                      {"name": "alone", "label": "linear model alone", "field": "alone"},
                      {"name": "refit", "label": f"with {what}", "field": "refit"}],
             rows=rows, row_key="k").props("dense flat bordered").classes("max-w-xl").mark(
        "linear-parameters")


def render_diagnosis(result: Mapping[str, Any], recording_view=None) -> None:
    """Verdict, findings with their explanation, where the mismatch lives (time windows,
    band, region), and the fit before/after on held-out data.

    ``recording_view(windows)``, when given, draws the recording with the time windows
    shaded (the page supplies it: it knows the session files).
    """
    from fielddiag.web.vehicle_view import is_full_vehicle_result, render_vehicle_diagnosis

    if is_full_vehicle_result(result):
        render_vehicle_diagnosis(result)
        return
    verdict = result.get("verdict")
    if verdict == "inconclusive":
        ui.label("Inconclusive: the recording cannot show whether physics is missing").classes(
            "text-lg font-semibold text-warning").mark("diagnosis-verdict")
        if result.get("inconclusive"):
            ui.label(str(result["inconclusive"])).classes("text-sm").mark(
                "diagnosis-inconclusive")
    elif verdict:
        missing = verdict != "adequate"
        ui.label("Missing physics found" if missing else
                 adequate_words(result).capitalize()).classes(
            "text-lg font-semibold " + ("text-negative" if missing else "text-positive")).mark(
            "diagnosis-verdict")
    warning_labels(result, "diagnosis-warning")
    ride = result.get("ride_height")
    if isinstance(ride, Mapping) and ride.get("message"):
        ui.label(f"Ride height: {ride['message']}").classes("text-sm").mark(
            "diagnosis-ride-height")

    ui.label("Findings").classes("text-base font-semibold")
    findings = result.get("findings")
    if isinstance(findings, list) and findings:
        for f in findings:
            if isinstance(f, Mapping):
                _finding_card(f)
            else:
                ui.label(str(f))
    else:
        ui.label("No finding: the clipped readings hide what the suspension does." if
                 verdict == "inconclusive" else
                 "No finding: the linear model explains the recording.").classes("text-gray-600")

    rows = []
    for key, label in (("baseline", "linear model"), ("augmented", "with the findings")):
        part = result.get(key)
        if isinstance(part, Mapping):
            rows.append({"k": label, "fit": _fmt(part.get("nrmse"), 3),
                         "val": _fmt(part.get("nrmse_validation"), 3)})
    metrics = find(result, "metrics", "fit_metrics", "improvement")
    if isinstance(metrics, Mapping):
        rows += [{"k": str(k), "fit": _fmt(v), "val": ""} for k, v in metrics.items()
                 if not isinstance(v, Mapping | list)]
    if rows:
        holdout = result.get("holdout", "data not used for the fit")
        ui.label(f"Fit before and after (NRMSE of the body acceleration; held out: {holdout})"
                 ).classes("text-base font-semibold")
        ui.table(columns=[{"name": "k", "label": "model", "field": "k", "align": "left"},
                          {"name": "fit", "label": "fit data", "field": "fit"},
                          {"name": "val", "label": "held-out data", "field": "val"}],
                 rows=rows, row_key="k").props("dense flat bordered").classes(
            "max-w-xl").mark("fit-metrics")
    _linear_parameters_table(result)

    where = mismatch_location(result)
    fits = _fit_series(result)
    for fs in fits:
        wins = [(float(w["start_s"]), float(w["end_s"])) for w in where["windows"]
                if isinstance(w, Mapping) and _same_drive(w.get("session"), fs["session"])]
        ui.echart(xy_options(fs["series"], x_name="time [s]",
                             y_name="body acceleration [m/s²]",
                             title=_fit_title(fs["session"], bool(wins)),
                             mark_x_windows=wins, zoom=True)).classes("w-full h-96").classes(
            "fd-fit-chart").mark("fit-chart")
        if fs["residuals"]:
            ui.echart(xy_options(fs["residuals"], x_name="time [s]",
                                 y_name="residual [m/s²]",
                                 title="Residual: recording minus model",
                                 mark_x_windows=wins, zoom=True)).classes(
                "w-full h-56").classes("fd-residual-chart").mark("residual-chart")
    unit = "N" if result.get("mode") == "pair" else "N/kg"
    for loop in result.get("restoring_force") or []:
        r = _arr(loop.get("r_m")) if isinstance(loop, Mapping) else None
        if r is None:
            continue
        series = [{"name": "recording", "x": 1e3 * r, "y": _arr(loop.get("measured")),
                   "color": "#7f7f7f", "width": 3, "opacity": 0.5}]
        for key, label in (("linear", "linear model"), ("augmented", "with findings")):
            y = _arr(loop.get(key))
            if y is not None and y.size == r.size:
                series.append({"name": label, "x": 1e3 * r, "y": y, "width": 1.2,
                               "color": FIT_COLOURS[label], "dashed": label == "with findings"})
        ui.echart(xy_options(series, x_name="suspension travel [mm] (+ rebound)",
                             y_name=f"restoring force [{unit}]",
                             title=f"Restoring force against travel, held out: "
                                   f"{loop.get('session', '')}")).classes(
            "w-full h-96").classes("fd-loop-chart").mark("loop-chart")
    if not fits and recording_view is not None and where["windows"]:
        recording_view(where["windows"])

    spec = find(result, "residual_psd", "spectrum", "residual_spectrum")
    f_hz = _arr(find(spec, "freq_hz"))
    band = where["band_hz"]
    if f_hz is not None:
        curves = {PSD_LABELS.get(k, k): _arr(v) for k, v in spec.items() if k != "freq_hz"}
        curves = {k: v for k, v in curves.items() if v is not None and v.size == f_hz.size}
        if curves:
            ui.echart(spectrum_options(
                f_hz, curves, band_hz=tuple(band) if band else None,
                band_label="exceeds the noise", y_name="PSD [(m/s²)²/Hz]",
                title="Residual spectrum of the linear model (body acceleration)",
            )).classes("w-full h-96").classes("fd-band-chart").mark("band-chart")
    elif band:
        ui.label(f"The residual stands out of the noise in {band[0]:.2g}–{band[1]:.2g} Hz "
                 "(this result holds no spectrum to draw)").classes("text-sm")
    # the map and its outline only where a finding locates something: on a car judged
    # adequate an outlined region reads as a fault
    located = bool(verdict == "missing_physics" and isinstance(findings, list) and findings)
    dmap = find(result, "departure_map", "departure") if located else None
    regions = mismatch_regions(result) if located else []
    if isinstance(dmap, Mapping) and _arr(dmap.get("r_edges_m")) is not None:
        re_, ve = _arr(dmap["r_edges_m"]), _arr(dmap["rdot_edges_mps"])
        ui.echart(heatmap_options(0.5 * (re_[1:] + re_[:-1]), 0.5 * (ve[1:] + ve[:-1]),
                                  dmap.get("mean") or [],
                                  title="Force the linear model misses over (r, rdot)",
                                  value_name="departure", region=regions,
                                  value_unit="N" if result.get("mode") == "pair" else "N/kg",
                                  x_edges=re_, y_edges=ve)).classes(
            "w-full h-[480px]").classes("fd-region-chart").mark("region-chart")
        if regions:
            ui.label("Outlined, where the mismatch lives: " + "; ".join(
                f"{g['name']}: {_region_text(g)}" for g in regions)).classes(
                "text-sm").mark("region-text")
    elif regions:
        ui.label("Region of the restoring-force map where the mismatch lives: " + "; ".join(
            f"{g['name']}: {_region_text(g)}" for g in regions)).classes("text-sm").mark(
            "region-text")
    sf = _surface(result)
    if sf is not None:
        regions = find(result, "mismatch.regions", "regions") if located else []
        ui.echart(surface_options(sf["r"], sf["rdot"], sf["force"],
                                  title="Where the model misses (restoring-force map)",
                                  regions=regions if isinstance(regions, list) else ())).classes(
            "w-full h-96").classes("fd-region-chart").mark("region-chart")
    text = _diagnosis_summary(result)
    if text:
        with ui.expansion("Summary", icon="notes").classes("w-full"):
            ui.label(text).classes("text-xs whitespace-pre-wrap font-mono").mark(
                "diagnosis-summary")


def _diagnosis_summary(result: Mapping[str, Any]) -> str:
    try:
        from fielddiag.diagnose.report import format_summary

        return format_summary(dict(result))
    except Exception:  # another result layout: the panels above still show it
        return ""
