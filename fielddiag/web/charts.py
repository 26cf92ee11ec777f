"""ECharts option dictionaries for the dashboard's plots (layout only, no numerics).

Every builder takes arrays that are already small (downsampled by
:mod:`fielddiag.downsample` or produced by the pipeline) and returns an options dict for
``ui.echart``. Numbers are rounded to what a screen can show (about 6 significant
digits) so the JSON sent to the browser stays small.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from fielddiag.channels import Event, Gap
from fielddiag.downsample import Trace

PALETTE = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#17becf", "#8c564b",
           "#e377c2", "#7f7f7f", "#bcbd22"]
GRID_HEIGHT_PX = 96
GRID_GAP_PX = 34
TOP_PX = 44
BOTTOM_PX = 70

__all__ = [
    "bin_position",
    "heatmap_options",
    "pairs",
    "region_box",
    "spectrum_options",
    "surface_options",
    "timeseries_height_px",
    "timeseries_options",
    "xy_options",
    "zoom_window",
]


def _decimals(values: np.ndarray, digits: int = 6) -> int:
    finite = values[np.isfinite(values)]
    if finite.size == 0:
        return 3
    big = float(np.max(np.abs(finite)))
    if big == 0.0:
        return 3
    return int(min(12, max(0, digits - 1 - math.floor(math.log10(big)))))


def pairs(x: np.ndarray, y: np.ndarray, x_decimals: int | None = None) -> list[list[Any]]:
    """``[[x, y], ...]`` rounded for display; NaN becomes None (a break in the line)."""
    x = np.asarray(x, dtype="f8")
    y = np.asarray(y, dtype="f8")
    xd = _decimals(x, 9) if x_decimals is None else x_decimals
    xr = np.round(x, xd).tolist()
    yr = np.round(y, _decimals(y)).tolist()
    return [[a, (None if b != b else b)] for a, b in zip(xr, yr, strict=True)]


def pairs_array(x: np.ndarray, y: np.ndarray, x_decimals: int | None = None) -> np.ndarray:
    """Like :func:`pairs` but an ``(n, 2)`` array: serialised by orjson straight from
    numpy (NaN as null), without the thousands of small lists that :func:`pairs` makes.
    For charts redrawn many times a second, where those lists kept the garbage
    collector's full passes busy."""
    x = np.asarray(x, dtype="f8")
    y = np.asarray(y, dtype="f8")
    xd = _decimals(x, 9) if x_decimals is None else x_decimals
    return np.column_stack([np.round(x, xd), np.round(y, _decimals(y))])


def zoom_window(
    args: dict[str, Any], t_start_s: float, t_end_s: float
) -> tuple[float, float] | None:
    """The time window an ECharts ``datazoom`` event asks for, or None if it says nothing.

    The event carries either percentages of the full axis (``start``/``end``) or axis
    values (``startValue``/``endValue``), at top level or in ``batch[0]``.
    """
    ev = args
    if isinstance(args.get("batch"), list) and args["batch"]:
        ev = args["batch"][0]
    span = t_end_s - t_start_s
    if ev.get("startValue") is not None and ev.get("endValue") is not None:
        lo, hi = float(ev["startValue"]), float(ev["endValue"])
    elif ev.get("start") is not None and ev.get("end") is not None:
        lo = t_start_s + span * float(ev["start"]) / 100.0
        hi = t_start_s + span * float(ev["end"]) / 100.0
    else:
        return None
    lo, hi = max(t_start_s, min(lo, hi)), min(t_end_s, max(lo, hi))
    return (lo, hi) if hi > lo else None


#: ECharts formats its own tick values, and on log axes (and some value axes) shows float
#: artefacts such as 0.30000000000000004: labels are rounded to 6 significant digits.
NICE_LABEL_JS = ("(v) => { const x = Number(v); "
                 "return Number.isFinite(x) ? String(+x.toPrecision(6)) : v; }")


def nice_axis_labels(options: dict[str, Any]) -> dict[str, Any]:
    """``options`` with every shown value or log axis labelled with rounded numbers."""
    for key in ("xAxis", "yAxis"):
        axes = options.get(key)
        for axis in axes if isinstance(axes, list) else [axes] if isinstance(axes, dict) else []:
            if axis.get("type") in ("value", "log") and axis.get("show", True):
                label = axis.setdefault("axisLabel", {})
                if "formatter" not in label:
                    label.setdefault(":formatter", NICE_LABEL_JS)
    return options


def timeseries_options(
    traces: Sequence[Trace],
    t_start_s: float,
    t_end_s: float,
    *,
    window: tuple[float, float] | None = None,
    events: Sequence[Event] = (),
    gaps: Sequence[Gap] = (),
) -> dict[str, Any]:
    """Stacked plots, one per trace, sharing one zoomable time axis.

    Parameters
    ----------
    traces : sequence of Trace
        What to draw (already downsampled).
    t_start_s, t_end_s : float
        The full time axis (the zoom slider spans it).
    window : (lo, hi) or None
        The visible window; None shows everything.
    events, gaps : sequences
        Drawn as labelled vertical lines and shaded spans on every plot.
    """
    span = max(t_end_s - t_start_s, 1e-9)
    lo, hi = window if window else (t_start_s, t_end_s)
    start_pct = 100.0 * (lo - t_start_s) / span
    end_pct = 100.0 * (hi - t_start_s) / span
    n = max(1, len(traces))
    grids, xaxes, yaxes, series, titles = [], [], [], [], []
    for i, tr in enumerate(traces):
        top = TOP_PX + i * (GRID_HEIGHT_PX + GRID_GAP_PX)
        grids.append({"left": 70, "right": 24, "top": top, "height": GRID_HEIGHT_PX})
        titles.append(
            {
                "text": f"{tr.name} [{tr.unit}]" if tr.unit else tr.name,
                "top": top - 22,
                "left": 70,
                "textStyle": {"fontSize": 12, "fontWeight": "normal"},
            }
        )
        xaxes.append(
            {
                "type": "value",
                "gridIndex": i,
                "min": t_start_s,
                "max": t_end_s,
                "axisLabel": {"show": i == n - 1},
                "name": "time [s]" if i == n - 1 else "",
                "nameLocation": "middle",
                "nameGap": 24,
            }
        )
        yaxes.append({"type": "value", "gridIndex": i, "scale": True, "splitNumber": 3})
        s: dict[str, Any] = {
            "name": tr.name,
            "type": "line",
            "xAxisIndex": i,
            "yAxisIndex": i,
            "showSymbol": False,
            "animation": False,
            "lineStyle": {"width": 1},
            "color": PALETTE[i % len(PALETTE)],
            "step": "end" if tr.kind == "signal" else False,
            "data": pairs(tr.time_s, tr.values),
        }
        mark_lines = [
            {"xAxis": round(e.time_s, 6), "label": {"show": i == 0, "formatter": e.label[:24]}}
            for e in events
        ]
        if mark_lines:
            s["markLine"] = {
                "symbol": "none",
                "silent": True,
                "animation": False,
                "lineStyle": {"type": "dashed", "color": "#555", "width": 1},
                "label": {"position": "end", "fontSize": 10},
                "data": mark_lines,
            }
        if gaps:
            s["markArea"] = {
                "silent": True,
                "itemStyle": {"color": "rgba(214, 39, 40, 0.18)"},
                "data": [[{"xAxis": g.start_s, "name": "gap" if i == 0 else ""},
                          {"xAxis": g.end_s}] for g in gaps],
            }
        series.append(s)
    all_x = list(range(len(traces)))
    return nice_axis_labels({
        "animation": False,
        "title": titles,
        "grid": grids,
        "xAxis": xaxes,
        "yAxis": yaxes,
        "series": series,
        "tooltip": {"trigger": "axis", "axisPointer": {"type": "line"}},
        "axisPointer": {"link": [{"xAxisIndex": "all"}]},
        "toolbox": {
            "right": 20,
            "feature": {"dataZoom": {"yAxisIndex": "none"}, "restore": {}},
        },
        "dataZoom": [
            {"type": "inside", "xAxisIndex": all_x, "filterMode": "none",
             "start": start_pct, "end": end_pct, "throttle": 120},
            {"type": "slider", "xAxisIndex": all_x, "filterMode": "none",
             "start": start_pct, "end": end_pct, "bottom": 8, "height": 22, "throttle": 120},
        ],
    })


def timeseries_height_px(n_traces: int) -> int:
    """Height of the chart :func:`timeseries_options` lays out for ``n_traces`` plots."""
    return TOP_PX + max(1, n_traces) * (GRID_HEIGHT_PX + GRID_GAP_PX) + BOTTOM_PX


def xy_options(
    series: Sequence[dict[str, Any]],
    *,
    x_name: str,
    y_name: str,
    x_log: bool = False,
    y_log: bool = False,
    title: str = "",
    mark_x_band: tuple[float, float] | None = None,
    mark_x_windows: Sequence[tuple[float, float]] = (),
    y_min: float | None = None,
    y_max: float | None = None,
    zoom: bool = False,
) -> dict[str, Any]:
    """One x/y plot of several named line series.

    Parameters
    ----------
    series : sequence of dict
        Each ``{"name", "x", "y"}`` with arrays; optional ``"dashed": True``, ``"color"``,
        ``"width"`` (px) and ``"opacity"``.
    mark_x_band : (lo, hi) or None
        A shaded band on the x axis (the frequency band where a mismatch lives).
    mark_x_windows : sequence of (lo, hi)
        Shaded windows on the x axis (time windows where a mismatch lives).
    zoom : bool
        Zoom the x axis with the mouse wheel and the toolbox's box zoom (in the browser:
        the series hold every point already).
    """
    out_series = []
    for i, s in enumerate(series):
        d: dict[str, Any] = {
            "name": s["name"],
            "type": "line",
            "showSymbol": False,
            "animation": False,
            "color": s.get("color", PALETTE[i % len(PALETTE)]),
            "lineStyle": {"width": s.get("width", 1.5), "opacity": s.get("opacity", 1.0),
                          "type": "dashed" if s.get("dashed") else "solid"},
            "data": pairs(s["x"], s["y"]),
        }
        out_series.append(d)
    areas = []
    if mark_x_band is not None:
        areas.append([{"xAxis": mark_x_band[0], "name": "mismatch"}, {"xAxis": mark_x_band[1]}])
    areas += [[{"xAxis": a}, {"xAxis": b}] for a, b in mark_x_windows]
    if areas and out_series:
        out_series[0]["markArea"] = {
            "silent": True,
            "itemStyle": {"color": "rgba(255, 165, 0, 0.22)"},
            "data": areas,
        }
    y_axis: dict[str, Any] = {"type": "log" if y_log else "value", "name": y_name,
                              "nameLocation": "middle", "nameGap": 50, "scale": not y_log}
    if y_min is not None:
        y_axis["min"] = y_min
    if y_max is not None:
        y_axis["max"] = y_max
    options: dict[str, Any] = {
        "animation": False,
        "title": {"text": title, "left": "center", "textStyle": {"fontSize": 13}},
        "legend": {"top": 24},
        "grid": {"left": 70, "right": 24, "top": 60, "bottom": 50},
        "tooltip": {"trigger": "axis"},
        "xAxis": {"type": "log" if x_log else "value", "name": x_name,
                  "nameLocation": "middle", "nameGap": 28, "scale": not x_log},
        "yAxis": y_axis,
        "series": out_series,
    }
    if zoom:
        options["dataZoom"] = [{"type": "inside", "xAxisIndex": 0, "filterMode": "none"}]
        options["toolbox"] = {"right": 20, "feature": {"dataZoom": {"yAxisIndex": "none"},
                                                       "restore": {}}}
    return nice_axis_labels(options)


def spectrum_options(
    freq_hz: np.ndarray,
    curves: dict[str, np.ndarray],
    *,
    coherence: dict[str, np.ndarray] | None = None,
    title: str = "Transmissibility |X2/X1|",
    band_hz: tuple[float, float] | None = None,
    band_label: str = "mismatch",
    y_name: str = "|T|",
) -> dict[str, Any]:
    """Transmissibility magnitudes (log-log) above their coherences (linear, 0..1).

    Any spectra will do (``y_name`` names their axis), e.g. a residual's PSD.
    """
    freq_hz = np.asarray(freq_hz, dtype="f8")
    pos = freq_hz > 0
    series: list[dict[str, Any]] = []
    bases: list[str] = []  # "before" and "before model" share a colour

    def colour(name: str) -> str:
        base = name.removesuffix(" model")
        if base not in bases:
            bases.append(base)
        return PALETTE[bases.index(base) % len(PALETTE)]

    for name, mag in curves.items():
        series.append({
            "name": name, "type": "line", "showSymbol": False, "animation": False,
            "xAxisIndex": 0, "yAxisIndex": 0, "color": colour(name),
            "lineStyle": {"width": 1.5, "type": "dashed" if name.endswith("model") else "solid"},
            "data": pairs(freq_hz[pos], np.abs(np.asarray(mag))[pos]),
        })
    for name, coh in (coherence or {}).items():
        series.append({
            "name": f"coherence {name}", "type": "line", "showSymbol": False,
            "animation": False, "xAxisIndex": 1, "yAxisIndex": 1,
            "color": colour(name), "lineStyle": {"width": 1},
            "data": pairs(freq_hz[pos], np.asarray(coh)[pos]),
        })
    if band_hz is not None and series:
        series[0]["markArea"] = {
            "silent": True, "itemStyle": {"color": "rgba(255, 165, 0, 0.22)"},
            "data": [[{"xAxis": band_hz[0], "name": band_label}, {"xAxis": band_hz[1]}]],
        }
    has_coh = bool(coherence)
    grids = [{"left": 70, "right": 24, "top": 70, "height": 270 if has_coh else 360}]
    x_axes: list[dict[str, Any]] = [{"type": "log", "gridIndex": 0, "name": "" if has_coh
                                     else "frequency [Hz]", "nameLocation": "middle",
                                     "nameGap": 28}]
    y_axes: list[dict[str, Any]] = [{"type": "log", "gridIndex": 0, "name": y_name,
                                     "nameLocation": "middle", "nameGap": 50}]
    if has_coh:
        grids.append({"left": 70, "right": 24, "top": 370, "height": 90})
        x_axes.append({"type": "log", "gridIndex": 1, "name": "frequency [Hz]",
                       "nameLocation": "middle", "nameGap": 28})
        y_axes.append({"type": "value", "gridIndex": 1, "min": 0, "max": 1,
                       "name": "coherence", "nameLocation": "middle", "nameGap": 50})
    return nice_axis_labels({
        "animation": False,
        "title": {"text": title, "left": "center", "textStyle": {"fontSize": 13}},
        "legend": {"top": 26, "type": "scroll"},
        "tooltip": {"trigger": "axis"},
        "axisPointer": {"link": [{"xAxisIndex": "all"}]},
        "grid": grids,
        "xAxis": x_axes,
        "yAxis": y_axes,
        "series": series,
    })


def surface_options(
    r_m: np.ndarray,
    rdot_mps: np.ndarray,
    force: np.ndarray,
    *,
    force_name: str = "restoring force per unit mass [N/kg]",
    title: str = "Restoring-force surface",
    regions: Sequence[dict[str, float]] = (),
    max_points: int = 4000,
) -> dict[str, Any]:
    """Restoring force over (r, rdot) as a scatter coloured by force.

    ``regions`` are rectangles ``{"r_min", "r_max", "rdot_min", "rdot_max"}`` drawn as
    shaded areas (where a mismatch lives on the map).
    """
    r = np.asarray(r_m, dtype="f8")
    v = np.asarray(rdot_mps, dtype="f8")
    f = np.asarray(force, dtype="f8")
    if r.size > max_points:  # an even spread of points is enough for a colour map
        keep = np.linspace(0, r.size - 1, max_points).astype(int)
        r, v, f = r[keep], v[keep], f[keep]
    fr = np.round(f, _decimals(f)).tolist()
    data = [[a, b, c] for a, b, c in zip(np.round(r, _decimals(r)).tolist(),
                                         np.round(v, _decimals(v)).tolist(), fr, strict=True)]
    finite = f[np.isfinite(f)]
    lo = float(np.min(finite)) if finite.size else 0.0
    hi = float(np.max(finite)) if finite.size else 1.0
    series: dict[str, Any] = {
        "type": "scatter", "symbolSize": 4, "animation": False, "data": data,
        "name": force_name,
    }
    if regions:
        series["markArea"] = {
            "silent": True,
            "itemStyle": {"color": "rgba(0, 0, 0, 0)", "borderColor": "#ff7f0e",
                          "borderWidth": 2},
            "data": [[{"coord": [g["r_min"], g["rdot_min"]], "name": g.get("name", "")},
                      {"coord": [g["r_max"], g["rdot_max"]]}] for g in regions],
        }
    return nice_axis_labels({
        "animation": False,
        "title": {"text": title, "left": "center", "textStyle": {"fontSize": 13}},
        "grid": {"left": 80, "right": 110, "top": 50, "bottom": 50},
        "tooltip": {"trigger": "item"},
        "xAxis": {"type": "value", "name": "suspension extension r [m]", "scale": True,
                  "nameLocation": "middle", "nameGap": 28},
        "yAxis": {"type": "value", "name": "rate dr/dt [m/s]", "scale": True,
                  "nameLocation": "middle", "nameGap": 55},
        "visualMap": {"min": lo, "max": hi, "dimension": 2, "orient": "vertical",
                      "right": 10, "top": "middle", "calculable": True, "text": ["F", ""],
                      "inRange": {"color": ["#313695", "#74add1", "#ffffbf", "#f46d43",
                                            "#a50026"]}},
        "series": [series],
    })


REGION_COLOURS = ("#000000", "#00a651", "#7b2cbf", "#ff00c8")


def _bin_edges(centers: np.ndarray) -> np.ndarray:
    """Edges of bins with the given centres (midpoints; the outer ones half a bin out)."""
    c = np.asarray(centers, dtype="f8")
    if c.size == 1:
        return np.array([c[0] - 0.5, c[0] + 0.5])
    mid = 0.5 * (c[1:] + c[:-1])
    return np.concatenate(([c[0] - (mid[0] - c[0])], mid, [c[-1] + (c[-1] - mid[-1])]))


def bin_position(value: float, edges: np.ndarray) -> float:
    """Where ``value`` falls on a category axis of bins with ``edges``, in bin indices.

    Bin ``i`` spans ``i - 0.5`` to ``i + 0.5`` (its centre is the category ``i``); values
    outside the grid are clipped to its border.
    """
    e = np.asarray(edges, dtype="f8")
    return float(np.interp(value, e, np.arange(e.size))) - 0.5


def region_box(region: dict[str, Any]) -> tuple[tuple[float, float], tuple[float, float]] | None:
    """``((r_lo, r_hi), (rdot_lo, rdot_hi))`` of a located region, or None if it has none.

    Accepts the engine's ``{"r_m": [lo, hi], "rdot_mps": [lo, hi]}`` and the rig
    diagnosis's ``{"displacement": [lo, hi], "velocity": [lo, hi]}``.
    """
    r = region.get("r_m", region.get("displacement"))
    v = region.get("rdot_mps", region.get("velocity"))
    try:
        (r0, r1), (v0, v1) = r, v
        box = ((float(r0), float(r1)), (float(v0), float(v1)))
    except (TypeError, ValueError):
        return None
    return box if all(math.isfinite(x) for pair in box for x in pair) else None


def heatmap_options(
    x_centers: np.ndarray,
    y_centers: np.ndarray,
    grid: Sequence[Sequence[float | None]],
    *,
    title: str,
    x_name: str = "extension r [mm]",
    y_name: str = "rate dr/dt [mm/s]",
    value_name: str = "force per unit mass [m/s²]",
    x_scale: float = 1e3,
    y_scale: float = 1e3,
    region: Sequence[dict[str, Any]] = (),
    x_edges: np.ndarray | None = None,
    y_edges: np.ndarray | None = None,
    value_unit: str = "m/s²",
) -> dict[str, Any]:
    """A binned surface ``grid[i][j]`` over (x_centers[i], y_centers[j]) as a heatmap.

    Empty bins (None) stay blank. Axis labels are the bin centres times the scales (mm).
    A surface of both signs gets a colour scale symmetric about 0 (0 in the neutral
    middle colour), so the sign of a cell reads at a glance.

    Parameters
    ----------
    region : sequence of dict
        Regions of (r, rdot) to outline (where a mismatch lives), each
        ``{"r_m": [lo, hi], "rdot_mps": [lo, hi], "name": label}`` in the units of the
        centres (m, m/s). Their ranges become bin-index ranges (fractional where a region
        does not sit on the bin edges) drawn on a hidden value axis laid over the
        category axes, so an outline covers whole cells, not cell centres.
    x_edges, y_edges : ndarray, optional
        Bin edges (default: midway between the centres).
    """
    xc = np.asarray(x_centers, dtype="f8")
    yc = np.asarray(y_centers, dtype="f8")
    xs = [f"{v * x_scale:.3g}" for v in xc]
    ys = [f"{v * y_scale:.3g}" for v in yc]
    data, vals = [], []
    for i, row in enumerate(grid):
        for j, v in enumerate(row):
            if v is None or (isinstance(v, float) and not math.isfinite(v)):
                continue
            data.append([i, j, round(float(v), 6)])
            vals.append(float(v))
    lo, hi = (min(vals), max(vals)) if vals else (0.0, 1.0)
    if lo < 0.0 < hi:
        hi = max(-lo, hi)
        lo = -hi
    series: list[dict[str, Any]] = [{"type": "heatmap", "data": data, "name": value_name,
                                     "progressive": 0, "animation": False}]
    # axisLine.onZero off: with the hidden value axes below on the same grid, ECharts
    # would otherwise draw each category axis line through the other axis's zero
    x_axes: list[dict[str, Any]] = [{"type": "category", "data": xs, "name": x_name,
                                     "nameLocation": "middle", "nameGap": 32,
                                     "axisLine": {"onZero": False},
                                     "splitArea": {"show": False}}]
    y_axes: list[dict[str, Any]] = [{"type": "category", "data": ys, "name": y_name,
                                     "nameLocation": "middle", "nameGap": 55,
                                     "axisLine": {"onZero": False},
                                     "splitArea": {"show": False}}]
    areas = _region_areas(region, _bin_edges(xc) if x_edges is None else x_edges,
                          _bin_edges(yc) if y_edges is None else y_edges)
    if areas and xc.size and yc.size:
        for axes, n in ((x_axes, xc.size), (y_axes, yc.size)):
            axes.append({"type": "value", "min": -0.5, "max": n - 0.5, "show": False})
        series.append({
            "type": "scatter", "name": "mismatch region", "xAxisIndex": 1, "yAxisIndex": 1,
            "data": [], "silent": True, "animation": False,
            # above the heatmap's cells (a markArea lies at z 1, under series at z 2)
            "markArea": {"silent": True, "animation": False, "z": 5, "data": areas},
        })
    return {
        "animation": False,
        "title": {"text": title, "left": "center", "textStyle": {"fontSize": 13}},
        "grid": {"left": 80, "right": 100, "top": 40 if title else 16, "bottom": 60},
        "tooltip": {"position": "top"},
        "xAxis": x_axes if len(x_axes) > 1 else x_axes[0],
        "yAxis": y_axes if len(y_axes) > 1 else y_axes[0],
        "visualMap": {"min": lo, "max": hi, "calculable": True, "orient": "vertical",
                      "right": 5, "top": "middle", "text": [value_unit, ""], "seriesIndex": 0,
                      "inRange": {"color": ["#313695", "#74add1", "#ffffbf", "#f46d43",
                                            "#a50026"]}},
        "series": series,
    }


def _region_areas(regions: Sequence[dict[str, Any]], x_edges: np.ndarray,
                  y_edges: np.ndarray) -> list[list[dict[str, Any]]]:
    """markArea pairs (bin-index corners) outlining each region, each in its own colour."""
    areas = []
    for k, reg in enumerate(regions):
        box = region_box(reg)
        if box is None:
            continue
        (r0, r1), (v0, v1) = box
        colour = REGION_COLOURS[k % len(REGION_COLOURS)]
        areas.append([
            {"name": str(reg.get("name", "")),
             "coord": [round(bin_position(min(r0, r1), x_edges), 4),
                       round(bin_position(min(v0, v1), y_edges), 4)],
             "itemStyle": {"color": "rgba(0, 0, 0, 0)", "borderColor": colour,
                           "borderWidth": 3, "borderType": "dashed" if k else "solid"},
             "label": {"show": True, "position": "insideTop", "color": colour,
                       "fontWeight": "bold", "backgroundColor": "rgba(255, 255, 255, 0.8)",
                       "padding": [1, 3]}},
            {"coord": [round(bin_position(max(r0, r1), x_edges), 4),
                       round(bin_position(max(v0, v1), y_edges), 4)]},
        ])
    return areas
