"""CAN vehicle data: a live python-can bus or a log file, signals decoded with a DBC.

Every raw frame is kept (time, id, bus, flags, data) so a session can be decoded again
later with another DBC; the signals the user names are decoded with cantools and stored
as session signals.

``can://INTERFACE/CHANNEL?dbc=FILE&signal=NAME...``
    Any python-can interface: ``can://socketcan/can0?bitrate=500000``,
    ``can://pcan/PCAN_USBBUS1``, ``can://slcan//dev/ttyACM0?bitrate=500000``,
    ``can://virtual/demo`` (in-process), ``can://udp_multicast/239.74.163.2`` (between
    processes; needs the msgpack package). Frames arrive through python-can's
    ``Notifier``, whose thread only appends them to a queue: converting and decoding
    happen in batches in :meth:`CanBusSource.read` (python-can's receive path already costs
    about 0.1 ms of CPU per frame).
``canlog://FILE?dbc=FILE&signal=NAME...``
    Any format python-can's ``LogReader`` reads (.asc, .blf, .log, .trc, .csv, .mf4...),
    replayed at ``rate`` times real time (1 by default; ``rate=0`` as fast as possible).

Options: ``dbc`` (file), ``signal`` (repeatable or comma-separated; ``SIGNAL``,
``MESSAGE.SIGNAL`` or ``ALIAS=MESSAGE.SIGNAL``), ``speed`` (which of them is the vehicle
speed; default the one called SPEED / VEHICLE_SPEED / ... or aliased ``vehicle_speed``),
``decode_channel`` (decode only frames from this bus channel, e.g. ``can0``: other buses
can reuse the same IDs), ``bus`` (index stored with every frame of a live bus). Other
options of a ``can://`` URL go to ``can.Bus`` (``bitrate``, ``fd``, ``data_bitrate``,
``sleep_after_open``...).

Decoding, units (SI: km/h -> m/s, deg -> rad, rpm -> rad/s, g -> m/s2...), CAN FD
lengths and signal names are those of :mod:`drivers.can_decode`, which the import of CAN
logs uses too: the same frames are stored as the same signals either way.
"""

from __future__ import annotations

import os
import time
from collections import deque
from collections.abc import Iterable, Iterator, Sequence
from typing import Any

import numpy as np

from drivers.base import (
    Block,
    Event,
    RateWindow,
    SignalSpec,
    Source,
    SourceURL,
    parse_source_url,
)
from drivers.can_decode import (
    BUS_RULE,
    BusTable,
    CanDecoder,
    Dbc,
    load_dbc,
    messages_to_frames,
    resolve_signals,
)
from fielddiag.errors import DeviceError
from fielddiag.session import CAN_FRAME_DTYPE

_COMMON_KEYS = {"dbc", "signal", "speed", "decode_channel", "bus"}


def decode_stored_frames(
    frames: np.ndarray,
    dbc: Any,
    signals: Iterable[str],
    *,
    speed_signal: str | None = None,
    decode_channel: int | None = None,
) -> tuple[list[SignalSpec], dict[str, tuple[np.ndarray, np.ndarray]], int]:
    """Decode raw frames stored in a session with a (possibly different) DBC.

    Parameters
    ----------
    frames : numpy.ndarray of CAN_FRAME_DTYPE
        As :meth:`fielddiag.session.SessionReader.can_frames` returns them.
    dbc : path or cantools Database
    signals : iterable of str
        ``SIGNAL``, ``MESSAGE.SIGNAL`` or ``ALIAS=MESSAGE.SIGNAL``.
    speed_signal : str or None
        Stored name of the vehicle speed (default: found by name).
    decode_channel : int or None
        Decode only the frames of this bus index.

    Returns
    -------
    specs : list of SignalSpec
    signals : dict
        ``{name: (time_s, value_si)}``, as the recorder would have stored them.
    errors : int
        Frames that failed to decode.
    """
    buses = None if decode_channel is None else frozenset({int(decode_channel)})
    dbc_obj = Dbc(load_dbc(dbc), _dbc_label(dbc), buses)
    dec = CanDecoder(resolve_signals(dbc_obj, signals, speed_signal=speed_signal))
    return dec.specs, dec.decode(frames), dec.errors


def _dbc_label(dbc: Any) -> str:
    return os.path.basename(os.fspath(dbc)) if isinstance(dbc, str | os.PathLike) else "the DBC"


# ------------------------------------------------------------------------ sources
def _typed(value: str) -> Any:
    low = value.lower()
    if low in ("true", "yes", "on"):
        return True
    if low in ("false", "no", "off"):
        return False
    for conv in (int, float):
        try:
            return conv(value)
        except ValueError:
            pass
    return value


class _CanSource(Source):
    kind = "can"

    def __init__(
        self,
        url: str,
        *,
        dbc: Any = None,
        signals: Sequence[str] = (),
        speed_signal: str | None = None,
        decode_channel: str | int | None = None,
        min_block_interval_s: float = 0.05,
    ) -> None:
        super().__init__(url)
        self.dbc = dbc
        self.signal_names = list(signals)
        self.speed_signal = speed_signal
        self.decode_channel = decode_channel
        self.min_block_interval_s = min_block_interval_s
        self.stores_can_frames = True
        self.dbc_label: str | None = None  # how to name a DBC given as a Database object
        self.decoder: CanDecoder | None = None
        self.frames_received = 0
        self._bus_table = BusTable()
        self._rate_window = RateWindow()
        self._last_values: dict[str, float] = {}

    @staticmethod
    def _common(u: SourceURL) -> dict[str, Any]:
        dc = u.get("decode_channel")
        return {
            "dbc": u.get("dbc"),
            "signals": u.get_all("signal"),
            "speed_signal": u.get("speed"),
            "decode_channel": dc,
        }

    def add_signals(self, names: Iterable[str]) -> None:
        """Decode these signals too (before :meth:`open`; the CLI's ``--signal``)."""
        for n in names:
            if n not in self.signal_names:
                self.signal_names.append(n)

    def _setup_decoder(self) -> None:
        if self.signal_names and self.dbc is None:
            raise DeviceError(f"{self.url}: signals {self.signal_names} need a DBC: add ?dbc=FILE")
        if self.dbc is None:
            self.signals = []
            return
        channel = self.decode_channel
        if channel is not None and not isinstance(channel, int):
            channel = self._bus_table.index(channel)
        dbc = Dbc(
            load_dbc(self.dbc),
            self.dbc_label or _dbc_label(self.dbc),
            None if channel is None else frozenset({channel}),
        )
        self.decoder = CanDecoder(
            resolve_signals(dbc, self.signal_names, speed_signal=self.speed_signal)
        )
        self.signals = list(self.decoder.specs)

    def _block(self, msgs: list[Any], time_s: np.ndarray, bus: np.ndarray | int) -> Block:
        frames = messages_to_frames(msgs, time_s, bus)
        signals = self.decoder.decode(frames) if self.decoder else {}
        for k, (_, v) in signals.items():
            self._last_values[k] = float(v[-1])
        self.frames_received += len(msgs)
        self._rate_window.add(len(msgs))
        return Block(signals=signals, can_frames=frames)

    def counters(self) -> dict[str, int]:
        return {
            "can_frames_received": self.frames_received,
            "can_decode_errors": self.decoder.errors if self.decoder else 0,
        }

    def status(self) -> dict[str, Any]:
        return {
            "url": self.url,
            "kind": self.kind,
            "connected": self.connected,
            "finished": self.finished,
            "frame_rate_hz": self._rate_window.rate_per_s(),
            "last_values": dict(self._last_values),
            "last_error": self.last_error,
            **self.counters(),
        }

    def describe(self) -> dict[str, Any]:
        return {
            "url": self.url,
            "kind": self.kind,
            "dbc": (
                os.path.abspath(self.dbc)
                if isinstance(self.dbc, str | os.PathLike)
                else self.dbc_label
            ),
            "signals": [s.to_dict() for s in self.signals],
        }


class _QueueListener:
    """python-can listener that only queues messages (runs in the Notifier thread)."""

    def __init__(self, queue: deque) -> None:
        self.queue = queue
        self.error: BaseException | None = None

    def on_message_received(self, msg: Any) -> None:
        self.queue.append(msg)

    def __call__(self, msg: Any) -> None:
        self.queue.append(msg)

    def on_error(self, exc: Exception) -> None:
        self.error = exc

    def stop(self) -> None:
        pass


class CanBusSource(_CanSource):
    """A live CAN bus through any python-can interface (``can://INTERFACE/CHANNEL``)."""

    schemes = ("can",)

    def __init__(
        self,
        url: str,
        interface: str,
        channel: str | None,
        *,
        bus_index: int = 0,
        bus_kwargs: dict[str, Any] | None = None,
        bus: Any = None,
        **kw: Any,
    ) -> None:
        super().__init__(url, **kw)
        self.interface = interface
        self.channel = channel
        self.bus_index = bus_index
        self.bus_kwargs = bus_kwargs or {}
        self._bus = bus
        self._own_bus = bus is None
        self._queue: deque = deque()
        self._listener = _QueueListener(self._queue)
        self._notifier = None
        self._last_read = 0.0
        self.reconnects = 0
        self.max_queue = 0

    @classmethod
    def from_url(cls, url: str) -> CanBusSource:
        u = parse_source_url(url)
        if not u.netloc:
            raise DeviceError(
                f"{url}: name the python-can interface, e.g. can://socketcan/can0 or "
                "can://virtual/demo"
            )
        channel = u.path[1:] if u.path.startswith("/") else u.path
        kwargs = {k: _typed(v[-1]) for k, v in u.params.items() if k not in _COMMON_KEYS}
        return cls(
            url,
            u.netloc,
            channel or None,
            bus_index=u.get_int("bus", 0),
            bus_kwargs=kwargs,
            **cls._common(u),
        )

    def _open_bus(self) -> Any:
        import can

        try:
            return can.Bus(interface=self.interface, channel=self.channel, **self.bus_kwargs)
        except Exception as exc:  # python-can raises interface-specific errors
            hint = ""
            if "msgpack" in str(exc):
                hint = " (pip install msgpack, or use the virtual ECU's slcan pty)"
            raise DeviceError(
                f"cannot open CAN interface {self.interface!r} channel {self.channel!r}: "
                f"{exc}{hint}"
            ) from None

    def open(self) -> None:
        self._setup_decoder()
        if self._bus is None:
            self._bus = self._open_bus()
        self.connected = True

    def start(self, clock) -> None:
        import can

        super().start(clock)
        self._queue.clear()
        self._notifier = can.Notifier(self._bus, [self._listener], timeout=0.1)

    def _reopen(self) -> Block | None:
        err = self._listener.error
        self._listener.error = None
        self.last_error = f"CAN bus error: {err}; reopening"
        self._stop_notifier()
        if self._own_bus:
            try:
                self._bus.shutdown()
            except Exception:
                pass
            try:
                self._bus = self._open_bus()
            except DeviceError as exc:
                self.last_error = str(exc)
                self.connected = False
                time.sleep(1.0)
                self._listener.error = err
                return None
        self.start(self.clock)
        self.connected = True
        self.reconnects += 1
        return Block(events=[Event(self.clock.now(), "CAN bus reopened")])

    def read(self, timeout_s: float = 0.1) -> Block | None:
        if self.clock is None:
            raise RuntimeError("start() the source before read()")
        if self._listener.error is not None:
            return self._reopen()
        wait = self._last_read + self.min_block_interval_s - time.monotonic()
        if wait > 0:
            time.sleep(min(wait, timeout_s))
        if not self._queue:
            time.sleep(min(timeout_s, self.min_block_interval_s))
        self._last_read = time.monotonic()
        q = self._queue
        n = len(q)
        if n == 0:
            return None
        self.max_queue = max(self.max_queue, n)
        msgs = [q.popleft() for _ in range(n)]
        ts = np.fromiter((m.timestamp for m in msgs), dtype="f8", count=n)
        return self._block(msgs, self.clock.from_unix(ts), self.bus_index)

    def counters(self) -> dict[str, int]:
        c = super().counters()
        c["reconnects"] = self.reconnects
        return c

    def status(self) -> dict[str, Any]:
        st = super().status()
        st["buffer_fill"] = min(1.0, len(self._queue) / 100_000)
        return st

    def _stop_notifier(self) -> None:
        if self._notifier is not None:
            try:
                self._notifier.stop(timeout=1.0)
            except Exception:
                pass
            self._notifier = None

    def close(self) -> None:
        self._stop_notifier()
        if self._bus is not None and self._own_bus:
            try:
                self._bus.shutdown()
            except Exception:
                pass
        self._bus = None
        self.connected = False

    def describe(self) -> dict[str, Any]:
        d = super().describe()
        d.update({"interface": self.interface, "channel": self.channel, "bus": self.bus_index})
        return d


class CanLogSource(_CanSource):
    """A CAN log file replayed through python-can's readers (``canlog://FILE``)."""

    schemes = ("canlog",)

    def __init__(self, url: str, path: str, *, rate: float = 1.0, **kw: Any) -> None:
        super().__init__(url, **kw)
        self.path = path
        self.rate = float(rate)
        self._iter: Iterator[Any] | None = None
        self._peek: Any = None
        self.log_t0_s = 0.0
        self._start_session_s = 0.0
        self._start_mono = 0.0
        self.batch_frames = 20000

    @classmethod
    def from_url(cls, url: str) -> CanLogSource:
        u = parse_source_url(url)
        u.check_keys(_COMMON_KEYS | {"rate"})
        if not u.location:
            raise DeviceError(f"{url}: no file; use canlog://path/to/drive.asc?dbc=car.dbc")
        return cls(url, u.location, rate=u.get_float("rate", 1.0), **cls._common(u))

    def open(self) -> None:
        import can

        if not os.path.isfile(self.path):
            raise DeviceError(f"CAN log {self.path} does not exist")
        self._setup_decoder()
        try:
            self._iter = iter(can.LogReader(self.path))
            self._peek = next(self._iter, None)
        except Exception as exc:
            raise DeviceError(
                f"cannot read CAN log {self.path}: {exc}; python-can reads .asc, .blf, "
                ".csv, .db, .log (candump -l), .mf4 and .trc"
            ) from None
        if self._peek is None:
            raise DeviceError(f"CAN log {self.path} holds no frames")
        self.log_t0_s = float(self._peek.timestamp)
        self.connected = True

    def start(self, clock) -> None:
        super().start(clock)
        self._start_session_s = clock.now()
        self._start_mono = time.monotonic()

    def _take(self, until_log_s: float | None, limit: int) -> list[Any]:
        out: list[Any] = []
        while self._peek is not None and len(out) < limit:
            if until_log_s is not None and self._peek.timestamp - self.log_t0_s > until_log_s:
                break
            out.append(self._peek)
            try:
                self._peek = next(self._iter)
            except StopIteration:
                self._peek = None
            except Exception as exc:
                self.last_error = f"{self.path}: {exc}; stopped reading there"
                self._peek = None
        if self._peek is None:
            self.finished = True
        return out

    def read(self, timeout_s: float = 0.1) -> Block | None:
        if self.clock is None:
            raise RuntimeError("start() the source before read()")
        if self.finished:
            return None
        if self.rate > 0:
            wait = self.min_block_interval_s
            time.sleep(min(wait, timeout_s))
            until = (time.monotonic() - self._start_mono) * self.rate
            msgs = self._take(until, 10 * self.batch_frames)
        else:
            msgs = self._take(None, self.batch_frames)
        if not msgs:
            return None
        ts = np.fromiter((m.timestamp for m in msgs), dtype="f8", count=len(msgs))
        bus = np.fromiter(
            (self._bus_table.index(m.channel) for m in msgs), dtype="u1", count=len(msgs)
        )
        return self._block(msgs, self._start_session_s + (ts - self.log_t0_s), bus)

    def close(self) -> None:
        self._iter = None
        self._peek = None
        self.connected = False

    def describe(self) -> dict[str, Any]:
        d = super().describe()
        d.update(
            {
                "path": os.path.abspath(self.path),
                "log_t0_unix_s": self.log_t0_s,
                "bus_rule": BUS_RULE,
            }
        )
        return d


def read_can_log(
    path: str | os.PathLike,
    dbc: Any,
    signals: Iterable[str],
    *,
    decode_channel: str | None = None,
    speed_signal: str | None = None,
) -> tuple[np.ndarray, dict[str, tuple[np.ndarray, np.ndarray]], list[SignalSpec], int]:
    """Read a whole CAN log: raw frames, decoded signals (time from the first frame), specs.

    Returns (frames, signals, specs, decode errors).
    """
    from drivers.base import SessionClock

    src = CanLogSource(
        f"canlog://{os.fspath(path)}",
        os.fspath(path),
        rate=0.0,
        dbc=dbc,
        signals=list(signals),
        speed_signal=speed_signal,
        decode_channel=decode_channel,
    )
    src.open()
    clock = SessionClock()
    src.start(clock)
    src._start_session_s = 0.0
    frames, acc = [], {}
    while not src.finished:
        b = src.read(0.0)
        if b is None:
            continue
        frames.append(b.can_frames)
        for k, (t, v) in b.signals.items():
            acc.setdefault(k, []).append((t, v))
    src.close()
    sig = {
        k: (np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts]))
        for k, parts in acc.items()
    }
    allf = np.concatenate(frames) if frames else np.zeros(0, CAN_FRAME_DTYPE)
    return allf, sig, src.signals, src.counters()["can_decode_errors"]


__all__ = [
    "CanBusSource",
    "CanLogSource",
    "decode_stored_frames",
    "read_can_log",
]
