"""fielddiag: diagnose vehicle suspensions from field recordings."""

from importlib.metadata import PackageNotFoundError, version

from fielddiag.cachedir import configure_numba_cache

configure_numba_cache()  # before anything imports numba: never cache inside the package

try:
    __version__ = version("fielddiag")
except PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0.0.0+unknown"

from fielddiag.errors import FieldDiagError  # noqa: E402

__all__ = ["FieldDiagError", "__version__"]
