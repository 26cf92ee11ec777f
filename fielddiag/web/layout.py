"""The frame around every page (header, navigation) and small shared widgets."""

from __future__ import annotations

import logging
from collections.abc import Mapping
from urllib.parse import quote

from nicegui import ui

from fielddiag import __version__
from fielddiag.errors import FieldDiagError

log = logging.getLogger("fielddiag.web")

NAV = (
    ("/", "Sessions", "folder_open"),
    ("/identify", "Identification", "tune"),
    ("/diagnose", "Diagnosis", "troubleshoot"),
    ("/live", "Live recording", "sensors"),
)


def header(root_label: str) -> None:
    """Top bar: product name, the sessions folder, and the pages."""
    with ui.header(elevated=True).classes("items-center gap-4 px-4 py-2 bg-slate-800"):
        ui.label("fielddiag").classes("text-lg font-bold tracking-wide")
        ui.label(root_label).classes("text-xs text-slate-300").mark("root-label")
        ui.space()
        for path, label, icon in NAV:
            with ui.link(target=path).classes("text-white no-underline").mark(f"nav-{label}"):
                with ui.row().classes("items-center gap-1"):
                    ui.icon(icon).classes("text-base")
                    ui.label(label).classes("text-sm")
        ui.label(f"v{__version__}").classes("text-xs text-slate-400")


def page_title(text: str, subtitle: str = "") -> None:
    ui.label(text).classes("text-xl font-semibold mt-2")
    if subtitle:
        ui.label(subtitle).classes("text-sm text-gray-600 -mt-1")


def warning_labels(result: object, mark: str, css_class: str = "") -> None:
    """One amber line per warning of a result (strings, or dicts with a ``message``)."""
    warnings = result.get("warnings") if isinstance(result, Mapping) else None
    for w in warnings if isinstance(warnings, list) else []:
        msg = w.get("message", str(w)) if isinstance(w, Mapping) else str(w)
        ui.label(f"⚠ {msg}").classes(f"text-sm text-amber-800 {css_class}".strip()).mark(mark)


def not_available(title: str, reason: str, hint: str = "") -> ui.card:
    """A clear panel saying a part of the pipeline is not there yet (instead of failing)."""
    with ui.card().classes("w-full bg-amber-50 border border-amber-300").mark(
        "not-available"
    ) as card:
        with ui.row().classes("items-center gap-2"):
            ui.icon("hourglass_empty").classes("text-amber-700 text-2xl")
            ui.label(f"{title}: not available yet").classes("text-base font-semibold")
        ui.label(reason).classes("text-sm text-gray-700")
        if hint:
            ui.label(hint).classes("text-sm text-gray-600")
    return card


def session_link(path: str) -> str:
    """URL of the session page for a session path relative to the root."""
    return f"/session?path={quote(path, safe='')}"


def file_link(path: str) -> str:
    """URL that downloads a file given relative to the root."""
    return f"/files/{quote(path)}"


def notify_error(message: str) -> None:
    """A readable error notification that stays until dismissed."""
    ui.notify(message, type="negative", close_button="OK", timeout=0, multi_line=True)


def notify_exception(what: str, exc: BaseException) -> str:
    """Say readably that ``what`` failed, and return the text shown.

    A :class:`FieldDiagError` is a problem with the data or a choice: its message says it
    all. Anything else is a bug: shown with its type, and logged with its traceback on
    the server for the bug report.
    """
    if isinstance(exc, FieldDiagError):
        text = f"{what}: {exc}"
    else:
        log.error("%s", what, exc_info=exc)
        text = f"{what}: {type(exc).__name__}: {exc}"
    notify_error(text)
    return text


def fmt_duration(seconds: float) -> str:
    s = float(seconds)
    if round(s) <= 120:
        # two drives of one nominal length read alike: 119.98 and 120.06 s (a recorder
        # stops on a frame, not on the second) are 120.0 and 120.1 s, not 2 min 00 s
        return f"{s:.1f} s"
    m, s = divmod(int(round(s)), 60)
    h, m = divmod(m, 60)
    return f"{h} h {m:02d} min" if h else f"{m} min {s:02d} s"


# Draws the newest pushed option of a chart at the browser's next frame. An update that
# arrives before that frame replaces the one waiting (a stale live frame is dropped, not
# queued: a browser slower than the server's frame rate stays responsive). The chart
# takes it once it shows ``n`` series (the layout goes first through the element's props).
_PUSH_JS = """window.fdPushChart = window.fdPushChart || function (id, n, option) {
    const pending = window.fdPendingCharts || (window.fdPendingCharts = new Map());
    const pushed = window.fdPushedCharts || (window.fdPushedCharts = new Map());
    const scheduled = pending.has(id);
    pending.set(id, [n, option]);
    if (scheduled) return;
    const lengths = (series) => (series || []).map(s => (s && s.data ? s.data.length : 0));
    const draw = (tries) => {
        const [want, opt] = pending.get(id);
        const c = getElement(id);
        const model = c && c.chart && !c.chart.isDisposed() && c.chart.getModel();
        if (!model || model.getSeriesCount() !== want) {
            if (tries < 1000) setTimeout(() => draw(tries + 1), 10); else pending.delete(id);
            return;
        }
        pending.delete(id);
        c.chart.setOption(opt);
        // the element's layout (its props, series without points) applied after this
        // wipes the points: an empty chart with its axes, one page load in three on the
        // session page. Looked at again for a few seconds and put back while no newer
        // update came
        pushed.set(id, opt);
        const expected = lengths(opt.series);
        const check = (k) => setTimeout(() => {
            if (pushed.get(id) !== opt || pending.has(id)) return;
            const e = getElement(id);
            if (!e || !e.chart || e.chart.isDisposed()) return;
            const got = lengths(e.chart.getOption().series);
            if (expected.some((m, i) => m > 0 && !got[i])) e.chart.setOption(opt);
            if (k < 5) check(k + 1);
        }, 50 * (1 << k));
        check(0);
    };
    requestAnimationFrame(() => draw(0));
};"""


def push_chart_update(chart, partial: dict, n_series: int) -> None:
    """Apply ``partial`` (a partial ECharts option, e.g. new series data) to ``chart``.

    Sent as a plain ``setOption`` call once the chart in the browser exists and shows
    ``n_series`` series, bypassing the element's reactive ``options`` prop: pushing a few
    hundred kB of points through Vue's deep reactivity costs the browser far more than
    the drawing itself. The caller keeps ``chart.options`` current on the server
    (:func:`keep_chart_options`). Drawn at the browser's next animation frame; of the
    updates that arrive before it, only the newest is drawn.
    """
    import orjson

    payload = orjson.dumps(partial, option=orjson.OPT_SERIALIZE_NUMPY).decode()
    ui.run_javascript(f"{_PUSH_JS}\nwindow.fdPushChart({chart.id}, {int(n_series)}, {payload});")


def keep_chart_options(chart, options: dict) -> None:
    """Make ``chart.options`` (the server's copy, sent again when a page reconnects) equal
    to ``options`` without sending it to the browser now.

    Since nicegui 3 the element's props are observable: changing them sends the whole
    option, every point, through Vue on the next update. Use this beside
    :func:`push_chart_update`, which sends the change itself.
    """
    suspend = getattr(chart.props, "suspend_updates", None)
    if suspend is None:  # nicegui 2: plain props, nothing is sent until update()
        chart.options.update(options)
        return
    with suspend():
        chart.options.update(options)
