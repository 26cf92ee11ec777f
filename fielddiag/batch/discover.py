"""Find sessions and pair each drive with added mass with its drive as the car is.

Two ways to pair, as a technician would:

* **By metadata** (default): sessions of the same ``vehicle`` and ``corner``; a session
  with ``added_mass_kg > 0`` is an *after* drive and is paired with the *before* drive
  (``added_mass_kg == 0``) of that vehicle and corner recorded closest in time (``created``),
  if that is within ``max_apart_h`` hours. The added mass of the pair is the difference
  of the two sessions' ``added_mass_kg``.
* **By a manifest**: a CSV file (``fielddiag-manifest.csv`` in a folder given, or
  ``--manifest FILE``) with a header line and the columns ``before,after`` and optionally
  ``added_mass_kg``; paths are relative to the manifest's folder. Sessions a manifest
  names are paired only as it says.

Only headers are read here (no samples): pairing 1000 sessions takes a second or so.
A session whose header cannot be read is reported (it fails alone, with the reason) and
left out of the pairs.
"""

from __future__ import annotations

import csv
import glob
import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from fielddiag.errors import FieldDiagError
from fielddiag.pairs import MAX_APART_H, DriveHeader, find_partner
from fielddiag.validate import number

SESSION_SUFFIXES = (".h5", ".hdf5")
MANIFEST_NAME = "fielddiag-manifest.csv"

__all__ = [
    "MANIFEST_NAME",
    "Pair",
    "Pairing",
    "SessionHeader",
    "find_sessions",
    "pair_sessions",
    "read_headers",
    "read_manifest",
]


#: What pairing needs from a session's header (the one definition is in fielddiag.pairs).
SessionHeader = DriveHeader


@dataclass(frozen=True)
class Pair:
    """A drive before and a drive after adding ``added_mass_kg`` on the body."""

    before: Path
    after: Path
    added_mass_kg: float
    vehicle: str = ""
    corner: str = ""
    source: str = "metadata"  # or the manifest's path


@dataclass
class Pairing:
    """Result of :func:`pair_sessions`: the pairs, and the sessions left out and why."""

    pairs: list[Pair] = field(default_factory=list)
    unpaired: list[tuple[Path, str]] = field(default_factory=list)
    unreadable: list[tuple[Path, str]] = field(default_factory=list)


def _is_session(path: Path) -> bool:
    return path.suffix.lower() in SESSION_SUFFIXES and not path.name.startswith(".")


def find_sessions(inputs: Sequence[str | os.PathLike]) -> tuple[list[Path], list[Path]]:
    """Session files and manifests named by folders (searched recursively), files or globs.

    Returns
    -------
    sessions, manifests : lists of Path
        Absolute, de-duplicated, sorted. Hidden files and folders (``.name``, e.g. the
        partial file of an import in progress) are skipped.

    Raises
    ------
    FieldDiagError
        An input names nothing (a missing folder or file, a glob that matches nothing).
    """
    sessions: set[Path] = set()
    manifests: set[Path] = set()
    for item in inputs:
        text = os.fspath(item)
        if glob.has_magic(text):
            matches = [Path(m) for m in sorted(glob.glob(text, recursive=True))]
            if not matches:
                raise FieldDiagError(f"{text!r} matches no file")
        else:
            p = Path(text)
            if not p.exists():
                raise FieldDiagError(f"{text} does not exist; give folders, session files "
                                     "(.h5) or glob patterns")
            matches = [p]
        for m in matches:
            if m.is_dir():
                for dirpath, dirnames, filenames in os.walk(m):
                    dirnames[:] = [d for d in dirnames if not d.startswith(".")]
                    for name in filenames:
                        f = Path(dirpath) / name
                        if _is_session(f):
                            sessions.add(f.resolve())
                        elif name == MANIFEST_NAME:
                            manifests.add(f.resolve())
            elif m.name == MANIFEST_NAME or (m.suffix.lower() == ".csv"
                                             and not glob.has_magic(text)):
                manifests.add(m.resolve())
            elif _is_session(m):
                sessions.add(m.resolve())
    return sorted(sessions), sorted(manifests)


def read_headers(paths: Iterable[Path]) -> list[SessionHeader]:
    """The pairing fields of each session's header (unreadable files get ``error``).

    Files are read through :func:`fielddiag.session_guard.untrusted_info`, so a
    truncated or damaged file is refused (within a time limit) and the rest go on.
    """
    from fielddiag.errors import FieldDiagError
    from fielddiag.session_guard import untrusted_info

    out = []
    for p in paths:
        try:
            md = untrusted_info(p)["metadata"]
            out.append(SessionHeader(p, str(md["vehicle"]), str(md["corner"]),
                                     float(md["added_mass_kg"]), str(md["created"])))
        except FieldDiagError as exc:
            out.append(SessionHeader(p, error=f"cannot read the session header: {exc}"))
        except Exception as exc:  # a corrupt file fails alone, with its reason
            out.append(SessionHeader(p, error=f"cannot read the session header: {exc}"))
    return out


def read_manifest(path: str | os.PathLike) -> list[tuple[Path, Path, float | None]]:
    """``(before, after, added_mass_kg or None)`` rows of a manifest CSV.

    Raises
    ------
    FieldDiagError
        No ``before``/``after`` columns, an empty cell, or an ``added_mass_kg`` that is not
        a positive number; the message names the line.
    """
    path = Path(path)
    folder = path.resolve().parent
    try:
        with path.open(newline="", encoding="utf-8-sig") as fh:
            reader = csv.DictReader(fh)
            cols = {c.strip().lower(): c for c in (reader.fieldnames or [])}
            if "before" not in cols or "after" not in cols:
                raise FieldDiagError(
                    f"manifest {path}: needs a header line with the columns before,after "
                    "(and optionally added_mass_kg)")
            rows = []
            for line_no, row in enumerate(reader, start=2):
                b = (row.get(cols["before"]) or "").strip()
                a = (row.get(cols["after"]) or "").strip()
                if not b and not a:
                    continue
                if not b or not a:
                    raise FieldDiagError(f"manifest {path} line {line_no}: give both a "
                                         "before and an after session")
                mass: float | None = None
                raw = (row.get(cols.get("added_mass_kg", ""), "") or "").strip()
                if raw:
                    mass = number(raw, "added_mass_kg", "added_mass",
                                  source=f"manifest {path} line {line_no}")
                rows.append(((folder / b).resolve(), (folder / a).resolve(), mass))
            return rows
    except OSError as exc:
        raise FieldDiagError(f"cannot read manifest {path}: {exc.strerror or exc}") from exc
    except UnicodeDecodeError:
        raise FieldDiagError(f"manifest {path} is not UTF-8 text; save it as UTF-8 CSV with "
                             "the columns before,after[,added_mass_kg]") from None
    except csv.Error as exc:
        raise FieldDiagError(f"manifest {path} is not a readable CSV: {exc}") from exc


def pair_sessions(
    headers: Sequence[SessionHeader],
    manifests: Sequence[str | os.PathLike] = (),
    *,
    max_apart_h: float = MAX_APART_H,
) -> Pairing:
    """Pair before/after drives by manifest first, then by metadata (see module doc).

    Parameters
    ----------
    headers : sequence of SessionHeader
        From :func:`read_headers`.
    manifests : paths
        Manifest CSVs; a session they name is paired only as they say.
    max_apart_h : float
        Longest time between a before and an after drive paired by metadata.
    """
    result = Pairing()
    by_path = {h.path: h for h in headers}
    for h in headers:
        if h.error:
            result.unreadable.append((h.path, h.error))
    used: set[Path] = set()
    for m in manifests:
        for before, after, mass in read_manifest(m):
            missing = [p for p in (before, after) if p not in by_path and not p.is_file()]
            if missing:
                raise FieldDiagError(f"manifest {m} names {missing[0]}, which does not exist")
            hb, ha = by_path.get(before), by_path.get(after)
            used.update((before, after))
            if (hb and hb.error) or (ha and ha.error):
                continue  # reported as unreadable
            if mass is None:
                mass = (ha.added_mass_kg if ha else 0.0) - (hb.added_mass_kg if hb else 0.0)
                if not mass > 0:
                    raise FieldDiagError(
                        f"manifest {m}: no added_mass_kg for {after.name} and the sessions' "
                        "own added_mass_kg do not differ; add an added_mass_kg column")
            result.pairs.append(Pair(before, after, float(mass), ha.vehicle if ha else "",
                                     ha.corner if ha else "", source=str(m)))

    groups: dict[tuple[str, str], list[SessionHeader]] = {}
    for h in headers:
        if not h.error and h.path not in used:
            groups.setdefault((h.vehicle.strip().lower(), h.corner.strip().lower()),
                              []).append(h)
    for _group, members in sorted(groups.items()):
        paired_befores: set[Path] = set()
        for a in (h for h in members if h.is_after):
            best, why = find_partner(a, members, max_apart_h=max_apart_h)
            if best is None:
                result.unpaired.append((a.path, why))
                continue
            paired_befores.add(best.path)
            result.pairs.append(Pair(best.path, a.path, a.added_mass_kg - best.added_mass_kg,
                                     a.vehicle, a.corner))
        for b in members:
            if not b.is_after and b.path not in paired_befores:
                result.unpaired.append((b.path, "no drive with added mass to pair it with"))
    result.pairs.sort(key=lambda p: (str(p.before), str(p.after)))
    result.unpaired.sort()
    return result
