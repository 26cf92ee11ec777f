"""Outputs written whole or not at all.

Every file the command line writes (JSON results, plots, exports, imported sessions) goes
through here: the target is checked before any work is done (its folder exists and can be
written, it is not a folder, a device node or a link to one, it is replaced only when
allowed), the data is written under a hidden temporary name in the target's folder, and
the temporary file is renamed over the target only when it is complete. On any failure
(a full disk included) the temporary file is removed, so no half-written file, 0-byte JSON
or empty plot folder is ever left behind, and an existing target is left as it was.
"""

from __future__ import annotations

import errno
import os
import re
import secrets
import shutil
import stat
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from fielddiag.errors import FieldDiagError, OutputError

__all__ = ["atomic_dir", "atomic_file", "check_folder", "check_target", "write_text"]

_WHAT_TO_DO = {
    errno.ENOSPC: "free some space or write elsewhere",
    errno.EDQUOT: "free some space or write elsewhere",
    errno.EROFS: "the file system is read-only; write elsewhere",
    errno.EACCES: "choose a folder you can write to",
    errno.EPERM: "choose a folder you can write to",
}


_H5_ERRNO = re.compile(r"errno = (\d+)")


def _errno_of(exc: BaseException) -> int | None:
    """The errno of an OSError, or the one HDF5 puts in its messages (h5py raises those
    as RuntimeError or OSError with the system error inside the text)."""
    if isinstance(exc, OSError) and exc.errno:
        return exc.errno
    m = _H5_ERRNO.search(str(exc))
    return int(m.group(1)) if m else None


def os_error(path: str | os.PathLike, exc: BaseException) -> OutputError:
    """A one-line :class:`OutputError` for a system error met while writing ``path``."""
    code = _errno_of(exc)
    if code is not None:
        why = os.strerror(code)
    else:
        why = getattr(exc, "strerror", None) or " ".join(str(exc).split())
    todo = _WHAT_TO_DO.get(code or 0, "choose another path")
    return OutputError(f"cannot write {path}: {why}; {todo}")


def _kind(mode: int) -> str:
    if stat.S_ISDIR(mode):
        return "a folder"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    if stat.S_ISFIFO(mode):
        return "a pipe"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "not a regular file"


def _probe(folder: Path, shown: str | os.PathLike) -> None:
    """Create and delete a hidden file in ``folder``: the only sure test that it is writable
    (as root, permission bits do not stop a write, but /proc or a read-only mount do)."""
    probe = folder / f".fielddiag-probe-{secrets.token_hex(4)}"
    try:
        fd = os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except OSError as exc:
        raise os_error(shown, exc) from None
    os.close(fd)
    probe.unlink(missing_ok=True)


#: Least free space to start work whose result goes to a file / a folder of plots (a
#: diagnosis' JSON is about 0.4 MB, its plots about 1.3 MB): below it the work would only
#: end in "No space left on device", seconds or minutes later.
MIN_FREE_FILE_BYTES = 1 << 20
MIN_FREE_FOLDER_BYTES = 4 << 20


def _check_free(folder: Path, shown: str | os.PathLike, need_bytes: int) -> None:
    """Refuse a folder whose file system has less than ``need_bytes`` free."""
    try:
        free = shutil.disk_usage(folder).free
    except OSError:
        return  # no answer (an exotic file system): the write itself will tell
    if free < need_bytes:
        raise OutputError(
            f"cannot write {shown}: No space left on device ({free / 1024:.0f} kB free, "
            f"at least {need_bytes / 2**20:.0f} MB needed); free some space or write "
            "elsewhere")


def check_target(
    path: str | os.PathLike, *, overwrite: bool, flag: str = "-o",
    need_bytes: int = MIN_FREE_FILE_BYTES,
) -> Path:
    """Check that ``path`` can be written, before any work is done.

    Parameters
    ----------
    path : path-like
        The file to write.
    overwrite : bool
        Whether an existing regular file may be replaced. Anything but a regular file (a
        folder, a device such as ``/dev/full``, a pipe, a link to one of those) is refused
        even then.
    flag : str
        The option that named it, for the message.
    need_bytes : int
        Least free space on its file system (default 1 MiB).

    Returns
    -------
    Path
        The file to replace: ``path``, or the regular file a symbolic link points to.

    Raises
    ------
    OutputError
        The target cannot or must not be written; the message says what to do.
    """
    p = Path(path)
    if str(path) == "" or p.name in ("", ".", ".."):
        raise OutputError(f"{flag} {str(path)!r}: give a file name to write")
    try:
        st = p.stat()  # follows links: a link to /dev/full is a device
    except FileNotFoundError:
        st = None
    except OSError as exc:
        raise os_error(p, exc) from None
    if st is not None:
        if not stat.S_ISREG(st.st_mode):
            raise OutputError(f"{p} is {_kind(st.st_mode)}; {flag} must name a regular file "
                              "(existing files are only replaced when they are regular files)")
        if not overwrite:
            raise OutputError(f"{p} already exists; choose another file name, or pass "
                              "--overwrite to replace it")
        p = p.resolve()
    parent = p.parent
    if not parent.is_dir():
        raise OutputError(f"folder {parent} of {p.name} does not exist; create it first")
    _probe(parent, p)
    _check_free(parent, p, need_bytes)
    return p


def check_folder(path: str | os.PathLike, flag: str = "--plots") -> Path:
    """Check that the folder ``path`` can be created (or exists) and written."""
    p = Path(path)
    try:
        st = p.stat()
    except FileNotFoundError:
        st = None
    except OSError as exc:
        raise os_error(p, exc) from None
    if st is not None and not stat.S_ISDIR(st.st_mode):
        kind = "a file" if stat.S_ISREG(st.st_mode) else _kind(st.st_mode)
        raise OutputError(f"{p} is {kind}; {flag} must name a folder")
    if st is None:
        parent = p.absolute().parent
        if not parent.is_dir():
            raise OutputError(f"folder {parent} does not exist; create it first, or give "
                              f"{flag} a folder inside an existing one")
        _probe(parent, p)
        _check_free(parent, p, MIN_FREE_FOLDER_BYTES)
    else:
        _probe(p, p)
        _check_free(p, p, MIN_FREE_FOLDER_BYTES)
    return p


def _temp_name(target: Path) -> Path:
    # the real suffix last: some writers (asammdf) choose the format by it
    return target.with_name(f".{target.stem}.tmp-{secrets.token_hex(4)}{target.suffix}")


@contextmanager
def atomic_file(
    path: str | os.PathLike, *, overwrite: bool = True, flag: str = "-o"
) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` (not yet created); on a clean exit it is
    renamed over ``path``, on any exception it (and anything named after it) is removed.

    Parameters
    ----------
    overwrite : bool
        Whether an existing regular file may be replaced (see :func:`check_target`).
    """
    target = check_target(path, overwrite=overwrite, flag=flag)
    tmp = _temp_name(target)
    try:
        yield tmp
        if not tmp.exists():
            raise OutputError(f"nothing was written to {path}")
        if not overwrite and target.exists():
            raise OutputError(f"{target} appeared while writing; not replacing it")
        os.replace(tmp, target)
    except OSError as exc:
        _remove(tmp)
        raise os_error(path, exc) from None
    except RuntimeError as exc:  # h5py: a system error reported inside the text
        _remove(tmp)
        if _errno_of(exc) is None:
            raise
        raise os_error(path, exc) from None
    except BaseException:
        _remove(tmp)
        raise


def _remove(tmp: Path) -> None:
    """Remove a temporary file and any sibling a writer made from its name (``.partial``)."""
    for p in [tmp, *tmp.parent.glob(f".{tmp.name}.*")]:
        try:
            if p.is_dir() and not p.is_symlink():
                shutil.rmtree(p, ignore_errors=True)
            else:
                p.unlink(missing_ok=True)
        except OSError:
            pass


def write_text(path: str | os.PathLike, text: str, *, overwrite: bool = True,
               flag: str = "--json") -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically; returns the path written."""
    with atomic_file(path, overwrite=overwrite, flag=flag) as tmp:
        with open(tmp, "w", encoding="utf-8") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
    return Path(path)


@contextmanager
def atomic_dir(path: str | os.PathLike, flag: str = "--plots") -> Iterator[Path]:
    """Yield a hidden temporary folder; on a clean exit its files are moved into ``path``
    (created if needed), replacing files of the same names; on any exception the temporary
    folder is removed and ``path`` is left as it was (not created if it did not exist)."""
    target = check_folder(path, flag)
    parent = target.absolute().parent if not target.is_dir() else target
    tmp = parent / f".{target.name or 'plots'}.tmp-{secrets.token_hex(4)}"
    created = False
    try:
        tmp.mkdir()
        yield tmp
        files = sorted(tmp.iterdir())
        if not target.exists():
            os.mkdir(target)
            created = True
        for f in files:
            dest = target / f.name
            if dest.exists() and not dest.is_file():
                raise FieldDiagError(f"{dest} is not a regular file; remove it or give "
                                     f"{flag} another folder")
            os.replace(f, dest)
    except OSError as exc:
        if created:
            shutil.rmtree(target, ignore_errors=True)
        raise os_error(path, exc) from None
    except BaseException:
        if created:
            shutil.rmtree(target, ignore_errors=True)
        raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def write_plots(writer, folder: str | os.PathLike, *args, flag: str = "--plots",
                **kwargs) -> list[Path]:
    """Run a plot writer (``writer(*args, tmp_folder, **kwargs)`` returning the paths it
    wrote) into a temporary folder and move its files into ``folder`` when all are written.

    Returns
    -------
    list of Path
        The plots, at their final places in ``folder``.
    """
    with atomic_dir(folder, flag=flag) as tmp:
        written = writer(*args, tmp, **kwargs)
    return [Path(folder) / Path(p).name for p in written]
