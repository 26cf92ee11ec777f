"""Diagnosis page: where the linear model misses the recording, and which physics explains it.

Pick one drive, or a before/after pair (the second with a known added mass); the
diagnosis runs in the background with its progress messages and is stored as
``<stem>.diagnose.json`` beside the first session. Shown: the verdict, the findings with
their explanation, where the mismatch lives (time windows on the recording, the frequency
band, the region of (r, rdot)) and the fit before and after on held-out data.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from nicegui import background_tasks, run, ui

from fielddiag.catalog import result_path
from fielddiag.errors import FieldDiagError
from fielddiag.pairs import pair_of
from fielddiag.validate import number
from fielddiag.web.charts import xy_options
from fielddiag.web.layout import not_available, notify_error, notify_exception, page_title
from fielddiag.web.pages.identify import write_result
from fielddiag.web.results_view import render_diagnosis
from fielddiag.web.services import diagnosis_backend, load_result

KIND = "diagnose"
#: A diagnosis of one drive alone is stored under its own name, so that it never
#: overwrites the diagnosis of the pair the drive belongs to.
KIND_SINGLE = "diagnose-single"
NO_SECOND = ""


def run_diagnosis(target, sessions: list[Path], out: Path, added_mass_kg: float | None = None,
                  progress=None) -> dict[str, Any]:
    """Diagnose one session or a pair, store the result as JSON at ``out``, return it.

    Parameters
    ----------
    target : callable
        :func:`fielddiag.web.services.diagnose_drives` (or a stand-in with its signature).
    sessions : list of Path
        One session file or a before/after pair.
    out : Path
        Where the result JSON goes.
    added_mass_kg : float or None
        Mass added for the second drive of a pair [kg]; not used for one drive.
    progress : callable or None
        ``progress(None, message)``: the diagnosis says what it does, not how far.

    Returns
    -------
    dict
        The result as stored (``session_paths`` included).

    Raises
    ------
    FieldDiagError
        The drives cannot be diagnosed (the engine's message).
    """

    def said(message: Any) -> None:  # the engine reports what it is doing, not how far
        if progress is not None:
            progress(None, str(message))

    mass = added_mass_kg if len(sessions) > 1 else None
    result = target(list(sessions), added_mass_kg=mass, progress=said)
    d = result.to_dict() if hasattr(result, "to_dict") else dict(result)
    d.setdefault("session_paths", [p.name for p in sessions])
    write_result(out, d)
    return d


def render(state, session: str = "", after: str = "") -> None:
    """Build the diagnosis page (``session``/``after``: session paths to preselect)."""
    page_title("Diagnosis", "find the physics a linear model leaves out, and show the fit "
                            "improve on data not used for the fit")
    backend = diagnosis_backend()
    if not backend.available:
        not_available(
            "Diagnosis", backend.reason,
            "Stored results (<session>.diagnose.json) are shown below when you pick a session.",
        )
    with ui.card().classes("w-full"):
        with ui.row().classes("w-full items-end gap-3"):
            sel = ui.select({}, label="drive", with_input=True).classes("w-96").mark(
                "diagnose-session")
            second = ui.select({}, label="second drive with added mass (optional)",
                               with_input=True, clearable=True).classes("w-96").mark(
                "diagnose-after")
            mass = ui.number("added mass [kg]", value=None, min=0.0, step=0.5,
                             format="%.1f").classes("w-40").mark("diagnose-mass")
            run_button = ui.button("Run diagnosis", icon="play_arrow").mark("run-diagnose")
            if not backend.available:
                run_button.disable()
        progress = ui.linear_progress(value=0.0, show_value=False).classes("w-full")
        status = ui.label("").classes("text-sm text-gray-600").mark("diagnose-status")
        pair_note = ui.label("").classes("text-sm text-amber-800").mark("pair-note")
        progress.set_visibility(False)
    results = ui.column().classes("w-full").mark("diagnose-results")
    summaries: dict[str, Any] = {}

    def recording_view(first_rel: str, result: dict):
        """Draws the recorded body acceleration with the mismatch windows shaded."""
        names = result.get("sessions") or []
        by_label = {}
        for s in names:
            if isinstance(s, dict) and s.get("label"):
                rel = (first_rel.rsplit("/", 1)[0] + "/" if "/" in first_rel else "") + str(
                    s.get("name", ""))
                by_label[s["label"]] = rel if s.get("name") else first_rel

        def draw(windows: list) -> None:
            box = ui.column().classes("w-full")

            async def fill() -> None:
                labels = sorted({str(w.get("session", "")) for w in windows
                                 if isinstance(w, dict)}) or [""]
                for label in labels:
                    rel = by_label.get(label, first_rel)
                    try:
                        tr = await run.io_bound(_body_overview, state, rel)
                    except Exception as exc:  # a moved session, or a bug (logged)
                        with box:
                            ui.label(notify_exception(f"Cannot draw {rel}", exc)).classes(
                                "text-sm text-negative")
                        continue
                    wins = [(float(w["start_s"]), float(w["end_s"])) for w in windows
                            if isinstance(w, dict) and str(w.get("session", "")) == label]
                    with box:
                        ui.echart(xy_options(
                            [{"name": f"{rel} body", "x": tr.time_s, "y": tr.values}],
                            x_name="time [s]", y_name=f"{tr.name} [{tr.unit}]",
                            title=f"Where the residual stands out: {label or rel}",
                            mark_x_windows=wins, zoom=True)).classes("w-full h-80").classes(
                            "fd-windows-chart").mark("windows-chart")

            background_tasks.create(fill(), name="diagnosis windows")

        return draw

    def show(rel: str, result: dict) -> None:
        results.clear()
        with results:
            render_diagnosis(result, recording_view=recording_view(rel, result))

    async def show_stored(rel: str | None) -> None:
        results.clear()
        if not rel:
            return
        try:
            stored = await run.io_bound(load_result, state.resolve(rel), KIND)
        except Exception as exc:  # a broken result file, or a bug (shown with its type)
            notify_exception(f"Cannot show the stored result of {rel}", exc)
            return
        if stored is None:
            with results:
                ui.label(f"{rel} has not been diagnosed yet.").classes("text-gray-600")
            return
        show(rel, stored)
        with results:
            ui.label(f"stored diagnosis of {rel}").classes("text-xs text-gray-500")

    def fill_mass() -> None:
        a, b = summaries.get(sel.value), summaries.get(second.value)
        if a is not None and b is not None:
            mass.value = round(max(0.0, b.added_mass_kg - a.added_mass_kg), 3)
        elif b is None:
            mass.value = None

    async def on_first(e) -> None:
        fill_mass()
        await show_stored(e.value)

    sel.on_value_change(on_first)
    second.on_value_change(lambda _e: fill_mass())

    def watch(job, rel: str) -> None:
        progress.set_visibility(True)
        run_button.disable()

        def poll() -> None:
            progress.value = job.progress.fraction
            if job.progress.fraction <= 0.0 and not job.finished:
                progress.props("indeterminate")
            else:
                progress.props(remove="indeterminate")
            status.text = f"{job.title}: {job.progress.message} ({job.elapsed_s:.0f} s)"
            if not job.finished:
                return
            timer.cancel()
            if backend.available:
                run_button.enable()
            progress.set_visibility(False)
            if job.state == "failed":
                status.text = f"{job.title} failed: {job.error}"
                notify_error(f"Diagnosis failed: {job.error}")
                return
            status.text = f"{job.title}: done in {job.elapsed_s:.1f} s"
            ui.notify("diagnosis done", type="positive")
            show(rel, job.result)
            background_tasks.create(list_sessions(), name="relist sessions")  # "processed"

        timer = ui.timer(0.2, poll)

    def start() -> None:
        if not sel.value:
            notify_error("Pick a drive.")
            return
        rels = [sel.value] + ([second.value] if second.value else [])
        if len(rels) == 2 and rels[0] == rels[1]:
            notify_error("The two drives must be different sessions.")
            return
        added_mass_kg = None
        if len(rels) == 2:
            try:
                added_mass_kg = number("" if mass.value is None else mass.value,
                                       "added mass", "added_mass")
            except FieldDiagError as exc:
                notify_error(f"{exc} for the second drive.")
                return
        try:
            paths = [state.resolve(r) for r in rels]
        except FieldDiagError as exc:
            notify_error(str(exc))
            return
        # a drive that belongs to a pair keeps the pair's result: diagnosed alone, its
        # result is stored under a name of its own
        alone_in_pair = len(rels) == 1 and bool(
            all(pair_of(rels[0], list(summaries.values()))[:2]))
        job = state.jobs.submit(
            KIND, f"diagnose {' / '.join(rels)}", run_diagnosis, backend.target, paths,
            result_path(paths[0], KIND_SINGLE if alone_in_pair else KIND), added_mass_kg)
        job.params["session"] = rels[0]
        watch(job, rels[0])

    run_button.on_click(start)

    async def list_sessions() -> dict[str, str] | None:
        """Offer every readable session (with what has been done to it) in the selects."""
        try:
            found = await run.io_bound(state.catalog.scan)
        except Exception as exc:  # a vanished folder, a permission problem, a bug
            notify_exception("Cannot list the sessions", exc)
            return None
        if found is None:  # the server is stopping (nicegui's io_bound gives None then)
            return None
        usable = [s for s in found if not s.error]
        summaries.update({s.path: s for s in usable})
        options = {s.path: f"{s.path}  (+{s.added_mass_kg:g} kg; "
                           f"{', '.join(s.processed) or 'not processed'})" for s in usable}
        sel.set_options(options, value=sel.value if sel.value in options else None)
        seconds = {NO_SECOND: "(none: one drive)", **options}
        second.set_options(seconds, value=second.value if second.value in seconds else None)
        return options

    async def load() -> None:
        options = await list_sessions()
        if options is None:
            return
        usable = list(summaries.values())
        if session in options:
            # the pair this drive belongs to, by the one pairing rule (same vehicle and
            # corner, closest in time): a drive opened from its page keeps its partner
            pb, pa, dm, why = pair_of(session, usable)
            sel.value = pb or session
            if after in options:
                second.value = after
            elif pb and pa:
                second.value = pa
            if second.value and dm is not None:
                mass.value = round(dm, 3)
            pair_note.text = "" if second.value else (
                f"{session}: {why}; diagnosed alone, its parameters are per unit sprung mass")
        else:
            if after in options:
                second.value = after
            done = [s for s in usable if KIND in s.processed]
            if done:
                sel.value = done[0].path
        running = [j for j in state.jobs.jobs(KIND) if not j.finished]
        if running:
            watch(running[0], running[0].params.get("session", ""))

    ui.timer(0.0, load, once=True)


def _body_overview(state, rel: str):
    """The body-acceleration channel of a session, downsampled for the whole drive."""
    src = state.plots.get(state.resolve(rel))
    body = src.reader.channel_for_role("body")
    return src.trace("channel", body.name)
