"""Identification page: a before/after pair and the added mass -> mass, stiffness, damping.

The work runs in the background (:class:`fielddiag.web.jobs.JobRunner`) with a progress
bar; the result is stored beside the *before* session as ``<stem>.identify.json`` (which
also marks the session processed in the list) and drawn: transmissibility before/after
with coherence, the restoring-force surface, the parameter table with standard
deviations.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from nicegui import run, ui

from fielddiag.catalog import result_path
from fielddiag.errors import FieldDiagError
from fielddiag.pairs import pair_of
from fielddiag.validate import number
from fielddiag.web.layout import not_available, notify_error, notify_exception, page_title
from fielddiag.web.results_view import render_identification
from fielddiag.web.services import identification_backend, load_result

KIND = "identify"


def _jsonable(o: Any) -> Any:
    if hasattr(o, "tolist"):
        return o.tolist()
    if hasattr(o, "to_dict"):
        return o.to_dict()
    return str(o)


def write_result(path: Path, result: dict[str, Any]) -> None:
    """Write a result JSON atomically (a temporary file renamed into place)."""
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    tmp.write_text(json.dumps(result, indent=1, default=_jsonable), encoding="utf-8")
    os.replace(tmp, path)


def run_identification(
    target, before: Path, after: Path, added_mass_kg: float, out: Path, progress=None
) -> dict[str, Any]:
    """Call the pipeline on a pair, store its result as JSON at ``out``, return the dict.

    Parameters
    ----------
    target : callable
        :func:`fielddiag.web.services.identify_pair` (or a stand-in with its signature).
    before, after : Path
        Session files of the pair.
    added_mass_kg : float
        Mass added for the second drive [kg].
    out : Path
        Where the result JSON goes.
    progress : callable or None
        ``progress(fraction, message)``.

    Returns
    -------
    dict
        The result as stored (``added_mass_kg`` included).

    Raises
    ------
    FieldDiagError
        The pair cannot be identified (the pipeline's message).
    """
    if progress is not None:
        progress(0.0, "identifying (spectra, noise floors, band, both routes, jackknife)")
    result = target(before, after, added_mass_kg=added_mass_kg, progress=progress)
    if progress is not None:
        progress(0.95, "writing the result")
    d = result.to_dict() if hasattr(result, "to_dict") else dict(result)
    d.setdefault("added_mass_kg", added_mass_kg)
    write_result(out, d)
    return d


def render(state, before: str = "", after: str = "") -> None:
    """Build the identification page (``before``/``after``: session paths to preselect)."""
    page_title("Identification",
               "a drive before and after adding a known mass to the body -> sprung mass, "
               "stiffness and damping with their standard deviations")
    backend = identification_backend()
    if not backend.available:
        not_available(
            "Identification", backend.reason,
            "Results already stored beside a session (<session>.identify.json) are shown "
            "below when you pick it.",
        )

    with ui.card().classes("w-full"):
        with ui.row().classes("w-full items-end gap-3"):
            before_sel = ui.select({}, label="before (as the car is)", with_input=True).classes(
                "w-80").mark("before")
            after_sel = ui.select({}, label="after (mass added)", with_input=True).classes(
                "w-80").mark("after")
            mass = ui.number("added mass [kg]", value=None, min=0.0, step=0.5,
                             format="%.1f").classes("w-40").mark("added-mass")
            run_button = ui.button("Run identification", icon="play_arrow").mark("run-identify")
            if not backend.available:
                run_button.disable()
        progress = ui.linear_progress(value=0.0, show_value=False).classes("w-full").mark(
            "identify-progress")
        progress_label = ui.label("").classes("text-sm text-gray-600").mark("identify-status")
        pair_note = ui.label("").classes("text-sm text-amber-800").mark("pair-note")
        progress.set_visibility(False)

    results = ui.column().classes("w-full").mark("identify-results")
    summaries: dict[str, Any] = {}

    async def show_stored(rel: str | None) -> None:
        results.clear()
        if not rel:
            return
        try:
            stored = await run.io_bound(load_result, state.resolve(rel), KIND)
        except Exception as exc:  # a broken result file, or a bug (shown with its type)
            notify_exception(f"Cannot show the stored result of {rel}", exc)
            return
        with results:
            if stored is None:
                ui.label(f"{rel} has no identification result yet.").classes("text-gray-600")
                return
            ui.label(f"Stored result of {rel}").classes("text-sm text-gray-600")
            render_identification(stored)

    def fill_mass() -> None:
        b, a = summaries.get(before_sel.value), summaries.get(after_sel.value)
        if b is not None and a is not None:
            mass.value = round(max(0.0, a.added_mass_kg - b.added_mass_kg), 3)

    async def on_before(_e) -> None:
        fill_mass()
        await show_stored(before_sel.value)

    before_sel.on_value_change(on_before)
    after_sel.on_value_change(lambda _e: fill_mass())

    def watch(job) -> None:
        progress.set_visibility(True)
        run_button.disable()

        def poll() -> None:
            progress.value = job.progress.fraction
            # a pipeline without step-by-step progress: a moving bar and the elapsed time
            if job.progress.fraction <= 0.0 and not job.finished:
                progress.props("indeterminate")
            else:
                progress.props(remove="indeterminate")
            progress_label.text = f"{job.title}: {job.progress.message} ({job.elapsed_s:.0f} s)"
            if not job.finished:
                return
            timer.cancel()
            if backend.available:
                run_button.enable()
            progress.set_visibility(False)
            if job.state == "failed":
                progress_label.text = f"{job.title} failed: {job.error}"
                notify_error(f"Identification failed: {job.error}")
                return
            progress_label.text = f"{job.title}: done in {job.elapsed_s:.1f} s"
            ui.notify("identification done", type="positive")
            results.clear()
            with results:
                render_identification(job.result)

        timer = ui.timer(0.2, poll)

    def start() -> None:
        b, a = before_sel.value, after_sel.value
        if not b or not a:
            notify_error("Pick a 'before' and an 'after' session.")
            return
        if b == a:
            notify_error("'before' and 'after' must be two different sessions.")
            return
        try:
            added_mass_kg = number("" if mass.value is None else mass.value, "added mass",
                                   "added_mass")
        except FieldDiagError as exc:
            notify_error(f"{exc}.")
            return
        try:
            bp, ap = state.resolve(b), state.resolve(a)
        except FieldDiagError as exc:
            notify_error(str(exc))
            return
        job = state.jobs.submit(
            KIND, f"identify {b} / {a}", run_identification, backend.target, bp, ap,
            added_mass_kg, result_path(bp, KIND),
        )
        watch(job)

    run_button.on_click(start)

    async def load() -> None:
        try:
            found = await run.io_bound(state.catalog.scan)
        except Exception as exc:  # a vanished folder, a permission problem, a bug
            notify_exception("Cannot list the sessions", exc)
            return
        if found is None:  # the server is stopping (nicegui's io_bound gives None then)
            return
        usable = [s for s in found if not s.error]
        summaries.update({s.path: s for s in usable})
        options = {s.path: f"{s.path}  ({s.vehicle or '?'}, +{s.added_mass_kg:g} kg)"
                   for s in usable}
        before_sel.set_options(options)
        after_sel.set_options(options)
        # the pair the asked-for session belongs to (or the first before drive that has a
        # partner), by the one pairing rule: same vehicle and corner, closest in time
        start = before if before in options else after if after in options else next(
            (s.path for s in usable if s.added_mass_kg == 0 and pair_of(s.path, usable)[1]),
            None)
        if start:
            pb, pa, dm, why = pair_of(start, usable)
            before_sel.value = pb or None
            after_sel.value = after if after in options else (pa or None)
            if dm is not None:
                mass.value = round(dm, 3)
            pair_note.text = f"{start}: {why}" if why else ""
        running = [j for j in state.jobs.jobs(KIND) if not j.finished]
        if running:
            watch(running[0])
        if not usable:
            with results:
                ui.label("No sessions yet.").classes("text-gray-600")
                ui.link("Sessions", "/")

    ui.timer(0.0, load, once=True)
