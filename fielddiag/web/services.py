"""What the dashboard calls in the rest of fielddiag: one function per back-end operation.

Each operation names the function it calls and passes every argument explicitly, by
keyword: nothing is guessed by name and nothing is dropped. An argument an operation does
not take is refused with a ``TypeError`` naming it (Python's own, from the keyword-only
signatures below), and a mass given where it has no meaning with an
:class:`fielddiag.errors.InvalidValueError`.

The ``*_backend()`` functions tell a page whether a part of the pipeline can be loaded
here and give the operation to call; a part that cannot be imported (a missing optional
dependency, a broken installation) shows as a "not available" panel with the reason
instead of taking the page down. Nothing here computes anything.
"""

from __future__ import annotations

import importlib
import json
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from fielddiag.catalog import result_path
from fielddiag.errors import InvalidValueError, SessionError

__all__ = [
    "Backend",
    "diagnose_drives",
    "diagnosis_backend",
    "identification_backend",
    "identify_pair",
    "load_result",
    "observability_backend",
    "recorder_backend",
]


@dataclass(frozen=True)
class Backend:
    """A part of the pipeline: the operation (or class) to use, or why it is missing.

    Attributes
    ----------
    name : str
        Short name of the part (``identify``, ``diagnose``, ``recorder``,
        ``observability``).
    target : callable or None
        The operation to call (see the module's functions), None when unavailable.
    reason : str
        Why the part is unavailable ("" when it is available).
    """

    name: str
    target: Any = None
    reason: str = ""

    @property
    def available(self) -> bool:
        """True when :attr:`target` can be used."""
        return self.target is not None


def _backend(name: str, module: str, target: Callable[[], Any], what: str) -> Backend:
    """The part ``name`` if ``module`` imports, with ``target()`` as its operation."""
    try:
        importlib.import_module(module)
    except Exception as exc:  # a missing dependency must not take the dashboard down
        return Backend(name, reason=f"{what} cannot be loaded here ({module}: "
                                    f"{type(exc).__name__}: {exc})")
    return Backend(name, target=target())


# ---------------------------------------------------------------------- operations
def identify_pair(
    before_path: str | os.PathLike,
    after_path: str | os.PathLike,
    *,
    added_mass_kg: float | None,
    progress: Callable[[float, str], None] | None = None,
) -> Any:
    """Identify sprung mass, stiffness and damping from a before/after pair of drives.

    Calls :func:`fielddiag.identify.pipeline.identify_sessions`.

    Parameters
    ----------
    before_path, after_path : str or Path
        Session files of the drive as the car is and of the drive with the mass added.
    added_mass_kg : float or None
        Mass added on the body for the second drive [kg]; None: the difference of the
        sessions' recorded added masses.
    progress : callable or None
        ``progress(fraction, message)``, fraction 0..1.

    Returns
    -------
    fielddiag.identify.results.IdentificationResult
        Parameters with their standard deviations (``to_dict()`` for the JSON stored).

    Raises
    ------
    TypeError
        An argument this operation does not take (named in the message).
    FieldDiagError
        The pair cannot be identified (too short, swapped drives, a bad mass...).
    """
    from fielddiag.identify.pipeline import identify_sessions

    return identify_sessions(before_path, after_path, added_mass_kg=added_mass_kg,
                             progress=progress)


def diagnose_drives(
    paths: Sequence[str | os.PathLike],
    *,
    added_mass_kg: float | None = None,
    progress: Callable[[str], None] | None = None,
) -> Any:
    """Diagnose one drive, or a before/after pair: the physics the linear model misses.

    Calls :func:`fielddiag.diagnose.engine.diagnose_sessions`.

    Parameters
    ----------
    paths : sequence of str or Path
        One session file, or two (the drive as the car is, then with a mass added).
    added_mass_kg : float or None
        For a pair: mass added on the body for the second drive [kg]; None: the
        difference of the sessions' recorded added masses. Must be None for one drive.
    progress : callable or None
        ``progress(message)``: what the diagnosis is doing.

    Returns
    -------
    fielddiag.diagnose.engine.Diagnosis
        Verdict, findings and fit metrics (``to_dict()`` for the JSON stored).

    Raises
    ------
    TypeError
        An argument this operation does not take (named in the message).
    InvalidValueError
        Not one or two drives, or an added mass given with one drive.
    FieldDiagError
        A drive cannot be diagnosed (unreadable, too short, not a pair...).
    """
    from fielddiag.diagnose.engine import diagnose_sessions

    paths = list(paths)
    if len(paths) not in (1, 2):
        raise InvalidValueError(f"give one drive or a before/after pair, not {len(paths)} "
                                "sessions")
    if len(paths) == 1 and added_mass_kg is not None:
        raise InvalidValueError(
            f"added_mass_kg={added_mass_kg:g}: an added mass belongs to a pair of drives; "
            "give the second drive, or no mass for one drive")
    return diagnose_sessions(paths, added_mass_kg=added_mass_kg, progress=progress)


# ---------------------------------------------------------------------- availability
def identification_backend() -> Backend:
    """The before/after identification: :func:`identify_pair`, if it loads here.

    Returns
    -------
    Backend
        ``target`` is :func:`identify_pair`, or ``reason`` says why it is missing.
    """
    return _backend("identify", "fielddiag.identify.pipeline", lambda: identify_pair,
                    "Identification")


def diagnosis_backend() -> Backend:
    """The mismatch diagnosis: :func:`diagnose_drives`, if it loads here.

    Returns
    -------
    Backend
        ``target`` is :func:`diagnose_drives`, or ``reason`` says why it is missing.
    """
    return _backend("diagnose", "fielddiag.diagnose.engine", lambda: diagnose_drives,
                    "Diagnosis")


def recorder_backend() -> Backend:
    """Live recording: :class:`fielddiag.recorder.Recorder`, if it loads here.

    Returns
    -------
    Backend
        ``target`` is the Recorder class (the live page records through
        :class:`fielddiag.web.live_control.LiveRecording`), or ``reason``.
    """
    def recorder() -> Any:
        from fielddiag.recorder import Recorder

        return Recorder

    return _backend("recorder", "fielddiag.recorder", recorder, "Live recording")


def observability_backend() -> Backend:
    """The on-line estimator with its observability measure, if it loads here.

    Returns
    -------
    Backend
        ``target`` is :class:`fielddiag.identify.online.OnlineEstimator` (attached by the
        recorder, :meth:`fielddiag.recorder.Recorder.attach_online_estimator`), or
        ``reason``.
    """
    def estimator() -> Any:
        from fielddiag.identify.online import OnlineEstimator

        return OnlineEstimator

    return _backend("observability", "fielddiag.identify.online", estimator,
                    "The on-line observability meter")


# ---------------------------------------------------------------------- stored results
def load_result(session_path: str | Path, kind: str) -> dict[str, Any] | None:
    """The ``kind`` result stored beside a session (``<stem>.<kind>.json``), if any.

    Parameters
    ----------
    session_path : str or Path
        The session file.
    kind : str
        ``identify``, ``diagnose``, ``diagnose-single``...

    Returns
    -------
    dict or None
        The stored JSON, None when there is none.

    Raises
    ------
    SessionError
        The file exists but is not valid JSON.
    """
    for p in (result_path(session_path, kind), Path(f"{session_path}.{kind}.json")):
        if p.is_file():
            try:
                return json.loads(p.read_text(encoding="utf-8"))
            except (OSError, ValueError) as exc:
                raise SessionError(f"{p.name} cannot be read ({exc}); run the step again") from None
    return None
