"""Import a CSV recording by upload (size-limited) into the sessions folder."""

from __future__ import annotations

import re
import shutil
import tempfile
from collections.abc import Awaitable, Callable
from pathlib import Path

from nicegui import ui

from fielddiag.catalog import OutsideRootError, resolve_under_root
from fielddiag.channels import SessionMetadata
from fielddiag.errors import FieldDiagError
from fielddiag.io.csv_import import CsvImportOptions
from fielddiag.units import ACCEL_UNITS, SPEED_UNITS, TIME_UNITS
from fielddiag.validate import RANGES, number
from fielddiag.web.layout import notify_error

IMPORT_FOLDER = "imports"
_DEFAULTS = CsvImportOptions(roles={}, time_column="")
#: The units offered (the tables also hold spellings such as "m/s^2" that the CLI accepts).
_CHOICES = {"accel": ("m/s2", "g", "mg"), "time": tuple(TIME_UNITS), "speed": ("m/s", "km/h",
                                                                             "mph")}
assert set(_CHOICES["accel"]) <= set(ACCEL_UNITS) and set(_CHOICES["speed"]) <= set(SPEED_UNITS)
_SAFE_NAME = re.compile(r"[^A-Za-z0-9_.\-]+")


def csv_header(path: Path) -> list[str]:
    """Column names of a CSV file's header row (delimiter ``,``, ``;`` or tab)."""
    with open(path, encoding="utf-8-sig", errors="replace") as fh:
        line = fh.readline().strip()
    if not line:
        return []
    delim = max((",", ";", "\t"), key=line.count)
    return [c.strip() for c in line.split(delim) if c.strip()]


def safe_session_name(name: str) -> str:
    """A session file name made from an uploaded file's name (letters, digits, ``_-.``)."""
    stem = Path(name).stem or "import"
    stem = _SAFE_NAME.sub("_", stem).strip("._") or "import"
    return f"{stem[:80]}.h5"


def import_panel(state, on_imported: Callable[[], Awaitable[None] | None]) -> None:
    """An expandable panel: upload a CSV, map its columns, import it as a session."""
    limit = state.config.max_upload_bytes
    uploaded: dict[str, Path] = {}

    with ui.expansion("Import a CSV recording", icon="upload_file").classes(
        "w-full border rounded"
    ).mark("import-panel"):
        ui.label(
            f"One row per sample with a header row; at most {limit / 1e6:.0f} MB. "
            f"The session is written to {IMPORT_FOLDER}/ in the sessions folder."
        ).classes("text-sm text-gray-600")
        with ui.row().classes("w-full items-start gap-4"):
            upload = ui.upload(
                label="CSV file",
                auto_upload=True,
                max_file_size=limit,
            ).props('accept=".csv,.txt"').classes("w-72").mark("csv-upload")
            with ui.column().classes("gap-1") as form:
                with ui.row().classes("gap-2"):
                    time_col = ui.select([], label="time column").classes("w-40").mark(
                        "csv-time")
                    wheel_col = ui.select([], label="wheel (below)").classes("w-40").mark(
                        "csv-wheel")
                    body_col = ui.select([], label="body (above)").classes("w-40").mark(
                        "csv-body")
                    speed_col = ui.select([], label="speed (optional)", clearable=True).classes(
                        "w-40").mark("csv-speed")
                with ui.row().classes("gap-2"):
                    # the same units and defaults as `fielddiag import`
                    accel_unit = ui.select(list(_CHOICES["accel"]), value=_DEFAULTS.accel_unit,
                                           label="acceleration unit").classes("w-40")
                    time_unit = ui.select(list(_CHOICES["time"]), value=_DEFAULTS.time_unit,
                                          label="time unit").classes("w-28")
                    speed_unit = ui.select(list(_CHOICES["speed"]), value=_DEFAULTS.speed_unit,
                                           label="speed unit").classes("w-28")
                    vehicle = ui.input("vehicle").classes("w-40").mark("csv-vehicle")
                    corner = ui.input("corner").classes("w-32")
                    mass = ui.number("added mass [kg]", value=0, min=0,
                                     max=RANGES["session_added_mass"].hi).classes(
                                         "w-32").mark("csv-added-mass")
                import_button = ui.button("Import", icon="input").mark("csv-import")
            form.set_visibility(False)

    def rejected() -> None:
        notify_error(
            f"That file is larger than the upload limit of {limit / 1e6:.0f} MB; "
            "import it on the command line with `fielddiag import` instead."
        )

    def failed() -> None:
        notify_error("The upload failed (the server refused it; is it over the size limit?).")

    async def received(e) -> None:
        name = Path(e.file.name or "upload.csv").name
        if "tmpdir" not in uploaded:
            uploaded["tmpdir"] = Path(tempfile.mkdtemp(prefix="fielddiag-upload-"))
        dest = uploaded["tmpdir"] / safe_session_name(name).replace(".h5", ".csv")
        await e.file.save(dest)
        uploaded["path"] = dest
        uploaded["name"] = name
        cols = csv_header(dest)
        if len(cols) < 3:
            notify_error(f"{name}: the header row has {len(cols)} columns; a recording needs "
                         "a time column and two acceleration columns")
            form.set_visibility(False)
            return
        lower = [c.lower() for c in cols]

        def guess(*words: str) -> str | None:
            for w in words:
                for c, lc in zip(cols, lower, strict=True):
                    if w in lc:
                        return c
            return None

        for sel, value in ((time_col, guess("time", "t_s", "t")), (wheel_col, guess("wheel")),
                           (body_col, guess("body")), (speed_col, guess("speed"))):
            sel.set_options(cols, value=value)
        form.set_visibility(True)
        ui.notify(f"{name}: {len(cols)} columns; check the mapping and press Import")

    def do_import() -> None:
        from fielddiag.io.csv_import import import_csv

        src = uploaded.get("path")
        if src is None:
            notify_error("upload a CSV file first")
            return
        if not (time_col.value and wheel_col.value and body_col.value):
            notify_error("choose the time, wheel and body columns")
            return
        roles = {"wheel": wheel_col.value, "body": body_col.value}
        if speed_col.value:
            roles["speed"] = speed_col.value
        out_rel = f"{IMPORT_FOLDER}/{safe_session_name(uploaded['name'])}"
        try:
            out = resolve_under_root(state.config.root, out_rel)
        except OutsideRootError as exc:
            notify_error(str(exc))
            return
        out.parent.mkdir(exist_ok=True)
        if out.exists():
            notify_error(f"{out_rel} already exists; rename the file before uploading it")
            return
        opts = CsvImportOptions(roles=roles, time_column=time_col.value,
                                time_unit=time_unit.value, accel_unit=accel_unit.value,
                                speed_unit=speed_unit.value)
        try:
            added_mass_kg = number(0.0 if mass.value is None else mass.value, "added mass",
                                   "session_added_mass")
        except FieldDiagError as exc:
            notify_error(str(exc))
            return
        meta = SessionMetadata(vehicle=vehicle.value or "", corner=corner.value or "",
                               added_mass_kg=added_mass_kg,
                               notes=f"imported from {uploaded['name']} via the dashboard")
        job = state.jobs.submit("import", f"import {uploaded['name']}", import_csv, src, out,
                                opts, meta)
        import_button.props("loading")

        async def poll() -> None:
            if not job.finished:
                return
            timer.cancel()
            import_button.props(remove="loading")
            if job.state == "failed":
                notify_error(job.error)
                return
            ui.notify(f"imported {out_rel}", type="positive")
            form.set_visibility(False)
            upload.reset()
            result = on_imported()
            if result is not None:
                await result

        timer = ui.timer(0.2, poll)

    upload.on_upload(received)
    upload.on_rejected(rejected)
    upload.on("failed", failed)
    import_button.on_click(do_import)
    ui.context.client.on_delete(
        lambda: shutil.rmtree(uploaded["tmpdir"], ignore_errors=True)
        if "tmpdir" in uploaded else None
    )
