"""Virtual devices: the executable spec of the DAQ protocol and the demo's hardware.

:class:`VirtualDAQ`
    A fielddiag DAQ behind a pseudo-terminal. It answers INFO/START/STOP and streams DATA
    frames (``drivers/PROTOCOL.md``) in real time from an array of accelerations (the
    quarter-car simulator's, see :func:`simulated_accelerations`), with optional faults:
    byte corruption, garbage bursts, a pulled cable, a stall, clock drift. The pty is
    reached through a stable symlink (``/tmp/fielddiag-vdaq-XXXX/ttyVDAQ0``) that is
    removed while the "cable" is out and re-pointed at a new pty when it comes back, like
    ``/dev/ttyUSB0`` disappearing and reappearing.
:class:`VirtualECU`
    Publishes vehicle speed and the four wheel speeds (and, for a full-vehicle drive, the
    car's longitudinal and lateral accelerations), encoded with a DBC, on a python-can
    bus (in-process ``virtual`` bus, ``udp_multicast`` if msgpack is installed) or on an
    :class:`SlcanPty` (an SLCAN adapter emulated on a pty, which python-can's ``slcan``
    interface reads from another process).

A full-vehicle drive (:func:`fielddiag.vehicle.simulate_vehicle`) is streamed as eight
channels by one :class:`VirtualDAQ` (``fielddiag.vehicle.corner_map`` says which channel is
which corner's sensor); :func:`full_scale_for` picks a measuring range its hub
accelerations do not clip.

The virtual DAQ keeps acquiring while its cable is out (a self-powered logger behind a
USB-serial adapter): frames made meanwhile are lost and their sequence numbers skipped,
so the host can count the loss exactly. ``power_cycle_on_disconnect`` emulates a
bus-powered device instead, which reboots (sequence and clock restart).
"""

from __future__ import annotations

import errno
import math
import os
import shutil
import tempfile
import threading
import time
import tty
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from drivers.protocol import (
    FORMAT_CODES,
    SAMPLE_FORMATS,
    ChannelInfo,
    DeviceInfo,
    encode_data,
    encode_info,
)
from fielddiag.units import GRAVITY_MPS2 as G_MPS2

#: DBC of the virtual ECU. SPEED (0x0B4) and WHEEL_SPEEDS (0x0AA) have the byte layout,
#: scaling and names of the Toyota RAV4 powertrain DBC of opendbc (MIT, Copyright (c) 2020
#: Comma.ai, Inc.), so frames of the virtual ECU decode the same with either file.
VIRTUAL_ECU_DBC = """VERSION ""

NS_ :

BS_:

BU_: VECU

BO_ 170 WHEEL_SPEEDS: 8 VECU
 SG_ WHEEL_SPEED_FR : 6|15@0+ (0.01,-67.67) [-67.67|260] "km/h" Vector__XXX
 SG_ WHEEL_SPEED_FL : 22|15@0+ (0.01,-67.67) [-67.67|260] "km/h" Vector__XXX
 SG_ WHEEL_SPEED_RR : 38|15@0+ (0.01,-67.67) [-67.67|260] "km/h" Vector__XXX
 SG_ WHEEL_SPEED_RL : 54|15@0+ (0.01,-67.67) [-67.67|260] "km/h" Vector__XXX

BO_ 180 SPEED: 8 VECU
 SG_ ENCODER : 39|8@0+ (1,0) [0|255] "" Vector__XXX
 SG_ SPEED : 47|16@0+ (0.01,0) [0|250] "km/h" Vector__XXX
 SG_ CHECKSUM : 63|8@0+ (1,0) [0|255] "" Vector__XXX

BO_ 192 KINEMATICS: 8 VECU
 SG_ ACCEL_X : 0|16@1- (0.001,0) [-32.768|32.767] "m/s^2" Vector__XXX
 SG_ ACCEL_Y : 16|16@1- (0.001,0) [-32.768|32.767] "m/s^2" Vector__XXX
"""
#: KINEMATICS (0x0C0, fielddiag's own, not from opendbc): the car's longitudinal
#: (``ACCEL_X``, forward positive) and lateral (``ACCEL_Y``, left positive) acceleration,
#: 1 mm/s^2 per bit. Sent only for a full-vehicle drive.
KINEMATICS_SIGNALS = ("KINEMATICS.ACCEL_X", "KINEMATICS.ACCEL_Y")

#: Measuring ranges of the accelerometers the virtual DAQ can be given [g].
FULL_SCALE_RANGES_G = (2, 4, 8, 16, 32, 64, 128)


# ----------------------------------------------------------------------------- signals
def simulated_accelerations(
    duration_s: float,
    *,
    sample_rate_hz: float = 500.0,
    n_channels: int = 2,
    added_mass_kg: float = 0.0,
    seed: int = 0,
    params: Any = None,
    road_class: str | None = "C",
    effects: Sequence[Any] = (),
    noise_std_mps2: float = 0.02,
    drive: Any = None,
) -> tuple[np.ndarray, Any]:
    """Accelerometer readings of a simulated drive, one column per DAQ channel.

    Channel 0 is the wheel sensor, channel 1 the body sensor (both read acceleration + g,
    from :func:`fielddiag.sim.simulate` with ``added_mass_kg`` on the body); channels 2 and
    up are "other" channels carrying seeded white noise of ``noise_std_mps2``.

    Returns
    -------
    signals : ndarray (n, n_channels) [m/s2]
    drive : fielddiag.sim.SimulatedDrive
        The drive (vehicle speed for the virtual ECU, truth for tests).
    """
    from fielddiag import sim

    if drive is None:
        drive = sim.simulate(
            params if params is not None else sim.QuarterCarParams(),
            duration_s=duration_s,
            road_class=road_class,
            effects=tuple(effects),
            added_mass_kg=added_mass_kg,
            sensor=sim.SensorModel(output_rate_hz=sample_rate_hz, noise_std_mps2=noise_std_mps2),
            seed=seed,
        )
    n = drive.wheel_accel_mps2.size
    cols = [drive.wheel_accel_mps2, drive.body_accel_mps2][: max(1, n_channels)]
    rng = np.random.default_rng(seed + 7919)
    for _ in range(2, n_channels):
        cols.append(rng.normal(0.0, noise_std_mps2, n))
    return np.column_stack(cols), drive


def full_scale_for(signals_mps2: np.ndarray, headroom: float = 1.25) -> float:
    """The smallest range of :data:`FULL_SCALE_RANGES_G` that holds the signals with headroom.

    Integer samples clip at the full scale without any sign in the data; the range is
    chosen so that ``headroom`` times the largest absolute reading fits. (Resolution is no
    concern with int32 samples: 1 LSB is full scale / 2**31, 7e-8 m/s^2 at 16 g.)

    Parameters
    ----------
    signals_mps2 : ndarray
        What the sensors will read [m/s^2].
    headroom : float
        Margin above the largest reading (>= 1).

    Returns
    -------
    float
        Full scale [m/s^2].

    Raises
    ------
    ValueError
        The readings exceed the largest range.
    """
    peak = float(np.max(np.abs(signals_mps2))) if np.size(signals_mps2) else 0.0
    for g in FULL_SCALE_RANGES_G:
        if headroom * peak <= g * G_MPS2:
            return g * G_MPS2
    raise ValueError(f"readings of {peak / G_MPS2:.0f} g exceed the largest range, "
                     f"{FULL_SCALE_RANGES_G[-1]} g")


def to_counts(signals_mps2: np.ndarray, full_scale_mps2: float, sample_format: int) -> np.ndarray:
    """Raw samples a DAQ with this full scale and format would send for ``signals_mps2``."""
    dt = SAMPLE_FORMATS[sample_format]
    if dt.kind == "f":
        return np.asarray(signals_mps2, dtype=dt)
    top = 2 ** (8 * dt.itemsize - 1)
    c = np.round(np.asarray(signals_mps2) / full_scale_mps2 * top)
    return np.clip(c, -top, top - 1).astype(dt)


# ----------------------------------------------------------------------------- pty link
class PtyLink:
    """A pseudo-terminal reached through a stable symlink that can be "unplugged".

    Parameters
    ----------
    link_name : str
        Name of the symlink inside a new folder ``fielddiag-<kind>-XXXX`` in the temp dir.
    kind : str
        ``vdaq`` or ``vecu`` (only names the folder; ``fielddiag ports`` looks for them).
    """

    def __init__(self, link_name: str = "ttyVDAQ0", kind: str = "vdaq") -> None:
        self.dir = tempfile.mkdtemp(prefix=f"fielddiag-{kind}-")
        self.path = os.path.join(self.dir, link_name)
        self.master: int | None = None
        self._slave: int | None = None
        self.connect()

    @property
    def up(self) -> bool:
        return self.master is not None

    def connect(self) -> None:
        """Open a new pty and point the symlink at it (atomically)."""
        master, slave = os.openpty()
        tty.setraw(slave)
        os.set_blocking(master, False)
        tmp = self.path + ".new"
        if os.path.lexists(tmp):
            os.unlink(tmp)
        os.symlink(os.ttyname(slave), tmp)
        os.replace(tmp, self.path)
        self.master, self._slave = master, slave

    def disconnect(self) -> None:
        """Pull the cable: the host's open port errors out and the path disappears."""
        if os.path.lexists(self.path):
            os.unlink(self.path)
        for fd in (self.master, self._slave):
            if fd is not None:
                try:
                    os.close(fd)
                except OSError:
                    pass
        self.master = self._slave = None

    def write(self, data: bytes | bytearray | memoryview) -> int:
        """Write what the pty takes now (non-blocking); bytes written."""
        if self.master is None or not data:
            return 0
        try:
            return os.write(self.master, data)
        except BlockingIOError:
            return 0
        except OSError as exc:
            if exc.errno in (errno.EAGAIN, errno.EIO):
                return 0
            raise

    def drain_unread(self) -> int:
        """Take from the pty what the host has not read yet; return how many bytes.

        Called when the cable is pulled: these bytes were on their way and are lost with
        it. Reading them here (the device holds the pty's other end too) tells exactly
        how many the host will never see.
        """
        if self._slave is None:
            return 0
        os.set_blocking(self._slave, False)
        n = 0
        while True:
            try:
                chunk = os.read(self._slave, 1 << 16)
            except (BlockingIOError, OSError):
                break
            if not chunk:
                break
            n += len(chunk)
        return n

    def read(self) -> bytes:
        """What the host wrote (non-blocking)."""
        if self.master is None:
            return b""
        try:
            return os.read(self.master, 4096)
        except (BlockingIOError, OSError):
            return b""

    def close(self) -> None:
        self.disconnect()
        shutil.rmtree(self.dir, ignore_errors=True)


# ----------------------------------------------------------------------------- DAQ
@dataclass
class VirtualDAQStats:
    """What the virtual DAQ did (ground truth for tests)."""

    frames_made: int = 0
    frames_queued: int = 0
    frames_written: int = 0  # completely written to the pty
    frames_corrupted: int = 0
    frames_dropped_overflow: int = 0
    frames_dropped_outage: int = 0
    frames_lost_in_link: int = 0  # queued, or written but not read by the host, at the pull
    garbage_bytes: int = 0
    bytes_written: int = 0
    disconnects: int = 0
    reconnects: int = 0
    stalls: int = 0
    corrupted_seqs: set[int] = field(default_factory=set)
    #: Every frame the device made but did not deliver (outage, overflow, lost in the link).
    dropped_seqs: list[int] = field(default_factory=list)
    written_seqs: list[int] = field(default_factory=list)
    written_at: list[float] = field(default_factory=list)  # monotonic time of each write
    disconnect_times: list[float] = field(default_factory=list)

    @property
    def frames_dropped(self) -> int:
        """Frames the device made that never reached the host whole."""
        return self.frames_dropped_outage + self.frames_dropped_overflow + self.frames_lost_in_link


class VirtualDAQ:
    """A fielddiag DAQ on a pseudo-terminal, streaming ``signals_mps2`` in real time.

    Parameters
    ----------
    signals_mps2 : ndarray (n, n_channels)
        What the sensors read [m/s2]; looped when ``loop`` (else the device stops at the end).
    sample_rate_hz : float
        Sample rate on the device clock.
    samples_per_frame : int or None
        Samples per channel per DATA frame (default: about 100 frames per second).
    sample_format : {"int16", "int32", "float32"}
    full_scale_mps2 : float
        Physical value of raw 2**(bits-1) (default 16 g).
    roles : sequence of str
        Channel roles (default wheel, body, other...).
    corrupt_rate : float
        Probability that any byte sent is altered.
    garbage_every_s : float or None
        Insert a burst of 16-512 random bytes between frames this often.
    disconnect_at_s, disconnect_for_s : float or None
        Pull the cable this long after the first START, for this long.
    stall_at_s, stall_for_s : float or None
        Stop sending (frames pile up in the device's TX buffer, then overflow) for a while.
    power_cycle_on_disconnect : bool
        Reboot on reconnect (bus-powered device): sequence and clock restart, waits for START.
    clock_drift_ppm : float
        The device clock runs fast by this much relative to the host.
    tx_jitter_s : float
        Mean of an exponentially distributed extra delay before each frame is sent (a busy
        USB bus, a late interrupt); frames stay in order, so a late frame also holds back
        the ones behind it. 0: a frame is sent as soon as its last sample is acquired.
    tx_buffer_bytes : int
        The device's transmit FIFO; whole frames that do not fit are dropped.
    seed : int
        Seeds the fault injection.
    """

    def __init__(
        self,
        signals_mps2: np.ndarray,
        *,
        sample_rate_hz: float,
        samples_per_frame: int | None = None,
        sample_format: str = "int32",
        full_scale_mps2: float = 16.0 * G_MPS2,
        roles: Sequence[str] | None = None,
        serial_number: str = "VDAQ-0001",
        model: str = "fielddiag-vdaq",
        corrupt_rate: float = 0.0,
        garbage_every_s: float | None = None,
        disconnect_at_s: float | None = None,
        disconnect_for_s: float = 2.0,
        stall_at_s: float | None = None,
        stall_for_s: float = 1.0,
        power_cycle_on_disconnect: bool = False,
        clock_drift_ppm: float = 0.0,
        tx_jitter_s: float = 0.0,
        tx_buffer_bytes: int = 65536,
        loop: bool = True,
        seed: int = 0,
        link_name: str = "ttyVDAQ0",
    ) -> None:
        sig = np.asarray(signals_mps2, dtype="f8")
        if sig.ndim == 1:
            sig = sig[:, None]
        n, nch = sig.shape
        if sample_format not in FORMAT_CODES:
            raise ValueError(f"sample_format must be one of {sorted(FORMAT_CODES)}")
        self.format_code = FORMAT_CODES[sample_format]
        self.sample_rate_hz = float(sample_rate_hz)
        spf = samples_per_frame or max(1, int(round(sample_rate_hz / 100.0)))
        self.samples_per_frame = int(spf)
        self.counts = to_counts(sig, full_scale_mps2, self.format_code)
        roles = list(roles) if roles else (["wheel", "body"] + ["other"] * nch)[:nch]
        self.info = DeviceInfo(
            serial_number=serial_number,
            model=model,
            sample_rate_hz=self.sample_rate_hz,
            sample_format=self.format_code,
            samples_per_frame=self.samples_per_frame,
            channels=tuple(ChannelInfo(float(full_scale_mps2), r, "z") for r in roles),
        )
        self.corrupt_rate = float(corrupt_rate)
        self.garbage_every_s = garbage_every_s
        self.disconnect_at_s = disconnect_at_s
        self.disconnect_for_s = float(disconnect_for_s)
        self.stall_at_s = stall_at_s
        self.stall_for_s = float(stall_for_s)
        self.power_cycle_on_disconnect = power_cycle_on_disconnect
        self.clock_drift_ppm = float(clock_drift_ppm)
        self.tx_jitter_s = float(tx_jitter_s)
        self.tx_buffer_bytes = int(tx_buffer_bytes)
        self.loop = loop
        self._rng = np.random.default_rng(seed)
        self.stats = VirtualDAQStats()
        self.link = PtyLink(link_name, "vdaq")
        self.path = self.link.path
        self._tx = bytearray()
        self._tx_frames: deque[tuple[int, int]] = deque()  # (end offset in stream, seq)
        self._tx_base = 0  # stream offset of _tx[0]
        self._tx_hold: deque[tuple[int, float]] = deque()  # (start offset, send not before)
        self._sent: deque[tuple[int, int]] = deque()  # written frames (end offset, seq)
        self._cmd = bytearray()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()
        self.finished = False
        self._boot()

    # -------------------------------------------------------------- device clock
    def _boot(self) -> None:
        self._boot_mono = time.monotonic() - float(self._rng.uniform(10.0, 1000.0))
        self.seq = 0
        self.streaming = False
        self._data_index = 0
        self._run_start_dev_s = 0.0
        self._run_frames = 0
        self._run_seq0 = 0
        self._run_index0 = 0
        self._run_started = False

    def device_time_s(self, mono: float | None = None) -> float:
        """Device clock (seconds since boot) at host monotonic time ``mono``."""
        mono = time.monotonic() if mono is None else mono
        return (mono - self._boot_mono) * (1.0 + self.clock_drift_ppm * 1e-6)

    def _mono_of_device(self, dev_s: float) -> float:
        return self._boot_mono + dev_s / (1.0 + self.clock_drift_ppm * 1e-6)

    # -------------------------------------------------------------- truth
    def truth(self, seq: int) -> np.ndarray:
        """Raw samples (n, n_channels) of the frame with sequence number ``seq``."""
        n = self.samples_per_frame
        idx = (seq * n + np.arange(n)) % self.counts.shape[0]
        return self.counts[idx]

    def data_time_s(self, mono: float | None = None) -> float | None:
        """How far into ``signals_mps2`` the device is at host time ``mono`` [s].

        Sample ``k`` of the signals is acquired at data time ``k / sample_rate_hz``; a
        device that plays a drive with another one (the virtual ECU) follows this clock.
        Not wrapped when looping; after a STOP (or the end of the signals) it runs on from
        the last run. None before the first START (since power-on).
        """
        if not self._run_started:
            return None
        return (self._run_index0 / self.sample_rate_hz
                + self.device_time_s(mono) - self._run_start_dev_s)

    def acquired_at(self, seq: int) -> float:
        """Host monotonic time at which frame ``seq`` of the current run started acquiring."""
        dev = self._run_start_dev_s + (seq - self._run_seq0) * self.samples_per_frame / (
            self.sample_rate_hz
        )
        return self._mono_of_device(dev)

    # -------------------------------------------------------------- lifecycle
    def start(self) -> VirtualDAQ:
        """Run the device in a background thread."""
        self._thread = threading.Thread(target=self.run, name="virtual-daq", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop the device and remove its pty and symlink."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5.0)
        self.link.close()

    def __enter__(self) -> VirtualDAQ:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # -------------------------------------------------------------- main loop
    def run(self) -> None:
        """The device's firmware loop (blocking; :meth:`start` runs it in a thread)."""
        first_start: float | None = None
        outage_until: float | None = None
        stall_until: float | None = None
        disconnected_once = stalled_once = False
        next_garbage: float | None = None
        period_frame = self.samples_per_frame / self.sample_rate_hz
        while not self._stop.is_set():
            now = time.monotonic()
            # ---- the cable
            if outage_until is not None and now >= outage_until:
                self.link.connect()
                self.stats.reconnects += 1
                outage_until = None
                if self.power_cycle_on_disconnect:
                    self._boot()
            since = None if first_start is None else now - first_start
            if (
                self.disconnect_at_s is not None
                and not disconnected_once
                and since is not None
                and since >= self.disconnect_at_s
            ):
                disconnected_once = True
                self._pull_cable()
                outage_until = now + self.disconnect_for_s
            if (
                self.stall_at_s is not None
                and not stalled_once
                and since is not None
                and since >= self.stall_at_s
            ):
                stalled_once = True
                stall_until = now + self.stall_for_s
                self.stats.stalls += 1
            # ---- commands
            if self.link.up:
                self._handle_commands(self.link.read())
                if self.streaming and first_start is None:
                    first_start = now
                    if self.garbage_every_s:
                        next_garbage = now + self.garbage_every_s
            # ---- acquisition
            if self.streaming:
                self._produce(now)
            if next_garbage is not None and now >= next_garbage:
                burst = self._rng.integers(0, 256, int(self._rng.integers(16, 513)), "u1")
                self._enqueue(burst.tobytes(), None)
                self.stats.garbage_bytes += burst.size
                next_garbage += self.garbage_every_s
            # ---- transmission
            if stall_until is not None and now >= stall_until:
                stall_until = None
            if self.link.up and stall_until is None:
                self._transmit()
            # sleep until the next frame is due (a real device sends it right away)
            wait = 0.005
            if self.streaming:
                t_next = self._run_start_dev_s + (self._run_frames + 1) * period_frame
                wait = self._mono_of_device(t_next) - time.monotonic()
            if self._tx_hold:
                wait = min(wait, self._tx_hold[0][1] - time.monotonic())
            time.sleep(min(max(wait, 0.0002), 0.005))

    def _handle_commands(self, data: bytes) -> None:
        if not data:
            return
        self._cmd += data
        *lines, rest = self._cmd.split(b"\n")
        self._cmd = bytearray(rest[-64:])
        for raw in lines:
            cmd = raw.strip().upper()
            if cmd == b"INFO":
                self._enqueue(encode_info(self.info), None)
            elif cmd == b"START":
                if not self.streaming:
                    self._run_start_dev_s = self.device_time_s()
                    self._run_frames = 0
                    self._run_seq0 = self.seq
                    self._run_index0 = self._data_index
                    self._run_started = True  # last: data_time_s() reads the run's start
                    self.streaming = True
            elif cmd == b"STOP":
                self.streaming = False

    def _produce(self, now: float) -> None:
        n = self.samples_per_frame
        rate = self.sample_rate_hz
        dev_now = self.device_time_s(now)
        while True:
            t_first = self._run_start_dev_s + self._run_frames * n / rate
            if t_first + n / rate > dev_now:
                return
            total = self.counts.shape[0]
            if not self.loop and self._data_index + n > total:
                self.finished = True
                self.streaming = False
                return
            idx = (self._data_index + np.arange(n)) % total
            frame = encode_data(
                self.seq, int(round(t_first * 1e6)), self.counts[idx], self.format_code
            )
            self.stats.frames_made += 1
            if not self.link.up:
                self.stats.frames_dropped_outage += 1
                self.stats.dropped_seqs.append(self.seq)
            elif len(self._tx) + len(frame) > self.tx_buffer_bytes:
                self.stats.frames_dropped_overflow += 1
                self.stats.dropped_seqs.append(self.seq)
            else:
                if self.corrupt_rate > 0:
                    frame = self._corrupt(frame)
                self._enqueue(frame, self.seq)
                self.stats.frames_queued += 1
            self.seq = (self.seq + 1) & 0xFFFFFFFF
            self._data_index += n
            self._run_frames += 1

    def _corrupt(self, frame: bytes) -> bytes:
        hit = self._rng.random(len(frame)) < self.corrupt_rate
        if not hit.any():
            return frame
        arr = np.frombuffer(frame, "u1").copy()
        arr[hit] ^= self._rng.integers(1, 256, int(hit.sum()), dtype="u1")
        self.stats.frames_corrupted += 1
        self.stats.corrupted_seqs.add(self.seq)
        return arr.tobytes()

    def _enqueue(self, data: bytes, seq: int | None) -> None:
        if not self.link.up:
            return
        if seq is not None and self.tx_jitter_s > 0:
            delay = float(self._rng.exponential(self.tx_jitter_s))
            self._tx_hold.append((self._tx_base + len(self._tx), time.monotonic() + delay))
        self._tx += data
        if seq is not None:
            self._tx_frames.append((self._tx_base + len(self._tx), seq))

    def _transmit(self) -> None:
        now = time.monotonic()
        hold = self._tx_hold
        while hold and hold[0][1] <= now:
            hold.popleft()
        # bytes that may go now: up to the first frame still held back (tx_jitter_s)
        ready = (hold[0][0] if hold else self._tx_base + len(self._tx)) - self._tx_base
        while ready > 0:
            k = self.link.write(self._tx[:ready])
            if k <= 0:
                break
            del self._tx[:k]
            self._tx_base += k
            ready -= k
            self.stats.bytes_written += k
        while self._tx_frames and self._tx_frames[0][0] <= self._tx_base:
            end, seq = self._tx_frames.popleft()
            self._sent.append((end, seq))
            self.stats.frames_written += 1
            self.stats.written_seqs.append(seq)
            self.stats.written_at.append(now)
        # a pty holds well under 1 MB: older frames have certainly been read
        while self._sent and self._sent[0][0] < self._tx_base - (1 << 20):
            self._sent.popleft()

    def _pull_cable(self) -> None:
        """The cable comes out: what is queued, and what the host has not read, is lost."""
        self.stats.disconnects += 1
        self.stats.disconnect_times.append(time.monotonic())
        time.sleep(0.001)  # let the bytes written last reach the pty's input queue
        unread = self.link.drain_unread()
        first_unread = self._tx_base - unread  # stream offset of the first byte not read
        lost = [seq for end, seq in self._sent if end > first_unread]
        lost += [seq for _, seq in self._tx_frames]
        self.stats.frames_lost_in_link += len(lost)
        self.stats.dropped_seqs.extend(lost)
        self._sent.clear()
        self._tx_frames.clear()
        self._tx_hold.clear()
        self._tx_base += len(self._tx)
        self._tx.clear()
        self._cmd.clear()
        self.link.disconnect()


# ----------------------------------------------------------------------------- ECU
class SlcanPty:
    """The adapter side of an SLCAN (Lawicel) CAN-USB adapter, emulated on a pty.

    A process holding this object "is" a CAN bus behind a serial adapter: python-can's
    ``slcan`` interface in another process opens :attr:`path` and receives the frames
    given to :meth:`send` once it has opened the channel (``O`` command). Commands are
    acknowledged with ``\\r`` as real adapters do. :meth:`time_since_first_open` is a
    clock for a :class:`VirtualECU` that starts its drive when the host first opens the
    channel (a recording starting), not when the process starts.
    """

    def __init__(self, link_name: str = "ttyVECU0") -> None:
        self.link = PtyLink(link_name, "vecu")
        self.path = self.link.path
        self.is_open = False
        #: Monotonic time [s] the host first opened the channel (None: not yet).
        self.first_opened_at_s: float | None = None
        self._cmd = bytearray()
        self._lock = threading.Lock()
        self.frames_sent = 0

    def _poll(self) -> None:
        data = self.link.read()
        if not data:
            return
        self._cmd += data
        while True:
            i = self._cmd.find(b"\r")
            if i < 0:
                break
            cmd = bytes(self._cmd[:i])
            del self._cmd[: i + 1]
            if cmd.startswith(b"O") or cmd.startswith(b"L"):
                self.is_open = True
                if self.first_opened_at_s is None:
                    self.first_opened_at_s = time.monotonic()
            elif cmd.startswith(b"C"):
                self.is_open = False
            if cmd.startswith(b"V"):
                self.link.write(b"V1013\r")
            elif cmd.startswith(b"N"):
                self.link.write(b"NVECU\r")
            else:
                self.link.write(b"\r")

    def time_since_first_open(self) -> float:
        """Seconds since the host first opened the channel, 0 before (the host's commands
        are answered meanwhile): a :class:`VirtualECU` ``time_fn``."""
        with self._lock:
            self._poll()
            t0 = self.first_opened_at_s
        return 0.0 if t0 is None else time.monotonic() - t0

    def send(self, msg: Any, timeout: float | None = None) -> None:
        """Put a ``can.Message`` on the emulated bus."""
        with self._lock:
            self._poll()
            if not self.is_open:
                return
            if msg.is_extended_id:
                head = f"T{msg.arbitration_id:08X}{msg.dlc:d}"
            else:
                head = f"t{msg.arbitration_id:03X}{msg.dlc:d}"
            self.link.write(head.encode() + bytes(msg.data).hex().upper().encode() + b"\r")
            self.frames_sent += 1

    def shutdown(self) -> None:
        self.link.close()


class VirtualECU:
    """Publish vehicle speed and wheel speeds (and the car's accelerations) on a CAN bus,
    encoded with a DBC.

    Parameters
    ----------
    bus : object with ``send(can.Message)``
        A python-can bus or an :class:`SlcanPty`.
    speed_time_s, speed_mps : ndarray
        The vehicle speed over time (e.g. a simulated drive's); held after the end, or
        looped when ``loop``.
    dbc : cantools Database, path or None
        Default :data:`VIRTUAL_ECU_DBC`. Must have ``speed_message`` with ``speed_signal``
        and (optional) ``wheel_message`` with the four ``wheel_signals``.
    speed_period_s, wheel_period_s : float
        Transmission periods (the RAV4 sends SPEED at 41 Hz and WHEEL_SPEEDS at 83 Hz).
    accel_mps2 : (ndarray, ndarray) or None
        The car's longitudinal (forward positive) and lateral (left positive) acceleration
        on ``speed_time_s`` [m/s^2] (a full-vehicle drive's), sent in ``accel_message``
        as ``accel_signals`` every ``accel_period_s``. Each value sent is the mean of the
        series over the period centred on the time it is sent for (an anti-alias filter
        without delay: the samples between two frames are not aliased into the band).
        None: not sent.
    time_fn : callable or None
        The ECU's clock (seconds); default: seconds since :meth:`start`. Give a session
        clock's ``now`` to report the speed of that session time, or a virtual DAQ's
        :meth:`VirtualDAQ.data_time_s` to play the drive it streams, in step with it.
    """

    def __init__(
        self,
        bus: Any,
        speed_time_s: np.ndarray,
        speed_mps: np.ndarray,
        *,
        dbc: Any = None,
        speed_message: str = "SPEED",
        speed_signal: str = "SPEED",
        wheel_message: str | None = "WHEEL_SPEEDS",
        wheel_signals: Sequence[str] = (
            "WHEEL_SPEED_FL",
            "WHEEL_SPEED_FR",
            "WHEEL_SPEED_RL",
            "WHEEL_SPEED_RR",
        ),
        speed_period_s: float = 1 / 41.0,
        wheel_period_s: float = 1 / 83.0,
        accel_mps2: tuple[np.ndarray, np.ndarray] | None = None,
        accel_message: str = "KINEMATICS",
        accel_signals: Sequence[str] = ("ACCEL_X", "ACCEL_Y"),
        accel_period_s: float = 0.01,
        loop: bool = False,
        seed: int = 0,
        on_send: Callable[[Any], None] | None = None,
        time_fn: Callable[[], float] | None = None,
    ) -> None:
        import cantools

        if dbc is None:
            dbc = cantools.database.load_string(VIRTUAL_ECU_DBC, strict=False)
        elif isinstance(dbc, str | os.PathLike):
            dbc = cantools.database.load_file(os.fspath(dbc), strict=False)
        self.db = dbc
        self.bus = bus
        self.t = np.asarray(speed_time_s, dtype="f8")
        self.v = np.asarray(speed_mps, dtype="f8")
        self.speed_msg = dbc.get_message_by_name(speed_message)
        self.speed_signal = speed_signal
        self.wheel_msg = dbc.get_message_by_name(wheel_message) if wheel_message else None
        self.wheel_signals = tuple(wheel_signals)
        self.speed_period_s = speed_period_s
        self.wheel_period_s = wheel_period_s
        self.accel_msg = dbc.get_message_by_name(accel_message) if accel_mps2 else None
        self.accel_signals = tuple(accel_signals)
        self.accel_period_s = float(accel_period_s)
        # running sums of the accelerations: the mean over any window in two look-ups
        self._accel_sums = None if accel_mps2 is None else [
            np.concatenate([[0.0], np.cumsum(np.asarray(a, dtype="f8"))]) for a in accel_mps2]
        self.loop = loop
        rng = np.random.default_rng(seed)
        self._wheel_factor = 1.0 + rng.normal(0.0, 0.002, 4)  # tyre radius differences
        self.frames_sent = 0
        self.on_send = on_send
        self.time_fn = time_fn
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._t0 = 0.0
        self.error: BaseException | None = None

    def speed_at(self, t_s: float) -> float:
        """Vehicle speed [m/s] the ECU reports at ``t_s`` after its start."""
        if self.loop and self.t.size > 1:
            t_s = t_s % self.t[-1]
        return float(np.interp(t_s, self.t, self.v))

    def accel_at(self, t_s: float) -> tuple[float, float]:
        """Longitudinal and lateral acceleration [m/s^2] the ECU reports at ``t_s``: the
        mean of the series over ``accel_period_s`` centred on ``t_s``."""
        if self._accel_sums is None:
            raise ValueError("this ECU has no accelerations to send (accel_mps2=None)")
        if self.loop and self.t.size > 1:
            t_s = t_s % self.t[-1]
        half = 0.5 * self.accel_period_s
        i0, i1 = np.searchsorted(self.t, [t_s - half, t_s + half], side="left")
        i0 = min(int(i0), self.t.size - 1)
        i1 = max(int(i1), i0 + 1)
        return tuple(float((c[i1] - c[i0]) / (i1 - i0)) for c in self._accel_sums)

    def _encode(self, msg: Any, values: dict[str, float]) -> bytes:
        full = {}
        for s in msg.signals:
            v = values.get(s.name, 0.0 if s.offset <= 0 else s.offset)
            lo = s.minimum if s.minimum is not None else -math.inf
            hi = s.maximum if s.maximum is not None else math.inf
            if lo < hi:
                v = min(max(v, lo), hi)
            full[s.name] = v
        return msg.encode(full, scaling=True, strict=False)

    def _send(self, msg: Any, values: dict[str, float]) -> None:
        import can

        m = can.Message(
            arbitration_id=msg.frame_id,
            data=self._encode(msg, values),
            is_extended_id=msg.is_extended_frame,
        )
        self.bus.send(m)
        self.frames_sent += 1
        if self.on_send:
            self.on_send(m)

    def step(self, t_s: float, send_speed: bool, send_wheels: bool,
             send_accel: bool = False) -> None:
        """Send the frames due at ``t_s`` (used by the thread; public for tests)."""
        if send_accel and self.accel_msg is not None:
            self._send(self.accel_msg, dict(zip(self.accel_signals, self.accel_at(t_s),
                                                strict=True)))
        v_kmh = self.speed_at(t_s) * 3.6
        if send_speed:
            self._send(self.speed_msg, {self.speed_signal: v_kmh})
        if send_wheels and self.wheel_msg is not None:
            self._send(
                self.wheel_msg,
                {
                    name: v_kmh * f
                    for name, f in zip(self.wheel_signals, self._wheel_factor, strict=True)
                },
            )

    def run(self) -> None:
        """Transmit until stopped (blocking)."""
        self._t0 = time.monotonic()
        now = self.time_fn or (lambda: time.monotonic() - self._t0)
        next_speed = next_wheel = now()
        next_accel = next_speed if self.accel_msg is not None else math.inf
        try:
            while not self._stop.is_set():
                t = now()
                if not self.loop and t > self.t[-1] + 1.0:
                    break
                due_s, due_w, due_a = t >= next_speed, t >= next_wheel, t >= next_accel
                if due_s or due_w or due_a:
                    self.step(t, due_s, due_w, due_a)
                    if due_s:
                        next_speed += self.speed_period_s
                    if due_w:
                        next_wheel += self.wheel_period_s
                    if due_a:
                        next_accel += self.accel_period_s
                wait = min(next_speed, next_wheel, next_accel) - now()
                if wait > 0:
                    self._stop.wait(wait)
        except Exception as exc:  # a bus error ends the ECU; keep the reason
            self.error = exc

    def start(self) -> VirtualECU:
        self._thread = threading.Thread(target=self.run, name="virtual-ecu", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)

    def __enter__(self) -> VirtualECU:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
