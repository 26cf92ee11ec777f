"""Accelerometer DAQ over a serial port (pyserial): the binary protocol and the text mode.

``serial://PORT?baud=921600`` speaks the fielddiag binary protocol (``drivers/PROTOCOL.md``):
a device-info handshake, START/STOP, CRC-checked data frames with sequence numbers and
device time stamps. ``serial+ascii://PORT?baud=115200`` reads ``t_us,ch0,ch1,...`` lines
from Arduino-style streamers.

What the driver does with a real, imperfect link:

* garbage between frames is skipped and counted; frames failing a CRC are dropped and
  counted; sequence gaps become gaps in the session with the exact number of samples
  lost (frames lost x samples per frame);
* if the port disappears (cable pulled) the source keeps going: it closes the port,
  watches for the same path to come back (every 50 ms; failed opens of a path that is
  there back off to 1 s), re-checks that the same device came back, sends START again,
  and records the outage as a gap (exact when the device kept counting frames while the
  host was away). The port is opened without flushing its input: frames the device sent
  before the host got there are sequence-numbered and time-stamped, so they are kept;
* every frame is stamped with the host time it arrived (bytes are read as they come,
  even though blocks are handed over at most every ``block_ms``), and device time stamps
  are mapped to session time with :class:`drivers.clock_fit.DeviceClockFit`: a line
  fitted under the least-delayed arrivals (it also gives the device clock drift in ppm),
  applied without jumps. The first 0.25 s of a clock epoch are held back until the fit
  has settled.

Query options of the URL (all optional):

``baud``
    Baud rate (921600; ignored by USB CDC devices and pseudo-terminals).
``roles``, ``names``
    Comma-separated channel roles / names overriding those from the device.

A channel map set on the source before it is opened (:attr:`_SerialPortSource.role_map`,
``{channel index: role}``; ``fielddiag record --role wheel_fl=0 ...``) gives the mapped
channels their role and name (``wheel_fl``...) and makes every other channel ``other``:
the device's INFO frame cannot say which corner a sensor is on. A channel index the
device does not have is refused when the device has said how many it has.
``reconnect``
    ``false`` to stop the recording on disconnect instead of waiting for the device.
``handshake_timeout``
    Seconds to wait for the INFO answer (2).
``block_ms``
    Least time between blocks handed to the recorder (20 ms), to batch small frames.
Text mode only: ``rate`` (Hz; estimated from the time stamps if absent), ``channels``
(count; detected from the first line if absent), ``scale`` and ``offset`` (physical =
value * scale + offset, default 1 and 0), ``unit`` (m/s2).
"""

from __future__ import annotations

import glob
import os
import select
import tempfile
import time
from typing import Any

import numpy as np
import serial
import serial.tools.list_ports

from drivers.base import (
    Block,
    ChannelSpec,
    Event,
    Gap,
    RateWindow,
    Source,
    parse_source_url,
)
from drivers.clock_fit import DeviceClockFit
from drivers.protocol import (
    CMD_INFO,
    CMD_START,
    CMD_STOP,
    FORMAT_NAMES,
    DataFrame,
    DeviceInfo,
    FrameParser,
    TextLineParser,
)
from fielddiag.channels import CHANNEL_ROLES
from fielddiag.errors import DeviceError

SEQ_MOD = 1 << 32
#: Size of the Linux tty receive buffer (N_TTY_BUF_SIZE); "buffer fill" is relative to it.
TTY_BUFFER_BYTES = 4096
_PORT_ERRORS = (serial.SerialException, OSError)
#: How often a vanished port's path is checked for the device coming back.
RECONNECT_POLL_S = 0.05


class _KeepInputSerial(serial.Serial):
    """pyserial's port, except that opening it keeps the bytes already received.

    pyserial flushes the input queue when it opens a port (POSIX). After a reconnect
    that queue holds the frames the device sent since it came back, each with its
    sequence number and time stamp: keeping them is what makes the loss of a pulled
    cable equal to what the device could not send.
    """

    _opening = False

    def open(self) -> None:
        self._opening = True
        try:
            super().open()
        finally:
            self._opening = False

    def _reset_input_buffer(self) -> None:
        if not self._opening:
            super()._reset_input_buffer()


def list_ports(include_virtual: bool = True) -> list[dict[str, Any]]:
    """Serial ports that may have a DAQ behind them (``fielddiag ports``).

    Returns one dict per port: ``device``, ``description``, ``hwid``, ``vid``, ``pid``,
    ``serial_number``, ``manufacturer``. With ``include_virtual``, running virtual DAQs and
    virtual ECUs (their stable links in the temp folder) are listed too.
    """
    out = []
    for p in sorted(serial.tools.list_ports.comports(), key=lambda p: p.device):
        out.append(
            {
                "device": p.device,
                "description": p.description,
                "hwid": p.hwid,
                "vid": p.vid,
                "pid": p.pid,
                "serial_number": p.serial_number,
                "manufacturer": p.manufacturer,
            }
        )
    if include_virtual:
        tmp = tempfile.gettempdir()
        for pattern, what in (
            ("fielddiag-vdaq-*/ttyVDAQ*", "fielddiag virtual DAQ (serial://)"),
            ("fielddiag-vecu-*/ttyVECU*", "fielddiag virtual ECU (can://slcan/)"),
        ):
            for link in sorted(glob.glob(os.path.join(tmp, pattern))):
                if os.path.exists(link):
                    out.append(
                        {
                            "device": link,
                            "description": what,
                            "hwid": f"-> {os.path.realpath(link)}",
                            "vid": None,
                            "pid": None,
                            "serial_number": None,
                            "manufacturer": "fielddiag",
                        }
                    )
    return out


class _SerialPortSource(Source):
    """Port handling shared by the binary and the text source: open, read, reconnect."""

    kind = "daq"

    def __init__(
        self,
        url: str,
        port: str,
        *,
        baudrate: int = 921600,
        roles: list[str] | None = None,
        names: list[str] | None = None,
        reconnect: bool = True,
        handshake_timeout_s: float = 2.0,
        min_block_interval_s: float = 0.02,
        reconnect_max_interval_s: float = 1.0,
    ) -> None:
        super().__init__(url)
        self.port = port
        self.baudrate = int(baudrate)
        self.roles = roles
        self.names = names
        self.reconnect = reconnect
        self.handshake_timeout_s = handshake_timeout_s
        self.min_block_interval_s = min_block_interval_s
        self.reconnect_max_interval_s = reconnect_max_interval_s
        #: Channel index -> role, applied when the device has told its channels (see the
        #: module docstring); None keeps the roles of the device or of ``?roles=``.
        self.role_map: dict[int, str] | None = None
        self._port: serial.Serial | None = None
        self._port_timeout: float | None = None
        self._last_read = 0.0
        self._backoff_s = 0.1
        self._next_attempt = 0.0
        self._down_since_s: float | None = None
        self._disconnected_flag = False
        self.disconnects = 0
        self.reconnects = 0
        self._buffer_fill = 0.0
        self._last_data_mono = time.monotonic()
        self._last_start_sent = 0.0

    def _mapped(self, roles: list[str], names: list[str] | None, n: int
                ) -> tuple[list[str], list[str] | None]:
        """Roles and names of the ``n`` channels after :attr:`role_map` (if any).

        Raises
        ------
        DeviceError
            The map names a channel the device does not have (the port is closed first).
        """
        if not self.role_map:
            return roles, names
        beyond = sorted(i for i in self.role_map if not 0 <= i < n)
        if beyond:
            self._close_port()
            i = beyond[0]
            raise DeviceError(
                f"{self.url}: channel {i} ({self.role_map[i]}) is not on the device: it has "
                f"{n} channel{'s' if n != 1 else ''}, numbered 0 to {n - 1}; correct the "
                "channel map")
        mapped = [self.role_map.get(i, "other") for i in range(n)]
        given = list(names or [])
        out = [given[i] if i < len(given) and given[i] else
               (mapped[i] if i in self.role_map else "") for i in range(n)]
        return mapped, out

    # -------------------------------------------------------------- port primitives
    def _open_port(self) -> serial.Serial:
        try:
            p = _KeepInputSerial(self.port, self.baudrate, timeout=0.1, write_timeout=1.0)
        except _PORT_ERRORS as exc:
            why = os.strerror(exc.errno) if getattr(exc, "errno", None) else str(exc)
            raise DeviceError(
                f"cannot open {self.port} ({why}). Check the cable and the port name "
                "(`fielddiag ports` lists them) and that no other program uses it"
            ) from None
        self._port_timeout = 0.1
        return p

    def _write(self, data: bytes) -> None:
        assert self._port is not None
        self._port.write(data)

    def _read_available(self, timeout_s: float) -> bytes:
        """Bytes that arrived within ``timeout_s`` (raises the port's errors)."""
        assert self._port is not None
        now = time.monotonic()
        wait = self._last_read + self.min_block_interval_s - now
        if wait > 0:
            time.sleep(min(wait, timeout_s))
        if self._port_timeout != timeout_s:
            self._port.timeout = timeout_s
            self._port_timeout = timeout_s
        waiting = self._port.in_waiting
        self._buffer_fill = max(self._buffer_fill, min(1.0, waiting / TTY_BUFFER_BYTES))
        data = self._port.read(max(1, waiting))
        if data:
            more = self._port.in_waiting
            if more:
                data += self._port.read(more)
        self._last_read = time.monotonic()
        return data

    def _close_port(self) -> None:
        if self._port is not None:
            try:
                self._port.close()
            except _PORT_ERRORS:
                pass
        self._port = None
        self.connected = False

    # -------------------------------------------------------------- disconnect / reconnect
    def _on_disconnect(self, exc: BaseException) -> Block:
        self._close_port()
        self.disconnects += 1
        t = self.clock.now() if self.clock else 0.0
        self._down_since_s = t
        self._disconnected_flag = True
        self._backoff_s = RECONNECT_POLL_S
        self._next_attempt = time.monotonic() + RECONNECT_POLL_S
        self.last_error = f"{self.port} disconnected: waiting for the device to come back"
        self._reset_stream_state()
        if not self.reconnect:
            raise DeviceError(
                f"the DAQ on {self.port} was disconnected; check the cable, or record "
                "with ?reconnect=true in the DAQ URL to wait for it to come back"
            )
        return Block(events=[Event(t, "DAQ disconnected")])

    def _try_reconnect(self, timeout_s: float) -> Block | None:
        now = time.monotonic()
        if now < self._next_attempt:
            time.sleep(min(timeout_s, self._next_attempt - now))
            return None
        if not os.path.exists(self.port) and os.path.isabs(self.port):
            # the device node (or link) is gone: look again soon, it costs one stat()
            self._next_attempt = time.monotonic() + RECONNECT_POLL_S
            return None
        try:
            self._port = self._open_port()
            self._after_reconnect()
        except (DeviceError, *_PORT_ERRORS) as exc:
            if isinstance(exc, DeviceError) and "different device" in str(exc):
                raise
            self._close_port()
            self._backoff_s = min(self._backoff_s * 2.0, self.reconnect_max_interval_s)
            self._next_attempt = time.monotonic() + self._backoff_s
            self.last_error = f"{self.port}: waiting for the device to come back"
            return None
        self.connected = True
        self.reconnects += 1
        t = self.clock.now() if self.clock else 0.0
        down = t - (self._down_since_s if self._down_since_s is not None else t)
        self.last_error = ""
        self._last_data_mono = time.monotonic()
        return Block(events=[Event(t, f"DAQ reconnected after {down:.1f} s")])

    def _kick(self) -> None:
        """Called after 2 s without data on an open port (subclasses)."""

    def _reset_stream_state(self) -> None:
        """Forget partial input after a disconnect (subclasses)."""

    def _after_reconnect(self) -> None:
        """Handshake and restart streaming on a freshly opened port (subclasses)."""

    # -------------------------------------------------------------- reading
    def _process(self, data: bytes, t_arrival_s: float) -> Block | None:
        raise NotImplementedError

    def _has_pending(self) -> bool:
        """True when input received earlier still waits to be processed (subclasses)."""
        return False

    def read(self, timeout_s: float = 0.1) -> Block | None:
        if self.clock is None:
            raise RuntimeError("start() the source before read()")
        if self._port is None:
            return self._try_reconnect(timeout_s)
        try:
            data = self._read_available(timeout_s)
        except _PORT_ERRORS as exc:
            return self._on_disconnect(exc)
        t_arrival = self.clock.now()
        if not data:
            silent = time.monotonic() - self._last_data_mono
            if silent > 2.0 and time.monotonic() - self._last_start_sent > 2.0:
                self._last_start_sent = time.monotonic()
                try:
                    self._kick()
                except _PORT_ERRORS as exc:
                    return self._on_disconnect(exc)
            if not self._has_pending():
                return None
        else:
            self._last_data_mono = time.monotonic()
        return self._process(data, t_arrival)

    def close(self) -> None:
        if self._port is not None:
            try:
                self._write(CMD_STOP)
                self._port.flush()
            except _PORT_ERRORS:
                pass
        self._close_port()

    def _base_status(self) -> dict[str, Any]:
        fill, self._buffer_fill = self._buffer_fill, 0.0
        return {
            "url": self.url,
            "kind": self.kind,
            "port": self.port,
            "connected": self.connected,
            "buffer_fill": fill,
            "silent_s": time.monotonic() - self._last_data_mono,
            "disconnects": self.disconnects,
            "reconnects": self.reconnects,
            "last_error": self.last_error,
        }


def _channel_specs(
    n: int,
    roles: list[str],
    axes: list[str],
    scales: list[float],
    dtype: str,
    sensor: str,
    names: list[str] | None,
    unit: str = "m/s2",
    offsets: list[float] | None = None,
) -> list[ChannelSpec]:
    specs = []
    used: set[str] = set()
    for i in range(n):
        role = roles[i]
        if role not in CHANNEL_ROLES:
            raise DeviceError(
                f"channel role {role!r} unknown; roles are {', '.join(CHANNEL_ROLES)}"
            )
        if names and i < len(names) and names[i]:
            name = names[i]
        elif role in ("wheel", "body"):
            name = f"{role}_{axes[i]}"
        else:
            name = f"ch{i}"
        if name in used:
            name = f"{name}_{i}"
        used.add(name)
        specs.append(
            ChannelSpec(
                name=name,
                unit=unit,
                role=role,
                axis=axes[i],
                sensor=f"{sensor} ch{i}",
                scale=float(scales[i]),
                offset=float(offsets[i]) if offsets else 0.0,
                dtype=dtype,
            )
        )
    return specs


class SerialDAQSource(_SerialPortSource):
    """The fielddiag DAQ over serial, binary protocol (``serial://PORT?baud=921600``)."""

    schemes = ("serial",)

    def __init__(self, url: str, port: str, **kw: Any) -> None:
        super().__init__(url, port, **kw)
        self.info: DeviceInfo | None = None
        self._parser = FrameParser()
        self._sync = DeviceClockFit()
        # frames parsed but not yet processed, with the session time each arrived
        self._backlog: list[tuple[DataFrame | DeviceInfo, float]] = []
        # frames of a new clock epoch held back until the clock fit has settled
        self._held: list[tuple[DataFrame, float]] = []
        self._last_block_mono = 0.0
        # counters
        self.frames_received = 0
        self.frames_lost = 0
        self.samples_lost = 0
        self.frames_rejected = 0
        self._parser_totals = [0, 0, 0, 0]  # discarded, header, crc, malformed (old parsers)
        self.gaps: list[Gap] = []
        # stream state
        self._last_seq: int | None = None
        self._last_t_dev_end = 0.0
        self._last_time_s: float | None = None
        self._epoch_gap_pending = False
        self._after_reconnect_frames = 0
        self._epochs = 0
        #: Set to a list to log the sequence number of every frame received (tests, tools).
        self.seq_log: list[int] | None = None
        self._rate_window = RateWindow()

    @classmethod
    def from_url(cls, url: str) -> SerialDAQSource:
        u = parse_source_url(url)
        u.check_keys({"baud", "roles", "names", "reconnect", "handshake_timeout", "block_ms"})
        if not u.location:
            raise DeviceError(f"{url}: no port; use serial:///dev/ttyUSB0 or serial://COM3")
        return cls(
            url,
            u.location,
            baudrate=u.get_int("baud", 921600),
            roles=u.get_all("roles") or None,
            names=u.get_all("names") or None,
            reconnect=u.get_bool("reconnect", True),
            handshake_timeout_s=u.get_float("handshake_timeout", 2.0),
            min_block_interval_s=u.get_float("block_ms", 20.0) / 1000.0,
        )

    # ------------------------------------------------------------------ handshake
    def _handshake(self, timeout_s: float) -> DeviceInfo:
        assert self._port is not None
        self._write(CMD_INFO)
        deadline = time.monotonic() + timeout_s
        next_ask = time.monotonic() + 0.5
        while time.monotonic() < deadline:
            data = self._port.read(max(1, self._port.in_waiting))
            if data:
                t = self.clock.now() if self.clock else 0.0
                frames = self._parser.feed(data)
                for k, f in enumerate(frames):
                    if isinstance(f, DeviceInfo):
                        # data frames that came in the same read are kept, not dropped
                        self._backlog.extend(
                            (g, t) for g in frames[k + 1:] if not isinstance(g, DeviceInfo)
                        )
                        return f
                    self._backlog.append((f, t))
            if time.monotonic() > next_ask:
                self._write(CMD_INFO)
                next_ask = time.monotonic() + 0.5
        c = self._parser.counters
        hint = (
            f" ({c.bytes_received} bytes arrived, none of them an INFO frame: is it a text "
            "streamer? then use serial+ascii://)"
            if c.bytes_received
            else " (nothing arrived: check power, cable, port and baud rate)"
        )
        raise DeviceError(f"{self.port}: no answer to the INFO command{hint}")

    def open(self) -> None:
        self._port = self._open_port()
        try:
            info = self._handshake(self.handshake_timeout_s)
        except BaseException:
            self._close_port()
            raise
        self._backlog.clear()  # frames of an earlier run, before this recording
        self.connected = True
        self.info = info
        self.sample_rate_hz = info.sample_rate_hz
        n = info.n_channels
        roles = list(self.roles or [c.role for c in info.channels])
        if len(roles) != n:
            raise DeviceError(
                f"{self.url}: {len(roles)} roles given for a device with {n} channels; give "
                "one role per channel in ?roles="
            )
        roles, names = self._mapped(roles, self.names, n)
        self.channels = _channel_specs(
            n,
            roles,
            [c.axis for c in info.channels],
            [info.scale(i) for i in range(n)],
            FORMAT_NAMES[info.sample_format],
            f"{info.model} #{info.serial_number}",
            names,
        )

    def start(self, clock) -> None:
        super().start(clock)
        self._write(CMD_START)
        self._last_start_sent = time.monotonic()
        self._last_data_mono = time.monotonic()

    def _kick(self) -> None:
        # The device may have rebooted and be waiting for START; a no-op if streaming.
        self._write(CMD_START)

    def _after_reconnect(self) -> None:
        self._parser = FrameParser()
        info = self._handshake(min(self.handshake_timeout_s, 1.5))
        old = self.info
        if old is not None and (
            info.serial_number != old.serial_number
            or info.n_channels != old.n_channels
            or info.sample_format != old.sample_format
            or info.sample_rate_hz != old.sample_rate_hz
        ):
            raise DeviceError(
                f"a different device appeared on {self.port} (serial {info.serial_number}, "
                f"{info.n_channels} channels at {info.sample_rate_hz:g} Hz; expected "
                f"{old.serial_number}); stop and start a new recording"
            )
        self._write(CMD_START)
        self._last_start_sent = time.monotonic()

    def _reset_stream_state(self) -> None:
        c = self._parser.counters
        self._parser_totals[0] += c.bytes_discarded + self._parser.pending_bytes
        self._parser_totals[1] += c.header_errors
        self._parser_totals[2] += c.crc_errors
        self._parser_totals[3] += c.malformed
        self._parser = FrameParser()

    # ------------------------------------------------------------------ counters
    def _crc_total(self) -> int:
        c = self._parser.counters
        return self._parser_totals[1] + self._parser_totals[2] + c.header_errors + c.crc_errors

    def counters(self) -> dict[str, int]:
        c = self._parser.counters
        return {
            "frames_received": self.frames_received,
            "frames_lost": self.frames_lost,
            "crc_errors": self._crc_total(),
            "samples_lost": self.samples_lost,
            "bytes_discarded": self._parser_totals[0] + c.bytes_discarded,
            "reconnects": self.reconnects,
        }

    @property
    def drift_ppm(self) -> float | None:
        """Estimated device clock drift (positive: device clock fast), None until known."""
        return self._sync.drift_ppm if self._sync.drift_known else None

    def status(self) -> dict[str, Any]:
        st = self._base_status()
        rate = self._rate_window.rate_per_s()
        c = self._parser.counters
        st.update(self.counters())
        st.update(
            {
                "sample_rate_hz": self.sample_rate_hz,
                "measured_rate_hz": rate,
                "gaps": len(self.gaps),
                "header_errors": self._parser_totals[1] + c.header_errors,
                "frames_rejected": self.frames_rejected + self._parser_totals[3] + c.malformed,
                "drift_ppm": self.drift_ppm,
                "clock_offset_s": self._sync.fit_offset_s,
                "pending_bytes": self._parser.pending_bytes,
            }
        )
        return st

    def describe(self) -> dict[str, Any]:
        return {
            "url": self.url,
            "kind": self.kind,
            "port": self.port,
            "device": self.info.to_dict() if self.info else None,
        }

    # ------------------------------------------------------------------ reading
    def _read_available(self, timeout_s: float) -> bytes:
        """Read bytes as they arrive and parse them, each frame stamped with its arrival.

        Returns once frames are in hand and ``block_ms`` has passed since the last block
        (so small frames are handed over in batches), or after ``timeout_s``. The frames
        wait in the backlog for :meth:`_process`; the bytes are returned only to tell
        whether anything arrived.
        """
        port = self._port
        assert port is not None
        got = bytearray()
        now = time.monotonic()
        end = now + timeout_s
        fd = port.fileno() if hasattr(port, "fileno") else None
        while True:
            waiting = port.in_waiting
            self._buffer_fill = max(self._buffer_fill, min(1.0, waiting / TTY_BUFFER_BYTES))
            if waiting:
                data = port.read(waiting)
            else:
                limit = end
                if self._backlog:
                    limit = min(end, self._last_block_mono + self.min_block_interval_s)
                wait = limit - time.monotonic()
                if wait <= 0:
                    break
                if fd is not None:
                    ready, _, _ = select.select([fd], [], [], wait)
                    if not ready:
                        break
                    data = port.read(max(1, port.in_waiting))
                else:  # no file descriptor (Windows): let the port's timeout wait
                    data = port.read(1)
                    data += port.read(port.in_waiting) if data else b""
                if not data:
                    break
            t = self.clock.now()
            got += data
            self._backlog.extend((f, t) for f in self._parser.feed(data))
            due = end
            if self._backlog:
                due = min(end, self._last_block_mono + self.min_block_interval_s)
            if time.monotonic() >= due:  # a stream that never pauses still gets handed over
                break
        self._last_read = time.monotonic()
        return bytes(got)

    def _has_pending(self) -> bool:
        return bool(self._backlog or self._held)

    # ------------------------------------------------------------------ frames -> block
    def _process(self, data: bytes, t_arrival_s: float) -> Block | None:
        """Turn the frames parsed by :meth:`_read_available` into a block (``data`` is
        already parsed)."""
        items, self._backlog = self._backlog, []
        frames: list[tuple[DataFrame, float]] = []
        for f, t in items:
            if isinstance(f, DeviceInfo):
                continue  # an INFO answer while streaming: nothing new
            if f.n_channels != self.info.n_channels or f.sample_format != self.info.sample_format:
                self.frames_rejected += 1
                fmt = FORMAT_NAMES.get(f.sample_format, "an unknown format")
                self.last_error = (
                    f"a frame of {f.n_channels} channels in {fmt} came from a device that "
                    f"announced {self.info.n_channels} channels in "
                    f"{FORMAT_NAMES[self.info.sample_format]}; it was dropped"
                )
                continue
            frames.append((f, t))
        if self._held or not self._sync.settled:
            # the start of a clock epoch: hold the frames until the clock fit has settled
            rate = self.info.sample_rate_hz
            for f, t in frames:
                if self._held and f.t_us <= self._held[-1][0].t_us:
                    break  # time went backwards while holding: process what is held now
                self._sync.observe(f.t_us / 1e6 + f.n_samples / rate, t)
            else:
                self._held.extend(frames)
                waited = self._held and t_arrival_s - self._held[0][1] >= self._sync.settle_s
                if not (self._sync.settled or waited):
                    return None
                frames = []
            frames, self._held = self._held + frames, []
        if not frames:
            return None
        self._last_block_mono = time.monotonic()
        return self._frames_to_block(frames)

    def _frames_to_block(self, frames: list[tuple[DataFrame, float]]) -> Block:
        rate = self.info.sample_rate_hz
        out_t: list[np.ndarray] = []
        out_s: list[bytes] = []
        gaps: list[Gap] = []
        events: list[Event] = []
        seg: list[DataFrame] = []
        marks: list[tuple[int, int, str]] = []  # (sample index in seg, samples lost, cause)
        n_seg = 0
        for k, (f, t_arr) in enumerate(frames):
            n = f.n_samples
            t_first = f.t_us / 1e6
            if self._last_seq is not None:
                d = (f.seq - self._last_seq - 1) % SEQ_MOD
                jump_s = t_first - self._last_t_dev_end
                tol = max(2.0 * n / rate, 0.01 * abs(jump_s))
                if d == 0 and abs(jump_s) <= tol:
                    pass
                elif 0 < d < SEQ_MOD // 2 and abs(jump_s - d * n / rate) <= tol:
                    self.frames_lost += d
                    self.samples_lost += d * n
                    marks.append((n_seg, d * n, self._gap_cause(f)))
                elif d == 0 and jump_s > 0:
                    marks.append((n_seg, 0, "device paused"))
                else:
                    # Sequence number and device time disagree: the device restarted. The
                    # frames of the new clock epoch wait until its clock fit has settled.
                    self._emit(seg, marks, out_t, out_s, gaps)
                    self._sync.reset()
                    self._epochs += 1
                    self._epoch_gap_pending = True
                    self._last_seq = None
                    events.append(Event(t_arr, "DAQ restarted (its clock began again)"))
                    self._held = []
                    for g, tg in frames[k:]:
                        self._sync.observe(g.t_us / 1e6 + g.n_samples / rate, tg)
                        self._held.append((g, tg))
                    seg = []
                    break
            self._sync.observe(t_first + n / rate, t_arr)
            self._last_seq, self._last_t_dev_end = f.seq, t_first + n / rate
            if self._disconnected_flag:
                self._after_reconnect_frames = 10  # losses right after a reconnect: the outage
            elif self._after_reconnect_frames > 0:
                self._after_reconnect_frames -= 1
            self._disconnected_flag = False
            seg.append(f)
            n_seg += n
            self.frames_received += 1
            if self.seq_log is not None:
                self.seq_log.append(f.seq)
        self._emit(seg, marks, out_t, out_s, gaps)
        self._rate_window.add(sum(len(t) for t in out_t))
        samples = np.frombuffer(b"".join(out_s), dtype=self.info.dtype).reshape(
            -1, self.info.n_channels
        )
        time_s = np.concatenate(out_t) if out_t else np.zeros(0)
        return Block(time_s=time_s, samples=samples, gaps=gaps, events=events)

    def _emit(
        self,
        seg: list[DataFrame],
        marks: list[tuple[int, int, str]],
        out_t: list[np.ndarray],
        out_s: list[bytes],
        gaps: list[Gap],
    ) -> None:
        """Map a run of frames of one clock epoch to session time; record its gaps."""
        if not seg:
            return
        rate = self.info.sample_rate_hz
        period = 1.0 / rate
        n0 = seg[0].n_samples
        if all(f.n_samples == n0 for f in seg):
            t_first = np.fromiter((f.t_us for f in seg), "f8", len(seg)) / 1e6
            t_dev = (t_first[:, None] + np.arange(n0) * period).ravel()
        else:
            t_dev = np.concatenate([f.t_us / 1e6 + np.arange(f.n_samples) * period for f in seg])
        t_end = float(t_dev[-1]) + period
        if not self._sync.locked:
            self._sync.steer(float(t_dev[0]))
        time_s = self._sync.map(t_dev)
        prev = self._last_time_s
        if prev is not None and time_s[0] <= prev:
            time_s += prev - time_s[0] + period  # never run backwards
        if self._epoch_gap_pending and prev is not None:
            start = prev + period
            end = max(float(time_s[0]), start)
            lost = max(0, int(round((end - start) * rate)))
            self.samples_lost += lost
            g = Gap(start, end, lost, "device restarted (estimated)")
            gaps.append(g)
            self.gaps.append(g)
        self._epoch_gap_pending = False
        for k, lost, cause in marks:
            before = float(time_s[k - 1]) if k > 0 else prev
            if before is None:
                continue
            start = before + period
            g = Gap(start, max(float(time_s[k]), start), lost, cause)
            gaps.append(g)
            self.gaps.append(g)
        self._sync.steer(t_end)  # the next samples follow the newest fit, continuously
        self._last_time_s = float(time_s[-1])
        out_t.append(time_s)
        out_s.append(b"".join(f.payload for f in seg))

    def _gap_cause(self, f: DataFrame) -> str:
        if self._disconnected_flag or self._after_reconnect_frames > 0:
            return "disconnected"
        if f.skipped_bytes > 0:
            return "corrupted"  # bytes were thrown away where the missing frames were
        return "dropped by device"


class SerialTextSource(_SerialPortSource):
    """A text streamer: one ``t_us,ch0,ch1,...`` line per sample (``serial+ascii://PORT``).

    No handshake, no CRC and no sequence numbers (see PROTOCOL.md, "Text mode"): malformed
    lines are dropped and counted as CRC errors, and lost samples are inferred from jumps
    of the time stamps larger than 1.5 sample periods. ``t_us`` may wrap at 2**32 (an
    Arduino's ``micros()``); the wrap is undone.
    """

    schemes = ("serial+ascii",)

    def __init__(
        self,
        url: str,
        port: str,
        *,
        rate_hz: float | None = None,
        n_channels: int | None = None,
        scale: float = 1.0,
        offset: float = 0.0,
        unit: str = "m/s2",
        **kw: Any,
    ) -> None:
        kw.setdefault("baudrate", 115200)
        super().__init__(url, port, **kw)
        self.rate_hz = rate_hz
        self.n_channels = n_channels
        self.scale = scale
        self.offset = offset
        self.unit = unit
        self._parser = TextLineParser()
        self._sync = DeviceClockFit()
        self._wrap_us = 0
        self._last_t_us: int | None = None
        self._last_time_s: float | None = None
        self._resync = False
        self.lines_received = 0
        self.samples_lost = 0
        self.gaps: list[Gap] = []
        self._bad_total = 0
        self._discarded_total = 0

    @classmethod
    def from_url(cls, url: str) -> SerialTextSource:
        u = parse_source_url(url)
        u.check_keys(
            {
                "baud",
                "roles",
                "names",
                "reconnect",
                "handshake_timeout",
                "block_ms",
                "rate",
                "channels",
                "scale",
                "offset",
                "unit",
            }
        )
        if not u.location:
            raise DeviceError(f"{url}: no port; use serial+ascii:///dev/ttyACM0")
        return cls(
            url,
            u.location,
            baudrate=u.get_int("baud", 115200),
            roles=u.get_all("roles") or None,
            names=u.get_all("names") or None,
            reconnect=u.get_bool("reconnect", True),
            handshake_timeout_s=u.get_float("handshake_timeout", 3.0),
            min_block_interval_s=u.get_float("block_ms", 20.0) / 1000.0,
            rate_hz=u.get_float("rate"),
            n_channels=u.get_int("channels"),
            scale=u.get_float("scale", 1.0),
            offset=u.get_float("offset", 0.0),
            unit=u.get("unit", "m/s2"),
        )

    def open(self) -> None:
        self._port = self._open_port()
        times: list[np.ndarray] = []
        deadline = time.monotonic() + self.handshake_timeout_s
        try:
            while time.monotonic() < deadline:
                batch = self._parser.feed(self._port.read(max(1, self._port.in_waiting)))
                times.append(batch.t_us)
                n = sum(len(t) for t in times)
                if self._parser.n_channels and n >= 20 and (self.rate_hz or n >= 20):
                    break
        except _PORT_ERRORS as exc:
            self._close_port()
            why = os.strerror(exc.errno) if getattr(exc, "errno", None) else str(exc)
            raise DeviceError(
                f"reading {self.port} failed ({why}); check the cable and that no other "
                "program uses the port"
            ) from None
        nch = self.n_channels or self._parser.n_channels
        if not nch:
            self._close_port()
            raise DeviceError(
                f"{self.port}: no 't_us,ch0,ch1,...' lines arrived within "
                f"{self.handshake_timeout_s:g} s; check the baud rate and the sketch"
            )
        if self.n_channels and self._parser.n_channels and self._parser.n_channels != nch:
            self._close_port()
            raise DeviceError(
                f"the lines on {self.port} carry {self._parser.n_channels} values but the URL "
                f"says channels={nch}; correct ?channels= or leave it out"
            )
        self._parser.n_channels = nch
        if self.rate_hz is None:
            t = np.concatenate(times) if times else np.zeros(0)
            dt = np.diff(t)
            dt = dt[dt > 0]
            if dt.size < 5:
                self._close_port()
                raise DeviceError(
                    f"{self.port}: too few lines to estimate the sample rate; add ?rate=HZ"
                )
            self.rate_hz = 1e6 / float(np.median(dt))
        self.sample_rate_hz = float(self.rate_hz)
        self._parser = TextLineParser(n_channels=nch, header=self._parser.header)
        self.connected = True
        roles = list(self.roles or (["wheel", "body"] + ["other"] * nch)[:nch])
        if len(roles) != nch:
            raise DeviceError(
                f"{self.url}: {len(roles)} roles given for {nch} channels; give one role per "
                "channel in ?roles="
            )
        roles, names = self._mapped(roles, self.names or self._parser.header, nch)
        self.channels = _channel_specs(
            nch,
            roles,
            ["z"] * nch,
            [self.scale] * nch,
            "float64",
            f"text streamer on {self.port}",
            names,
            unit=self.unit,
            offsets=[self.offset] * nch,
        )

    def start(self, clock) -> None:
        super().start(clock)
        if self._port is not None:
            self._port.reset_input_buffer()
        self._last_data_mono = time.monotonic()

    def _reset_stream_state(self) -> None:
        self._bad_total += self._parser.bad_lines
        self._discarded_total += self._parser.bytes_discarded + len(self._parser._buf)
        self._parser = TextLineParser(n_channels=self.n_channels or self._parser.n_channels)
        self._resync = True  # the first line after a reconnect may be partial

    def counters(self) -> dict[str, int]:
        return {
            "frames_received": self.lines_received,
            "frames_lost": self.samples_lost,
            "crc_errors": self._bad_total + self._parser.bad_lines,
            "samples_lost": self.samples_lost,
            "bytes_discarded": self._discarded_total + self._parser.bytes_discarded,
            "reconnects": self.reconnects,
        }

    def status(self) -> dict[str, Any]:
        st = self._base_status()
        st.update(self.counters())
        st.update(
            {
                "sample_rate_hz": self.sample_rate_hz,
                "gaps": len(self.gaps),
                "drift_ppm": self._sync.drift_ppm if self._sync.drift_known else None,
            }
        )
        return st

    def _process(self, data: bytes, t_arrival_s: float) -> Block | None:
        if self._resync:
            cut = data.find(b"\n")
            if cut < 0:
                self._discarded_total += len(data)
                return None
            self._discarded_total += cut + 1
            data = data[cut + 1 :]
            self._resync = False
        batch = self._parser.feed(data)
        if batch.t_us.size == 0:
            return None
        period = 1.0 / self.sample_rate_hz
        t_us = batch.t_us + self._wrap_us
        # undo 32-bit wraps of micros()
        prev = self._last_t_us
        seq = np.concatenate(([prev], t_us)) if prev is not None else t_us
        back = np.diff(seq) < -(1 << 31)
        if back.any():
            wraps = np.cumsum(back) * (1 << 32)
            t_us = t_us + (wraps if prev is not None else np.concatenate(([0], wraps)))
            self._wrap_us += int(wraps[-1])
        gaps: list[Gap] = []
        events: list[Event] = []
        seq = np.concatenate(([prev], t_us)) if prev is not None else t_us
        dt_s = np.diff(seq) / 1e6
        if np.any(dt_s <= 0):
            # time went backwards: the streamer restarted; start a new clock epoch
            events.append(Event(t_arrival_s, "streamer restarted (time went backwards)"))
            self._sync.reset()
        t_dev = t_us / 1e6
        t_end = float(t_dev[-1])
        self._sync.observe(t_end, t_arrival_s)
        if not self._sync.locked:
            self._sync.steer(float(t_dev[0]))
        time_s = self._sync.map(t_dev)
        if self._last_time_s is not None and time_s[0] <= self._last_time_s:
            time_s = time_s + (self._last_time_s - time_s[0] + period)
        # keep it strictly increasing inside the block too
        bad = np.diff(time_s) <= 0
        if bad.any():
            time_s = np.maximum.accumulate(time_s + np.arange(time_s.size) * 1e-9)
        big = np.flatnonzero(dt_s > 1.5 * period)
        offset = 1 if prev is not None else 0
        for j in big:
            k = j + 1 - offset  # index in this block of the first sample after the gap
            lost = int(round(dt_s[j] * self.sample_rate_hz)) - 1
            if lost <= 0:
                continue
            before = float(time_s[k - 1]) if k > 0 else self._last_time_s
            start = before + period
            g = Gap(start, max(start, float(time_s[k])), lost, "time stamp gap")
            gaps.append(g)
            self.gaps.append(g)
            self.samples_lost += lost
        self._sync.steer(t_end + period)
        self._last_t_us = int(t_us[-1])
        self._last_time_s = float(time_s[-1])
        self.lines_received += int(t_us.size)
        return Block(time_s=time_s, samples=batch.values, gaps=gaps, events=events)
