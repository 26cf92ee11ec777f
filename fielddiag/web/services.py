"""What the dashboard needs from the rest of fielddiag, found at run time.

Parts of the pipeline land at different times (identification, diagnosis, the recorder);
the pages ask this module whether a part is there and show a clear "not available yet"
panel when it is not, instead of failing. Nothing here computes anything.
"""

from __future__ import annotations

import importlib
import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from fielddiag.catalog import result_path
from fielddiag.errors import SessionError

__all__ = [
    "Backend",
    "diagnosis_backend",
    "identification_backend",
    "load_result",
    "observability_backend",
    "recorder_backend",
]


@dataclass(frozen=True)
class Backend:
    """A part of the pipeline: the callable (or class) to use, or why it is missing."""

    name: str
    target: Any = None
    reason: str = ""

    @property
    def available(self) -> bool:
        return self.target is not None


def _find(name: str, module: str, candidates: tuple[str, ...], what: str) -> Backend:
    try:
        mod = importlib.import_module(module)
    except ModuleNotFoundError as exc:
        if exc.name and (module == exc.name or module.startswith(exc.name + ".")):
            return Backend(name, reason=f"{what} is not available yet ({module} does not exist)")
        return Backend(name, reason=f"{what} cannot be loaded: {exc}")
    except Exception as exc:  # a half-written module must not take the dashboard down
        return Backend(name, reason=f"{what} cannot be loaded: {type(exc).__name__}: {exc}")
    for attr in candidates:
        target = getattr(mod, attr, None)
        if target is not None and callable(target):
            return Backend(name, target=target)
    return Backend(
        name, reason=f"{what} is not available yet ({module} has none of {', '.join(candidates)})"
    )


def identification_backend() -> Backend:
    """The before/after identification pipeline (issue 4), if it exists."""
    return _find(
        "identify",
        "fielddiag.identify.pipeline",
        ("identify_pair", "identify_sessions", "run_pair", "identify", "run"),
        "Identification",
    )


def diagnosis_backend() -> Backend:
    """The mismatch diagnosis (issue 8), if it exists: ``diagnose_sessions(paths, *,
    added_mass_kg=None, progress=callable(message))`` returning an object with
    ``to_dict()``."""
    first = None
    for module in ("fielddiag.diagnose.pipeline", "fielddiag.diagnose.engine"):
        b = _find("diagnose", module, ("diagnose_sessions", "diagnose_session", "diagnose"),
                  "Diagnosis")
        if b.available:
            return b
        first = first or b
    return first


def recorder_backend() -> Backend:
    """The recorder (issue 3): a class ``Recorder`` with status/latest/add_event/stop."""
    b = _find("recorder", "fielddiag.recorder", ("Recorder",), "Live recording")
    if b.available:
        missing = [m for m in ("status", "latest", "add_event", "stop") if not hasattr(b.target, m)]
        if missing:
            return Backend(
                "recorder",
                reason=f"Live recording is not available yet (Recorder lacks {', '.join(missing)})",
            )
    return b


def observability_backend() -> Backend:
    """The on-line parameter estimator with its observability measure (issue 5), if any."""
    return _find(
        "observability",
        "fielddiag.identify.online",
        ("OnlineEstimator", "OnlineIdentifier", "ParameterKalmanFilter"),
        "The on-line observability meter",
    )


def load_result(session_path: str | Path, kind: str) -> dict[str, Any] | None:
    """The ``kind`` result stored beside a session (``<stem>.<kind>.json``), if any.

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


def call_with_supported(fn: Callable, /, *args: Any, **kwargs: Any) -> Any:
    """Call ``fn`` with only the keyword arguments its signature accepts."""
    import inspect

    try:
        params = inspect.signature(fn).parameters
    except (TypeError, ValueError):
        return fn(*args, **kwargs)
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
        return fn(*args, **kwargs)
    return fn(*args, **{k: v for k, v in kwargs.items() if k in params})
