"""The batch catalog: one SQLite file recording every pair processed and how it went.

``fielddiag-catalog.sqlite`` lives in the folder the batch was run on (the common folder
of the sessions found). Session and result paths are stored relative to that folder, so
the folder can be moved or shared. Only the process that runs the batch writes it (the
workers return their outcomes to it); the dashboard reads it, in WAL mode, while a batch
may be writing.

Table ``pairs`` (one row per before/after pair): ``before``, ``after`` (relative paths),
``vehicle``, ``corner``, ``added_mass_kg``, ``status`` (done, failed), ``message`` (why
it failed), ``processed_utc``, ``wall_s``, ``worker``, and for each step
(``identify``, ``diagnose``): ``<step>_status``, ``<step>_message``, ``<step>_json``
(result file, relative),
``<step>_fingerprint``, ``<step>_summary`` (JSON: mass, stiffness, damping with standard
deviations; verdict, findings, warnings), ``<step>_detail`` (traceback of an unexpected
error).
"""

from __future__ import annotations

import json
import os
import sqlite3
from collections.abc import Iterator
from contextlib import closing
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from fielddiag.batch.task import STEPS, PairOutcome
from fielddiag.errors import FieldDiagError

CATALOG_NAME = "fielddiag-catalog.sqlite"
SCHEMA_VERSION = 1

__all__ = ["CATALOG_NAME", "BatchCatalog", "find_catalog"]

_STEP_COLUMNS = ("status", "message", "json", "fingerprint", "summary", "detail")
_COLUMNS = (
    "before", "after", "vehicle", "corner", "added_mass_kg", "status", "message",
    "processed_utc", "wall_s", "worker",
    *(f"{s}_{c}" for s in STEPS for c in _STEP_COLUMNS),
)


def find_catalog(root: str | os.PathLike) -> Path | None:
    """The batch catalog covering ``root``: in ``root`` or the nearest folder above it."""
    folder = Path(root).resolve()
    for candidate in (folder, *folder.parents):
        p = candidate / CATALOG_NAME
        if p.is_file():
            return p
    return None


class BatchCatalog:
    """Read and write the batch catalog at ``path`` (created on first write).

    Parameters
    ----------
    path : path
        The SQLite file; session paths are stored relative to its folder.
    readonly : bool
        Open for reading only (the dashboard); a missing file then raises.
    """

    def __init__(self, path: str | os.PathLike, *, readonly: bool = False) -> None:
        self.path = Path(path).resolve()
        self.folder = self.path.parent
        self.readonly = readonly
        if readonly and not self.path.is_file():
            raise FieldDiagError(f"no batch catalog at {self.path}")
        if not readonly:
            with closing(self._connect()) as db, db:
                db.execute("PRAGMA journal_mode=WAL")
                cols = ", ".join(f"{c} {'REAL' if c in ('added_mass_kg', 'wall_s') else 'TEXT'}"
                                 for c in _COLUMNS)
                db.execute(f"CREATE TABLE IF NOT EXISTS pairs ({cols}, "
                           "PRIMARY KEY (before, after))")
                db.execute("CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT)")
                db.execute("INSERT OR REPLACE INTO meta VALUES ('schema_version', ?)",
                           (str(SCHEMA_VERSION),))

    def _connect(self) -> sqlite3.Connection:
        try:
            if self.readonly:
                db = sqlite3.connect(f"{self.path.as_uri()}?mode=ro", uri=True, timeout=10)
            else:
                db = sqlite3.connect(self.path, timeout=30)
        except sqlite3.Error as exc:
            raise FieldDiagError(f"cannot open the batch catalog {self.path}: {exc}") from exc
        db.row_factory = sqlite3.Row
        return db

    def relative(self, path: str | os.PathLike) -> str:
        """``path`` relative to the catalog's folder (absolute if it lies outside)."""
        p = Path(path).resolve()
        return p.relative_to(self.folder).as_posix() if p.is_relative_to(self.folder) \
            else p.as_posix()

    def absolute(self, stored: str) -> Path:
        """The file a stored relative path names."""
        return (self.folder / stored).resolve()

    def record(self, outcome: PairOutcome) -> None:
        """Store a pair's outcome; steps not in it keep what the row held. The row's
        ``status`` and ``message`` sum up all its steps."""
        key = (self.relative(outcome.before), self.relative(outcome.after))
        with closing(self._connect()) as db, db:
            old = db.execute("SELECT * FROM pairs WHERE before=? AND after=?", key).fetchone()
            row: dict[str, Any] = dict(old) if old is not None else {}
            row.update(before=key[0], after=key[1], vehicle=outcome.vehicle,
                       corner=outcome.corner, added_mass_kg=outcome.added_mass_kg)
            for st in outcome.steps:
                row.update({
                    f"{st.step}_status": "done" if st.status == "skipped" else st.status,
                    f"{st.step}_message": st.message if st.status == "failed" else "",
                    f"{st.step}_json": self.relative(st.output) if st.output else "",
                    f"{st.step}_fingerprint": st.fingerprint,
                    f"{st.step}_summary": json.dumps(st.summary),
                    f"{st.step}_detail": st.detail,
                })
            if old is None or outcome.status != "skipped":
                row.update(processed_utc=datetime.now(UTC).isoformat(timespec="seconds"),
                           wall_s=outcome.wall_s, worker=outcome.worker)
            failed = [s for s in STEPS if row.get(f"{s}_status") == "failed"]
            row["status"] = "failed" if failed else "done"
            row["message"] = "; ".join(f"{s}: {row[f'{s}_message']}" for s in failed)
            names = [c for c in _COLUMNS if c in row]
            db.execute(f"INSERT OR REPLACE INTO pairs ({', '.join(names)}) "
                       f"VALUES ({', '.join('?' for _ in names)})", [row[n] for n in names])

    def done_steps(self) -> dict[tuple[str, str, str], tuple[str, dict[str, Any]]]:
        """(before, after, step) as absolute paths -> (fingerprint, summary) of every step
        that succeeded: what a plan needs to skip up-to-date work, in one read."""
        out = {}
        for r in self.rows():
            b, a = str(self.absolute(r["before"])), str(self.absolute(r["after"]))
            for s in STEPS:
                if r.get(f"{s}_status") == "done" and r.get(f"{s}_fingerprint"):
                    out[(b, a, s)] = (r[f"{s}_fingerprint"], r[f"{s}_summary"])
        return out

    def rows(self) -> list[dict[str, Any]]:
        """Every pair row as a dict (summaries decoded), sorted by before and after."""
        return list(self._iter_rows())

    def _iter_rows(self) -> Iterator[dict[str, Any]]:
        try:
            with closing(self._connect()) as db:
                cursor = db.execute("SELECT * FROM pairs ORDER BY before, after")
                for r in cursor:
                    d = dict(r)
                    for s in STEPS:
                        try:
                            d[f"{s}_summary"] = json.loads(d.get(f"{s}_summary") or "{}")
                        except ValueError:
                            d[f"{s}_summary"] = {}
                    yield d
        except sqlite3.Error as exc:
            raise FieldDiagError(f"cannot read the batch catalog {self.path}: {exc}") from exc
