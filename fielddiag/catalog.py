"""The sessions under a root folder, summarised for listing (the dashboard, the batch jobs).

A *root* is a folder holding session files (``*.h5``) at any depth, and beside each
session the results made from it, named ``<stem>.<kind>.json`` (``drive.identify.json``,
``drive.diagnose.json``...; ``drive.h5.<kind>.json`` is accepted too). :class:`Catalog`
scans the root and summarises every session from its header only (no samples are read),
caching each summary by the file's modification time and size, so a rescan of a large
root costs one ``stat`` per file.

Every path a user gives (a URL, a form) is a path *relative to the root*;
:func:`resolve_under_root` turns it into a file path and refuses anything that would land
outside the root (``..``, absolute paths, symlinks pointing out).
"""

from __future__ import annotations

import os
import threading
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path, PurePosixPath, PureWindowsPath
from typing import Any

from fielddiag.errors import FieldDiagError, SessionError

SESSION_SUFFIXES = (".h5", ".hdf5")
RESULT_SUFFIX = ".json"

__all__ = [
    "Catalog",
    "OutsideRootError",
    "SessionSummary",
    "filter_sessions",
    "relative_to_root",
    "resolve_under_root",
    "result_path",
    "sort_sessions",
]


class OutsideRootError(SessionError):
    """A path given relative to the root would reach outside it."""


def resolve_under_root(root: str | os.PathLike, relative: str) -> Path:
    """The file ``relative`` names under ``root``, refusing anything outside the root.

    Parameters
    ----------
    root : path
        The folder everything is served from.
    relative : str
        A path relative to ``root`` with ``/`` separators (from a URL or a form).

    Returns
    -------
    Path
        The resolved (symlink-free, absolute) path. It need not exist.

    Raises
    ------
    OutsideRootError
        ``relative`` is empty, absolute, holds a NUL byte, or resolves (through ``..`` or
        symlinks) to a place outside ``root``.
    """
    if not isinstance(relative, str) or not relative.strip():
        raise OutsideRootError("no path given; give a path relative to the sessions folder")
    if "\0" in relative:
        raise OutsideRootError("a path cannot contain a NUL character")
    rel_posix = PurePosixPath(relative.replace("\\", "/"))
    if rel_posix.is_absolute() or PureWindowsPath(relative).drive:
        raise OutsideRootError(
            f"{relative!r} is an absolute path; give a path relative to the sessions folder"
        )
    root_resolved = Path(root).resolve()
    candidate = (root_resolved / Path(*rel_posix.parts)).resolve()
    if candidate != root_resolved and not candidate.is_relative_to(root_resolved):
        raise OutsideRootError(f"{relative!r} is outside the sessions folder; access refused")
    return candidate


def relative_to_root(root: str | os.PathLike, path: str | os.PathLike) -> str:
    """``path`` relative to ``root`` with ``/`` separators (raises OutsideRootError)."""
    root_resolved = Path(root).resolve()
    p = Path(path).resolve()
    if not p.is_relative_to(root_resolved):
        raise OutsideRootError(f"{path} is outside the sessions folder {root_resolved}")
    return p.relative_to(root_resolved).as_posix()


def result_path(session_path: str | os.PathLike, kind: str) -> Path:
    """Where the ``kind`` result of a session is stored: ``<stem>.<kind>.json`` beside it."""
    p = Path(session_path)
    return p.with_name(f"{p.stem}.{kind}{RESULT_SUFFIX}")


@dataclass(frozen=True)
class SessionSummary:
    """One session as listed: what the header says, plus the results found beside it.

    Attributes
    ----------
    path : str
        Path relative to the root, ``/`` separated (the session's id in URLs).
    processed : dict
        Result kind (``identify``, ``diagnose``...) -> path of the result file relative
        to the root.
    error : str
        Empty for a readable session; otherwise why it could not be read (the session
        is still listed, so a broken file is visible).
    batch : dict
        What ``fielddiag reprocess`` recorded for the pair this session belongs to (empty
        when none): ``role`` (before/after), ``partner`` (the other session, relative to
        the root), ``status`` (done/failed), ``result`` (one line), ``message``, ``when``.
    """

    path: str
    name: str
    vehicle: str = ""
    corner: str = ""
    operator: str = ""
    created: str = ""
    notes: str = ""
    duration_s: float = 0.0
    added_mass_kg: float = 0.0
    sample_rate_hz: float = 0.0
    n_samples: int = 0
    channels: tuple[str, ...] = ()
    signals: tuple[str, ...] = ()
    n_events: int = 0
    n_gaps: int = 0
    samples_lost: int = 0
    closed_cleanly: bool = True
    size_bytes: int = 0
    modified_unix_s: float = 0.0
    processed: dict[str, str] = field(default_factory=dict)
    error: str = ""
    batch: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["channels"] = list(self.channels)
        d["signals"] = list(self.signals)
        return d


def _read_header(path: Path, rel: str, st: os.stat_result) -> SessionSummary:
    """Summary from the session header (no samples read). The file is read through
    :func:`fielddiag.session_guard.untrusted_info`: a truncated or damaged file is listed
    with its error, and one that would hang the reader is refused within a time limit."""
    from fielddiag.session_guard import untrusted_info

    base = {"path": rel, "name": path.name, "size_bytes": st.st_size,
            "modified_unix_s": st.st_mtime}
    try:
        info = untrusted_info(path)
        md = info["metadata"]
        return SessionSummary(
            **base,
            vehicle=str(md["vehicle"]),
            corner=str(md["corner"]),
            operator=str(md["operator"]),
            created=str(md["created"]),
            notes=str(md["notes"]),
            duration_s=float(info["duration_s"]),
            added_mass_kg=float(md["added_mass_kg"]),
            sample_rate_hz=float(info["sample_rate_hz"]),
            n_samples=int(info["samples"]),
            channels=tuple(c["name"] for c in info["channels"]),
            signals=tuple(sig["name"] for sig in info["signals"]),
            n_events=int(info["events"]),
            n_gaps=len(info["gaps"]),
            samples_lost=int(info["samples_lost"]),
            closed_cleanly=bool(info["closed_cleanly"]),
        )
    except SessionError as exc:
        return SessionSummary(**base, error=str(exc))
    except Exception as exc:  # a corrupt file must not hide the others
        return SessionSummary(**base, error=f"cannot read {path.name}: {exc}")


class Catalog:
    """The sessions under ``root``, summarised and cached by modification time.

    Parameters
    ----------
    root : path
        Folder to scan (recursively). Hidden files and folders (a leading ``.``, e.g. the
        partial files of an import in progress) are skipped, and so are symlinks that lead
        outside the root.

    Examples
    --------
    >>> cat = Catalog("recordings")
    >>> for s in cat.scan():
    ...     print(s.path, s.vehicle, s.duration_s, sorted(s.processed))
    """

    def __init__(self, root: str | os.PathLike) -> None:
        self.root = Path(root).resolve()
        if not self.root.is_dir():
            raise SessionError(f"sessions folder {self.root} does not exist or is not a folder")
        self._cache: dict[str, tuple[int, int, SessionSummary]] = {}
        self._batch_cache: tuple[Any, dict[str, dict[str, Any]]] | None = None
        self._lock = threading.Lock()

    def resolve(self, relative: str) -> Path:
        """The file ``relative`` names under the root (see :func:`resolve_under_root`)."""
        return resolve_under_root(self.root, relative)

    def _walk(self) -> Iterable[tuple[Path, list[str]]]:
        """(folder, file names) for every folder under the root, hidden ones skipped."""
        for dirpath, dirnames, filenames in os.walk(self.root, followlinks=False):
            dirnames[:] = sorted(d for d in dirnames if not d.startswith("."))
            yield Path(dirpath), sorted(f for f in filenames if not f.startswith("."))

    def scan(self) -> list[SessionSummary]:
        """Every session under the root, sorted by path."""
        found: list[SessionSummary] = []
        seen: set[str] = set()
        for folder, names in self._walk():
            results = [n for n in names if n.endswith(RESULT_SUFFIX)]
            for name in names:
                if not name.lower().endswith(SESSION_SUFFIXES):
                    continue
                path = folder / name
                try:
                    rel = relative_to_root(self.root, path)
                except OutsideRootError:
                    continue  # a symlink out of the root
                summary = self._summary_cached(path, rel)
                if summary is None:
                    continue
                seen.add(rel)
                processed = _results_for(name, results, folder, self.root)
                found.append(_with_processed(summary, processed))
        with self._lock:
            for key in set(self._cache) - seen:
                del self._cache[key]
        batch = self._batch_rows()
        if batch:
            found = [_with_batch(s, batch[s.path]) if s.path in batch else s for s in found]
        return found

    def _batch_rows(self) -> dict[str, dict[str, Any]]:
        """Session (relative to the root) -> its pair's row in the batch catalog, cached by
        the catalog file's modification time. A broken catalog is ignored (the list must
        still show)."""
        from fielddiag.batch.store import find_catalog
        from fielddiag.batch.summary import batch_entries

        path = find_catalog(self.root)
        if path is None:
            return {}
        stamp = tuple(_file_stamp(q) for q in (path, path.with_name(path.name + "-wal")))
        with self._lock:
            if self._batch_cache is not None and self._batch_cache[0] == (path, stamp):
                return self._batch_cache[1]
        try:
            entries = batch_entries(path, self.root)
        except FieldDiagError:
            entries = {}
        with self._lock:
            self._batch_cache = ((path, stamp), entries)
        return entries

    def summary(self, relative: str) -> SessionSummary:
        """The summary of one session given by its path relative to the root."""
        path = self.resolve(relative)
        if not path.is_file():
            raise SessionError(f"no session {relative!r} under {self.root}")
        rel = relative_to_root(self.root, path)
        summary = self._summary_cached(path, rel)
        if summary is None:
            raise SessionError(f"no session {relative!r} under {self.root}")
        names = sorted(os.listdir(path.parent))
        results = [n for n in names if n.endswith(RESULT_SUFFIX)]
        summary = _with_processed(summary, _results_for(path.name, results, path.parent,
                                                        self.root))
        batch = self._batch_rows().get(rel)
        return _with_batch(summary, batch) if batch else summary

    def _summary_cached(self, path: Path, rel: str) -> SessionSummary | None:
        try:
            st = path.stat()
        except OSError:
            return None
        with self._lock:
            hit = self._cache.get(rel)
        if hit is not None and hit[0] == st.st_mtime_ns and hit[1] == st.st_size:
            return hit[2]
        summary = _read_header(path, rel, st)
        with self._lock:
            self._cache[rel] = (st.st_mtime_ns, st.st_size, summary)
        return summary


def _results_for(
    session_name: str, result_names: Sequence[str], folder: Path, root: Path
) -> dict[str, str]:
    """Result files beside a session: ``<stem>.<kind>.json`` or ``<name>.<kind>.json``."""
    stem = session_name.rsplit(".", 1)[0]
    out: dict[str, str] = {}
    for prefix in (f"{session_name}.", f"{stem}."):
        for rn in result_names:
            if not rn.startswith(prefix):
                continue
            kind = rn[len(prefix) : -len(RESULT_SUFFIX)]
            if kind and "." not in kind and kind not in out:
                out[kind] = (folder / rn).relative_to(root).as_posix()
    return dict(sorted(out.items()))


def _file_stamp(path: Path) -> tuple[int, int]:
    """(modification time ns, size) of a file; (0, 0) when it does not exist."""
    try:
        st = path.stat()
    except OSError:
        return (0, 0)
    return (st.st_mtime_ns, st.st_size)


def _with_batch(summary: SessionSummary, batch: dict[str, Any]) -> SessionSummary:
    """The summary with its batch entry; the pair's results count as processed for both
    sessions of the pair."""
    processed = {**batch.get("results", {}), **summary.processed}
    return replace(summary, batch=batch, processed=dict(sorted(processed.items())))


def _with_processed(summary: SessionSummary, processed: dict[str, str]) -> SessionSummary:
    if processed == summary.processed:
        return summary
    d = asdict(summary)
    d["processed"] = processed
    d["channels"] = summary.channels
    d["signals"] = summary.signals
    return SessionSummary(**d)


_SEARCH_FIELDS = ("path", "vehicle", "corner", "operator", "created", "notes")


def filter_sessions(sessions: Sequence[SessionSummary], query: str) -> list[SessionSummary]:
    """Sessions matching every word of ``query`` (case-insensitive).

    A word matches the path, vehicle, corner, operator, creation date, notes, a channel or
    signal name, a processed kind (``identify``), or the batch result (``failed``,
    ``coulomb_friction``). An empty query keeps everything.
    """
    words = query.lower().split()
    if not words:
        return list(sessions)
    out = []
    for s in sessions:
        hay = " ".join(
            [*(str(getattr(s, f)) for f in _SEARCH_FIELDS), *s.channels, *s.signals, *s.processed,
             str(s.batch.get("result", "")), str(s.batch.get("status", ""))]
        ).lower()
        if all(w in hay for w in words):
            out.append(s)
    return out


def sort_sessions(
    sessions: Sequence[SessionSummary], key: str = "created", descending: bool = True
) -> list[SessionSummary]:
    """Sessions sorted by one summary field (``created``, ``duration_s``, ``vehicle``...)."""
    if key not in SessionSummary.__dataclass_fields__:
        raise SessionError(f"cannot sort sessions by {key!r}")

    def k(s: SessionSummary) -> Any:
        v = getattr(s, key)
        return len(v) if isinstance(v, tuple | dict) else v

    return sorted(sessions, key=k, reverse=descending)
