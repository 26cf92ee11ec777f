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

The status on a console is :mod:`fielddiag.console`'s; a simulated drive recorded through
the virtual devices is :mod:`fielddiag.virtual_drive`'s.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

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
        """Open the sources, create the session, start recording.

        Returns
        -------
        Recorder
            self, recording.

        Raises
        ------
        DeviceError
            A source cannot be opened, or two sources decode signals of the same name.
        SessionError
            The session cannot be created (exists, no such folder, disk (almost) full).
            Sources opened before are closed again.
        """
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
        """Block until ``duration_s`` of session time, a failure, or all sources finished.

        Parameters
        ----------
        duration_s : float or None
            Session time to wait for [s]; None: until the recording ends by itself.
        poll_s : float
            Seconds between checks.
        """
        while self.running:
            if duration_s is not None and self.clock.now() >= duration_s:
                return
            time.sleep(poll_s)

    def stop(self) -> dict[str, Any]:
        """Stop the sources, close the session, and return the final status.

        Returns
        -------
        dict
            The final :meth:`status`, ``state`` ``stopped``.

        Raises
        ------
        FieldDiagError
            The error that stopped the recording (full disk, device gone...), raised
            after everything has been closed; the session holds all recorded before.
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
        """Mark an instant with a label.

        Parameters
        ----------
        label : str
            What happened (``speed bump``...).
        time_s : float or None
            Session time [s]; None: now.

        Returns
        -------
        float
            The event's session time [s].
        """
        t = self.clock.now() if time_s is None else float(time_s)
        self.writer.add_event(t, label)
        with self._lock:
            self._events.append((t, label))
        return t

    def latest(self, seconds: float) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """The last ``seconds`` of DAQ data from the live buffer.

        Parameters
        ----------
        seconds : float
            Length of the window [s], up to ``live_buffer_s``.

        Returns
        -------
        time_s : ndarray
            Session times [s].
        values : dict of str to ndarray
            Per channel name, the calibrated samples (physical unit of the channel).
        """
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
        """The last ``seconds`` of every vehicle signal from the live buffer.

        Parameters
        ----------
        seconds : float
            Length of the window [s].

        Returns
        -------
        dict of str to (ndarray, ndarray)
            Per signal name, session times [s] and values (SI units: m/s, rad...).
        """
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
        """Events so far: (session time [s], label), in the order they were marked."""
        with self._lock:
            return list(self._events)

    def status(self) -> dict[str, Any]:
        """Live status (JSON-ready).

        Returns
        -------
        dict
            ``state``, ``path``, ``elapsed_s`` [s], ``file_size_bytes``, ``samples``,
            ``sample_rate_hz`` and ``measured_rate_hz`` [Hz], ``gaps``, the counters
            (``frames_received``, ``frames_lost``, ``crc_errors``...), ``buffer_fill``
            (0..1), ``drift_ppm`` [ppm], ``connected``, ``listener_errors``,
            ``last_error``, ``sources`` (each source's own status) and, with an on-line
            estimator, ``online`` (its status) or ``online_error``.
        """
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

        Call after :meth:`start`. The estimator is compiled in a thread of its own before
        it is attached, so the source thread never waits for numba; but loading it beside
        running sources competes with their threads (a block read 0.2 s late), so a
        caller that can should compile first (``OnlineEstimator(rate).warm_up()`` before
        :meth:`start`, as ``fielddiag record`` does): then it is attached at once. Its status
        (estimates, information per parameter, advice for the technician) appears under
        ``"online"`` in :meth:`status`; :attr:`online_ready` is set once it is attached
        (or has failed, ``status()["online_error"]`` then says why).

        Parameters
        ----------
        **kw
            Keyword arguments of :class:`fielddiag.identify.online.OnlineEstimator`
            (``added_mass_kg``, ``target_rel_std``...).

        Returns
        -------
        OnlineEstimator or None
            The estimator, or None when the DAQ has no wheel and body channels.

        Raises
        ------
        TypeError
            A keyword the estimator does not take.
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
