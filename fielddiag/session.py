"""The HDF5 session format: a crash-safe appending writer and a lazy reader.

One HDF5 file holds one recording. The layout is documented in docs/session-format.md.

The writer opens the file in HDF5's single-writer/multiple-reader (SWMR) mode. Appended
blocks are buffered in memory and a background thread writes and flushes them at least
every ``flush_interval_s`` (0.5 s by default), so a writer killed with SIGKILL leaves a
file that opens and holds everything received up to the last flush. The same property lets
the dashboard read a session while it is being recorded.

Examples
--------
>>> from fielddiag.channels import ChannelSpec, SessionMetadata
>>> with SessionWriter("drive.h5", SessionMetadata(vehicle="demo"),
...                    [ChannelSpec("wheel_z", role="wheel"), ChannelSpec("body_z", role="body")],
...                    sample_rate_hz=500.0, time_base="uniform") as w:
...     w.append_daq(samples)                      # (n, 2) array in channel order
>>> with SessionReader("drive.h5") as s:
...     t, a_body = s.read_with_time(s.channel_for_role("body").name, start_s=10, end_s=20)
"""

from __future__ import annotations

import json
import os
import re
import threading
import time
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import fields
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from fielddiag.channels import (
    CHANNEL_ROLES,
    COUNTER_NAMES,
    ChannelSpec,
    Event,
    Gap,
    SessionMetadata,
    SignalSpec,
)
from fielddiag.errors import ChannelNotFoundError, SessionError

SCHEMA_VERSION = 1
FORMAT_NAME = "fielddiag-session"

_NAME_RE = re.compile(r"^[A-Za-z0-9_.\-]+$")
_CHUNK_SAMPLES = 16384
_LABEL_LEN = 128
_CAUSE_LEN = 64
CAN_DATA_BYTES = 64

#: Bits of the ``flags`` field of a stored CAN frame.
CAN_FLAG_EXTENDED = 1
CAN_FLAG_REMOTE = 2
CAN_FLAG_ERROR = 4
CAN_FLAG_FD = 8
CAN_FLAG_BRS = 16
CAN_FLAG_ESI = 32
CAN_FLAG_RX = 64

EVENT_DTYPE = np.dtype([("time_s", "<f8"), ("label", f"S{_LABEL_LEN}")])
GAP_DTYPE = np.dtype(
    [("start_s", "<f8"), ("end_s", "<f8"), ("samples_lost", "<i8"), ("cause", f"S{_CAUSE_LEN}")]
)
CAN_FRAME_DTYPE = np.dtype(
    [
        ("time_s", "<f8"),
        ("arbitration_id", "<u4"),
        ("bus", "u1"),
        ("flags", "u1"),
        ("dlc", "u1"),
        ("data", "u1", (CAN_DATA_BYTES,)),
    ]
)


def _utc_now_iso() -> str:
    return datetime.now(UTC).isoformat(timespec="milliseconds").replace("+00:00", "Z")


def _software_version() -> str:
    from fielddiag import __version__

    return __version__


def safe_name(text: str, default: str = "channel") -> str:
    """A valid channel or signal name made from any text (a CSV column, an MDF channel, a
    DBC signal): characters other than letters, digits, '_', '-' and '.' become '_'.

    Parameters
    ----------
    text : str
        Any text; surrounding blanks are dropped.
    default : str
        The name given to an empty text.

    Returns
    -------
    str

    Examples
    --------
    >>> safe_name("acc x [g]"), safe_name("  ")
    ('acc_x__g_', 'channel')
    """
    return re.sub(r"[^A-Za-z0-9_.\-]", "_", text.strip()) or default


def unique_name(text: str, taken: set[str], default: str = "channel") -> str:
    """:func:`safe_name` of ``text``, with ``_2``, ``_3``... until it is not in ``taken``.

    Parameters
    ----------
    text : str
        Any text.
    taken : set of str
        Names already used; the name returned is added to it.
    default : str
        The name given to an empty text.

    Returns
    -------
    str

    Examples
    --------
    >>> taken = {"speed"}
    >>> unique_name("speed", taken), unique_name("speed", taken)
    ('speed_2', 'speed_3')
    """
    base = safe_name(text, default)
    name, k = base, 2
    while name in taken:
        name, k = f"{base}_{k}", k + 1
    taken.add(name)
    return name


def _check_name(kind: str, name: str) -> None:
    if not _NAME_RE.match(name):
        raise SessionError(
            f"{kind} name {name!r} is not allowed: use letters, digits, '_', '-' or '.'"
        )


def _encode(text: str, length: int) -> bytes:
    raw = text.encode("utf-8")
    return raw[:length]


def _dtype_name(dtype: np.dtype) -> str:
    """'int16' for native/little-endian types (what users write), '>i2' otherwise."""
    return dtype.name if dtype.byteorder in ("=", "|", "<") else dtype.str


def _decode(raw: bytes) -> str:
    return raw.decode("utf-8", errors="replace")


class DiskFullError(OSError):
    """Raised before a write the disk has no room for (nothing was written)."""


class SessionWriter:
    """Append blocks of a recording to a new session file, durably.

    Parameters
    ----------
    path : str or Path
        File to create.
    metadata : SessionMetadata
        Root attributes. ``created`` and ``software_version`` are filled in if empty.
    channels : sequence of ChannelSpec
        DAQ channels, in the column order of :meth:`append_daq` arrays.
    sample_rate_hz : float
        Nominal DAQ sample rate.
    time_base : {"timestamps", "uniform"}
        ``timestamps``: every sample has a time stamp (device time mapped to session
        time), given to :meth:`append_daq`. ``uniform``: time is ``t0_s + i / sample_rate_hz``.
    t0_s : float
        Time of the first sample for the uniform time base.
    signals : sequence of SignalSpec
        Vehicle signals (CAN, GNSS, ...) with their own time stamps.
    store_can_frames : bool
        Keep every raw CAN frame so the session can be decoded again with another DBC.
    overwrite : bool
        Replace an existing file. Without it an existing file is never touched.
    atomic : bool
        Write to a hidden temporary file beside ``path`` and move it into place on a
        clean :meth:`close`; :meth:`abort` (or an exception inside ``with``) deletes it.
        Use for imports and exports, where a partial file is worse than none. Recordings
        use ``atomic=False`` so that a crash keeps what was received.
    flush_interval_s : float
        Longest time appended data waits in memory before it is written and flushed.
    """

    def __init__(
        self,
        path: str | os.PathLike,
        metadata: SessionMetadata,
        channels: Sequence[ChannelSpec],
        *,
        sample_rate_hz: float,
        time_base: str = "timestamps",
        t0_s: float = 0.0,
        signals: Sequence[SignalSpec] = (),
        store_can_frames: bool = False,
        overwrite: bool = False,
        atomic: bool = False,
        flush_interval_s: float = 0.5,
    ) -> None:
        self.path = Path(path)
        if time_base not in ("timestamps", "uniform"):
            raise SessionError(f"time_base must be 'timestamps' or 'uniform', not {time_base!r}")
        if not np.isfinite(sample_rate_hz) or sample_rate_hz <= 0:
            raise SessionError(f"sample rate must be a positive number of Hz, not {sample_rate_hz}")
        if self.path.exists() and not overwrite:
            raise SessionError(
                f"{self.path} already exists; choose another file name, or pass --overwrite "
                "to replace it"
            )
        if not self.path.parent.exists():
            raise SessionError(f"folder {self.path.parent} does not exist; create it first")
        names = [c.name for c in channels]
        for c in channels:
            _check_name("channel", c.name)
            if c.role not in CHANNEL_ROLES:
                raise SessionError(
                    f"channel {c.name!r} has role {c.role!r}; roles are {', '.join(CHANNEL_ROLES)}"
                )
        for s in signals:
            _check_name("signal", s.name)
        if len(set(names)) != len(names):
            raise SessionError(f"channel names must be unique, got {names}")
        if len({s.name for s in signals}) != len(signals):
            raise SessionError("signal names must be unique")

        self.channels = list(channels)
        self.signals = list(signals)
        self.sample_rate_hz = float(sample_rate_hz)
        self.time_base = time_base
        self.atomic = atomic
        self.flush_interval_s = float(flush_interval_s)
        self._final_path = self.path
        if atomic:
            self._file_path = self.path.with_name(f".{self.path.name}.partial-{os.getpid()}")
        else:
            self._file_path = self.path
        self.overwrite = overwrite

        self._lock = threading.RLock()
        self._pending_time: list[np.ndarray] = []
        self._pending_daq: list[np.ndarray] = []
        self._pending_signals: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {
            s.name: [] for s in self.signals
        }
        self._pending_frames: list[np.ndarray] = []
        self._pending_events: list[tuple[float, str]] = []
        self._pending_gaps: list[tuple[float, float, int, str]] = []
        self._pending_samples = 0
        self._counters = dict.fromkeys(COUNTER_NAMES, 0)
        self._counters_dirty = False
        self._n_daq = 0
        self._closed = False
        self.error: BaseException | None = None
        self._raw_dtypes = [np.dtype(c.dtype) for c in self.channels]

        meta = metadata.to_dict()
        meta["created"] = meta["created"] or _utc_now_iso()
        meta["software_version"] = meta["software_version"] or _software_version()
        self.metadata = SessionMetadata(**meta)

        try:
            self._file = h5py.File(self._file_path, "w", libver="latest")
        except OSError as exc:
            raise SessionError(f"cannot create {self._file_path}: {exc}") from None
        try:
            self._create_layout(t0_s, store_can_frames)
            self._file.swmr_mode = True
            self._file.flush()
        except Exception:
            try:
                self._file.close()
            except Exception:  # noqa: BLE001 - h5py cannot close cleanly after a full disk
                pass
            self._file_path.unlink(missing_ok=True)
            raise
        self._fsync_fd = os.open(self._file_path, os.O_RDONLY)
        self._stop = threading.Event()
        self._flusher = threading.Thread(
            target=self._flush_loop, name=f"flush-{self.path.name}", daemon=True
        )
        self._flusher.start()

    # ------------------------------------------------------------------ layout
    def _create_layout(self, t0_s: float, store_can_frames: bool) -> None:
        f = self._file
        f.attrs["format"] = FORMAT_NAME
        f.attrs["schema_version"] = SCHEMA_VERSION
        for fld in fields(SessionMetadata):
            value = getattr(self.metadata, fld.name)
            f.attrs[fld.name] = json.dumps(value) if fld.name == "extra" else value
        daq = f.create_group("daq")
        daq.attrs["time_base"] = self.time_base
        daq.attrs["sample_rate_hz"] = self.sample_rate_hz
        daq.attrs["t0_s"] = float(t0_s)
        daq.attrs["channel_order"] = json.dumps([c.name for c in self.channels])
        if self.time_base == "timestamps":
            daq.create_dataset(
                "time_s", shape=(0,), maxshape=(None,), dtype="<f8", chunks=(_CHUNK_SAMPLES,)
            )
        chans = daq.create_group("channels")
        for c in self.channels:
            ds = chans.create_dataset(
                c.name, shape=(0,), maxshape=(None,), dtype=c.dtype, chunks=(_CHUNK_SAMPLES,)
            )
            ds.attrs["unit"] = c.unit
            ds.attrs["role"] = c.role
            ds.attrs["axis"] = c.axis
            ds.attrs["sensor"] = c.sensor
            ds.attrs["calibration"] = json.dumps({"scale": c.scale, "offset": c.offset})
        sig = f.create_group("signals")
        for s in self.signals:
            g = sig.create_group(s.name)
            for key in ("unit", "source", "message", "role"):
                g.attrs[key] = getattr(s, key)
            g.create_dataset("time_s", shape=(0,), maxshape=(None,), dtype="<f8", chunks=(4096,))
            g.create_dataset("value", shape=(0,), maxshape=(None,), dtype="<f8", chunks=(4096,))
        if store_can_frames:
            f.create_dataset(
                "can_frames", shape=(0,), maxshape=(None,), dtype=CAN_FRAME_DTYPE, chunks=(4096,)
            )
        f.create_dataset("events", shape=(0,), maxshape=(None,), dtype=EVENT_DTYPE, chunks=(256,))
        f.create_dataset("gaps", shape=(0,), maxshape=(None,), dtype=GAP_DTYPE, chunks=(256,))
        cnt = f.create_dataset("counters", data=np.zeros(len(COUNTER_NAMES), dtype="<i8"))
        cnt.attrs["names"] = json.dumps(list(COUNTER_NAMES))
        f.create_dataset("status", data=np.array([b"recording"], dtype="S16"))

    # ------------------------------------------------------------------ appending
    def _check_open(self) -> None:
        if self.error is not None:
            raise SessionError(f"writing {self.path} failed: {self.error}") from self.error
        if self._closed:
            raise SessionError(f"{self.path} is closed")

    def append_daq(
        self,
        samples: np.ndarray | Mapping[str, np.ndarray],
        time_s: np.ndarray | None = None,
    ) -> None:
        """Append a block of DAQ samples.

        Parameters
        ----------
        samples : ndarray of shape (n, n_channels), or mapping channel name -> (n,) array
            Raw samples in the channels' dtypes (values are cast, so pass exact types to
            keep them bit for bit).
        time_s : ndarray of shape (n,), optional
            Session time of every sample; required for the ``timestamps`` time base.
        """
        self._check_open()
        if isinstance(samples, Mapping):
            missing = [c.name for c in self.channels if c.name not in samples]
            if missing:
                raise SessionError(f"block lacks channels {missing}")
            cols = [np.asarray(samples[c.name]) for c in self.channels]
            n = len(cols[0]) if cols else 0
            if any(len(col) != n for col in cols):
                raise SessionError("all channels of a block must have the same length")
            block = cols
        else:
            arr = np.asarray(samples)
            if arr.ndim == 1 and len(self.channels) == 1:
                arr = arr[:, None]
            if arr.ndim != 2 or arr.shape[1] != len(self.channels):
                raise SessionError(
                    f"block must have shape (n, {len(self.channels)}), got {arr.shape}"
                )
            n = arr.shape[0]
            block = [arr[:, i] for i in range(arr.shape[1])]
        if n == 0:
            return
        cols_typed = np.empty(len(self.channels), dtype=object)
        for i, col in enumerate(block):
            cols_typed[i] = np.ascontiguousarray(col, dtype=self._raw_dtypes[i])
        t = None
        if self.time_base == "timestamps":
            if time_s is None:
                raise SessionError("this session stores time stamps: pass time_s with every block")
            t = np.asarray(time_s, dtype="<f8")
            if t.shape != (n,):
                raise SessionError(f"time_s must have shape ({n},), got {t.shape}")
        with self._lock:
            self._pending_daq.append(cols_typed)
            if t is not None:
                self._pending_time.append(t)
            self._pending_samples += n * max(1, len(self.channels))
            if self._pending_samples >= 4_000_000:
                self._write_pending()

    def append_signal(self, name: str, time_s: np.ndarray, value: np.ndarray) -> None:
        """Append samples of one vehicle signal.

        Parameters
        ----------
        name : str
            A signal declared when the session was created.
        time_s : ndarray
            Session time of each sample [s].
        value : ndarray
            The calibrated values, in the signal's unit.

        Raises
        ------
        ChannelNotFoundError
            The signal was not declared.
        SessionError
            ``time_s`` and ``value`` differ in length, or the writer is closed.
        """
        self._check_open()
        if name not in self._pending_signals:
            raise ChannelNotFoundError(
                f"signal {name!r} was not declared when the session was created; "
                f"declared: {sorted(self._pending_signals)}"
            )
        t = np.asarray(time_s, dtype="<f8").ravel()
        v = np.asarray(value, dtype="<f8").ravel()
        if t.shape != v.shape:
            raise SessionError("time_s and value must have the same length")
        if t.size == 0:
            return
        with self._lock:
            self._pending_signals[name].append((t, v))

    def append_can_frames(self, frames: np.ndarray) -> None:
        """Append raw CAN frames.

        Parameters
        ----------
        frames : ndarray
            A structured array of :data:`CAN_FRAME_DTYPE` (session time [s], id, bus,
            flags, dlc, data).

        Raises
        ------
        SessionError
            The session was created without ``store_can_frames=True``.
        """
        self._check_open()
        if "can_frames" not in self._file:
            raise SessionError("this session was created without store_can_frames=True")
        arr = np.asarray(frames, dtype=CAN_FRAME_DTYPE)
        if arr.size:
            with self._lock:
                self._pending_frames.append(arr)

    def add_event(self, time_s: float, label: str) -> None:
        """Record a labelled instant.

        Parameters
        ----------
        time_s : float
            Session time [s].
        label : str
            What happened (``speed_bump``, ``button``); at most 128 UTF-8 bytes are kept.
        """
        self._check_open()
        with self._lock:
            self._pending_events.append((float(time_s), str(label)))

    def add_gap(self, start_s: float, end_s: float, samples_lost: int, cause: str) -> None:
        """Record a stretch without samples: where, how many samples were lost and why.

        Parameters
        ----------
        start_s, end_s : float
            Session time of the last sample before and the first after the gap [s].
        samples_lost : int
            Samples per channel that did not arrive.
        cause : str
            Why (``sequence gap``, ``usb stall``); at most 64 UTF-8 bytes are kept.
        """
        self._check_open()
        with self._lock:
            self._pending_gaps.append((float(start_s), float(end_s), int(samples_lost), cause))

    def set_counters(self, **counters: int) -> None:
        """Set recording counters (absolute values), e.g. ``frames_lost=3``.

        Parameters
        ----------
        **counters : int
            Values of counters named in :data:`fielddiag.channels.COUNTER_NAMES`.

        Raises
        ------
        SessionError
            A name is not a counter.
        """
        unknown = set(counters) - set(COUNTER_NAMES)
        if unknown:
            raise SessionError(f"unknown counters {sorted(unknown)}; known: {COUNTER_NAMES}")
        with self._lock:
            self._counters.update({k: int(v) for k, v in counters.items()})
            self._counters_dirty = True

    def same_flush(self) -> threading.RLock:
        """``with writer.same_flush():`` what is appended and set inside reaches the file in
        one flush, so a reader (or the file of a killed writer) never sees part of it."""
        return self._lock

    @property
    def counters(self) -> dict[str, int]:
        """The recording counters set so far (name -> value)."""
        with self._lock:
            return dict(self._counters)

    @property
    def samples_written(self) -> int:
        """DAQ samples (per channel) written so far, including pending ones."""
        with self._lock:
            return self._n_daq + sum(len(b[0]) for b in self._pending_daq if len(b))

    # ------------------------------------------------------------------ writing
    @staticmethod
    def _extend(ds: h5py.Dataset, data: np.ndarray) -> None:
        n0 = ds.shape[0]
        ds.resize((n0 + len(data),))
        ds[n0:] = data

    def _write_pending(self) -> None:
        """Write everything pending to the file (caller holds the lock)."""
        f = self._file
        if self._pending_daq:
            chans = f["daq/channels"]
            for i, c in enumerate(self.channels):
                col = np.concatenate([b[i] for b in self._pending_daq])
                self._extend(chans[c.name], col)
            n = sum(len(b[0]) for b in self._pending_daq) if self.channels else 0
            if self._pending_time:
                self._extend(f["daq/time_s"], np.concatenate(self._pending_time))
            self._n_daq += n
            self._pending_daq.clear()
            self._pending_time.clear()
            self._pending_samples = 0
        for name, parts in self._pending_signals.items():
            if parts:
                g = f["signals"][name]
                self._extend(g["time_s"], np.concatenate([p[0] for p in parts]))
                self._extend(g["value"], np.concatenate([p[1] for p in parts]))
                parts.clear()
        if self._pending_frames:
            self._extend(f["can_frames"], np.concatenate(self._pending_frames))
            self._pending_frames.clear()
        if self._pending_events:
            ev = np.array(
                [(t, _encode(lbl, _LABEL_LEN)) for t, lbl in self._pending_events],
                dtype=EVENT_DTYPE,
            )
            self._extend(f["events"], ev)
            self._pending_events.clear()
        if self._pending_gaps:
            gp = np.array(
                [(a, b, n, _encode(c, _CAUSE_LEN)) for a, b, n, c in self._pending_gaps],
                dtype=GAP_DTYPE,
            )
            self._extend(f["gaps"], gp)
            self._pending_gaps.clear()
        if self._counters_dirty:
            f["counters"][:] = np.array([self._counters[k] for k in COUNTER_NAMES], dtype="<i8")
            self._counters_dirty = False

    def _pending_bytes(self) -> int:
        n = sum(col.nbytes for b in self._pending_daq for col in b)
        n += sum(t.nbytes for t in self._pending_time)
        n += sum(t.nbytes + v.nbytes for parts in self._pending_signals.values() for t, v in parts)
        n += sum(f.nbytes for f in self._pending_frames)
        return n

    def _check_space(self) -> None:
        """Refuse to write when the disk cannot take it.

        HDF5 reports a failed chunk write only from a destructor (printed, not raised), so
        a full disk would silently zero data. Check before writing: the pending bytes, one
        new chunk per dataset that grows, and a margin for metadata.
        """
        st = os.statvfs(self._file_path.parent)
        free = st.f_bavail * st.f_frsize
        # worst case: every growing dataset allocates one new chunk, plus metadata
        chunks = sum(_CHUNK_SAMPLES * d.itemsize for d in self._raw_dtypes)
        chunks += _CHUNK_SAMPLES * 8 if self.time_base == "timestamps" else 0
        chunks += len(self.signals) * 2 * 4096 * 8
        if self._pending_frames:
            chunks += 4096 * CAN_FRAME_DTYPE.itemsize
        need = self._pending_bytes() + chunks + (256 << 10)
        if free < need:
            raise DiskFullError(
                f"disk full: {free / 1e6:.1f} MB free on {self._file_path.parent}, "
                f"{need / 1e6:.1f} MB needed for the next write"
            )

    def flush(self) -> None:
        """Write everything appended so far and make it durable on disk."""
        self._check_open()
        with self._lock:
            try:
                self._check_space()
                self._write_pending()
                self._file.flush()
                os.fsync(self._fsync_fd)
            except Exception as exc:  # a full disk, a yanked USB stick...
                self.error = exc
                raise SessionError(
                    f"writing {self.path} failed ({exc}); everything flushed before is intact"
                ) from exc

    def _flush_loop(self) -> None:
        """Flush on a monotonic schedule: flushes start every ``flush_interval_s``.

        The wait is measured to the next deadline, not from the end of the last flush,
        so the time a flush takes does not stretch the period. A flush that overruns its
        slot is followed at once by the next, and the schedule restarts from there.
        """
        interval_s = self.flush_interval_s
        deadline_s = time.monotonic() + interval_s
        while not self._stop.wait(max(0.0, deadline_s - time.monotonic())):
            try:
                self.flush()
            except SessionError:
                return
            deadline_s = max(deadline_s + interval_s, time.monotonic())

    # ------------------------------------------------------------------ closing
    def close(self) -> None:
        """Flush, mark the session closed cleanly, and (atomic mode) move it into place."""
        if self._closed:
            return
        self._stop.set()
        self._flusher.join()
        with self._lock:
            failed = self.error
            try:
                if failed is None:
                    self._check_space()
                    self._write_pending()
                if failed is None or isinstance(failed, DiskFullError):
                    # a refused write left the file consistent: it closes cleanly with
                    # everything written before (marking it needs no new space)
                    self._file["status"][0] = b"closed"
                    self._file.flush()
            except DiskFullError as exc:
                failed = self.error = exc
                self._file["status"][0] = b"closed"
                self._file.flush()
            except OSError as exc:
                failed = self.error = exc
            finally:
                self._file.close()
                os.close(self._fsync_fd)
                self._closed = True
        if failed is not None:
            raise SessionError(
                f"writing {self.path} failed ({failed}); everything flushed before is intact"
            )
        if self.atomic:
            if self._final_path.exists() and not self.overwrite:
                self._file_path.unlink(missing_ok=True)
                raise SessionError(f"{self._final_path} appeared while writing; not replacing it")
            os.replace(self._file_path, self._final_path)

    def abort(self) -> None:
        """Stop writing. Atomic sessions are deleted; recordings keep what they hold."""
        if self._closed:
            return
        self._stop.set()
        self._flusher.join()
        with self._lock:
            if self.atomic:
                self._file.close()
                self._file_path.unlink(missing_ok=True)
            else:
                try:
                    self._write_pending()
                    self._file.flush()
                finally:
                    self._file.close()
            os.close(self._fsync_fd)
            self._closed = True

    def __enter__(self) -> SessionWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        elif self.atomic:
            self.abort()
        else:
            self.close()


# ====================================================================== reading
def _open_h5(path: Path) -> tuple[h5py.File, bool, str]:
    """Open a session file; returns (file, opened_in_swmr_mode, why plain mode failed).

    The file is checked first (:func:`fielddiag.session_guard.precheck`: signature,
    superblock checksum, end-of-file address against the real size), so HDF5 never sees
    a truncated file. SWMR read mode, which skips HDF5's own end-of-file check, is used
    only for a file whose superblock says a writer has it open.
    """
    from fielddiag.session_guard import open_swmr_read, precheck

    check = precheck(path)
    try:
        return h5py.File(path, "r", libver="latest"), False, ""
    except OSError as first:
        if check.writer_open:
            # A writer still has it open, or was killed: SWMR read mode opens it anyway
            # and sees everything flushed.
            try:
                return open_swmr_read(path), True, str(first)
            except OSError:
                pass
        raise SessionError(
            f"{path} is not a readable session file ({first}); is it an HDF5 file "
            "written by fielddiag?"
        ) from None


def _one_line(exc: BaseException) -> str:
    """An exception's text on one line (HDF5 messages can span several)."""
    return " ".join(str(exc).split()) or type(exc).__name__


def _bisect_left(ds: h5py.Dataset, value: float, lo: int = 0, hi: int | None = None) -> int:
    """Binary search on a sorted 1-D dataset without reading it whole."""
    hi = ds.shape[0] if hi is None else hi
    while hi - lo > 4096:
        mid = (lo + hi) // 2
        if ds[mid] < value:
            lo = mid + 1
        else:
            hi = mid
    return lo + int(np.searchsorted(ds[lo:hi], value, side="left"))


class SessionReader:
    """Read a session lazily: nothing but the metadata is loaded until asked for.

    Parameters
    ----------
    path : str or Path
        The session file. Files whose writer is still running or was killed are opened
        in SWMR read mode (see :attr:`closed_cleanly`).
    """

    def __init__(self, path: str | os.PathLike) -> None:
        from fielddiag import session_guard

        self.path = Path(path)
        if session_guard.opens_guarded():  # the CLI: probed in a worker first (cached)
            session_guard.verify_untrusted(self.path)
        self._file, self.swmr, why_swmr = _open_h5(self.path)
        try:
            self._load_header()
            if "truncated file" in why_swmr and self.closed_cleanly:
                # Closed cleanly by its writer, shorter now: cut by a copy or a full disk.
                # SWMR mode would open it and read the missing part as zeros.
                raise SessionError(
                    f"{self.path} is truncated ({os.path.getsize(self.path)} bytes, its "
                    f"writer closed it complete: {why_swmr.split('(', 1)[-1].rstrip(')')}); "
                    "copy it again from the original"
                )
        except SessionError:
            self._file.close()
            raise
        except (KeyError, ValueError, TypeError, OSError, RuntimeError) as exc:
            self._file.close()
            raise SessionError(f"{self.path} is not a valid fielddiag session "
                               f"({_one_line(exc)}); copy it again from the original") from None

    def _load_header(self) -> None:
        f = self._file
        if f.attrs.get("format") != FORMAT_NAME:
            raise SessionError(f"{self.path} is an HDF5 file but not a fielddiag session")
        version = int(f.attrs["schema_version"])
        if version > SCHEMA_VERSION:
            raise SessionError(
                f"{self.path} uses session schema {version}; this fielddiag reads up to "
                f"{SCHEMA_VERSION}: upgrade fielddiag"
            )
        kw: dict[str, Any] = {}
        for fld in fields(SessionMetadata):
            if fld.name in f.attrs:
                v = f.attrs[fld.name]
                if fld.name == "extra":
                    v = json.loads(v)
                elif isinstance(v, np.generic):
                    v = v.item()
                kw[fld.name] = v
        self.metadata = SessionMetadata(**kw)
        daq = f["daq"]
        self.time_base = str(daq.attrs["time_base"])
        self.sample_rate_hz = float(daq.attrs["sample_rate_hz"])
        self._t0_s = float(daq.attrs["t0_s"])
        order = json.loads(daq.attrs["channel_order"])
        self.channels: list[ChannelSpec] = []
        for name in order:
            ds = daq["channels"][name]
            cal = json.loads(ds.attrs["calibration"])
            self.channels.append(
                ChannelSpec(
                    name=name,
                    unit=str(ds.attrs["unit"]),
                    role=str(ds.attrs["role"]),
                    axis=str(ds.attrs["axis"]),
                    sensor=str(ds.attrs["sensor"]),
                    scale=float(cal["scale"]),
                    offset=float(cal["offset"]),
                    dtype=_dtype_name(ds.dtype),
                )
            )
        self.signals: list[SignalSpec] = []
        for name, g in f["signals"].items():
            self.signals.append(
                SignalSpec(
                    name=name, **{k: str(g.attrs[k]) for k in ("unit", "source", "message", "role")}
                )
            )

    # ------------------------------------------------------------------ basics
    def refresh(self) -> None:
        """See data appended since opening (for a session still being recorded)."""
        if self.swmr:
            for obj in self._datasets():
                obj.refresh()
        # Opened in the writer's own process, the file handle is shared and always current.

    def _datasets(self) -> Iterable[h5py.Dataset]:
        out: list[h5py.Dataset] = []
        self._file.visititems(lambda _n, o: out.append(o) if isinstance(o, h5py.Dataset) else None)
        return out

    @property
    def closed_cleanly(self) -> bool:
        """False while the writer is running, or if it was killed before closing."""
        return bytes(self._file["status"][0]).rstrip(b"\0") == b"closed"

    @property
    def n_samples(self) -> int:
        """Number of DAQ samples per channel."""
        if not self.channels:
            return 0
        return int(min(self._file["daq/channels"][c.name].shape[0] for c in self.channels))

    def _signal_span(self) -> tuple[float, float] | None:
        """(first, last) time of the vehicle signals; None when they hold no samples."""
        lo, hi = float("inf"), float("-inf")
        for spec in self.signals:
            t = self._file["signals"][spec.name]["time_s"]
            if t.shape[0]:
                lo, hi = min(lo, float(t[0])), max(hi, float(t[t.shape[0] - 1]))
        return (lo, hi) if lo <= hi else None

    @property
    def start_s(self) -> float:
        """Time of the first DAQ sample (of the first vehicle signal sample in a session
        without DAQ samples, e.g. a CAN log)."""
        n = self.n_samples
        if n == 0:
            span = self._signal_span()
            return span[0] if span else self._t0_s
        return float(self._file["daq/time_s"][0]) if self.time_base == "timestamps" else self._t0_s

    @property
    def end_s(self) -> float:
        """Time of the last DAQ sample (of the last vehicle signal sample in a session
        without DAQ samples)."""
        n = self.n_samples
        if n == 0:
            span = self._signal_span()
            return span[1] if span else self._t0_s
        if self.time_base == "timestamps":
            return float(self._file["daq/time_s"][n - 1])
        return self._t0_s + (n - 1) / self.sample_rate_hz

    @property
    def duration_s(self) -> float:
        """Span of the DAQ time axis (one sample period more than last minus first)."""
        n = self.n_samples
        if n == 0:  # vehicle signals only: their span
            return self.end_s - self.start_s
        return self.end_s - self.start_s + 1.0 / self.sample_rate_hz

    # ------------------------------------------------------------------ channels
    def channel(self, name: str) -> ChannelSpec:
        """The channel called ``name``.

        Parameters
        ----------
        name : str

        Returns
        -------
        ChannelSpec

        Raises
        ------
        ChannelNotFoundError
            No channel has that name (the message lists them).
        """
        for c in self.channels:
            if c.name == name:
                return c
        raise ChannelNotFoundError(
            f"{self.path.name} has no channel {name!r}; it has "
            f"{', '.join(c.name for c in self.channels) or 'no channels'}"
        )

    def channels_for_role(self, role: str) -> list[ChannelSpec]:
        """The channels with ``role`` (``wheel``, ``body``, ``force``...), possibly none.

        A corner's accelerometers are found, with a message that says where to mount a
        missing one, by :func:`fielddiag.drive.find_channel`.

        Parameters
        ----------
        role : str

        Returns
        -------
        list of ChannelSpec
        """
        return [c for c in self.channels if c.role == role]

    def channel_for_role(self, role: str) -> ChannelSpec:
        """The one channel with ``role`` (``force``, ``displacement``...).

        Parameters
        ----------
        role : str

        Returns
        -------
        ChannelSpec

        Raises
        ------
        ChannelNotFoundError
            No channel or several channels have the role.
        """
        found = self.channels_for_role(role)
        if not found:
            have = ", ".join(f"{c.name} ({c.role})" for c in self.channels) or "none"
            raise ChannelNotFoundError(
                f"{self.path.name} has no channel with role {role!r} (channels: {have}); "
                f"record or import one with role {role!r}"
            )
        if len(found) > 1:
            raise ChannelNotFoundError(
                f"{self.path.name} has several channels with role {role!r}: "
                f"{', '.join(c.name for c in found)}; pick one by name"
            )
        return found[0]

    def index_range(
        self, start_s: float | None = None, end_s: float | None = None
    ) -> tuple[int, int]:
        """Sample indices [i0, i1) of the DAQ samples with start_s <= t < end_s.

        Parameters
        ----------
        start_s, end_s : float or None
            Session time limits [s]; None: from the first / to the last sample.

        Returns
        -------
        (int, int)
            Clipped to [0, :attr:`n_samples`], ``i1 >= i0``.
        """
        n = self.n_samples
        if self.time_base == "uniform":
            fs, t0 = self.sample_rate_hz, self._t0_s
            i0 = 0 if start_s is None else int(np.ceil((start_s - t0) * fs - 1e-9))
            i1 = n if end_s is None else int(np.ceil((end_s - t0) * fs - 1e-9))
        else:
            ds = self._file["daq/time_s"]
            i0 = 0 if start_s is None else _bisect_left(ds, start_s, 0, n)
            i1 = n if end_s is None else _bisect_left(ds, end_s, 0, n)
        i0 = min(max(i0, 0), n)
        i1 = min(max(i1, i0), n)
        return i0, i1

    def time_s(self, start_s: float | None = None, end_s: float | None = None) -> np.ndarray:
        """DAQ sample times in [start_s, end_s).

        Parameters
        ----------
        start_s, end_s : float or None
            Session time limits [s].

        Returns
        -------
        ndarray
            Session time of each sample [s].
        """
        i0, i1 = self.index_range(start_s, end_s)
        return self.time_at(i0, i1)

    def time_at(self, i0: int, i1: int) -> np.ndarray:
        """DAQ sample times of indices [i0, i1).

        Parameters
        ----------
        i0, i1 : int
            Sample indices.

        Returns
        -------
        ndarray
            Session time of each sample [s].
        """
        if self.time_base == "timestamps":
            return self._file["daq/time_s"][i0:i1]
        return self._t0_s + np.arange(i0, i1, dtype="f8") / self.sample_rate_hz

    def read_raw(self, name: str, i0: int = 0, i1: int | None = None) -> np.ndarray:
        """Raw samples of a channel by index, exactly as stored (calibration not applied).

        Parameters
        ----------
        name : str
            The channel.
        i0, i1 : int
            Sample indices [i0, i1); ``i1`` None: to the end.

        Returns
        -------
        ndarray
            The stored dtype (``int16``, ``float64``...).

        Raises
        ------
        ChannelNotFoundError
            No such channel.
        """
        self.channel(name)
        i1 = self.n_samples if i1 is None else i1
        return self._file["daq/channels"][name][i0:i1]

    def read(
        self,
        name: str,
        start_s: float | None = None,
        end_s: float | None = None,
        *,
        raw: bool = False,
    ) -> np.ndarray:
        """Samples of channel ``name`` with start_s <= t < end_s, calibrated unless ``raw``.

        Parameters
        ----------
        name : str
            The channel.
        start_s, end_s : float or None
            Session time limits [s].
        raw : bool
            Return the stored samples without the calibration.

        Returns
        -------
        ndarray
            ``raw * scale + offset`` in the channel's unit (float64), or the stored samples.
            Units are converted to SI by :mod:`fielddiag.units` (for a corner's
            accelerometers, by :func:`fielddiag.drive.read_corner_drive`).

        Raises
        ------
        ChannelNotFoundError
            No such channel.
        """
        spec = self.channel(name)
        i0, i1 = self.index_range(start_s, end_s)
        data = self._file["daq/channels"][name][i0:i1]
        if raw:
            return data
        out = data.astype("f8")
        if spec.scale != 1.0:
            out *= spec.scale
        if spec.offset != 0.0:
            out += spec.offset
        return out

    def read_with_time(
        self, name: str, start_s: float | None = None, end_s: float | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """(time_s, calibrated values) of channel ``name`` in [start_s, end_s).

        Parameters
        ----------
        name : str
            The channel.
        start_s, end_s : float or None
            Session time limits [s].

        Returns
        -------
        time_s : ndarray
            Session time of each sample [s].
        values : ndarray
            Calibrated samples, in the channel's unit.
        """
        i0, i1 = self.index_range(start_s, end_s)
        values = self.read(name, start_s, end_s)
        return self.time_at(i0, i1), values

    def read_role(
        self, role: str, start_s: float | None = None, end_s: float | None = None
    ) -> np.ndarray:
        """Calibrated samples of the one channel with ``role``.

        Parameters
        ----------
        role : str
        start_s, end_s : float or None
            Session time limits [s].

        Returns
        -------
        ndarray
            In the channel's unit.

        Raises
        ------
        ChannelNotFoundError
            No channel or several channels have the role.
        """
        return self.read(self.channel_for_role(role).name, start_s, end_s)

    # ------------------------------------------------------------------ signals
    def signal_spec(self, name: str) -> SignalSpec:
        """The vehicle signal called ``name``.

        Parameters
        ----------
        name : str

        Returns
        -------
        SignalSpec

        Raises
        ------
        ChannelNotFoundError
            No signal has that name (the message lists them).
        """
        for s in self.signals:
            if s.name == name:
                return s
        raise ChannelNotFoundError(
            f"{self.path.name} has no signal {name!r}; it has "
            f"{', '.join(s.name for s in self.signals) or 'no signals'}"
        )

    def signal_for_role(self, role: str) -> SignalSpec:
        """The first vehicle signal with ``role`` (``speed``).

        Parameters
        ----------
        role : str

        Returns
        -------
        SignalSpec

        Raises
        ------
        ChannelNotFoundError
            No signal has the role.
        """
        found = [s for s in self.signals if s.role == role]
        if not found:
            raise ChannelNotFoundError(f"{self.path.name} has no signal with role {role!r}")
        return found[0]

    def signal(
        self, name: str, start_s: float | None = None, end_s: float | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """(time_s, value) of a vehicle signal in [start_s, end_s).

        Parameters
        ----------
        name : str
            The signal.
        start_s, end_s : float or None
            Session time limits [s].

        Returns
        -------
        time_s : ndarray
            The signal's own time stamps [s].
        value : ndarray
            Its values, in the signal's unit.

        Raises
        ------
        ChannelNotFoundError
            No such signal.
        """
        self.signal_spec(name)
        g = self._file["signals"][name]
        n = min(g["time_s"].shape[0], g["value"].shape[0])
        i0 = 0 if start_s is None else _bisect_left(g["time_s"], start_s, 0, n)
        i1 = n if end_s is None else _bisect_left(g["time_s"], end_s, 0, n)
        return g["time_s"][i0:i1], g["value"][i0:i1]

    def signal_on_daq_time(
        self,
        name: str,
        start_s: float | None = None,
        end_s: float | None = None,
        *,
        method: str = "linear",
    ) -> np.ndarray:
        """A vehicle signal resampled onto the DAQ sample times in [start_s, end_s).

        Parameters
        ----------
        method : {"linear", "previous"}
            ``linear`` interpolates; ``previous`` holds the last received value (what a
            CAN receiver knew at that instant). Outside the signal's span the first/last
            value is held; NaN if the signal has no samples.
        """
        t_daq = self.time_s(start_s, end_s)
        t, v = self.signal(name)
        if t.size == 0:
            return np.full(t_daq.shape, np.nan)
        if method == "linear":
            return np.interp(t_daq, t, v)
        if method == "previous":
            idx = np.clip(np.searchsorted(t, t_daq, side="right") - 1, 0, t.size - 1)
            return v[idx]
        raise SessionError(f"method must be 'linear' or 'previous', not {method!r}")

    # ------------------------------------------------------------------ events etc.
    @property
    def events(self) -> list[Event]:
        """The labelled instants, in the order recorded."""
        return [Event(float(r["time_s"]), _decode(r["label"])) for r in self._file["events"][:]]

    @property
    def gaps(self) -> list[Gap]:
        """The stretches without DAQ samples the recorder noted."""
        return [
            Gap(float(r["start_s"]), float(r["end_s"]), int(r["samples_lost"]), _decode(r["cause"]))
            for r in self._file["gaps"][:]
        ]

    @property
    def counters(self) -> dict[str, int]:
        """The recording counters (frames received, lost, CRC errors...)."""
        ds = self._file["counters"]
        names = json.loads(ds.attrs["names"])
        return {k: int(v) for k, v in zip(names, ds[:], strict=True)}

    @property
    def has_can_frames(self) -> bool:
        """True when the session keeps its raw CAN frames."""
        return "can_frames" in self._file

    def can_frames(self, start: int = 0, stop: int | None = None) -> np.ndarray:
        """Raw CAN frames [start, stop) as a structured array of :data:`CAN_FRAME_DTYPE`.

        Parameters
        ----------
        start, stop : int or None
            Frame indices; ``stop`` None: to the end.

        Returns
        -------
        ndarray
            Empty when the session keeps no frames.
        """
        if not self.has_can_frames:
            return np.zeros(0, dtype=CAN_FRAME_DTYPE)
        return self._file["can_frames"][start:stop]

    def info(self) -> dict[str, Any]:
        """Everything ``fielddiag info`` shows, JSON-serialisable.

        Returns
        -------
        dict
            Path, schema version, metadata, time base, rate [Hz], samples, start and
            duration [s], channels, signals (with their rate [Hz]), events, gaps, samples
            lost, CAN frames and counters.
        """
        gaps = self.gaps
        signals = []
        for s in self.signals:
            t = self._file["signals"][s.name]["time_s"]
            n = t.shape[0]
            span = float(t[n - 1] - t[0]) if n > 1 else 0.0
            signals.append(
                {**s.to_dict(), "samples": n, "rate_hz": (n - 1) / span if span > 0 else None}
            )
        return {
            "path": str(self.path),
            "schema_version": int(self._file.attrs["schema_version"]),
            "metadata": self.metadata.to_dict(),
            "closed_cleanly": self.closed_cleanly,
            "time_base": self.time_base,
            "sample_rate_hz": self.sample_rate_hz,
            "samples": self.n_samples,
            "start_s": self.start_s,
            "duration_s": self.duration_s,
            "channels": [c.to_dict() for c in self.channels],
            "signals": signals,
            "events": len(self._file["events"]),
            "gaps": [g.__dict__ for g in gaps],
            "samples_lost": int(sum(g.samples_lost for g in gaps)),
            "can_frames": int(self._file["can_frames"].shape[0]) if self.has_can_frames else 0,
            "counters": self.counters,
        }

    def close(self) -> None:
        """Close the file (also done on leaving a ``with`` block)."""
        self._file.close()

    def __enter__(self) -> SessionReader:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def open_session(path: str | os.PathLike) -> SessionReader:
    """Open a session for reading (same as :class:`SessionReader`).

    Parameters
    ----------
    path : str or PathLike

    Returns
    -------
    SessionReader

    Raises
    ------
    SessionError
        Missing, unreadable, truncated or not a fielddiag session.
    """
    return SessionReader(path)


def write_session(
    path: str | os.PathLike,
    metadata: SessionMetadata,
    channels: Sequence[ChannelSpec],
    samples: np.ndarray,
    *,
    sample_rate_hz: float,
    time_s: np.ndarray | None = None,
    signals: Mapping[SignalSpec, tuple[np.ndarray, np.ndarray]] | None = None,
    events: Iterable[Event] = (),
    gaps: Iterable[Gap] = (),
    overwrite: bool = False,
) -> Path:
    """Write a whole session at once, atomically (for imports, the simulator, exports).

    Parameters
    ----------
    path : str or PathLike
        The file to create.
    metadata : SessionMetadata
        Root attributes.
    channels : sequence of ChannelSpec
        The DAQ channels, in the column order of ``samples``.
    samples : ndarray
        (n, channels) raw samples.
    sample_rate_hz : float
        Nominal sample rate [Hz].
    time_s : ndarray or None
        Time stamp of each sample [s]; None: a uniform time base starting at 0.
    signals : mapping of SignalSpec to (time_s, value) or None
        Vehicle signals with their own time stamps.
    events : iterable of Event
    gaps : iterable of Gap
    overwrite : bool
        Replace an existing file.

    Returns
    -------
    Path
        The session written.

    Raises
    ------
    SessionError
        The file exists (without ``overwrite``), its folder does not, or a name or role
        is invalid.

    Examples
    --------
    >>> write_session("drive.h5", SessionMetadata(vehicle="demo"),              # doctest: +SKIP
    ...               [ChannelSpec("wheel_z", role="wheel"), ChannelSpec("body_z", role="body")],
    ...               samples, sample_rate_hz=500.0)
    """
    signals = signals or {}
    with SessionWriter(
        path,
        metadata,
        channels,
        sample_rate_hz=sample_rate_hz,
        time_base="uniform" if time_s is None else "timestamps",
        signals=list(signals),
        overwrite=overwrite,
        atomic=True,
        flush_interval_s=3600.0,
    ) as w:
        w.append_daq(samples, time_s)
        for spec, (t, v) in signals.items():
            w.append_signal(spec.name, t, v)
        for e in events:
            w.add_event(e.time_s, e.label)
        for g in gaps:
            w.add_gap(g.start_s, g.end_s, g.samples_lost, g.cause)
    return Path(path)
