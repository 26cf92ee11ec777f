"""Live recording page: sources, start/stop, live plots, counters, events, observability.

One recording at a time per server (a laptop has one DAQ); it keeps running when the
page is left and the page reattaches to it. The plots show the last
:data:`WINDOW_S` seconds, redrawn every :data:`FRAME_S` seconds from the recorder's live
buffer, downsampled (min/max kept) to :data:`LIVE_POINTS` points per trace.
"""

from __future__ import annotations

import time

import numpy as np
from nicegui import background_tasks, run, ui

from fielddiag.catalog import OutsideRootError, resolve_under_root
from fielddiag.channels import SessionMetadata
from fielddiag.downsample import minmax_lttb_indices
from fielddiag.errors import FieldDiagError
from fielddiag.web.charts import PALETTE, nice_axis_labels, pairs_array
from fielddiag.web.layout import (
    keep_chart_options,
    not_available,
    notify_error,
    page_title,
    push_chart_update,
    session_link,
)
from fielddiag.web.services import observability_backend, recorder_backend

WINDOW_S = 10.0
#: Redraw period. 20 frames/s asked so that a loaded laptop still draws 10 or more (the
#: browser drops a frame when one arrives while it is still drawing the previous one).
FRAME_S = 0.05
LIVE_POINTS = 500
LIVE_FOLDER = "recordings"
CHART_CLASS = "fd-live-chart"

COUNTERS = (
    ("elapsed_s", "elapsed", "{:.1f} s"),
    ("measured_rate_hz", "DAQ rate", "{:.0f} Hz"),
    ("frames_received", "frames", "{}"),
    ("frames_lost", "frames lost", "{}"),
    ("crc_errors", "CRC errors", "{}"),
    ("gaps", "gaps", "{}"),
    ("samples_lost", "samples lost", "{}"),
    ("can_frames_received", "CAN frames", "{}"),
    ("buffer_fill", "buffer", "{:.0%}"),
    ("file_size_bytes", "file", "{:.1f} MB"),
)


def stop_all(state) -> None:
    """Stop a recording still running (server shutdown)."""
    rec = state.live.pop("recording", None)
    if rec is not None:
        rec.stop()


def live_options(traces: list[tuple[str, str, np.ndarray]], t_hi: float,
                 events: list[tuple[float, str]] = ()) -> dict:
    """Stacked live plots over the last WINDOW_S seconds ending at ``t_hi``, with the
    events of that window as labelled vertical lines. Each trace is (name, unit, points):
    ``(n, 2)`` time/value points (:func:`~fielddiag.web.charts.pairs_array`)."""
    marks = [{"xAxis": round(te, 3), "label": {"formatter": lbl[:20]}}
             for te, lbl in events if t_hi - WINDOW_S <= te <= t_hi]
    n = max(1, len(traces))
    h, gap, top = 110, 30, 30
    grids, xs, ys, series, titles = [], [], [], [], []
    for i, (name, unit, data) in enumerate(traces):
        y0 = top + i * (h + gap)
        grids.append({"left": 70, "right": 20, "top": y0, "height": h})
        titles.append({"text": f"{name} [{unit}]" if unit else name, "top": y0 - 20,
                       "left": 70, "textStyle": {"fontSize": 12, "fontWeight": "normal"}})
        # axis lines at the plot's edges, not through zero (time 0 sits mid-plot in the
        # first seconds of a recording)
        xs.append({"type": "value", "gridIndex": i, "min": round(t_hi - WINDOW_S, 3),
                   "max": round(t_hi, 3), "axisLine": {"onZero": False},
                   "name": "session time [s]" if i == n - 1 else "",
                   "nameLocation": "middle", "nameGap": 24,
                   "axisLabel": {"show": i == n - 1, "showMinLabel": False,
                                 "showMaxLabel": False}})
        ys.append({"type": "value", "gridIndex": i, "scale": True, "splitNumber": 3,
                   "axisLine": {"onZero": False}})
        series.append({"name": name, "type": "line", "xAxisIndex": i, "yAxisIndex": i,
                       "showSymbol": False, "animation": False, "lineStyle": {"width": 1},
                       "color": PALETTE[i % len(PALETTE)], "data": data,
                       "markLine": {"symbol": "none", "silent": True, "animation": False,
                                    "lineStyle": {"type": "dashed", "color": "#555"},
                                    "label": {"show": i == 0, "position": "end",
                                              "fontSize": 10},
                                    "data": marks}})
    return nice_axis_labels({"animation": False, "title": titles, "grid": grids, "xAxis": xs,
                             "yAxis": ys, "series": series})


def _observability_row(p: dict) -> None:
    """One parameter of the on-line estimate: name and state, a bar of how close its
    relative standard deviation is to the goal (full: reached), and the numbers."""
    rel = float(p.get("rel_std_pct") or float("inf"))
    target = float(p.get("target_rel_std_pct") or 5.0)
    level = min(1.0, target / rel) if rel > 0 else 1.0
    state = str(p.get("state", ""))
    colour = {"ok": "positive", "converging": "warning"}.get(state, "negative")
    with ui.column().classes("w-full gap-0").mark("observability-param"):
        with ui.row().classes("w-full items-center justify-between no-wrap"):
            ui.label(str(p.get("label", p.get("name", "?")))).classes("text-sm").mark(
                "observability-name")
            ui.badge(state, color=colour).classes("text-xs").mark("observability-state")
        ui.linear_progress(value=round(level, 3), show_value=False, color=colour).props(
            "rounded size=8px").mark("observability-bar")
        ui.label(f"{p.get('value', float('nan')):.4g} {p.get('unit', '')} "
                 f"± {rel:.1f} % (goal {target:.0f} %), "
                 f"{p.get('information_bits', 0.0):.1f} bit").classes(
            "text-xs text-gray-600 font-mono")


def _faults(corrupt_rate, garbage_every_s, stall_at_s, stall_for_s, buffer_kb) -> dict:
    """LiveOptions' fault keywords from the page's number inputs (None: the default)."""
    return {
        "corrupt_rate": float(corrupt_rate or 0.0),
        "garbage_every_s": float(garbage_every_s) if garbage_every_s else None,
        "stall_at_s": float(stall_at_s) if stall_at_s else None,
        "stall_for_s": float(stall_for_s) if stall_for_s else 1.0,
        "tx_buffer_bytes": int(float(buffer_kb or 64) * 1024),
    }


def render(state) -> None:
    """Build the live recording page."""
    page_title("Live recording", "record a drive from the DAQ and the car's CAN bus")
    backend = recorder_backend()
    if not backend.available:
        not_available("Live recording", backend.reason)
        return
    from fielddiag.web.live_control import (
        NONE,
        VIRTUAL,
        LiveOptions,
        LiveRecording,
        can_choices,
        daq_choices,
    )

    with ui.card().classes("w-full"):
        with ui.row().classes("w-full items-end gap-3"):
            daq = ui.select(daq_choices(), value=VIRTUAL, label="DAQ").classes("w-80").mark(
                "daq-source")
            daq_url = ui.input("or DAQ URL", placeholder="serial:///dev/ttyUSB0?baud=921600"
                               ).classes("w-72").mark("daq-url")
            can = ui.select(can_choices(), value=VIRTUAL, label="CAN").classes("w-80").mark(
                "can-source")
            can_url = ui.input("or CAN URL", placeholder="can://socketcan/can0?dbc=car.dbc"
                               ).classes("w-72").mark("can-url")
        with ui.row().classes("w-full items-end gap-3"):
            stamp = time.strftime("%Y%m%d-%H%M%S")
            name = ui.input("session file", value=f"{LIVE_FOLDER}/live-{stamp}.h5").classes(
                "w-80").mark("live-path")
            vehicle = ui.input("vehicle").classes("w-40").mark("live-vehicle")
            corner = ui.input("corner", value="front-left").classes("w-32")
            mass = ui.number("added mass [kg]", value=0, min=0).classes("w-32").mark(
                "live-mass")
            start_b = ui.button("Start", icon="fiber_manual_record", color="negative").mark(
                "live-start")
            stop_b = ui.button("Stop", icon="stop").mark("live-stop")
        with ui.expansion("Faults of the virtual DAQ (to see how the recorder copes)",
                          icon="bug_report").classes("w-full text-sm").mark("faults"):
            with ui.row().classes("w-full items-end gap-3"):
                corrupt = ui.number("byte corruption rate", value=0.0, min=0.0, max=0.099,
                                    step=0.0005, format="%.4f").classes("w-44").tooltip(
                    "probability that a byte on the serial link is altered: the frame "
                    "fails its CRC and is lost").mark("fault-corrupt-rate")
                garbage = ui.number("garbage burst every [s]", value=None, min=0.1,
                                    step=1.0).classes("w-44").mark("fault-garbage")
                stall_at = ui.number("stall at [s]", value=None, min=0.1, step=1.0).classes(
                    "w-32").tooltip("the device stops sending; frames that no longer fit "
                                    "its transmit buffer are dropped").mark("fault-stall-at")
                stall_for = ui.number("stall for [s]", value=3.0, min=0.1, step=1.0).classes(
                    "w-32").mark("fault-stall-for")
                tx_kb = ui.number("device buffer [kB]", value=64, min=1, step=1).classes(
                    "w-36").mark("fault-buffer")
    fault_inputs = (corrupt, garbage, stall_at, stall_for, tx_kb)
    with ui.row().classes("w-full gap-2 items-center"):
        counter_labels = {}
        for key, label, _fmt in COUNTERS:
            with ui.card().classes("px-3 py-1 gap-0"):
                ui.label(label).classes("text-xs text-gray-500")
                counter_labels[key] = ui.label("-").classes("text-base font-mono").mark(
                    f"counter-{key}")
        conn = ui.badge("idle", color="grey").mark("live-state")
    message = ui.label("").classes("text-sm text-negative").mark("live-error")
    saved_box = ui.row().classes("items-center")
    with ui.row().classes("w-full items-center gap-2"):
        event_label = ui.input("event label", value="bump").classes("w-60").mark("event-label")
        event_b = ui.button("Mark event", icon="flag").mark("mark-event")
        events_shown = ui.label("").classes("text-sm text-gray-600").mark("events-shown")
    with ui.row().classes("w-full gap-3 no-wrap items-start"):
        chart = ui.echart({"series": []}).classes(f"w-full {CHART_CLASS}").style(
            "height: 420px").mark("live-chart")
        with ui.card().classes("w-80 shrink-0").mark("observability"):
            ui.label("Observability").classes("font-semibold")
            obs_backend = observability_backend()
            obs_body = ui.column().classes("gap-1 w-full")
            if not obs_backend.available:
                with obs_body:
                    ui.label(obs_backend.reason).classes(
                        "text-sm text-gray-600").mark("observability-missing")

    view = {"frames": 0, "last_frame_s": 0.0, "layout": None, "finished_shown": False,
            "stopping": False}

    def current():
        return state.live.get("recording")

    def set_running(running: bool) -> None:
        start_b.set_enabled(not running)
        stop_b.set_enabled(running)
        event_b.set_enabled(running)
        for el in (daq, daq_url, can, can_url, name, vehicle, corner, mass, *fault_inputs):
            el.set_enabled(not running)

    def set_text(label, text: str) -> None:
        if label.text != text:  # unchanged labels send nothing to the browser
            label.text = text

    def update_counters(st: dict) -> None:
        for key, _label, fmt in COUNTERS:
            v = st.get(key)
            if key == "file_size_bytes" and v is not None:
                v = v / 1e6
            set_text(counter_labels[key], "-" if v is None else fmt.format(v))
        state_name = st.get("state", "idle")
        connected = st.get("connected", True)
        if state_name == "recording" and not connected:
            state_name = "recording, DISCONNECTED"
        if conn.text != state_name:
            conn.text = state_name
            color = {"recording": "positive", "recording, DISCONNECTED": "negative"}.get(
                state_name, "grey")
            conn.props(f"color={color}")
        set_text(message, st.get("last_error") or "")

    def frame() -> None:
        rec = current()
        if rec is None:
            return
        st = rec.status()
        if view["frames"] % 4 == 0 or not rec.running:  # counters: 5 times a second
            update_counters(st)
        if not rec.running:
            if not view["finished_shown"] and not view["stopping"]:
                # the recording ended by itself (device gone, disk full...): close it
                background_tasks.create(finish(rec), name="close recording")
            return
        t, chans = rec.latest(WINDOW_S)
        units = rec.units
        traces = []
        t_hi = float(t[-1]) if t.size else float(st.get("elapsed_s", 0.0))
        for ch_name, v in chans.items():
            idx = minmax_lttb_indices(t, v, LIVE_POINTS)
            traces.append((ch_name, units.get(ch_name, ""), pairs_array(t[idx], v[idx], 4)))
        for sig_name, (ts, vs) in rec.latest_signals(WINDOW_S).items():
            if sig_name in ("vehicle_speed",) or sig_name.lower().endswith("speed"):
                idx = minmax_lttb_indices(ts, vs, LIVE_POINTS)
                traces.append((sig_name, units.get(sig_name, ""), pairs_array(ts[idx], vs[idx], 4)))
                break
        events = rec.recorder.events
        opts = live_options(traces, t_hi, events)
        layout = [name for name, _, _ in traces]
        if layout != view["layout"]:
            # new set of traces: send the whole chart once
            view["layout"] = layout
            chart.style(f"height: {30 + max(1, len(traces)) * 140 + 30}px")
            chart.options.clear()
            chart.options.update(opts)
            chart.update()
        else:
            # same layout: send only the new data and time range (a small partial setOption
            # instead of the whole chart), and keep the server's copy of the options current
            keep_chart_options(chart, opts)
            push_chart_update(chart, {
                "xAxis": [{"min": x["min"], "max": x["max"]} for x in opts["xAxis"]],
                "series": [{"data": sr["data"], "markLine": {"data": sr["markLine"]["data"]}}
                           for sr in opts["series"]],
            }, len(opts["series"]))
        view["frames"] += 1
        view["last_frame_s"] = t_hi
        set_text(events_shown, ", ".join(f"{lbl} @ {te:.1f} s" for te, lbl in events[-5:]))
        if view["frames"] % 10 == 1:  # the estimate changes slowly: twice a second is enough
            show_observability(rec)

    def show_observability(rec) -> None:
        obs = rec.observability()
        if obs is None:
            if rec.estimator_error and not view.get("obs_reason_shown"):
                view["obs_reason_shown"] = True
                obs_body.clear()
                with obs_body:
                    ui.label(rec.estimator_error).classes("text-sm text-gray-600")
            return
        obs_body.clear()
        with obs_body:
            for p in obs.get("parameters", []):
                _observability_row(p)
            ui.label(str(obs.get("advice", ""))).classes("text-sm font-medium mt-1").mark(
                "observability-advice")

    async def start() -> None:
        if current() is not None and current().running:
            notify_error("A recording is already running; stop it first.")
            return
        rel = (name.value or "").strip()
        if not rel.endswith((".h5", ".hdf5")):
            rel += ".h5"
        try:
            out = resolve_under_root(state.config.root, rel)
        except OutsideRootError as exc:
            notify_error(str(exc))
            return
        if out.exists():
            notify_error(f"{rel} already exists; choose another session file name")
            return
        try:
            opts = LiveOptions(
                path=out,
                daq=(daq_url.value or "").strip() or daq.value or NONE,
                can=(can_url.value or "").strip() or can.value or NONE,
                metadata=SessionMetadata(vehicle=vehicle.value or "",
                                         corner=corner.value or "",
                                         added_mass_kg=float(mass.value or 0.0),
                                         operator="fielddiag dashboard"),
                **_faults(corrupt.value, garbage.value, stall_at.value, stall_for.value,
                          tx_kb.value),
            )
        except FieldDiagError as exc:
            notify_error(f"Cannot start recording: {exc}")
            return
        out.parent.mkdir(parents=True, exist_ok=True)
        start_b.props("loading")
        try:
            rec = await run.io_bound(LiveRecording(opts).start)
        except FieldDiagError as exc:
            notify_error(f"Cannot start recording: {exc}")
            return
        except Exception as exc:  # a driver bug: say what happened, keep the page alive
            notify_error(f"Cannot start recording: {type(exc).__name__}: {exc}")
            return
        finally:
            start_b.props(remove="loading")
        if rec is None:
            return
        state.live["recording"] = rec
        view["finished_shown"] = False
        chart.props(f'data-t0-unix="{rec.t0_unix_s:.6f}"')
        set_running(True)
        ui.notify(f"recording into {rel}", type="positive")

    async def finish(rec) -> None:
        """Stop and close a recording (off the event loop) and say how it went."""
        if view["stopping"]:
            return
        view["stopping"] = True
        stop_b.props("loading")
        try:
            final = await run.io_bound(rec.stop)
        finally:
            stop_b.props(remove="loading")
            view["stopping"] = False
        view["finished_shown"] = True
        set_running(False)
        if final:
            update_counters(final)
        if rec.error:
            notify_error(f"The recording stopped with an error: {rec.error}")
            return
        try:
            rel = rec.path.relative_to(state.config.root).as_posix()
        except ValueError:
            ui.notify(f"saved {rec.path}", type="positive")
            return
        ui.notify(f"saved {rel}", type="positive")
        saved_box.clear()
        with saved_box:
            ui.link(f"open {rel}", session_link(rel)).mark("live-saved-link")

    async def stop() -> None:
        rec = current()
        if rec is not None:
            await finish(rec)

    def mark_event() -> None:
        rec = current()
        try:
            if rec is None:
                raise FieldDiagError("not recording: start a recording first")
            t = rec.add_event((event_label.value or "event").strip() or "event")
        except FieldDiagError as exc:
            notify_error(str(exc))
            return
        ui.notify(f"event at {t:.2f} s")

    start_b.on_click(start)
    stop_b.on_click(stop)
    event_b.on_click(mark_event)
    rec0 = current()
    set_running(rec0 is not None and rec0.running)
    if rec0 is not None:
        chart.props(f'data-t0-unix="{rec0.t0_unix_s:.6f}"')
        view["finished_shown"] = not rec0.running
    ui.timer(FRAME_S, frame)
