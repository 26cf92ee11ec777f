"""Where fielddiag keeps caches: a per-user cache directory, never the installed package.

numba's ``cache=True`` writes compiled kernels beside the source by default, i.e. inside
``site-packages/fielddiag``. That breaks a read-only install and, worse, leaves a
``__pycache__`` tree that shadows a later editable install of the same package. Importing
:mod:`fielddiag` therefore points ``NUMBA_CACHE_DIR`` here before numba is imported
(a value the user set is kept).
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import platformdirs

__all__ = ["cache_dir", "configure_numba_cache", "writable"]


def writable(path: Path) -> bool:
    """Create ``path`` if needed and tell whether a file can be written in it."""
    try:
        path.mkdir(parents=True, exist_ok=True)
        probe = path / f".probe-{os.getpid()}"
        probe.write_text("")
        probe.unlink()
    except OSError:
        return False
    return True


def cache_dir(*parts: str) -> Path:
    """A writable per-user cache directory for fielddiag, with ``parts`` appended.

    ``FIELDDIAG_CACHE_DIR`` overrides the platform's user cache directory
    (``~/.cache/fielddiag`` on Linux). When neither is writable (a read-only home), a
    folder under the system's temporary directory is used instead.

    Parameters
    ----------
    *parts : str
        Sub-folders, e.g. ``cache_dir("numba")``.

    Returns
    -------
    Path
        The folder, created if needed.
    """
    base = os.environ.get("FIELDDIAG_CACHE_DIR") or platformdirs.user_cache_dir("fielddiag")
    path = Path(base).joinpath(*parts)
    if writable(path):
        return path
    fallback = Path(tempfile.gettempdir(), f"fielddiag-cache-{os.getuid()}").joinpath(*parts)
    fallback.mkdir(parents=True, exist_ok=True)
    return fallback


def configure_numba_cache() -> None:
    """Point numba's on-disk cache at :func:`cache_dir` unless ``NUMBA_CACHE_DIR`` is set.

    Must run before numba is first imported (``fielddiag/__init__.py`` calls it).
    """
    if not os.environ.get("NUMBA_CACHE_DIR"):
        os.environ["NUMBA_CACHE_DIR"] = str(cache_dir("numba"))
