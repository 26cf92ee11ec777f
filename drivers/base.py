"""What every data source has in common: blocks, the source interface, URLs, clocks.

A source is opened from a URL, the way python-can picks an interface from a name::

    serial:///dev/ttyUSB0?baud=921600                  fielddiag DAQ, binary protocol
    serial+ascii:///dev/ttyACM0?baud=115200&rate=100   text lines "t_us,ch0,ch1,..."
    can://socketcan/can0?bitrate=500000&dbc=car.dbc    any python-can interface
    canlog://drive.asc?dbc=car.dbc                      a log file python-can reads

(see :data:`SOURCE_SCHEMES` and :func:`open_source`). A source is used as::

    src = open_source(url)      # not connected yet
    src.open()                  # connect, handshake: src.channels / src.signals are known
    src.start(clock)            # start streaming; times are session times from ``clock``
    while ...:
        block = src.read(timeout_s=0.1)    # a Block, or None if nothing arrived
    src.close()

Session time zero is the start of the recording on the host (:class:`SessionClock`). Device
clocks are mapped onto it by :class:`ClockSync`.
"""

from __future__ import annotations

import importlib
import math
import threading
import time
import urllib.parse
from abc import ABC, abstractmethod
from collections import deque
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from fielddiag.channels import ChannelSpec, Event, Gap, SignalSpec
from fielddiag.errors import DeviceError

__all__ = [
    "Block",
    "ChannelSpec",
    "ClockSync",
    "Event",
    "Gap",
    "SessionClock",
    "SignalSpec",
    "Source",
    "SourceURL",
    "SOURCE_SCHEMES",
    "open_source",
    "parse_source_url",
    "register_source",
    "source_class",
]


# ------------------------------------------------------------------------------ blocks
@dataclass
class Block:
    """A batch of data read from one source.

    Parameters
    ----------
    time_s : ndarray (n,)
        Session time of every DAQ sample (float64).
    samples : ndarray (n, n_channels)
        Raw DAQ samples in the device's dtype (counts), in ``Source.channels`` order.
    signals : dict
        Decoded vehicle signals: name -> (time_s, value) in SI units.
    can_frames : ndarray or None
        Raw CAN frames (:data:`fielddiag.session.CAN_FRAME_DTYPE`).
    gaps, events : list
        Gaps (samples lost, with the cause) and events found while reading.
    """

    time_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    samples: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    signals: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    can_frames: np.ndarray | None = None
    gaps: list[Gap] = field(default_factory=list)
    events: list[Event] = field(default_factory=list)

    @property
    def n_samples(self) -> int:
        return int(self.time_s.shape[0])

    def is_empty(self) -> bool:
        return (
            self.n_samples == 0
            and not self.signals
            and (self.can_frames is None or len(self.can_frames) == 0)
            and not self.gaps
            and not self.events
        )

    def calibrated(self, channels: list[ChannelSpec]) -> Block:
        """A copy whose samples are in physical units (float64): raw * scale + offset."""
        phys = self.samples.astype("f8")
        if phys.size:
            scale = np.array([c.scale for c in channels])
            offset = np.array([c.offset for c in channels])
            phys = phys * scale + offset
        return Block(self.time_s, phys, self.signals, self.can_frames, self.gaps, self.events)


# ------------------------------------------------------------------------------ clocks
class SessionClock:
    """Session time: seconds since the recording started, on the host's monotonic clock.

    ``t0_unix_s`` is the wall-clock time of session time zero (stored in the session).
    Time stamps given in wall-clock time (python-can's ``msg.timestamp``) are converted
    with :meth:`from_unix`.
    """

    def __init__(self) -> None:
        self.t0_monotonic_s = time.monotonic()
        self.t0_unix_s = time.time()

    def now(self) -> float:
        """Session time now [s]."""
        return time.monotonic() - self.t0_monotonic_s

    def from_unix(self, t_unix_s: np.ndarray | float) -> np.ndarray | float:
        """Session time of wall-clock time stamps [s]."""
        return np.asarray(t_unix_s, dtype="f8") - self.t0_unix_s


class ClockSync:
    """Map a device clock onto host (session) time: offset plus drift, continuous, monotonic.

    The device stamps its samples with its own clock; the host sees each batch arrive a
    little later (USB latency, scheduling). :meth:`observe` takes (device time of the
    newest sample, host arrival time) pairs. Per ``window_s`` of device time the pair with
    the smallest host-minus-device difference is kept (the least delayed one); a robust
    straight-line fit through these minima over the last ``history_windows`` windows gives
    the drift and the offset. The mapping actually applied (:meth:`map`) is a continuous
    piecewise-linear function of device time that is steered toward the fitted line by
    changing its slope by at most ``max_slew`` (like NTP slewing), so time stamps never jump
    and never run backwards. Offsets further off than ``step_threshold_s`` are stepped.

    Parameters
    ----------
    window_s : float
        Device time per minimum-latency window.
    history_windows : int
        Windows kept for the fit (600 = the last 10 minutes).
    slew_time_s : float
        Time constant with which offset errors are corrected.
    max_slew : float
        Largest slope correction (2e-3 = 2 ms per second).
    min_fit_span_s : float
        Span of device time needed before the drift is estimated.
    step_threshold_s : float
        Offset error beyond which the mapping steps instead of slewing.
    """

    def __init__(
        self,
        *,
        window_s: float = 1.0,
        history_windows: int = 600,
        slew_time_s: float = 5.0,
        max_slew: float = 2e-3,
        min_fit_span_s: float = 10.0,
        step_threshold_s: float = 0.5,
    ) -> None:
        self.window_s = window_s
        self.history_windows = history_windows
        self.slew_time_s = slew_time_s
        self.max_slew = max_slew
        self.min_fit_span_s = min_fit_span_s
        self.step_threshold_s = step_threshold_s
        self.reset()

    def reset(self) -> None:
        """Forget everything (a new device clock epoch)."""
        self._anchor: tuple[float, float] | None = None
        self._rate = 1.0
        self._slope = 0.0  # d(host - device)/d(device) of the fit
        self._windows: deque[tuple[float, float]] = deque(maxlen=self.history_windows)
        self._cur_key: int | None = None
        self._cur_min = math.inf
        self._cur_d = 0.0
        self.fit_offset_s: float | None = None  # host - device at the newest window

    @property
    def locked(self) -> bool:
        """True once a first pair has anchored the mapping."""
        return self._anchor is not None

    @property
    def drift_ppm(self) -> float:
        """Device clock rate error: positive when the device clock runs fast [ppm]."""
        return -self._slope / (1.0 + self._slope) * 1e6

    @property
    def drift_known(self) -> bool:
        """True once enough device time has passed for a drift estimate."""
        return len(self._windows) >= 3 and (
            self._windows[-1][0] - self._windows[0][0] >= self.min_fit_span_s
        )

    def map(self, t_dev_s: np.ndarray | float) -> np.ndarray:
        """Host/session time of device times (the applied, continuous mapping)."""
        if self._anchor is None:
            raise RuntimeError("ClockSync.map before the first observe()")
        d0, h0 = self._anchor
        return h0 + self._rate * (np.asarray(t_dev_s, dtype="f8") - d0)

    def observe(self, t_dev_s: float, t_host_s: float) -> None:
        """A device time and the host time at which it was known to have passed."""
        if self._anchor is None:
            self._anchor = (t_dev_s, t_host_s)
        diff = t_host_s - t_dev_s
        key = math.floor(t_dev_s / self.window_s)
        if key != self._cur_key:
            if self._cur_key is not None:
                self._windows.append((self._cur_d, self._cur_min))
                self._update(t_dev_s)
            self._cur_key, self._cur_min, self._cur_d = key, diff, t_dev_s
        elif diff < self._cur_min:
            self._cur_min, self._cur_d = diff, t_dev_s

    def _update(self, tau: float) -> None:
        w = np.array(self._windows)
        d, off = w[:, 0], w[:, 1]
        if self.drift_known:
            x = d - d[-1]
            keep = np.ones(len(d), bool)
            a, b = float(np.min(off)), 0.0
            for _ in range(3):
                b, a = np.polyfit(x[keep], off[keep], 1)
                r = off - (a + b * x)
                mad = float(np.median(np.abs(r[keep] - np.median(r[keep]))))
                new = r <= max(3.0 * 1.4826 * mad, 2e-4)
                if new.sum() < 3 or np.array_equal(new, keep):
                    break
                keep = new
            self._slope = float(b)
            est = tau + a + b * (tau - d[-1])
            self.fit_offset_s = float(a)
        else:
            est = tau + float(np.min(off[-3:]))
            self.fit_offset_s = float(np.min(off[-3:]))
        cur = float(self.map(tau))
        err = est - cur
        if abs(err) > self.step_threshold_s:
            self._anchor = (tau, est)
            self._rate = 1.0 + self._slope
            return
        corr = min(max(err / self.slew_time_s, -self.max_slew), self.max_slew)
        self._anchor = (tau, cur)
        self._rate = 1.0 + self._slope + corr


class RateWindow:
    """Items received per second over the last few seconds, for a source's status.

    The reading thread adds while the recorder's thread reads the rate: both hold a lock
    (a deque iterated while another thread appends raises "deque mutated during
    iteration": it stopped a demo recording once, from the CAN source's status).

    Parameters
    ----------
    span_s : float
        How far back the rate is read [s].
    maxlen : int
        How many arrivals are kept at most.
    """

    def __init__(self, span_s: float = 5.0, maxlen: int = 200) -> None:
        self.span_s = span_s
        self._arrivals: deque[tuple[float, int]] = deque(maxlen=maxlen)
        self._lock = threading.Lock()

    def add(self, n: int) -> None:
        """``n`` items arrived now."""
        with self._lock:
            self._arrivals.append((time.monotonic(), n))

    def rate_per_s(self) -> float | None:
        """Items per second over the arrivals within :attr:`span_s` (the first one's
        items not counted: they arrived before the span began); None with fewer than two.
        """
        now = time.monotonic()
        with self._lock:
            win = [(t, n) for t, n in self._arrivals if now - t < self.span_s]
        if len(win) < 2 or win[-1][0] <= win[0][0]:
            return None
        return sum(n for _, n in win[1:]) / (win[-1][0] - win[0][0])


# ------------------------------------------------------------------------------ URLs
@dataclass(frozen=True)
class SourceURL:
    """A parsed source URL.

    ``location`` is what follows ``scheme://`` up to ``?``: for ``serial:///dev/ttyUSB0``
    it is ``/dev/ttyUSB0``, for ``canlog://logs/a.asc`` the relative path ``logs/a.asc``.
    ``params`` maps each query key to its values (repeatable keys such as ``signal``).
    """

    url: str
    scheme: str
    location: str
    netloc: str
    path: str
    params: dict[str, list[str]]

    def get(self, key: str, default: str | None = None) -> str | None:
        vals = self.params.get(key)
        return vals[-1] if vals else default

    def get_all(self, key: str) -> list[str]:
        out: list[str] = []
        for v in self.params.get(key, []):
            out.extend(p for p in v.split(",") if p)
        return out

    def get_float(self, key: str, default: float | None = None) -> float | None:
        v = self.get(key)
        if v is None:
            return default
        try:
            return float(v)
        except ValueError:
            raise DeviceError(f"{self.url}: {key}={v!r} is not a number") from None

    def get_int(self, key: str, default: int | None = None) -> int | None:
        v = self.get(key)
        if v is None:
            return default
        try:
            return int(float(v))
        except ValueError:
            raise DeviceError(f"{self.url}: {key}={v!r} is not a whole number") from None

    def get_bool(self, key: str, default: bool = False) -> bool:
        v = self.get(key)
        if v is None:
            return default
        if v.lower() in ("1", "true", "yes", "on"):
            return True
        if v.lower() in ("0", "false", "no", "off"):
            return False
        raise DeviceError(f"{self.url}: {key}={v!r} must be true or false")

    def check_keys(self, allowed: set[str]) -> None:
        """Raise DeviceError for unknown query keys (typos should not be silent)."""
        unknown = sorted(set(self.params) - allowed)
        if unknown:
            raise DeviceError(
                f"{self.url}: unknown option(s) {', '.join(unknown)}; "
                f"known: {', '.join(sorted(allowed))}"
            )


def parse_source_url(url: str) -> SourceURL:
    """Split a source URL into scheme, location and query parameters."""
    parts = urllib.parse.urlsplit(url)
    if not parts.scheme or "://" not in url:
        raise DeviceError(
            f"{url!r} is not a source URL; use e.g. serial:///dev/ttyUSB0, "
            "can://socketcan/can0?dbc=car.dbc or canlog://drive.asc?dbc=car.dbc"
        )
    netloc = urllib.parse.unquote(parts.netloc)
    path = urllib.parse.unquote(parts.path)
    params = urllib.parse.parse_qs(parts.query, keep_blank_values=True)
    return SourceURL(url, parts.scheme.lower(), netloc + path, netloc, path, params)


# ------------------------------------------------------------------------------ sources
class Source(ABC):
    """A data source: a DAQ (samples on channels) or a vehicle bus (signals, raw frames).

    Subclasses set ``channels`` (DAQ channels, empty for a bus) and ``signals`` (decoded
    signals, empty for a DAQ) in :meth:`open`, and return :class:`Block` s from :meth:`read`.
    """

    #: "daq" for a source of DAQ samples, "can" for a vehicle bus.
    kind: ClassVar[str] = "daq"
    #: URL schemes the class handles.
    schemes: ClassVar[tuple[str, ...]] = ()

    def __init__(self, url: str) -> None:
        self.url = url
        self.channels: list[ChannelSpec] = []
        self.signals: list[SignalSpec] = []
        self.sample_rate_hz: float | None = None
        self.stores_can_frames = False
        self.finished = False
        self.connected = False
        self.last_error: str = ""
        self.clock: SessionClock | None = None

    @classmethod
    @abstractmethod
    def from_url(cls, url: str) -> Source:
        """A source configured from its URL (not opened)."""

    @abstractmethod
    def open(self) -> None:
        """Connect and learn the channels/signals; raise DeviceError if impossible."""

    def start(self, clock: SessionClock) -> None:
        """Start streaming; times in blocks are session times of ``clock``."""
        self.clock = clock

    @abstractmethod
    def read(self, timeout_s: float = 0.1) -> Block | None:
        """Wait up to ``timeout_s`` for data; a Block of what arrived, or None."""

    @abstractmethod
    def close(self) -> None:
        """Stop streaming and release the device."""

    def counters(self) -> dict[str, int]:
        """Counters named as in :data:`fielddiag.channels.COUNTER_NAMES`."""
        return {}

    def status(self) -> dict[str, Any]:
        """Live status for the console and the dashboard (JSON-serialisable)."""
        return {"url": self.url, "kind": self.kind, "connected": self.connected}

    def describe(self) -> dict[str, Any]:
        """What to store in the session metadata about this source."""
        return {"url": self.url, "kind": self.kind}

    def __enter__(self) -> Source:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# ------------------------------------------------------------------------------ registry
#: URL scheme -> "module:Class" of the source that handles it (imported when used).
SOURCE_SCHEMES: dict[str, str] = {
    "serial": "drivers.serial_daq:SerialDAQSource",
    "serial+ascii": "drivers.serial_daq:SerialTextSource",
    "can": "drivers.can_vehicle:CanBusSource",
    "canlog": "drivers.can_vehicle:CanLogSource",
}


def register_source(scheme: str, target: str | type[Source]) -> None:
    """Make ``scheme://`` URLs open with ``target`` (a Source class or "module:Class")."""
    if isinstance(target, type):
        target = f"{target.__module__}:{target.__qualname__}"
    SOURCE_SCHEMES[scheme.lower()] = target


def source_class(url: str) -> type[Source]:
    """The Source class that handles ``url``'s scheme."""
    scheme = parse_source_url(url).scheme
    target = SOURCE_SCHEMES.get(scheme)
    if target is None:
        raise DeviceError(
            f"no driver for {scheme}:// URLs ({url}); known: "
            + ", ".join(f"{s}://" for s in sorted(SOURCE_SCHEMES))
        )
    module, _, name = target.partition(":")
    return getattr(importlib.import_module(module), name)


def open_source(url: str) -> Source:
    """The source for ``url``, configured but not opened (call ``open()``)."""
    return source_class(url).from_url(url)
