"""A pair of drives: the car as it is, and the same car with a known mass added to the body.

One rule everywhere: ``fielddiag identify`` and ``diagnose``, the dashboard's pages and
``fielddiag reprocess`` find a drive's partner and check a pair with the functions here.

* **Partner** (:func:`find_partner`): the same ``vehicle`` and ``corner`` (case and
  surrounding spaces ignored), on the other side of the added mass (a drive with
  ``added_mass_kg > 0`` is an *after* drive, one with ``0`` a *before* drive), recorded
  closest in time, and at most ``max_apart_h`` hours apart when both times are known.
* **Check** (:func:`check_pair`): what cannot be a pair is refused with one line saying
  what to do (the same file twice, a copy of one drive, before and after swapped,
  different vehicles or corners, no positive added mass); what may not be one is a
  warning the result carries (sample rates or channel units that differ, drives recorded
  far apart, a vehicle or corner not recorded, a given mass that differs from the
  sessions' own).
"""

from __future__ import annotations

import hashlib
import math
import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

from fielddiag.errors import FieldDiagError

__all__ = [
    "DriveHeader",
    "PairCheck",
    "PairError",
    "check_pair",
    "find_partner",
    "read_drive_header",
]

#: Longest time between a before and an after drive paired by metadata.
MAX_APART_H = 24.0
#: Sample rates that differ by more than this fraction are worth a warning (the spectra
#: are compared on a common frequency grid, so a tiny difference is harmless).
RATE_WARN_FRACTION = 0.01
#: Samples of the body channel hashed to recognise a copy of the same drive.
FINGERPRINT_SAMPLES = 4096


class PairError(FieldDiagError):
    """Two sessions that cannot be a before/after pair."""


def _norm(text: str) -> str:
    return str(text or "").strip().lower()


@dataclass(frozen=True)
class DriveHeader:
    """What pairing needs from a session, read without its samples (but a fingerprint).

    ``error`` is set (and the rest left empty) when the header cannot be read.
    """

    path: Path
    vehicle: str = ""
    corner: str = ""
    added_mass_kg: float = 0.0
    created: str = ""
    sample_rate_hz: float = 0.0
    n_samples: int = 0
    #: unit of each channel with a role, e.g. ``{"wheel": "m/s^2", "body": "g"}``
    role_units: tuple[tuple[str, str], ...] = ()
    #: hash of the first samples of the body channel ("" when not computed)
    fingerprint: str = ""
    error: str = ""

    @property
    def created_unix_s(self) -> float | None:
        """``created`` as seconds since 1970 (None when missing or not ISO 8601)."""
        if not self.created:
            return None
        try:
            dt = datetime.fromisoformat(self.created.replace("Z", "+00:00"))
        except ValueError:
            return None
        if dt.tzinfo is None:
            dt = dt.replace(tzinfo=UTC)
        return dt.timestamp()

    @property
    def is_after(self) -> bool:
        """A drive with mass added on the body."""
        return self.added_mass_kg > 0

    @property
    def group(self) -> tuple[str, str]:
        """(vehicle, corner) as compared when pairing."""
        return _norm(self.vehicle), _norm(self.corner)


def read_drive_header(path: str | os.PathLike, *, fingerprint: bool = True) -> DriveHeader:
    """The pairing fields of a session (its metadata, rate, channel units, fingerprint).

    Parameters
    ----------
    path : str or PathLike
        The session file.
    fingerprint : bool
        Also hash the first :data:`FINGERPRINT_SAMPLES` samples of the body channel, to
        recognise a copy of the same drive under another name (reads about 32 kB).

    Returns
    -------
    DriveHeader

    Raises
    ------
    FieldDiagError
        The file is not a readable session.
    """
    from fielddiag.session import SessionReader

    path = Path(path)
    with SessionReader(path) as s:
        md = s.metadata
        units = tuple(sorted((c.role, c.unit) for c in s.channels if c.role))
        digest = ""
        if fingerprint:
            body = s.channels_for_role("body")
            n = s.n_samples
            if len(body) == 1 and n:
                raw = s.read_raw(body[0].name, 0, min(n, FINGERPRINT_SAMPLES))
                digest = hashlib.sha1(raw.tobytes()).hexdigest() + f":{n}"
        return DriveHeader(path, str(md.vehicle), str(md.corner), float(md.added_mass_kg),
                           str(md.created), float(s.sample_rate_hz), int(s.n_samples),
                           units, digest)


def _hours_apart(a: DriveHeader, b: DriveHeader) -> float:
    """Hours between two recordings (inf when either time is unknown)."""
    ta, tb = a.created_unix_s, b.created_unix_s
    return abs(ta - tb) / 3600.0 if ta is not None and tb is not None else float("inf")


def find_partner(
    drive: DriveHeader,
    candidates: Iterable[DriveHeader],
    *,
    max_apart_h: float = MAX_APART_H,
) -> tuple[DriveHeader | None, str]:
    """The partner of ``drive`` among ``candidates`` by the pairing rule (module doc).

    Parameters
    ----------
    drive : DriveHeader
        A before or an after drive.
    candidates : iterable of DriveHeader
        Other sessions (``drive`` itself and unreadable ones are skipped).
    max_apart_h : float
        Longest time between the two recordings [h] when both times are known.

    Returns
    -------
    partner, reason : DriveHeader or None, str
        The partner, or None and why there is none (one sentence).
    """
    same = [c for c in candidates
            if not c.error and c.path != drive.path and c.group == drive.group
            and c.is_after != drive.is_after]
    what = "with" if not drive.is_after else "without"
    if not same:
        return None, (f"no drive {what} added mass for vehicle {drive.vehicle or '?'!r}, "
                      f"corner {drive.corner or '?'!r}")
    best = min(same, key=lambda c: (_hours_apart(drive, c), str(c.path)))
    apart_h = _hours_apart(drive, best)
    if apart_h == float("inf") and len(same) > 1:
        return None, (f"several drives {what} added mass and no recording times to choose "
                      "between them; pair them in a manifest")
    if apart_h != float("inf") and apart_h > max_apart_h:
        return None, (f"the closest drive {what} added mass ({best.path.name}) is more than "
                      f"{max_apart_h:g} h apart; pair them in a manifest if they belong "
                      "together")
    return best, ""


@dataclass(frozen=True)
class PairCheck:
    """A pair that passed :func:`check_pair`, with the mass to use and its warnings."""

    before: DriveHeader
    after: DriveHeader
    added_mass_kg: float
    warnings: tuple[str, ...] = ()


def _same_file(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return Path(a).resolve() == Path(b).resolve()


def check_pair(
    before: DriveHeader,
    after: DriveHeader,
    added_mass_kg: float | None = None,
    *,
    max_apart_h: float = MAX_APART_H,
) -> PairCheck:
    """Refuse two drives that cannot be a before/after pair; list what looks doubtful.

    Parameters
    ----------
    before, after : DriveHeader
        The drive as the car is and the drive with the added mass (from
        :func:`read_drive_header`).
    added_mass_kg : float or None
        Mass added on the body for ``after`` [kg]; None takes the difference of the
        sessions' own ``added_mass_kg``.
    max_apart_h : float
        Recordings further apart than this [h] get a warning.

    Returns
    -------
    PairCheck

    Raises
    ------
    PairError
        The same file twice, a copy of one drive, the drives swapped, different vehicles or
        corners recorded, or no positive finite added mass.
    """
    b, a = before, after
    if _same_file(b.path, a.path):
        raise PairError(f"{b.path.name} is given as both the before and the after drive (the "
                        "same file twice); give the drive as the car is, then the drive with "
                        "the added mass")
    if b.fingerprint and b.fingerprint == a.fingerprint:
        raise PairError(f"{b.path.name} and {a.path.name} hold the same recording (one is a "
                        "copy of the other); give the drive as the car is, then the drive "
                        "with the added mass")
    if b.added_mass_kg > a.added_mass_kg:
        raise PairError(
            f"the drives look swapped: {b.path.name} records {b.added_mass_kg:g} kg added and "
            f"{a.path.name} {a.added_mass_kg:g} kg; give the drive as the car is first: "
            f"{a.path.name} {b.path.name}")
    for what, vb, va in (("vehicle", b.vehicle, a.vehicle), ("corner", b.corner, a.corner)):
        if _norm(vb) and _norm(va) and _norm(vb) != _norm(va):
            raise PairError(
                f"{b.path.name} and {a.path.name} are of different {what}s ({vb!r} and "
                f"{va!r}); give two drives of the same car corner, the first as the car is "
                "and the second with the added mass")
    recorded_dm = a.added_mass_kg - b.added_mass_kg
    dm = recorded_dm if added_mass_kg is None else float(added_mass_kg)
    if not (math.isfinite(dm) and dm > 0):
        if added_mass_kg is None:
            raise PairError(
                f"{b.path.name} and {a.path.name} record no added mass (added_mass_kg "
                f"{b.added_mass_kg:g} and {a.added_mass_kg:g}); give it with --added-mass KG")
        raise PairError(f"--added-mass {added_mass_kg}: give the mass added on the body in kg, "
                        "a positive number")
    warnings: list[str] = []
    if added_mass_kg is not None and a.added_mass_kg and abs(recorded_dm - dm) > 1e-6:
        warnings.append(f"the sessions record an added mass of {recorded_dm:g} kg but {dm:g} kg "
                        "was given; the given value is used")
    missing = [w for w, vb, va in (("vehicle", b.vehicle, a.vehicle),
                                   ("corner", b.corner, a.corner))
               if not (_norm(vb) and _norm(va))]
    if missing:
        warnings.append(f"the {' and '.join(missing)} of one or both drives is not recorded, so "
                        "it cannot be checked that they are of the same car corner")
    if b.sample_rate_hz > 0 and a.sample_rate_hz > 0:
        frac = abs(a.sample_rate_hz - b.sample_rate_hz) / max(b.sample_rate_hz, a.sample_rate_hz)
        if frac > RATE_WARN_FRACTION:
            warnings.append(f"the drives were sampled at different rates ({b.sample_rate_hz:g} "
                            f"and {a.sample_rate_hz:g} Hz); they are compared on a common "
                            "frequency grid, but check the DAQ settings")
    ub, ua = dict(b.role_units), dict(a.role_units)
    differ = [r for r in ("wheel", "body") if r in ub and r in ua and ub[r] != ua[r]]
    if differ:
        warnings.append("the channel units differ between the drives ("
                        + ", ".join(f"{r}: {ub[r]} and {ua[r]}" for r in differ)
                        + "); both are converted to m/s^2, but check the DAQ settings")
    apart = _hours_apart(b, a)
    if apart != float("inf") and apart > max_apart_h:
        warnings.append(f"the drives were recorded {apart:.0f} h apart: the car may have "
                        "changed in between (tyre pressure, temperature, load)")
    return PairCheck(b, a, dm, tuple(warnings))


def check_pair_files(
    before_path: str | os.PathLike,
    after_path: str | os.PathLike,
    added_mass_kg: float | None = None,
) -> PairCheck:
    """:func:`check_pair` on two session files (reads their headers and fingerprints)."""
    return check_pair(read_drive_header(before_path), read_drive_header(after_path),
                      added_mass_kg)


def check_pair_before_work(
    before_path: str | os.PathLike,
    after_path: str | os.PathLike,
    added_mass_kg: float | None = None,
) -> None:
    """:func:`check_pair_files` as a command's first step, before it loads the numerics.

    Two drives that are no pair are refused in a fraction of a second instead of after
    seconds of imports. Sessions without a wheel and a body channel are left alone: the
    analysis says the missing channel first, as it always has.

    Raises
    ------
    PairError
        As :func:`check_pair_files`.
    """
    from fielddiag.session import SessionReader

    for path in (before_path, after_path):
        with SessionReader(path) as s:
            if not (s.channels_for_role("wheel") and s.channels_for_role("body")):
                return
    check_pair_files(before_path, after_path, added_mass_kg)


def header_of(summary: object) -> DriveHeader:
    """A :class:`DriveHeader` from anything listing a session (``path``, ``vehicle``,
    ``corner``, ``added_mass_kg``, ``created``; e.g. the dashboard's catalog entries)."""
    def get(name: str) -> object:
        return getattr(summary, name, None)

    return DriveHeader(Path(str(get("path"))), str(get("vehicle") or ""),
                       str(get("corner") or ""), float(get("added_mass_kg") or 0.0),
                       str(get("created") or ""),
                       float(getattr(summary, "sample_rate_hz", 0.0) or 0.0),
                       int(getattr(summary, "n_samples", 0) or 0),
                       error=str(getattr(summary, "error", "") or ""))


def pair_of(path: str, listed: Sequence[object]) -> tuple[str, str, float | None, str]:
    """The before/after pair a listed session belongs to, by the pairing rule.

    Parameters
    ----------
    path : str
        The session as listed (its ``path``).
    listed : sequence
        Every listed session (objects as :func:`header_of` takes; a ``batch`` dict with a
        ``partner`` recorded by ``fielddiag reprocess`` is honoured first).

    Returns
    -------
    before, after, added_mass_kg, reason : str, str, float or None, str
        The pair's paths ("" where none was found, with the reason) and the mass added.
    """
    by_path = {str(s.path): s for s in listed}  # type: ignore[attr-defined]
    me = by_path.get(path)
    if me is None:
        return "", "", None, f"{path} is not listed"
    own = header_of(me)
    batch = getattr(me, "batch", None) or {}
    partner = None
    if batch.get("partner") in by_path:
        partner = header_of(by_path[batch["partner"]])
        why = ""
    else:
        partner, why = find_partner(own, [header_of(s) for s in listed])
    if partner is None:
        return (path, "", None, why) if not own.is_after else ("", path, None, why)
    before, after = (partner, own) if own.is_after else (own, partner)
    dm = after.added_mass_kg - before.added_mass_kg
    return str(before.path), str(after.path), (dm if dm > 0 else None), ""
