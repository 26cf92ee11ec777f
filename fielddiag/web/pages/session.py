"""Session page: every channel and CAN signal against time, events and gaps marked.

The whole session is shown first (a min/max-preserving overview, cached per session);
zooming or panning asks the server for the visible window again at full detail, so a 1 h
recording at 2 kHz stays quick: the browser never holds more than about
``plot_points`` points per trace.
"""

from __future__ import annotations

import asyncio
import time
from urllib.parse import quote

from nicegui import background_tasks, run, ui

from fielddiag.catalog import OutsideRootError
from fielddiag.errors import FieldDiagError
from fielddiag.session_guard import verify_untrusted
from fielddiag.web.charts import timeseries_height_px, timeseries_options, zoom_window
from fielddiag.web.layout import (
    file_link,
    fmt_duration,
    notify_exception,
    page_title,
    push_chart_update,
)

CHART_CLASS = "fd-session-chart"


def _header(summary, state) -> None:
    page_title(
        summary.path,
        f"{summary.vehicle or 'unknown vehicle'} · {summary.corner or 'corner ?'} · "
        f"{summary.created[:19].replace('T', ' ')} · {fmt_duration(summary.duration_s)} · "
        f"{summary.sample_rate_hz:g} Hz · added mass {summary.added_mass_kg:g} kg",
    )
    with ui.row().classes("items-center gap-2"):
        ui.button("Download", icon="download").props(
            f'flat dense href="{file_link(summary.path)}" download'
        )
        for kind, rel in summary.processed.items():
            ui.button(kind, icon="description").props(
                f'flat dense color=positive href="{file_link(rel)}" target=_blank'
            )
        ui.button("Identify", icon="tune").props("flat dense").on_click(
            lambda: ui.navigate.to(f"/identify?before={quote(summary.path, safe='')}")
        )
        ui.button("Diagnose", icon="troubleshoot").props("flat dense").on_click(
            lambda: ui.navigate.to(f"/diagnose?session={quote(summary.path, safe='')}")
        )
        if summary.n_gaps:
            ui.badge(f"{summary.n_gaps} gaps, {summary.samples_lost} samples lost",
                     color="negative")
        if not summary.closed_cleanly:
            ui.badge("not closed cleanly (recording or interrupted)", color="warning")


def render(state, path: str = "") -> None:
    """Build the page of the session ``path`` (relative to the root)."""
    if not path:
        page_title("Session")
        ui.label("No session chosen; pick one on the Sessions page.")
        ui.link("Sessions", "/")
        return
    try:
        summary = state.catalog.summary(path)
    except (OutsideRootError, FieldDiagError) as exc:
        page_title("Session")
        ui.label(str(exc)).classes("text-negative").mark("session-error")
        ui.link("back to the sessions", "/")
        return
    except Exception as exc:  # a bug: shown with its type, logged with the traceback
        page_title("Session")
        ui.label(notify_exception(f"Cannot open {path}", exc)).classes("text-negative").mark(
            "session-error")
        ui.link("back to the sessions", "/")
        return
    if summary.error:
        page_title(summary.path)
        ui.label(summary.error).classes("text-negative").mark("session-error")
        return

    _header(summary, state)
    status = ui.label("loading...").classes("text-sm text-gray-600").mark("plot-status")
    n_traces = len(summary.channels) + len(summary.signals)
    chart = ui.echart({"series": []}).classes(f"w-full {CHART_CLASS}").style(
        f"height: {timeseries_height_px(n_traces)}px"
    ).mark("session-chart")
    ev_container = ui.column().classes("w-full")

    view: dict = {"window": None, "pending": None, "busy": False, "t0": 0.0, "t1": 0.0,
                  "events": [], "gaps": [], "fetch_s": 0.0}

    def _fetch(window):
        path = state.resolve(summary.path)
        verify_untrusted(path)  # one stat when the list has checked it already
        src = state.plots.get(path)
        r = src.reader
        lo, hi = (None, None) if window is None else window
        t_fetch = time.perf_counter()
        traces = src.traces(lo, hi)
        return (traces, r.start_s, r.end_s, r.events, r.gaps,
                time.perf_counter() - t_fetch)

    async def draw(window, prefetched=None) -> None:
        try:
            fetched = await (prefetched if prefetched is not None
                             else run.io_bound(_fetch, window))
            if fetched is None:  # the server is shutting down
                return
            if isinstance(fetched, Exception):  # the overview read ahead failed
                raise fetched
            traces, t0, t1, events, gaps, fetch_s = fetched
        except Exception as exc:  # a data problem, or a bug (shown with its type, logged)
            status.text = notify_exception(f"Cannot read {summary.path}", exc)
            return
        view.update(t0=t0, t1=t1 + 1.0 / max(summary.sample_rate_hz, 1e-9), events=events,
                    gaps=gaps, window=window, fetch_s=fetch_s)
        opts = timeseries_options(traces, view["t0"], view["t1"], window=window,
                                  events=events, gaps=gaps)
        data = {"series": [{"data": sr["data"]} for sr in opts["series"]],
                "dataZoom": [{"start": z["start"], "end": z["end"]} for z in opts["dataZoom"]]}
        chart.plotted = opts  # what the browser shows (for tests and the benchmark)
        if not view.get("drawn"):
            # The layout (axes, titles, events, gaps) goes through the element's props,
            # without the points; they follow as a plain setOption (push_chart_update).
            view["drawn"] = True
            chart.options.clear()
            chart.options.update(opts)
            chart.options["series"] = [{**sr, "data": []} for sr in opts["series"]]
            chart.update()
        push_chart_update(chart, data, len(opts["series"]))
        lo, hi = window or (view["t0"], view["t1"])
        n_raw = max((t.n_raw for t in traces if t.kind == "channel"), default=0)
        n_shown = max((len(t.time_s) for t in traces if t.kind == "channel"), default=0)
        detail = (f"{n_shown} of {n_raw} samples per channel (min/max kept)"
                  if n_raw > n_shown else f"all {n_raw} samples")
        status.text = (f"{lo:.3f}–{hi:.3f} s: {detail}; {len(events)} events, "
                       f"{len(gaps)} gaps; read in {fetch_s * 1000:.0f} ms")

    async def zoom_to(window) -> None:
        """Coalesce zoom requests: draw the newest one once the previous draw is done."""
        view["pending"] = window
        if view["busy"]:
            return
        view["busy"] = True
        try:
            while view["pending"] != "done":
                w = view["pending"]
                view["pending"] = "done"
                await asyncio.sleep(0.05)  # let a burst of wheel events settle
                if view["pending"] != "done":
                    continue
                await draw(w)
        finally:
            view["busy"] = False

    async def on_zoom(e) -> None:
        if not view["t1"]:
            return
        args = e.args if isinstance(e.args, dict) else {}
        w = zoom_window(args, view["t0"], view["t1"])
        if w is None:
            return
        full = (w[1] - w[0]) >= 0.999 * (view["t1"] - view["t0"])
        await zoom_to(None if full else w)

    chart.on("chart:datazoom", on_zoom, ["start", "end", "startValue", "endValue", "batch"])
    chart.on("chart:restore", lambda: zoom_to(None), [])

    # Start reading the overview now, while the browser is still loading and connecting.
    # Its failure is returned, not raised: a task that raises is logged as an error by
    # nicegui even when draw() handles it.
    async def read_overview():
        try:
            return await run.io_bound(_fetch, None)
        except Exception as exc:
            return exc

    overview = background_tasks.create(read_overview(), name="session overview")

    async def first_draw() -> None:
        await draw(None, prefetched=overview)
        with ev_container:
            if view["events"]:
                ui.label("Events (click to zoom)").classes("text-sm font-semibold")
                rows = [{"time_s": round(e.time_s, 3), "label": e.label} for e in view["events"]]
                tbl = ui.table(
                    columns=[{"name": "time_s", "label": "time [s]", "field": "time_s",
                              "sortable": True},
                             {"name": "label", "label": "event", "field": "label",
                              "align": "left"}],
                    rows=rows, row_key="time_s", pagination=10,
                ).props("dense flat bordered").classes("w-96").mark("events-table")
                tbl.on("rowClick", lambda e: zoom_to(
                    (max(view["t0"], e.args[1]["time_s"] - 5.0),
                     min(view["t1"], e.args[1]["time_s"] + 5.0))))

    ui.timer(0.0, first_draw, once=True)
