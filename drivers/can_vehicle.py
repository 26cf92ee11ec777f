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

Units: signals in km/h or mph are stored in m/s with unit ``m/s``; all other signals
keep their DBC unit.
"""

from __future__ import annotations

import os
import time
from collections import deque
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from drivers.base import Block, Event, SignalSpec, Source, SourceURL, parse_source_url
from fielddiag.errors import DeviceError
from fielddiag.session import (
    CAN_DATA_BYTES,
    CAN_FLAG_BRS,
    CAN_FLAG_ERROR,
    CAN_FLAG_ESI,
    CAN_FLAG_EXTENDED,
    CAN_FLAG_FD,
    CAN_FLAG_REMOTE,
    CAN_FLAG_RX,
    CAN_FRAME_DTYPE,
)

#: DBC units converted to SI on decoding: unit -> (factor to m/s, stored unit).
UNIT_CONVERSIONS = {
    "km/h": (1 / 3.6, "m/s"),
    "kph": (1 / 3.6, "m/s"),
    "kmh": (1 / 3.6, "m/s"),
    "mph": (0.44704, "m/s"),
}
SPEED_NAMES = {"SPEED", "VEHICLESPEED", "VEHSPEED", "WHEELBASEDVEHICLESPEED", "VEHICLE_SPEED"}

_COMMON_KEYS = {"dbc", "signal", "speed", "decode_channel", "bus"}


def load_dbc(path: str | os.PathLike | Any) -> Any:
    """Load a DBC (or any cantools database file) leniently; pass a Database through."""
    import cantools

    if not isinstance(path, str | os.PathLike):
        return path
    p = os.fspath(path)
    if not os.path.exists(p):
        raise DeviceError(f"DBC file {p} does not exist")
    try:
        return cantools.database.load_file(p, strict=False)
    except Exception as exc:  # cantools raises many kinds of parse errors
        raise DeviceError(f"cannot read DBC {p}: {exc}") from None


# ------------------------------------------------------------------------ signal choice
@dataclass(frozen=True)
class SignalRequest:
    """A signal to decode: stored as ``name``, from DBC ``message``.``signal``."""

    name: str
    message: str
    signal: str


def resolve_signals(db: Any, requests: Iterable[str]) -> list[SignalRequest]:
    """Turn ``SIGNAL``, ``MESSAGE.SIGNAL`` or ``ALIAS=MESSAGE.SIGNAL`` into SignalRequests."""
    out: list[SignalRequest] = []
    for text in requests:
        alias, _, ref = text.rpartition("=")
        msg_name, _, sig_name = ref.rpartition(".")
        if msg_name:
            try:
                msg = db.get_message_by_name(msg_name)
            except KeyError:
                raise DeviceError(
                    f"the DBC has no message {msg_name!r} (asked for {text!r})"
                ) from None
            if sig_name not in [s.name for s in msg.signals]:
                raise DeviceError(
                    f"message {msg_name} has no signal {sig_name!r}; it has "
                    f"{', '.join(s.name for s in msg.signals)}"
                )
            found = [msg]
        else:
            found = [m for m in db.messages if any(s.name == sig_name for s in m.signals)]
            if not found:
                raise DeviceError(
                    f"no message of the DBC has a signal {sig_name!r}; name one as "
                    "MESSAGE.SIGNAL (see `cantools dump FILE.dbc`)"
                )
            if len(found) > 1:
                raise DeviceError(
                    f"signal {sig_name!r} is in several messages "
                    f"({', '.join(m.name for m in found)}); write MESSAGE.{sig_name}"
                )
        out.append(SignalRequest(alias or sig_name, found[0].name, sig_name))
    names = [r.name for r in out]
    dup = {n for n in names if names.count(n) > 1}
    if dup:
        raise DeviceError(f"signals named twice: {sorted(dup)}; give aliases (ALIAS=MSG.SIG)")
    return out


class SignalDecoder:
    """Decode the requested signals from batches of raw frames (cantools, per frame).

    Parameters
    ----------
    db : cantools Database
    requests : sequence of SignalRequest
    speed_signal : str or None
        Name (as stored) of the vehicle speed; None picks one by name.
    decode_channel : int or None
        Only frames with this bus index are decoded.
    """

    def __init__(
        self,
        db: Any,
        requests: Sequence[SignalRequest],
        *,
        speed_signal: str | None = None,
        decode_channel: int | None = None,
    ) -> None:
        self.db = db
        self.requests = list(requests)
        self.decode_channel = decode_channel
        self.errors = 0
        self.decoded_frames = 0
        by_id: dict[int, tuple[Any, list[tuple[str, str, float]]]] = {}
        self.specs: list[SignalSpec] = []
        if speed_signal is None:
            for r in self.requests:
                if r.name == "vehicle_speed" or r.signal.upper().replace("_", "") in {
                    n.replace("_", "") for n in SPEED_NAMES
                }:
                    speed_signal = r.name
                    break
        elif speed_signal not in [r.name for r in self.requests]:
            raise DeviceError(
                f"speed signal {speed_signal!r} is not among the decoded signals "
                f"{[r.name for r in self.requests]}"
            )
        self.speed_signal = speed_signal
        for r in self.requests:
            msg = db.get_message_by_name(r.message)
            sig = msg.get_signal_by_name(r.signal)
            unit = (sig.unit or "").strip()
            factor, si_unit = UNIT_CONVERSIONS.get(unit.lower(), (1.0, unit))
            entry = by_id.setdefault(msg.frame_id, (msg, []))
            entry[1].append((r.name, r.signal, factor))
            self.specs.append(
                SignalSpec(
                    name=r.name,
                    unit=si_unit,
                    source="can",
                    message=r.message,
                    role="speed" if r.name == speed_signal else "other",
                )
            )
        self._by_id = by_id

    def decode(
        self, frames: np.ndarray, data: Sequence[bytes]
    ) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Signals in ``frames`` (CAN_FRAME_DTYPE) whose payloads are ``data``."""
        if not self._by_id or len(frames) == 0:
            return {}
        ids = frames["arbitration_id"]
        wanted = np.isin(ids, np.fromiter(self._by_id, dtype="u4"))
        if self.decode_channel is not None:
            wanted &= frames["bus"] == self.decode_channel
        idx = np.flatnonzero(wanted)
        if idx.size == 0:
            return {}
        times = frames["time_s"]
        acc: dict[str, tuple[list[float], list[float]]] = {}
        for i in idx.tolist():
            msg, outs = self._by_id[int(ids[i])]
            try:
                values = msg.decode(data[i], decode_choices=False, allow_truncated=True)
            except Exception:  # a frame the DBC cannot decode (length, multiplexer...)
                self.errors += 1
                continue
            self.decoded_frames += 1
            t = float(times[i])
            for name, sig, factor in outs:
                v = values.get(sig)
                if v is None:
                    continue
                tl, vl = acc.setdefault(name, ([], []))
                tl.append(t)
                vl.append(float(v) * factor)
        return {k: (np.array(t), np.array(v)) for k, (t, v) in acc.items()}


# ------------------------------------------------------------------------ raw frames
def _flags(m: Any) -> int:
    f = 0
    if m.is_extended_id:
        f |= CAN_FLAG_EXTENDED
    if m.is_remote_frame:
        f |= CAN_FLAG_REMOTE
    if m.is_error_frame:
        f |= CAN_FLAG_ERROR
    if m.is_fd:
        f |= CAN_FLAG_FD
    if m.bitrate_switch:
        f |= CAN_FLAG_BRS
    if m.error_state_indicator:
        f |= CAN_FLAG_ESI
    if m.is_rx:
        f |= CAN_FLAG_RX
    return f


def messages_to_frames(
    msgs: Sequence[Any], time_s: np.ndarray, bus: np.ndarray | int
) -> tuple[np.ndarray, list[bytes]]:
    """Raw frames (CAN_FRAME_DTYPE) of python-can messages, and their payloads."""
    n = len(msgs)
    out = np.zeros(n, dtype=CAN_FRAME_DTYPE)
    if n == 0:
        return out, []
    data = [bytes(m.data) for m in msgs]
    out["time_s"] = time_s
    out["arbitration_id"] = [m.arbitration_id for m in msgs]
    out["bus"] = bus
    out["flags"] = [_flags(m) for m in msgs]
    out["dlc"] = [m.dlc for m in msgs]
    raw = b"".join(d[:CAN_DATA_BYTES].ljust(CAN_DATA_BYTES, b"\0") for d in data)
    out["data"] = np.frombuffer(raw, dtype="u1").reshape(n, CAN_DATA_BYTES)
    return out, data


def frames_payloads(frames: np.ndarray) -> list[bytes]:
    """Payloads of stored frames (their first ``dlc`` bytes)."""
    # python-can stores the byte count in Message.dlc, so dlc is the length already.
    lengths = np.minimum(frames["dlc"], CAN_DATA_BYTES).tolist()
    return [bytes(row[:n]) for row, n in zip(frames["data"], lengths, strict=True)]


def decode_stored_frames(
    frames: np.ndarray,
    dbc: Any,
    signals: Iterable[str],
    *,
    speed_signal: str | None = None,
    decode_channel: int | None = None,
) -> tuple[list[SignalSpec], dict[str, tuple[np.ndarray, np.ndarray]], int]:
    """Decode raw frames stored in a session with a (possibly different) DBC.

    Returns (signal specs, {name: (time_s, value)}, decode errors).
    """
    db = load_dbc(dbc)
    dec = SignalDecoder(
        db,
        resolve_signals(db, signals),
        speed_signal=speed_signal,
        decode_channel=decode_channel,
    )
    return dec.specs, dec.decode(frames, frames_payloads(frames)), dec.errors


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


BUS_RULE = (
    "bus = the number ending the log's channel name (can0 -> 0, vcan1 -> 1, ASC/BLF channel "
    "2 -> 2); other names get the next free number in order of appearance"
)


def _bus_index(channel: Any, table: dict[Any, int]) -> int:
    """Bus index of a log channel (see :data:`BUS_RULE`)."""
    if channel in table:
        return table[channel]
    s = str(channel)
    k = len(s)
    while k > 0 and s[k - 1].isdigit():
        k -= 1
    digits = s[k:]
    idx = int(digits) if digits and int(digits) < 256 else None
    if idx is None or idx in table.values():
        idx = len(table)
        while idx in table.values():
            idx += 1
    table[channel] = idx
    return idx


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
        self.decoder: SignalDecoder | None = None
        self.frames_received = 0
        self._bus_table: dict[Any, int] = {}
        self._rate_window: deque[tuple[float, int]] = deque(maxlen=200)
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
        db = load_dbc(self.dbc)
        channel = self.decode_channel
        if channel is not None and not isinstance(channel, int):
            channel = _bus_index(channel, self._bus_table)
        self.decoder = SignalDecoder(
            db,
            resolve_signals(db, self.signal_names),
            speed_signal=self.speed_signal,
            decode_channel=channel,
        )
        self.signals = list(self.decoder.specs)

    def _block(self, msgs: list[Any], time_s: np.ndarray, bus: np.ndarray | int) -> Block:
        frames, data = messages_to_frames(msgs, time_s, bus)
        signals = self.decoder.decode(frames, data) if self.decoder else {}
        for k, (_, v) in signals.items():
            self._last_values[k] = float(v[-1])
        self.frames_received += len(msgs)
        self._rate_window.append((time.monotonic(), len(msgs)))
        return Block(signals=signals, can_frames=frames)

    def counters(self) -> dict[str, int]:
        return {
            "can_frames_received": self.frames_received,
            "can_decode_errors": self.decoder.errors if self.decoder else 0,
        }

    def _frame_rate(self) -> float | None:
        now = time.monotonic()
        win = [(t, n) for t, n in self._rate_window if now - t < 5.0]
        if len(win) < 2 or win[-1][0] <= win[0][0]:
            return None
        return sum(n for _, n in win[1:]) / (win[-1][0] - win[0][0])

    def status(self) -> dict[str, Any]:
        return {
            "url": self.url,
            "kind": self.kind,
            "connected": self.connected,
            "finished": self.finished,
            "frame_rate_hz": self._frame_rate(),
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
            (_bus_index(m.channel, self._bus_table) for m in msgs), dtype="u1", count=len(msgs)
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
    "SignalDecoder",
    "SignalRequest",
    "decode_stored_frames",
    "load_dbc",
    "messages_to_frames",
    "read_can_log",
    "resolve_signals",
]
