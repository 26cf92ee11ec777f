"""Sessions page: every session under the root, searchable and sortable."""

from __future__ import annotations

from datetime import datetime

from nicegui import run, ui

from fielddiag.catalog import SessionSummary, filter_sessions
from fielddiag.web.layout import fmt_duration, notify_error, page_title, session_link

COLUMNS = [
    {"name": "path", "label": "Session", "field": "path", "sortable": True, "align": "left"},
    {"name": "vehicle", "label": "Vehicle", "field": "vehicle", "sortable": True,
     "align": "left"},
    {"name": "corner", "label": "Corner", "field": "corner", "sortable": True, "align": "left"},
    {"name": "created", "label": "Date", "field": "created", "sortable": True, "align": "left"},
    {"name": "duration_s", "label": "Duration", "field": "duration_s", "sortable": True},
    {"name": "added_mass_kg", "label": "Added mass [kg]", "field": "added_mass_kg",
     "sortable": True},
    {"name": "channels", "label": "Channels", "field": "channels", "align": "left"},
    {"name": "processed", "label": "Processed", "field": "processed", "sortable": True,
     "align": "left"},
    {"name": "status", "label": "Status", "field": "status", "sortable": True, "align": "left"},
    {"name": "batch", "label": "Batch result (fielddiag reprocess)", "field": "batch",
     "sortable": True, "align": "left"},
]

_LINK_SLOT = r"""
<q-td :props="props">
  <a :href="'/session?path=' + encodeURIComponent(props.value)"
     class="text-primary font-medium">{{ props.value }}</a>
</q-td>
"""
_DURATION_SLOT = r"""<q-td :props="props">{{ props.row.duration }}</q-td>"""
_PROCESSED_SLOT = r"""
<q-td :props="props">
  <q-badge v-for="k in (props.value ? props.value.split(', ') : [])" :key="k" :label="k"
           color="positive" class="q-mr-xs"/>
  <span v-if="!props.value" class="text-grey-6">not yet</span>
</q-td>
"""
_BATCH_SLOT = r"""
<q-td :props="props">
  <span v-if="props.row.batch_status === 'failed'" class="text-negative">
    failed: {{ props.row.batch_message }}</span>
  <span v-else-if="props.value">{{ props.value }}
    <span class="text-grey-6">({{ props.row.batch_role }} of {{ props.row.batch_partner }})
    </span></span>
  <span v-else class="text-grey-6">-</span>
</q-td>
"""
_CHANNELS_SLOT = r"""
<q-td :props="props">
  <div :title="props.value" style="max-width: 22rem; overflow: hidden;
       text-overflow: ellipsis; white-space: nowrap">{{ props.value }}</div>
</q-td>
"""
_STATUS_SLOT = r"""
<q-td :props="props">
  <q-badge :color="props.value === 'ok' ? 'grey-5' : (props.value === 'unreadable'
                   ? 'negative' : 'warning')" :label="props.value"/>
</q-td>
"""


def _created_label(created: str) -> str:
    try:
        dt = datetime.fromisoformat(created.replace("Z", "+00:00"))
    except ValueError:
        return created
    return dt.strftime("%Y-%m-%d %H:%M")


def row_of(s: SessionSummary) -> dict:
    """A table row (scalars and strings only) of a session summary."""
    if s.error:
        status = "unreadable"
    elif not s.closed_cleanly:
        status = "recording or interrupted"
    else:
        status = "ok"
    return {
        "path": s.path,
        "vehicle": s.vehicle or "-",
        "corner": s.corner or "-",
        "created": _created_label(s.created),
        "duration_s": round(s.duration_s, 3),
        "duration": fmt_duration(s.duration_s),
        "added_mass_kg": round(s.added_mass_kg, 3),
        "channels": ", ".join(s.channels + s.signals),
        "processed": ", ".join(s.processed),
        "status": status,
        "error": s.error,
        "batch": s.batch.get("result", ""),
        "batch_status": s.batch.get("status", ""),
        "batch_message": s.batch.get("message", ""),
        "batch_role": s.batch.get("role", ""),
        "batch_partner": s.batch.get("partner", ""),
    }


def render(state) -> None:
    """Build the sessions page."""
    page_title("Sessions", f"{state.config.root}")
    sessions: list[SessionSummary] = []

    with ui.row().classes("w-full items-center gap-3"):
        search = (
            ui.input(placeholder="search vehicle, corner, date, channel, 'identify'...")
            .props("clearable dense outlined")
            .classes("w-96")
            .mark("search")
        )
        with search.add_slot("prepend"):
            ui.icon("search")
        refresh_button = ui.button("Rescan", icon="refresh").props("flat").mark("rescan")
        count = ui.label("").classes("text-sm text-gray-600").mark("session-count")

    table = (
        ui.table(columns=COLUMNS, rows=[], row_key="path", pagination=25)
        .classes("w-full")
        .props("dense flat bordered")
        .mark("sessions-table")
    )
    table.add_slot("body-cell-path", _LINK_SLOT)
    table.add_slot("body-cell-duration_s", _DURATION_SLOT)
    table.add_slot("body-cell-processed", _PROCESSED_SLOT)
    table.add_slot("body-cell-status", _STATUS_SLOT)
    table.add_slot("body-cell-batch", _BATCH_SLOT)
    table.add_slot("body-cell-channels", _CHANNELS_SLOT)  # long lists must not push the
    # batch result off screen: cut with an ellipsis, whole list on hover
    table.on("rowClick", lambda e: ui.navigate.to(session_link(e.args[1]["path"])))
    empty = ui.label("").classes("text-gray-600").mark("sessions-empty")

    def show() -> None:
        shown = filter_sessions(sessions, search.value or "")
        table.rows = [row_of(s) for s in shown]
        table.update()
        count.text = f"{len(shown)} of {len(sessions)} sessions"
        if not sessions:
            empty.text = (
                f"No sessions under {state.config.root} yet: record one (Live recording), "
                "import a CSV below, or run `fielddiag demo`."
            )
        elif not shown:
            empty.text = f"No session matches {search.value!r}."
        else:
            empty.text = ""

    async def load() -> None:
        nonlocal sessions
        refresh_button.props("loading")
        try:
            sessions = await run.io_bound(state.catalog.scan)
        except Exception as exc:  # a vanished folder, a permission problem
            notify_error(f"cannot list the sessions: {exc}")
        finally:
            refresh_button.props(remove="loading")
        if sessions is not None:
            show()

    search.on_value_change(lambda _: show())
    refresh_button.on_click(load)

    from fielddiag.web.pages.upload import import_panel

    import_panel(state, on_imported=load)
    ui.timer(0.0, load, once=True)
