"""Run data sources concurrently into one session; live buffer and counters for the UI.

:class:`Recorder` opens the sources (the DAQ handshake tells the channels), creates the
session (:class:`fielddiag.session.SessionWriter`, SWMR, flushed every 0.4 s so a killed
recorder loses at most the last half second and the file can be read while it grows), and
runs every source in its own thread. What the sources read goes to the session as it
arrives: raw DAQ counts bit for bit with their session times, gaps with the samples
lost, decoded CAN signals in SI units, every raw CAN frame, events. Counters (frames
received/lost, CRC errors, ...) are kept in the session and in :meth:`Recorder.status`.
The counters stored always describe the data stored: each source's counters are taken in
its own thread with the block it just read and reach the file in the same flush as that
block, so a killed recorder leaves a file whose counters match its samples and gaps.

The device clock drift estimated by the serial DAQ driver cannot go into the root
attributes (a SWMR file cannot get new attributes once recording has started), so it is
stored as the signal ``daq_clock_drift_ppm`` (unit ppm, source ``daq``): one estimate per
second, the last value being the best.

:func:`record_virtual_drive` records a simulated drive through the virtual DAQ (real pty,
real serial driver) and the virtual ECU (python-can virtual bus, real CAN driver); the
demo uses it.
"""

from __future__ import annotations

import os
import shutil
import sys
import textwrap
import threading
import time
import uuid
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from drivers.base import Block, SessionClock, Source
from fielddiag.channels import COUNTER_NAMES, ChannelSpec, SessionMetadata, SignalSpec
from fielddiag.errors import DeviceError, FieldDiagError, SessionError
from fielddiag.session import SessionWriter

DRIFT_SIGNAL = SignalSpec(
    "daq_clock_drift_ppm", unit="ppm", source="daq", message="clock sync", role="other"
)
_SIGNAL_BUFFER_HZ = 200.0


class _Ring:
    """Fixed-capacity ring of (time, values[k]) rows; reads return the newest rows in order."""

    def __init__(self, capacity: int, width: int) -> None:
        self.capacity = max(1, int(capacity))
        self.t = np.zeros(self.capacity)
        self.v = np.zeros((self.capacity, width))
        self.n = 0  # rows ever written

    def push(self, t: np.ndarray, v: np.ndarray) -> None:
        k = len(t)
        if k == 0:
            return
        if k > self.capacity:
            t, v, k = t[-self.capacity :], v[-self.capacity :], self.capacity
        i = self.n % self.capacity
        first = min(k, self.capacity - i)
        self.t[i : i + first] = t[:first]
        self.v[i : i + first] = v[:first]
        if first < k:
            self.t[: k - first] = t[first:]
            self.v[: k - first] = v[first:]
        self.n += k

    def newest(self, count: int) -> tuple[np.ndarray, np.ndarray]:
        count = min(count, self.n, self.capacity)
        if count <= 0:
            return np.zeros(0), np.zeros((0, self.v.shape[1]))
        end = self.n % self.capacity
        idx = (np.arange(end - count, end)) % self.capacity
        return self.t[idx], self.v[idx]


class Recorder:
    """Record sources into one session file.

    Parameters
    ----------
    path : str or Path
        Session file to create.
    sources : sequence of Source
        At most one DAQ source (``kind == "daq"``) and any number of CAN sources.
    metadata : SessionMetadata
        Vehicle, corner, added mass...; ``t0_unix_s`` is set to the recording start and a
        description of each source is added to ``extra["sources"]``.
    overwrite : bool
        Replace an existing file.
    live_buffer_s : float
        Seconds kept in the live ring buffer (:meth:`latest`).
    disk_reserve_bytes : int or None
        The recording stops (with a message, the file closed cleanly) when less than this
        is free on the disk of ``path``. HDF5 cannot be relied on to report a full disk
        (its chunk cache drops failed writes), so the recorder stops before that point.
        Default: three HDF5 chunk allocations plus 10 s of data plus 1 MB.
    flush_interval_s : float
        Longest time data waits in memory before it is on disk. A killed recorder loses
        up to this plus the time a block waits before it is appended (20-50 ms): 0.4 s
        keeps that within half a second.

    Attributes
    ----------
    block_listeners : list of callables
        Each is called with every calibrated DAQ :class:`~drivers.base.Block` (samples in
        physical units, float64), from the source's thread. Exceptions are counted in
        ``status()["listener_errors"]`` and do not stop the recording.

    Examples
    --------
    >>> rec = Recorder("drive.h5", [open_source("serial:///dev/ttyUSB0")]).start()
    >>> rec.wait(60.0)          # or poll rec.status() / rec.latest(10.0)
    >>> rec.stop()
    """

    def __init__(
        self,
        path: str | os.PathLike,
        sources: Sequence[Source],
        *,
        metadata: SessionMetadata | None = None,
        overwrite: bool = False,
        live_buffer_s: float = 60.0,
        flush_interval_s: float = 0.4,
        read_timeout_s: float = 0.1,
        disk_reserve_bytes: int | None = None,
    ) -> None:
        self.path = Path(path)
        self.disk_reserve_bytes = disk_reserve_bytes
        self.sources = list(sources)
        daq = [s for s in self.sources if s.kind == "daq"]
        if len(daq) > 1:
            raise DeviceError("a session has one DAQ time base: record one DAQ source at a time")
        if not self.sources:
            raise DeviceError("nothing to record: give a DAQ and/or a CAN source")
        self.daq: Source | None = daq[0] if daq else None
        self.metadata = metadata or SessionMetadata()
        self.overwrite = overwrite
        self.live_buffer_s = float(live_buffer_s)
        self.flush_interval_s = float(flush_interval_s)
        self.read_timeout_s = float(read_timeout_s)
        self.block_listeners: list[Callable[[Block], None]] = []
        self.online: Any = None  # OnlineEstimator, see attach_online_estimator
        self.online_error = ""
        self.online_ready = threading.Event()  # set once the estimator is attached or failed
        self.writer: SessionWriter | None = None
        self.clock: SessionClock | None = None
        self.error: FieldDiagError | None = None
        self.listener_errors = 0
        self.channels: list[ChannelSpec] = []
        self.signals: list[SignalSpec] = []
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._lock = threading.Lock()
        self._ring: _Ring | None = None
        self._sig_rings: dict[str, _Ring] = {}
        self._samples = 0
        self._gaps = 0
        self._events: list[tuple[float, str]] = []
        self._finished: set[int] = set()
        self._state = "new"
        self._stopped_at: float | None = None
        self._last_drift_t = -1.0
        self._rate_hist: list[tuple[float, int]] = []
        self._reserve = 0
        self._stored_counters: dict[int, dict[str, int]] = {}  # per source, as stored

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> Recorder:
        """Open the sources, create the session, start recording. Returns self."""
        opened: list[Source] = []
        try:
            for s in self.sources:
                s.open()
                opened.append(s)
            self._create_writer()
        except BaseException:
            for s in opened:
                try:
                    s.close()
                except Exception:
                    pass
            raise
        self._state = "recording"
        for i, s in enumerate(self.sources):
            s.start(self.clock)
            th = threading.Thread(
                target=self._run_source, args=(i, s), daemon=True, name=f"rec-{s.kind}-{i}"
            )
            self._threads.append(th)
        for th in self._threads:
            th.start()
        hk = threading.Thread(target=self._housekeeping, daemon=True, name="rec-housekeeping")
        self._threads.append(hk)
        hk.start()
        return self

    def _free_bytes(self) -> int:
        st = os.statvfs(self.path.parent if self.path.parent.exists() else ".")
        return int(st.f_bavail * st.f_frsize)

    def _reserve_bytes(self, channels: list[ChannelSpec], signals: list[SignalSpec]) -> int:
        if self.disk_reserve_bytes is not None:
            return int(self.disk_reserve_bytes)
        from fielddiag.session import CAN_FRAME_DTYPE

        item = sum(np.dtype(c.dtype).itemsize for c in channels)
        chunk_round = 16384 * (item + 8) + len(signals) * 4096 * 16
        if any(s.stores_can_frames for s in self.sources):
            chunk_round += 4096 * CAN_FRAME_DTYPE.itemsize
        rate = (self.daq.sample_rate_hz or 0.0) if self.daq else 0.0
        per_s = rate * (item + 8) + 2000 * CAN_FRAME_DTYPE.itemsize
        return int(3 * chunk_round + 10 * per_s + 1_000_000)

    def _disk_full_error(self, free: int) -> SessionError:
        return SessionError(
            f"the disk of {self.path} is (almost) full: {free / 1e6:.1f} MB free, "
            f"{self._reserve / 1e6:.1f} MB needed to keep recording safely; the recording "
            "stopped and everything recorded before is intact. Free some space or record "
            "to another disk"
        )

    def _create_writer(self) -> None:
        signals: list[SignalSpec] = []
        for s in self.sources:
            signals.extend(s.signals)
        self.channels = list(self.daq.channels) if self.daq else []
        if self.daq is not None and hasattr(self.daq, "drift_ppm"):
            signals.append(DRIFT_SIGNAL)
        names = [s.name for s in signals]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise DeviceError(f"two sources decode signals with the same name {dup}; use aliases")
        self.signals = signals
        self._reserve = self._reserve_bytes(self.channels, signals)
        free = self._free_bytes()
        if free < self._reserve:
            raise self._disk_full_error(free)
        rate = (self.daq.sample_rate_hz if self.daq else None) or 1.0
        self.clock = SessionClock()
        extra = dict(self.metadata.extra)
        extra["sources"] = [s.describe() for s in self.sources]
        meta = replace(self.metadata, t0_unix_s=self.clock.t0_unix_s, extra=extra)
        self.writer = SessionWriter(
            self.path,
            meta,
            self.channels,
            sample_rate_hz=rate,
            time_base="timestamps",
            signals=signals,
            store_can_frames=any(s.stores_can_frames for s in self.sources),
            overwrite=self.overwrite,
            flush_interval_s=self.flush_interval_s,
        )
        if self.channels:
            self._ring = _Ring(int(self.live_buffer_s * rate) + 1, len(self.channels))
        for sig in signals:
            self._sig_rings[sig.name] = _Ring(int(self.live_buffer_s * _SIGNAL_BUFFER_HZ), 1)

    def _fail(self, exc: BaseException, doing: str = "recording") -> None:
        with self._lock:
            if self.error is None:
                if isinstance(exc, FieldDiagError):
                    self.error = exc
                else:
                    why = str(exc) or "no reason given"
                    self.error = DeviceError(
                        f"the recording stopped: {doing} failed ({why}); everything "
                        f"recorded before is in {self.path}. Check the device and start a "
                        "new recording"
                    )
            self._state = "failed"
        self._stop.set()

    def _run_source(self, i: int, src: Source) -> None:
        while not self._stop.is_set():
            try:
                block = src.read(self.read_timeout_s)
            except Exception as exc:  # a device error ends the recording, with the reason
                self._fail(exc, f"reading {src.url}")
                return
            if block is not None and not block.is_empty():
                try:
                    self._store(src, block, i)
                except Exception as exc:  # SessionError: disk full, file gone...
                    self._fail(exc, f"storing what {src.url} sent")
                    return
            if src.finished:
                with self._lock:
                    self._finished.add(i)
                return

    def _store(self, src: Source, block: Block, index: int) -> None:
        w = self.writer
        # the source's counters now describe exactly what it has handed over, this block
        # included (taken in its own thread, before it reads on)
        counters = src.counters()
        cal = None
        if block.n_samples:
            # the live view first: appending waits while the writer flushes to disk (up
            # to a few hundred ms), which the live plot should not
            cal = block.calibrated(src.channels)
            with self._lock:
                self._ring.push(cal.time_s, cal.samples)
        for name, (t, v) in block.signals.items():
            with self._lock:
                self._sig_rings[name].push(t, v[:, None])
        with w.same_flush():  # the block and the counters that count it: one flush
            if block.n_samples:
                w.append_daq(block.samples, block.time_s)
            for name, (t, v) in block.signals.items():
                w.append_signal(name, t, v)
            if block.can_frames is not None and len(block.can_frames):
                w.append_can_frames(block.can_frames)
            for g in block.gaps:
                w.add_gap(g.start_s, g.end_s, g.samples_lost, g.cause)
            for e in block.events:
                w.add_event(e.time_s, e.label)
            with self._lock:
                self._stored_counters[index] = counters
                total = self._sum_counters(self._stored_counters.values())
            w.set_counters(**total)
        with self._lock:
            self._samples += block.n_samples
            self._gaps += len(block.gaps)
            self._events.extend((e.time_s, e.label) for e in block.events)
        if cal is not None:
            for fn in list(self.block_listeners):
                try:
                    fn(cal)
                except Exception:
                    self.listener_errors += 1

    @staticmethod
    def _sum_counters(per_source: Any) -> dict[str, int]:
        total = dict.fromkeys(COUNTER_NAMES, 0)
        for counters in per_source:
            for k, v in counters.items():
                if k in total:
                    total[k] += int(v)
        return total

    def _counters(self) -> dict[str, int]:
        """The sources' counters now (live; the file holds those of the data stored)."""
        return self._sum_counters(s.counters() for s in self.sources)

    def _housekeeping(self) -> None:
        while not self._stop.wait(0.25):
            w = self.writer
            if w.error is not None:
                self._fail(
                    SessionError(
                        f"writing {self.path} failed ({w.error}); the recording stopped and "
                        "everything flushed before is intact"
                    )
                )
                return
            try:
                free = self._free_bytes()
            except OSError:
                free = self._reserve
            if free < self._reserve:
                self._fail(self._disk_full_error(free))
                return
            try:
                self._append_drift()
            except SessionError as exc:
                self._fail(exc)
                return
            now = time.monotonic()
            with self._lock:
                self._rate_hist.append((now, self._samples))
                self._rate_hist = [(t, n) for t, n in self._rate_hist if now - t <= 5.0]
                all_done = len(self._finished) == len(self.sources)
            if all_done:
                self._stop.set()
                return

    def _append_drift(self) -> None:
        if self.daq is None or not hasattr(self.daq, "drift_ppm"):
            return
        drift = self.daq.drift_ppm
        t = self.clock.now()
        if drift is not None and t - self._last_drift_t >= 1.0:
            self.writer.append_signal(DRIFT_SIGNAL.name, np.array([t]), np.array([drift]))
            with self._lock:
                self._sig_rings[DRIFT_SIGNAL.name].push(np.array([t]), np.array([[drift]]))
            self._last_drift_t = t

    @property
    def running(self) -> bool:
        """True while recording (not stopped, not failed, sources not all finished)."""
        return self._state == "recording" and not self._stop.is_set()

    def wait(self, duration_s: float | None = None, poll_s: float = 0.2) -> None:
        """Block until ``duration_s`` of session time, a failure, or all sources finished."""
        while self.running:
            if duration_s is not None and self.clock.now() >= duration_s:
                return
            time.sleep(poll_s)

    def stop(self) -> dict[str, Any]:
        """Stop the sources, close the session, and return the final status.

        Raises the error that stopped the recording (a FieldDiagError: full disk,
        device gone...) after everything has been closed.
        """
        if self._state in ("stopped", "new"):
            if self.error is not None:
                raise self.error
            return self.status()
        self._stop.set()
        for th in self._threads:
            th.join(5.0)
        for s in self.sources:
            try:
                s.close()
            except Exception:
                pass
        w = self.writer
        try:
            if w.error is None:
                if self.error is None:  # every block read was stored: count them all
                    w.set_counters(**self._counters())
                self._append_drift_final()
            w.close()
        except SessionError as exc:
            if self.error is None:
                self.error = exc
        self._stopped_at = self.clock.now()
        final = self.status()
        self._state = "stopped" if self.error is None else "failed"
        final["state"] = self._state
        if self.error is not None:
            raise self.error
        return final

    def _append_drift_final(self) -> None:
        self._last_drift_t = -1.0
        self._append_drift()

    def __enter__(self) -> Recorder:
        return self.start()

    def __exit__(self, exc_type, exc, tb) -> None:
        if self._state == "recording" or self._state == "failed":
            try:
                self.stop()
            except FieldDiagError:
                if exc_type is None:
                    raise

    # ------------------------------------------------------------------ live access
    def add_event(self, label: str, time_s: float | None = None) -> float:
        """Mark an instant (now by default) with a label; returns its session time."""
        t = self.clock.now() if time_s is None else float(time_s)
        self.writer.add_event(t, label)
        with self._lock:
            self._events.append((t, label))
        return t

    def latest(self, seconds: float) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """The last ``seconds`` of DAQ data: (time_s, {channel name: calibrated values})."""
        if self._ring is None:
            return np.zeros(0), {}
        rate = self.daq.sample_rate_hz or 1.0
        with self._lock:
            t, v = self._ring.newest(int(seconds * rate * 1.1) + 2)
        if t.size:
            keep = t >= t[-1] - seconds
            t, v = t[keep], v[keep]
        return t, {c.name: v[:, i].copy() for i, c in enumerate(self.channels)}

    def latest_signals(self, seconds: float) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """The last ``seconds`` of every vehicle signal: {name: (time_s, value)}."""
        out = {}
        with self._lock:
            for name, ring in self._sig_rings.items():
                t, v = ring.newest(int(seconds * _SIGNAL_BUFFER_HZ) + 2)
                if t.size:
                    keep = t >= t[-1] - seconds
                    t, v = t[keep], v[keep]
                out[name] = (t, v[:, 0].copy())
        return out

    @property
    def events(self) -> list[tuple[float, str]]:
        with self._lock:
            return list(self._events)

    def status(self) -> dict[str, Any]:
        """Live status: elapsed time, rates, counters, buffer fill, errors (JSON-ready)."""
        if self.clock is None:
            return {"state": self._state, "path": str(self.path)}
        elapsed = self._stopped_at if self._stopped_at is not None else self.clock.now()
        src_status = [s.status() for s in self.sources]
        with self._lock:
            hist = list(self._rate_hist)
            samples = self._samples
            gaps = self._gaps
        rate = None
        if len(hist) >= 2 and hist[-1][0] > hist[0][0]:
            rate = (hist[-1][1] - hist[0][1]) / (hist[-1][0] - hist[0][0])
        try:
            size = self.path.stat().st_size
        except OSError:
            size = 0
        daq_status = next(
            (st for st, s in zip(src_status, self.sources, strict=True) if s is self.daq), {}
        )
        errors = [st.get("last_error") for st in src_status if st.get("last_error")]
        return {
            "state": self._state,
            "path": str(self.path),
            "elapsed_s": float(elapsed),
            "file_size_bytes": size,
            "samples": samples,
            "sample_rate_hz": self.daq.sample_rate_hz if self.daq else None,
            "measured_rate_hz": rate,
            "gaps": gaps,
            **self._counters(),
            "buffer_fill": max(
                (st.get("buffer_fill", 0.0) or 0.0 for st in src_status), default=0.0
            ),
            "drift_ppm": daq_status.get("drift_ppm"),
            "connected": all(st.get("connected", True) or st.get("finished") for st in src_status),
            "listener_errors": self.listener_errors,
            "last_error": str(self.error) if self.error else (errors[0] if errors else ""),
            "sources": src_status,
            **({"online": self.online.status()} if self.online is not None else {}),
            **({"online_error": self.online_error} if self.online_error else {}),
        }

    def attach_online_estimator(self, **kw: Any) -> Any:
        """Estimate suspension parameters on-line from the wheel and body channels.

        Call after :meth:`start`. Returns the :class:`fielddiag.identify.online.OnlineEstimator`
        (compiled before it is attached, so the source thread never waits for numba), or
        None when the DAQ has no wheel and body channels. Its status (estimates, information
        per parameter, advice for the technician) appears under ``"online"`` in
        :meth:`status`; :attr:`online_ready` is set once it is attached (or has failed,
        ``status()["online_error"]`` then says why).
        """
        from fielddiag.identify.online import OnlineEstimator

        roles = {c.role for c in self.channels}
        if self.daq is None or not {"wheel", "body"} <= roles:
            self.online_ready.set()
            return None
        est = OnlineEstimator(self.daq.sample_rate_hz, **kw)
        listener = est.block_listener(self.channels)

        def warm_then_attach() -> None:
            # compiling may take seconds the first time: never in the caller's or the
            # source's thread; the estimate starts with the blocks after it is ready
            try:
                est.warm_up()
            except Exception as exc:  # an estimator failure must not touch the recording
                self.listener_errors += 1
                self.online_error = str(exc)
                self.online_ready.set()
                return
            self.block_listeners.append(listener)
            self.online = est
            self.online_ready.set()

        threading.Thread(target=warm_then_attach, name="online-warm-up", daemon=True).start()
        return est


def format_status(st: dict[str, Any]) -> str:
    """One console line of :meth:`Recorder.status`."""
    parts = [f"{st.get('elapsed_s', 0.0):7.1f} s"]
    if st.get("sample_rate_hz"):
        rate = st.get("measured_rate_hz")
        parts.append(
            f"DAQ {rate:6.0f} Hz" if rate is not None else f"DAQ {st['sample_rate_hz']:g} Hz"
        )
        parts.append(
            f"frames {st['frames_received']} lost {st['frames_lost']} crc {st['crc_errors']} "
            f"gaps {st['gaps']}"
        )
        if st.get("drift_ppm") is not None:
            parts.append(f"drift {st['drift_ppm']:+.0f} ppm")
    for s in st.get("sources", []):
        if s.get("kind") == "can":
            fr = s.get("frame_rate_hz")
            txt = f"CAN {fr:5.0f} fr/s" if fr is not None else "CAN -"
            for k, v in s.get("last_values", {}).items():
                if k == "vehicle_speed" or "SPEED" == k.upper():
                    txt += f" {k} {v * 3.6:.1f} km/h"
                    break
            parts.append(txt)
    parts.append(f"buf {100 * st.get('buffer_fill', 0.0):3.0f}%")
    parts.append(f"{st.get('file_size_bytes', 0) / 1e6:.1f} MB")
    if not st.get("connected", True) and st.get("state") == "recording":
        parts.append("DISCONNECTED")
    if st.get("last_error"):
        parts.append(f"[{st['last_error'][:60]}]")
    return " | ".join(parts)


def status_lines(st: Mapping[str, Any]) -> list[str]:
    """The live status as lines: recorder counters, then the on-line estimate and its advice.

    Nothing is cut: the advice for the technician is a line of its own, whole.
    """
    lines = [format_status(st)]
    online = st.get("online")
    if online:  # the estimator is running, so its module is imported already
        from fielddiag.identify.online import format_estimate

        lines.append(format_estimate(online))
        lines.append("advice: " + online.get("advice", ""))
    elif st.get("online_error"):
        lines.append("on-line estimate unavailable: " + st["online_error"])
    return lines


class StatusPrinter:
    """Show :meth:`Recorder.status` on a console, the on-line estimate included.

    On a terminal the status lines are redrawn in place, wrapped to the terminal width
    (never cut). Otherwise (a log file, a pipe) each update is one full line appended.

    Parameters
    ----------
    stream : text stream or None
        Default ``sys.stderr``.
    terminal : bool or None
        Redraw in place; default: whether ``stream`` is a terminal.
    width : int or None
        Terminal columns; default: the terminal's size.
    """

    def __init__(self, stream: TextIO | None = None, *, terminal: bool | None = None,
                 width: int | None = None) -> None:
        self.stream = stream or sys.stderr
        if terminal is None:
            isatty = getattr(self.stream, "isatty", None)
            terminal = bool(isatty()) if isatty is not None else False
        self.terminal = terminal
        self.width = width
        self._rows_shown = 0  # terminal rows of the last redraw

    def _rows(self, lines: list[str]) -> list[str]:
        width = self.width or shutil.get_terminal_size((120, 24)).columns
        room = max(20, width - 1)  # a full last column would make the terminal wrap itself
        rows: list[str] = []
        for line in lines:
            if len(line) <= room:
                rows.append(line)
            else:
                rows.extend(textwrap.wrap(line, room, subsequent_indent="    ",
                                          break_on_hyphens=False))
        return rows

    def show(self, st: Mapping[str, Any]) -> None:
        """Print one status (:meth:`Recorder.status`)."""
        lines = status_lines(st)
        if not self.terminal:
            self.stream.write(" | ".join(lines) + "\n")
        else:
            rows = self._rows(lines)
            up = f"\x1b[{self._rows_shown - 1}A" if self._rows_shown > 1 else ""
            # back to the first row of the last redraw, clear to the end of the screen
            self.stream.write("\r" + up + "\x1b[J" + "\n".join(rows))
            self._rows_shown = len(rows)
        self.stream.flush()

    def finish(self) -> None:
        """End the live display: what follows is printed below it."""
        if self.terminal and self._rows_shown:
            self.stream.write("\n")
            self.stream.flush()
        self._rows_shown = 0


# ------------------------------------------------------------------ virtual drives
def record_virtual_drive(
    path: str | os.PathLike,
    *,
    duration_s: float,
    added_mass_kg: float = 0.0,
    seed: int = 0,
    vehicle: str = "virtual car",
    corner: str = "front-left",
    rate_hz: float = 500.0,
    progress: Callable[[dict[str, Any]], None] | None = None,
    n_channels: int = 2,
    params: Any = None,
    effects: Sequence[Any] = (),
    road_class: str | None = "C",
    drive: Any = None,
    operator: str = "fielddiag demo",
    notes: str = "",
    include_recipe: bool = True,
    overwrite: bool = False,
    faults: dict[str, Any] | None = None,
    online: bool | Mapping[str, Any] = False,
) -> Path:
    """Record a simulated drive through the virtual DAQ (pty) and the virtual ECU.

    The drive is simulated with :func:`fielddiag.sim.simulate` (``added_mass_kg`` on the
    body), streamed in real time by a :class:`drivers.virtual.VirtualDAQ` on a
    pseudo-terminal (channel 0 wheel, 1 body, others noise) and read back through the real
    serial driver; a :class:`drivers.virtual.VirtualECU` publishes the drive's speed and
    wheel speeds on an in-process python-can ``virtual`` bus, read by the real CAN driver
    (signals ``vehicle_speed`` (role speed) and ``WHEEL_SPEED_FL/FR/RL/RR``, in m/s).
    Takes ``duration_s`` of wall-clock time.

    Parameters
    ----------
    path : str or Path
        Session file to create.
    duration_s : float
        Length of the recording [s].
    added_mass_kg : float
        Mass added on the body (simulation and session metadata).
    seed : int
        Seeds the simulated road, speed profile and noise.
    vehicle, corner, operator, notes : str
        Session metadata.
    rate_hz : float
        DAQ sample rate.
    progress : callable or None
        Called about 4 times a second with :meth:`Recorder.status`.
    n_channels : int
        DAQ channels (>= 2).
    params, effects, road_class : optional
        Passed to the simulator (default car, no effects, ISO class C road).
    drive : fielddiag.sim.SimulatedDrive or None
        Stream this drive instead of simulating one (its rate and added mass are used).
    include_recipe : bool
        Store how the drive was made in ``extra["simulation"]``.
    overwrite : bool
        Replace an existing session file.
    faults : dict or None
        Fault injection passed to VirtualDAQ (``corrupt_rate``, ``garbage_every_s``,
        ``disconnect_at_s``, ``disconnect_for_s``, ``stall_at_s``...).
    online : bool or mapping
        Estimate stiffness and damping on-line while recording
        (:meth:`Recorder.attach_online_estimator`; a mapping gives its keyword arguments).
        The estimator is compiled before the drive starts, so it sees the whole drive; its
        status is under ``"online"`` in what ``progress`` receives.

    Returns
    -------
    Path
        The session file.
    """
    import can

    from drivers.can_vehicle import CanBusSource
    from drivers.serial_daq import SerialDAQSource
    from drivers.virtual import VirtualDAQ, VirtualECU, simulated_accelerations

    if drive is not None:
        rate_hz = drive.sample_rate_hz
        added_mass_kg = drive.added_mass_kg
    signals, drive = simulated_accelerations(
        duration_s + 2.0,
        sample_rate_hz=rate_hz,
        n_channels=max(2, n_channels),
        added_mass_kg=added_mass_kg,
        seed=seed,
        params=params,
        effects=effects,
        road_class=road_class,
        drive=drive,
    )
    daq = VirtualDAQ(signals, sample_rate_hz=rate_hz, loop=False, seed=seed, **(faults or {}))
    channel = f"fielddiag-vecu-{uuid.uuid4().hex[:8]}"
    ecu_bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    ecu = VirtualECU(ecu_bus, drive.vehicle_speed_time_s, drive.vehicle_speed_mps, seed=seed)
    extra: dict[str, Any] = {"virtual_drive": {"seed": seed, "rate_hz": rate_hz}}
    if include_recipe:
        extra["simulation"] = drive.to_dict()
    meta = SessionMetadata(
        vehicle=vehicle,
        corner=corner,
        operator=operator,
        added_mass_kg=float(added_mass_kg),
        notes=notes,
        extra=extra,
    )
    online_kw = dict(online) if isinstance(online, Mapping) else {}
    if online:
        from fielddiag.identify.online import OnlineEstimator

        OnlineEstimator(rate_hz, **online_kw).warm_up()  # compile now, not during the drive
    daq.start()
    rec = None
    try:
        daq_src = SerialDAQSource.from_url(f"serial://{daq.path}")
        can_src = CanBusSource.from_url(f"can://virtual/{channel}")
        can_src.dbc = ecu.db
        can_src.dbc_label = "drivers.virtual.VIRTUAL_ECU_DBC"
        can_src.add_signals(
            ["vehicle_speed=SPEED.SPEED"]
            + [f"WHEEL_SPEEDS.WHEEL_SPEED_{w}" for w in ("FL", "FR", "RL", "RR")]
        )
        rec = Recorder(path, [daq_src, can_src], metadata=meta, overwrite=overwrite)
        rec.start()
        if online:
            rec.attach_online_estimator(**online_kw)
            rec.online_ready.wait(10.0)  # compiled already: attached at once
        ecu.time_fn = rec.clock.now  # speed of the drive at the session time it is sent
        ecu.start()
        next_progress = 0.0
        while rec.running and rec.clock.now() < duration_s:
            time.sleep(0.05)
            if progress is not None and time.monotonic() >= next_progress:
                progress(rec.status())
                next_progress = time.monotonic() + 0.25
        final = rec.stop()
        if progress is not None:
            progress(final)
    finally:
        ecu.stop()
        if rec is not None and rec.running:
            try:
                rec.stop()
            except FieldDiagError:
                pass
        daq.stop()
        ecu_bus.shutdown()
    return Path(path)
