"""Open session files that may be damaged without ever hanging or crashing the caller.

HDF5 trusts the file it is given. A session cut short by an interrupted copy or a full
disk, or with a few bytes flipped, can make the library read garbage addresses; opened in
SWMR mode (which skips the library's own end-of-file check) a truncated file of a few kB
made h5py spin for 15 minutes and more. Two layers keep that away from the dashboard,
``reprocess`` and the CLI:

1. :func:`precheck` (pure Python, about 0.1 ms): the HDF5 signature (at offset 0, 512,
   1024, 2048...), the superblock version and its checksum, the end-of-file address the
   superblock stores against the real file size, and the root group's object header (its
   address inside the file, its signature and checksum). It catches truncation and most
   damage to the file's first bytes. :class:`fielddiag.session.SessionReader` runs it on
   every open.
2. :func:`open_untrusted`: the pre-check, then a first open of the file in a separate
   worker process with a time limit (:func:`probe`): the worker opens the session and
   reads everything a summary needs. A worker that does not answer in time is killed and
   the file is refused. The verdict is cached by (path, size, modification time, inode),
   so a good file is probed once per process and later opens cost one ``stat``.

Untrusted opens (the dashboard's session list and pages, ``reprocess`` discovery,
``fielddiag info``) go through :func:`open_untrusted`. A refused file raises
:class:`SessionCorruptError` (a :class:`~fielddiag.errors.SessionError`) with a one-line
message naming the file.
"""

from __future__ import annotations

import atexit
import contextlib
import json
import os
import select
import subprocess
import sys
import threading
import time
from collections import OrderedDict
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from fielddiag.errors import SessionError

__all__ = [
    "FileCheck",
    "SessionCorruptError",
    "clear_cache",
    "guarded_opens",
    "open_untrusted",
    "precheck",
    "probe",
    "stop_worker",
    "untrusted_info",
    "verify_untrusted",
]

HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"
#: Seconds a worker may take to open a session and read its header.
DEFAULT_TIMEOUT_S = float(os.environ.get("FIELDDIAG_OPEN_TIMEOUT_S", "10"))
_UNDEFINED = (1 << 64) - 1
_CACHE_MAX = 4096
_FLAG_WRITE = 0x01  # superblock v3 file consistency flags
_FLAG_SWMR_WRITE = 0x04


class SessionCorruptError(SessionError):
    """A session file is truncated, damaged, or could not be opened in time."""


def _incomplete(path: Path, detail: str) -> SessionCorruptError:
    return SessionCorruptError(f"{path} is not a complete fielddiag session ({detail}")


# ---------------------------------------------------------------------- lookup3
def _rot(x: int, k: int) -> int:
    return ((x << k) | (x >> (32 - k))) & 0xFFFFFFFF


def lookup3(data: bytes, initval: int = 0) -> int:
    """Bob Jenkins' lookup3 ``hashlittle``, the checksum HDF5 stores after its metadata.

    Parameters
    ----------
    data : bytes
        The checksummed bytes.
    initval : int
        Initial value (0 in HDF5).

    Returns
    -------
    int
        The 32-bit checksum.
    """
    m = 0xFFFFFFFF
    length = len(data)
    a = b = c = (0xDEADBEEF + length + initval) & m
    k = 0
    while length > 12:
        a = (a + int.from_bytes(data[k : k + 4], "little")) & m
        b = (b + int.from_bytes(data[k + 4 : k + 8], "little")) & m
        c = (c + int.from_bytes(data[k + 8 : k + 12], "little")) & m
        a = (a - c) & m; a ^= _rot(c, 4); c = (c + b) & m  # noqa: E702
        b = (b - a) & m; b ^= _rot(a, 6); a = (a + c) & m  # noqa: E702
        c = (c - b) & m; c ^= _rot(b, 8); b = (b + a) & m  # noqa: E702
        a = (a - c) & m; a ^= _rot(c, 16); c = (c + b) & m  # noqa: E702
        b = (b - a) & m; b ^= _rot(a, 19); a = (a + c) & m  # noqa: E702
        c = (c - b) & m; c ^= _rot(b, 4); b = (b + a) & m  # noqa: E702
        length -= 12
        k += 12
    if length == 0:
        return c
    tail = data[k : k + length] + bytes(12 - length)
    a = (a + int.from_bytes(tail[0:4], "little")) & m
    b = (b + int.from_bytes(tail[4:8], "little")) & m
    c = (c + int.from_bytes(tail[8:12], "little")) & m
    c ^= b; c = (c - _rot(b, 14)) & m  # noqa: E702
    a ^= c; a = (a - _rot(c, 11)) & m  # noqa: E702
    b ^= a; b = (b - _rot(a, 25)) & m  # noqa: E702
    c ^= b; c = (c - _rot(b, 16)) & m  # noqa: E702
    a ^= c; a = (a - _rot(c, 4)) & m  # noqa: E702
    b ^= a; b = (b - _rot(a, 14)) & m  # noqa: E702
    c ^= b; c = (c - _rot(b, 24)) & m  # noqa: E702
    return c


# ---------------------------------------------------------------------- pre-check
@dataclass(frozen=True)
class FileCheck:
    """What :func:`precheck` found in a file's superblock.

    Attributes
    ----------
    size_bytes : int
        The file's real size.
    superblock_offset : int
        Where the HDF5 signature is (0, or after a user block of 512, 1024... bytes).
    superblock_version : int
        0 to 3; fielddiag writes 3.
    end_of_file_bytes : int
        The size the file must have: base address + the end-of-file address stored in
        the superblock.
    writer_open : bool
        The superblock says a writer has the file open (it is being recorded now, or its
        writer was killed before closing it).
    """

    size_bytes: int
    superblock_offset: int
    superblock_version: int
    end_of_file_bytes: int
    writer_open: bool


def _find_signature(fh, size: int) -> int | None:
    offset = 0
    while offset + len(HDF5_SIGNATURE) <= size:
        fh.seek(offset)
        if fh.read(len(HDF5_SIGNATURE)) == HDF5_SIGNATURE:
            return offset
        offset = 512 if offset == 0 else offset * 2
    return None


def precheck(path: str | os.PathLike) -> FileCheck:
    """Check that a file is a whole HDF5 file before HDF5 opens it (no HDF5 call made).

    Parameters
    ----------
    path : path
        The session file.

    Returns
    -------
    FileCheck
        What the superblock says.

    Raises
    ------
    SessionError
        The file does not exist or is a folder.
    SessionCorruptError
        No HDF5 signature, a superblock that is cut short or fails its checksum, a file
        shorter than its superblock says (truncated), or a root group header that is
        missing or damaged.
    """
    p = Path(path)
    try:
        fh = open(p, "rb")  # noqa: SIM115 (closed below; a folder raises here)
    except FileNotFoundError:
        raise SessionError(f"{p} does not exist") from None
    except IsADirectoryError:
        raise SessionError(f"{p} is a folder, not a session file") from None
    except OSError as exc:
        raise SessionError(f"cannot read {p}: {exc.strerror or exc}") from None
    with fh:
        size = os.fstat(fh.fileno()).st_size
        sb_at = _find_signature(fh, size)
        if sb_at is None:
            raise SessionCorruptError(f"{p} is not a readable session file ({size} bytes, no "
                                      "HDF5 signature); is it an HDF5 file written by "
                                      "fielddiag?")
        fh.seek(sb_at)
        head = fh.read(256)
        return _check_superblock(p, fh, head, sb_at, size)


def _addr(buf: bytes, at: int, n: int) -> int:
    return int.from_bytes(buf[at : at + n], "little")


def _check_superblock(p: Path, fh, head: bytes, sb_at: int, size: int) -> FileCheck:
    if len(head) < 12:
        raise _incomplete(p, f"truncated at {size} bytes, inside the HDF5 superblock): copy "
                          "it again from the original")
    version = head[8]
    if version in (2, 3):
        n_off = head[9]
        if n_off not in (2, 4, 8) or head[10] not in (2, 4, 8):
            raise _incomplete(p, "damaged HDF5 superblock: bad address size): copy it again "
                              "from the original")
        flags = head[11]
        end = 12 + 4 * n_off
        if len(head) < end + 4:
            raise _incomplete(p, f"truncated at {size} bytes, inside the HDF5 superblock): "
                              "copy it again from the original")
        if lookup3(head[:end]) != _addr(head, end, 4):
            raise _incomplete(p, "damaged HDF5 superblock: checksum mismatch): copy it again "
                              "from the original")
        base, ext, eof, root = (_addr(head, 12 + i * n_off, n_off) for i in range(4))
        writer_open = bool(flags & (_FLAG_WRITE | _FLAG_SWMR_WRITE))
    elif version in (0, 1):
        n_off, n_len = head[13], head[14]
        if n_off not in (2, 4, 8) or n_len not in (2, 4, 8):
            raise _incomplete(p, "damaged HDF5 superblock: bad address size): copy it again "
                              "from the original")
        at = 24 if version == 0 else 28
        need = at + 4 * n_off + 2 * n_off + 24
        if len(head) < need:
            raise _incomplete(p, f"truncated at {size} bytes, inside the HDF5 superblock): "
                              "copy it again from the original")
        base, _free, eof, _drv = (_addr(head, at + i * n_off, n_off) for i in range(4))
        root = _addr(head, at + 5 * n_off, n_off)  # root symbol table entry: name, header
        ext = _UNDEFINED if n_off == 8 else (1 << (8 * n_off)) - 1
        writer_open = bool(_addr(head, 20, 4) & 0x1)
    else:
        raise _incomplete(p, f"unknown HDF5 superblock version {version}): is it an HDF5 "
                          "file written by fielddiag?")
    undefined = (1 << (8 * n_off)) - 1
    if eof == undefined or base == undefined:
        raise _incomplete(p, "damaged HDF5 superblock: no end-of-file address): copy it again "
                          "from the original")
    need_bytes = base + eof
    if need_bytes > size:
        what = ("its writer still has it open or was killed; wait for the recording to "
                "flush, or copy it again" if writer_open else "copy it again from the original")
        raise _incomplete(p, f"truncated at {size} of {need_bytes} bytes): {what}")
    if root == undefined or base + root >= need_bytes:
        raise _incomplete(p, "damaged HDF5 superblock: root group outside the file): copy it "
                          "again from the original")
    if ext != undefined and base + ext >= need_bytes:
        raise _incomplete(p, "damaged HDF5 superblock: extension outside the file): copy it "
                          "again from the original")
    if version >= 2:
        _check_object_header(p, fh, base + root, need_bytes)
    return FileCheck(size, sb_at, version, need_bytes, writer_open)


def _check_object_header(p: Path, fh, at: int, end: int) -> None:
    """The root group's version-2 object header: signature and chunk-0 checksum."""
    fh.seek(at)
    head = fh.read(32)
    if head[:4] != b"OHDR" or len(head) < 7 or head[4] != 2:
        if head[:1] == b"\x01":  # a version-1 object header has no checksum
            return
        raise _incomplete(p, "damaged root group header): copy it again from the original")
    flags = head[5]
    at_size = 6 + (16 if flags & 0x20 else 0) + (4 if flags & 0x10 else 0)
    n = 1 << (flags & 0x3)
    chunk0 = _addr(head, at_size, n)
    total = at_size + n + chunk0
    if at + total + 4 > end or chunk0 > 1 << 24:
        raise _incomplete(p, "damaged root group header: longer than the file): copy it again "
                          "from the original")
    fh.seek(at)
    body = fh.read(total + 4)
    if len(body) < total + 4 or lookup3(body[:total]) != _addr(body, total, 4):
        raise _incomplete(p, "damaged root group header: checksum mismatch): copy it again "
                          "from the original")


# ---------------------------------------------------------------------- SWMR reads
#: Metadata read attempts in SWMR read mode. HDF5 retries a metadata block whose checksum
#: fails (the writer may be half way through writing it), sleeping 1 ns, 2 ns, 4 ns...
#: between attempts; its default of 100 attempts makes a damaged file wait for ages (more
#: than 15 minutes were seen). 28 attempts retry for about 0.27 s in all, ample for a
#: writer's flush. ``FIELDDIAG_SWMR_READ_ATTEMPTS`` overrides it.
SWMR_READ_ATTEMPTS = int(os.environ.get("FIELDDIAG_SWMR_READ_ATTEMPTS", "28"))
_set_read_attempts = None


def _read_attempts_setter():
    """``H5Pset_metadata_read_attempts`` of the HDF5 library h5py uses (None if not found)."""
    global _set_read_attempts
    if _set_read_attempts is None:
        import ctypes

        fn = False
        try:
            with open("/proc/self/maps", encoding="utf-8") as maps:
                libs = {line.split()[-1] for line in maps if "/libhdf5" in line}
            for lib in sorted(libs):
                if os.path.basename(lib).startswith("libhdf5_"):
                    continue  # libhdf5_hl
                cand = getattr(ctypes.CDLL(lib), "H5Pset_metadata_read_attempts", None)
                if cand is not None:
                    cand.argtypes = [ctypes.c_int64, ctypes.c_uint]
                    cand.restype = ctypes.c_int
                    fn = cand
                    break
        except OSError:
            fn = False
        _set_read_attempts = fn
    return _set_read_attempts or None


def open_swmr_read(path: str | os.PathLike):
    """Open an HDF5 file in SWMR read mode with :data:`SWMR_READ_ATTEMPTS` metadata read
    attempts (``h5py.File(path, "r", libver="latest", swmr=True)`` otherwise).

    Returns
    -------
    h5py.File
    """
    import h5py

    fapl = h5py.h5p.create(h5py.h5p.FILE_ACCESS)
    fapl.set_libver_bounds(h5py.h5f.LIBVER_LATEST, h5py.h5f.LIBVER_LATEST)
    setter = _read_attempts_setter()
    if setter is None or setter(fapl.id, SWMR_READ_ATTEMPTS) < 0:
        return h5py.File(path, "r", libver="latest", swmr=True)
    fid = h5py.h5f.open(os.fsencode(path), h5py.h5f.ACC_RDONLY | h5py.h5f.ACC_SWMR_READ,
                        fapl=fapl)
    return h5py.File(fid)


# ---------------------------------------------------------------------- worker
def _touch(reader) -> dict:
    """Read everything a summary or ``fielddiag info`` needs (returned: the reader's
    ``info()``), the whole chunk index and the first and last samples of every dataset,
    so that a damaged index shows here and not later."""
    import h5py

    info = reader.info()
    f = reader._file
    datasets: list[h5py.Dataset] = []
    f.visititems(lambda _n, o: datasets.append(o) if isinstance(o, h5py.Dataset) else None)
    for ds in datasets:
        dict(ds.attrs)
        if ds.chunks is not None:
            ds.id.chunk_iter(lambda _info: None)  # the whole chunk index, no data
        if ds.shape and ds.shape[0]:
            ds[:1]
            ds[-1:]
        elif ds.shape == ():
            ds[()]
    return info


def _answer(path: str) -> dict:
    """The worker's verdict on one file."""
    from fielddiag.errors import FieldDiagError
    from fielddiag.session import SessionReader

    try:
        with SessionReader(path) as s:
            return {"ok": True, "info": _touch(s)}
    except FieldDiagError as exc:
        return {"ok": False, "error": str(exc)}
    except Exception as exc:  # noqa: BLE001 (any failure of a bad file is its verdict)
        return {"ok": False, "error": f"{path} is not a readable fielddiag session "
                f"({type(exc).__name__}: {exc}); copy it again from the original"}


def _serve(rfd: int, wfd: int, parent: int) -> None:  # pragma: no cover (in the worker)
    """The worker's loop: one JSON request per line in, one JSON answer per line out."""
    global _guarded_depth, _worker
    _guarded_depth = 0  # the worker opens files itself (a forked one inherits the switch)
    _worker = None

    def orphaned() -> None:  # the caller died while a read hangs here: go too
        while os.getppid() == parent:
            time.sleep(1.0)
        os._exit(0)

    threading.Thread(target=orphaned, daemon=True).start()
    os.write(wfd, b'{"ready": true}\n')
    with os.fdopen(rfd, "r", encoding="utf-8") as requests:
        for line in requests:
            answer = _answer(json.loads(line)["path"])
            os.write(wfd, (json.dumps(answer).replace("\n", " ") + "\n").encode())


def _worker_main() -> None:  # pragma: no cover (runs in the worker process)
    parent = int(sys.argv[1]) if len(sys.argv) > 1 else os.getppid()
    _serve(sys.stdin.fileno(), sys.stdout.fileno(), parent)


def _close_inherited_fds(keep: tuple[int, ...]) -> None:  # pragma: no cover (in the child)
    """In a forked worker: close every descriptor inherited from the parent except
    stdin/stdout/stderr and ``keep``, as ``subprocess`` does for a new interpreter.

    Above all the parent's sockets: a worker holding a copy of a server's connection keeps
    it open after the server has closed it (no FIN is sent while a copy is open), so a
    browser reuses that keep-alive connection for its next request and waits for an answer
    forever (the dashboard's page then stopped updating after a session page had forked
    the worker). A serial port or pty held by the worker would likewise never hang up.
    """
    low = 3
    for fd in sorted(set(keep)):
        if fd >= low:
            os.closerange(low, fd)
            low = fd + 1
    try:
        high = os.sysconf("SC_OPEN_MAX")
    except (AttributeError, ValueError, OSError):
        high = 65536
    os.closerange(low, max(high, low))


def _can_fork() -> bool:
    """Fork the worker (about 10 ms, h5py already loaded) from a process with one thread
    only, such as the CLI; with more threads (the dashboard) one of them could hold a lock
    the child would wait for forever, so the worker is a new interpreter there (~0.5 s,
    once). Nor is it forked while this process has an HDF5 file open."""
    if not hasattr(os, "fork") or threading.active_count() != 1:
        return False
    import h5py

    return h5py.h5f.get_obj_count(h5py.h5f.OBJ_ALL, h5py.h5f.OBJ_FILE) == 0


class _Worker:
    """One reader process, reused for every probe until it must be killed."""

    START_TIMEOUT_S = 60.0

    def __init__(self) -> None:
        self._buf = b""
        self._proc: subprocess.Popen | None = None
        self.exited = False
        if _can_fork():
            import fielddiag.session  # noqa: F401 (loaded once, before the fork)

            req_r, self.wfd = os.pipe()
            self.rfd, ans_w = os.pipe()
            parent = os.getpid()
            pid = os.fork()
            if pid == 0:  # pragma: no cover (the child)
                try:
                    _close_inherited_fds(keep=(req_r, ans_w))
                    _serve(req_r, ans_w, parent)
                finally:
                    os._exit(0)
            os.close(req_r)
            os.close(ans_w)
            self.pid = pid
        else:
            self._proc = subprocess.Popen(
                [sys.executable, "-m", "fielddiag.session_guard", str(os.getpid())],
                stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                close_fds=True,
            )
            self.pid = self._proc.pid
            self.wfd = self._proc.stdin.fileno()
            self.rfd = self._proc.stdout.fileno()
        if self._line(self.START_TIMEOUT_S) is None:
            self.kill()
            raise SessionError("the session reader process did not start; try again")

    def alive(self) -> bool:
        if self.exited:
            return False
        if self._proc is not None:
            self.exited = self._proc.poll() is not None
        else:
            self.exited = os.waitpid(self.pid, os.WNOHANG) != (0, 0)
        return not self.exited

    def _line(self, timeout_s: float) -> dict | None:
        """The next answer line, or None when none came in time (or the worker died)."""
        deadline = time.monotonic() + timeout_s
        while b"\n" not in self._buf:
            left = deadline - time.monotonic()
            if left <= 0:
                return None
            ready, _, _ = select.select([self.rfd], [], [], left)
            if not ready:
                return None
            chunk = os.read(self.rfd, 65536)
            if not chunk:
                return None
            self._buf += chunk
        line, self._buf = self._buf.split(b"\n", 1)
        return json.loads(line)

    def ask(self, path: str, timeout_s: float) -> dict | None:
        try:
            os.write(self.wfd, (json.dumps({"path": path}) + "\n").encode())
        except OSError:
            return None
        return self._line(timeout_s)

    def kill(self) -> None:
        if self.alive():
            try:
                os.kill(self.pid, 9)
            except ProcessLookupError:
                pass
        if self._proc is not None:
            self._proc.wait()
            for pipe in (self._proc.stdin, self._proc.stdout):
                try:
                    pipe.close()
                except OSError:
                    pass
        else:
            if not self.exited:
                os.waitpid(self.pid, 0)
            for fd in (self.wfd, self.rfd):
                try:
                    os.close(fd)
                except OSError:
                    pass
        self.exited = True


_worker: _Worker | None = None
_guarded_depth = 0
atexit.register(lambda: stop_worker())
_worker_lock = threading.Lock()
_cache: OrderedDict[tuple, str] = OrderedDict()
_cache_lock = threading.Lock()


def probe(path: str | os.PathLike, timeout_s: float | None = None) -> str:
    """Open a session in the worker process and read its header, with a time limit.

    Parameters
    ----------
    path : path
        The session file.
    timeout_s : float, optional
        Longest wait for the worker's answer (:data:`DEFAULT_TIMEOUT_S` by default). A
        worker that takes longer is killed (the next probe starts a new one).

    Returns
    -------
    str
        Empty when the file opened and read; otherwise the one-line reason.
    """
    return _probe(path, timeout_s)[0]


def _probe(path: str | os.PathLike, timeout_s: float | None) -> tuple[str, dict | None]:
    """(:func:`probe`'s verdict, the session's ``info()`` when it is good)."""
    global _worker
    timeout_s = DEFAULT_TIMEOUT_S if timeout_s is None else float(timeout_s)
    given = str(path)
    p = str(Path(path).absolute())
    with _worker_lock:
        t0 = time.monotonic()
        for _attempt in range(2):  # a worker that died since the last probe is replaced
            if _worker is None or not _worker.alive():
                if _worker is not None:
                    _worker.kill()
                _worker = _Worker()
            answer = _worker.ask(p, timeout_s)
            if answer is not None:
                if answer.get("ok"):
                    info = answer.get("info") or {}
                    info["path"] = given
                    return "", info
                return str(answer.get("error", "unreadable")).replace(p, given), None
            crashed = not _worker.alive()
            _worker.kill()
            _worker = None
            if not crashed:
                return (f"{given} is not a complete fielddiag session (it did not open within "
                        f"{timeout_s:g} s; the reader was stopped): copy it again from the "
                        "original"), None
            if time.monotonic() - t0 > timeout_s:
                break
        return (f"{given} is not a readable fielddiag session (the reader crashed on it): "
                "copy it again from the original"), None


def stop_worker() -> None:
    """Stop the worker process (a new one starts on the next probe)."""
    global _worker
    with _worker_lock:
        if _worker is not None:
            _worker.kill()
            _worker = None


def clear_cache() -> None:
    """Forget every verdict (files are probed again on their next open)."""
    with _cache_lock:
        _cache.clear()


def _key(path: Path) -> tuple:
    st = path.stat()
    return (str(path.absolute()), st.st_size, st.st_mtime_ns, st.st_ino)


def verify_untrusted(path: str | os.PathLike, timeout_s: float | None = None) -> None:
    """Refuse a session file that is truncated, damaged, or does not open in time.

    The :func:`precheck`, then a :func:`probe` in the worker; the verdict is cached by
    (path, size, modification time, inode), so a file already found good costs one
    ``stat``.

    Raises
    ------
    SessionError
        The file does not exist or is a folder.
    SessionCorruptError
        The file is not a complete, readable session (one line naming the file).
    """
    _verify(path, timeout_s)


def _verify(path: str | os.PathLike, timeout_s: float | None) -> dict | None:
    """:func:`verify_untrusted`; the session's ``info()`` when it was probed now."""
    p = Path(path)
    info = None
    try:
        key = _key(p)
    except FileNotFoundError:
        raise SessionError(f"{p} does not exist") from None
    except OSError as exc:
        raise SessionError(f"cannot read {p}: {exc.strerror or exc}") from None
    with _cache_lock:
        verdict = _cache.get(key)
        if verdict is not None:
            _cache.move_to_end(key)
    if verdict is None:
        try:
            precheck(p)
            verdict, info = _probe(p, timeout_s)
        except SessionCorruptError as exc:
            verdict = str(exc)
        with _cache_lock:
            _cache[key] = verdict
            while len(_cache) > _CACHE_MAX:
                _cache.popitem(last=False)
    if verdict:
        raise SessionCorruptError(verdict)
    return info


@contextlib.contextmanager
def guarded_opens() -> Iterator[None]:
    """Within this block every :class:`~fielddiag.session.SessionReader` of this process
    first calls :func:`verify_untrusted` (the CLI runs its commands so; cached, a file
    already found good costs one ``stat``)."""
    global _guarded_depth
    _guarded_depth += 1
    try:
        yield
    finally:
        _guarded_depth -= 1


def opens_guarded() -> bool:
    """True inside :func:`guarded_opens`."""
    return _guarded_depth > 0


def untrusted_info(path: str | os.PathLike, timeout_s: float | None = None) -> dict:
    """:meth:`fielddiag.session.SessionReader.info` of an untrusted file.

    A file not seen before is read by the worker (one open in all); one already found
    good is opened in this process.

    Raises
    ------
    SessionError, SessionCorruptError
        As :func:`verify_untrusted`.
    """
    from fielddiag.session import SessionReader

    info = _verify(path, timeout_s)
    if info is None:
        with SessionReader(path) as s:
            info = s.info()
    return info


def open_untrusted(path: str | os.PathLike, timeout_s: float | None = None):
    """:func:`verify_untrusted`, then open the session in this process.

    Returns
    -------
    fielddiag.session.SessionReader
    """
    from fielddiag.session import SessionReader

    verify_untrusted(path, timeout_s)
    return SessionReader(path)


if __name__ == "__main__":
    _worker_main()
