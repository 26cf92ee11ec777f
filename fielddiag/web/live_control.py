"""A recording started from the dashboard: its sources (virtual ones included) and recorder.

:class:`LiveRecording` turns the choices of the live page (a DAQ, a CAN source, where to
write) into :mod:`drivers` sources and a :class:`fielddiag.recorder.Recorder`, and for the
virtual choices also runs the virtual devices behind them: a :class:`VirtualDAQ` on a
pseudo-terminal streaming a simulated drive in a loop, read through the real serial
driver, and a :class:`VirtualECU` on a python-can ``virtual`` bus, read through the real
CAN driver. Everything it starts it stops again in :meth:`stop`.
"""

from __future__ import annotations

import os
import threading
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from fielddiag.channels import SessionMetadata
from fielddiag.errors import DeviceError, FieldDiagError

VIRTUAL = "virtual"
NONE = "none"
VIRTUAL_LOOP_S = 120.0

__all__ = ["LiveOptions", "LiveRecording", "daq_choices", "can_choices"]


def daq_choices() -> dict[str, str]:
    """DAQ sources to offer: the virtual DAQ, then serial ports found on this machine."""
    out = {VIRTUAL: "virtual DAQ (simulated car, real serial driver on a pty)"}
    try:
        from drivers.serial_daq import list_ports

        for p in list_ports(include_virtual=False):
            out[f"serial://{p['device']}"] = f"{p['device']} ({p.get('description') or 'serial'})"
    except Exception:  # no pyserial tools, no permission: offer what we have
        pass
    return out


def can_choices() -> dict[str, str]:
    """CAN sources to offer."""
    return {
        NONE: "no CAN",
        VIRTUAL: "virtual ECU (python-can virtual bus, DBC-decoded speed)",
    }


@dataclass
class LiveOptions:
    """What to record and where.

    Attributes
    ----------
    path : Path
        New session file.
    daq, can : str
        ``virtual``, ``none`` or a source URL (``serial:///dev/ttyUSB0``,
        ``can://socketcan/can0?dbc=car.dbc``...).
    metadata : SessionMetadata
    sample_rate_hz : float
        Rate of the virtual DAQ.
    n_channels : int
        Channels of the virtual DAQ (wheel, body, then noise channels).
    seed : int
        Seeds the virtual drive and its faults.
    corrupt_rate : float
        Virtual DAQ fault: probability that any byte it sends is altered (the serial
        driver counts a CRC error and loses the frame). 0 for a clean link.
    garbage_every_s : float or None
        Virtual DAQ fault: a burst of random bytes between frames this often.
    stall_at_s, stall_for_s : float or None, float
        Virtual DAQ fault: it stops sending this long after the start, for this long;
        frames pile up in its transmit buffer and those that do not fit are dropped.
    tx_buffer_bytes : int
        The virtual DAQ's transmit buffer (small: a stall drops frames sooner).
    """

    path: Path
    daq: str = VIRTUAL
    can: str = VIRTUAL
    metadata: SessionMetadata | None = None
    sample_rate_hz: float = 500.0
    n_channels: int = 2
    seed: int = 0
    corrupt_rate: float = 0.0
    garbage_every_s: float | None = None
    stall_at_s: float | None = None
    stall_for_s: float = 1.0
    tx_buffer_bytes: int = 65536

    def __post_init__(self) -> None:
        if not 0.0 <= self.corrupt_rate < 0.1:
            raise DeviceError("the byte corruption rate must be at least 0 and below 0.1, "
                              f"not {self.corrupt_rate:g}")
        for name in ("garbage_every_s", "stall_at_s"):
            v = getattr(self, name)
            if v is not None and not v > 0:
                raise DeviceError(f"{name} must be positive (or empty for none), not {v:g}")
        if not self.stall_for_s > 0 or self.tx_buffer_bytes < 1024:
            raise DeviceError("the stall must last more than 0 s and the transmit buffer "
                              "hold at least 1024 bytes")

    def daq_faults(self) -> dict[str, Any]:
        """The fault keywords of :class:`drivers.virtual.VirtualDAQ`."""
        return {"corrupt_rate": self.corrupt_rate, "garbage_every_s": self.garbage_every_s,
                "stall_at_s": self.stall_at_s, "stall_for_s": self.stall_for_s,
                "tx_buffer_bytes": self.tx_buffer_bytes}


class LiveRecording:
    """Sources + recorder for one recording started from the dashboard."""

    def __init__(self, options: LiveOptions) -> None:
        self.options = options
        self.recorder = None
        self._vdaq = None
        self._ecu = None
        self._bus = None
        self.final_status: dict[str, Any] | None = None
        self.error: str = ""
        self.estimator = None
        self.estimator_error: str = ""
        self._stop_lock = threading.Lock()

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> LiveRecording:
        """Open the sources and start recording (raises FieldDiagError with the reason)."""
        from drivers.base import open_source
        from fielddiag.recorder import Recorder

        o = self.options
        meta = o.metadata or SessionMetadata()
        sources = []
        drive = None
        try:
            if o.daq == VIRTUAL:
                from drivers.serial_daq import SerialDAQSource
                from drivers.virtual import VirtualDAQ, simulated_accelerations

                signals, drive = simulated_accelerations(
                    VIRTUAL_LOOP_S, sample_rate_hz=o.sample_rate_hz,
                    n_channels=max(2, o.n_channels), added_mass_kg=meta.added_mass_kg,
                    seed=o.seed,
                )
                self._vdaq = VirtualDAQ(signals, sample_rate_hz=o.sample_rate_hz, loop=True,
                                        seed=o.seed, **o.daq_faults(),
                                        link_name=f"ttyVDAQ{uuid.uuid4().hex[:6]}").start()
                sources.append(SerialDAQSource.from_url(f"serial://{self._vdaq.path}"))
            elif o.daq and o.daq != NONE:
                sources.append(open_source(o.daq))
            if o.can == VIRTUAL:
                sources.append(self._virtual_can(drive, o))
            elif o.can and o.can != NONE:
                sources.append(open_source(o.can))
            if not sources:
                raise DeviceError("choose a DAQ and/or a CAN source to record")
            self.recorder = Recorder(o.path, sources, metadata=meta)
            self.recorder.start()
            self._attach_estimator(meta)
            if self._ecu is not None:
                self._ecu.start()
        except BaseException:
            self._stop_devices()
            raise
        return self

    def _attach_estimator(self, meta: SessionMetadata) -> None:
        """Feed the on-line estimator (issue 5) from the recorder, if it exists here."""
        from fielddiag.web.services import observability_backend

        backend = observability_backend()
        rec = self.recorder
        if not backend.available or rec.daq is None:
            self.estimator_error = backend.reason or "no DAQ: nothing to estimate from"
            return
        try:
            est = backend.target(rec.daq.sample_rate_hz, added_mass_kg=meta.added_mass_kg)
            rec.block_listeners.append(est.block_listener(rec.channels))
        except FieldDiagError as exc:  # e.g. no wheel/body channel pair
            self.estimator_error = str(exc)
            return
        self.estimator = est

    def _virtual_can(self, drive: Any, o: LiveOptions):
        import can

        from drivers.can_vehicle import CanBusSource
        from drivers.virtual import VirtualECU

        if drive is None:
            from fielddiag import sim

            drive = sim.simulate(duration_s=VIRTUAL_LOOP_S, seed=o.seed,
                                 sensor=sim.SensorModel(output_rate_hz=100.0))
        channel = f"fielddiag-vecu-{uuid.uuid4().hex[:8]}"
        self._bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
        self._ecu = VirtualECU(self._bus, drive.vehicle_speed_time_s, drive.vehicle_speed_mps,
                               loop=True, seed=o.seed)
        src = CanBusSource.from_url(f"can://virtual/{channel}")
        src.dbc = self._ecu.db
        src.dbc_label = "drivers.virtual.VIRTUAL_ECU_DBC"
        src.add_signals(["vehicle_speed=SPEED.SPEED"]
                        + [f"WHEEL_SPEEDS.WHEEL_SPEED_{w}" for w in ("FL", "FR", "RL", "RR")])
        return src

    def _stop_devices(self) -> None:
        for obj in (self._ecu, self._vdaq):
            if obj is not None:
                try:
                    obj.stop()
                except Exception:
                    pass
        if self._bus is not None:
            try:
                self._bus.shutdown()
            except Exception:
                pass
        self._ecu = self._vdaq = self._bus = None

    def stop(self) -> dict[str, Any]:
        """Stop recording, close the session, stop the virtual devices; final status.

        Safe to call from several threads and more than once.
        """
        with self._stop_lock:
            return self._stop_locked()

    def _stop_locked(self) -> dict[str, Any]:
        try:
            if self.recorder is not None and self.final_status is None:
                try:
                    self.final_status = self.recorder.stop()
                except FieldDiagError as exc:
                    self.error = str(exc)
                    self.final_status = self.recorder.status()
        finally:
            self._stop_devices()
        return self.final_status or {}

    # ------------------------------------------------------------------ live access
    @property
    def running(self) -> bool:
        return self.recorder is not None and self.recorder.running

    @property
    def t0_unix_s(self) -> float:
        """Wall-clock time of session time zero."""
        clock = getattr(self.recorder, "clock", None)
        return float(clock.t0_unix_s) if clock is not None else 0.0

    def status(self) -> dict[str, Any]:
        if self.recorder is None:
            return {"state": "new"}
        st = self.recorder.status()
        if self.error and not st.get("last_error"):
            st["last_error"] = self.error
        return st

    def latest(self, seconds: float) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        if self.recorder is None:
            return np.zeros(0), {}
        return self.recorder.latest(seconds)

    def latest_signals(self, seconds: float) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        if self.recorder is None or not hasattr(self.recorder, "latest_signals"):
            return {}
        return self.recorder.latest_signals(seconds)

    def add_event(self, label: str) -> float:
        if self.recorder is None or not self.running:
            raise DeviceError("not recording: start a recording before marking events")
        return self.recorder.add_event(label)

    def observability(self) -> dict[str, Any] | None:
        """The on-line estimator's status (parameters with their information and state,
        and advice for the technician), or None when no estimator runs."""
        if self.estimator is None:
            return None
        return self.estimator.status()

    @property
    def units(self) -> dict[str, str]:
        rec = self.recorder
        out = {c.name: c.unit for c in getattr(rec, "channels", [])}
        out.update({s.name: s.unit for s in getattr(rec, "signals", [])})
        return out

    @property
    def path(self) -> Path:
        return Path(os.fspath(self.options.path))
