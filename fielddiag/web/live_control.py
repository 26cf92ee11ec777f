"""A recording started from the dashboard: the page's choices, its sources and recorder.

:class:`LiveOptions` holds the choices of the live page (a DAQ, a CAN source, where to
write, the faults of the virtual DAQ) and checks them; :class:`LiveRecording` records
them through :class:`fielddiag.virtual_drive.VirtualDrive`, the one harness of the virtual
devices (a :class:`drivers.virtual.VirtualDAQ` on a pseudo-terminal streaming a simulated
drive in a loop, read through the real serial driver, and a
:class:`drivers.virtual.VirtualECU` on a python-can ``virtual`` bus, read through the real
CAN driver), with real sources given by URL alongside. Everything it starts it stops
again in :meth:`LiveRecording.stop`.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from fielddiag.channels import SessionMetadata
from fielddiag.errors import DeviceError
from fielddiag.virtual_drive import LOOP_DRIVE_S, VirtualDrive

if TYPE_CHECKING:
    from fielddiag.recorder import Recorder

VIRTUAL = "virtual"
NONE = "none"

__all__ = ["LiveOptions", "LiveRecording", "daq_choices", "can_choices"]


def daq_choices() -> dict[str, str]:
    """DAQ sources to offer: the virtual DAQ, then serial ports found on this machine.

    Returns
    -------
    dict of str to str
        Choice (``virtual`` or a ``serial://`` URL) to the label shown.
    """
    out = {VIRTUAL: "virtual DAQ (simulated car, real serial driver on a pty)"}
    try:
        from drivers.serial_daq import list_ports

        for p in list_ports(include_virtual=False):
            out[f"serial://{p['device']}"] = f"{p['device']} ({p.get('description') or 'serial'})"
    except Exception:  # no pyserial tools, no permission: offer what we have
        pass
    return out


def can_choices() -> dict[str, str]:
    """CAN sources to offer.

    Returns
    -------
    dict of str to str
        Choice (``none`` or ``virtual``) to the label shown.
    """
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
        """The fault keywords of :class:`drivers.virtual.VirtualDAQ`.

        Returns
        -------
        dict
            ``corrupt_rate``, ``garbage_every_s`` [s], ``stall_at_s`` [s],
            ``stall_for_s`` [s], ``tx_buffer_bytes`` [bytes].
        """
        return {"corrupt_rate": self.corrupt_rate, "garbage_every_s": self.garbage_every_s,
                "stall_at_s": self.stall_at_s, "stall_for_s": self.stall_for_s,
                "tx_buffer_bytes": self.tx_buffer_bytes}


class LiveRecording:
    """Sources + recorder for one recording started from the dashboard.

    The virtual devices, the recorder, the on-line estimator and the order in which they
    start and stop are :class:`fielddiag.virtual_drive.VirtualDrive`'s (the harness
    ``fielddiag demo`` records with); this class turns the page's choices into it and
    gives the page what it shows.

    Parameters
    ----------
    options : LiveOptions
        What to record and where.
    """

    def __init__(self, options: LiveOptions) -> None:
        self.options = options
        self.run: VirtualDrive | None = None

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> LiveRecording:
        """Start the virtual devices chosen, open the sources, start recording.

        Returns
        -------
        LiveRecording
            self, recording.

        Raises
        ------
        FieldDiagError
            No source chosen, a source URL that is not understood or cannot be opened,
            a full disk...: the message says which.
        """
        from drivers.base import open_source

        o = self.options
        virtual_daq, virtual_ecu = o.daq == VIRTUAL, o.can == VIRTUAL
        sources = [open_source(url) for url in (o.daq, o.can)
                   if url and url not in (VIRTUAL, NONE)]
        if not (virtual_daq or virtual_ecu or sources):
            raise DeviceError("choose a DAQ and/or a CAN source to record")
        self.run = VirtualDrive(
            o.path, drive_s=LOOP_DRIVE_S, loop=True, virtual_daq=virtual_daq,
            virtual_ecu=virtual_ecu, sources=sources, metadata=o.metadata,
            sample_rate_hz=o.sample_rate_hz, n_channels=o.n_channels, seed=o.seed,
            faults=o.daq_faults() if virtual_daq else None, online=True,
            include_recipe=False,
        )
        self.run.start()
        return self

    def stop(self) -> dict[str, Any]:
        """Stop recording, close the session, stop the virtual devices.

        Safe to call from several threads and more than once.

        Returns
        -------
        dict
            The final status (empty when the recording never started); :attr:`error`
            says why it failed, if it did.
        """
        return self.run.stop() if self.run is not None else {}

    # ------------------------------------------------------------------ live access
    @property
    def recorder(self) -> Recorder | None:
        """The :class:`fielddiag.recorder.Recorder` (None before the start)."""
        return self.run.recorder if self.run is not None else None

    @property
    def error(self) -> str:
        """Why the recording failed ("" while it has not)."""
        err = self.run.error if self.run is not None else None
        return str(err) if err is not None else ""

    @property
    def running(self) -> bool:
        """True while recording."""
        return self.run is not None and self.run.running

    @property
    def t0_unix_s(self) -> float:
        """Wall-clock time of session time zero [s since the epoch]; 0 before the start."""
        clock = getattr(self.recorder, "clock", None)
        return float(clock.t0_unix_s) if clock is not None else 0.0

    def status(self) -> dict[str, Any]:
        """The live status (:meth:`fielddiag.virtual_drive.VirtualDrive.status`)."""
        return self.run.status() if self.run is not None else {"state": "new"}

    def latest(self, seconds: float) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """The last ``seconds`` [s] of DAQ data: (time [s], {channel: calibrated values})."""
        if self.recorder is None:
            return np.zeros(0), {}
        return self.recorder.latest(seconds)

    def latest_signals(self, seconds: float) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """The last ``seconds`` [s] of every vehicle signal: {name: (time [s], value [SI])}."""
        if self.recorder is None:
            return {}
        return self.recorder.latest_signals(seconds)

    def add_event(self, label: str) -> float:
        """Mark now with ``label``; returns its session time [s].

        Raises
        ------
        DeviceError
            Not recording.
        """
        if self.recorder is None or not self.running:
            raise DeviceError("not recording: start a recording before marking events")
        return self.recorder.add_event(label)

    def observability(self) -> dict[str, Any] | None:
        """The on-line estimator's status (parameters with their information and state,
        and advice for the technician), or None when no estimator runs."""
        online = getattr(self.recorder, "online", None)
        return online.status() if online is not None else None

    @property
    def estimator_error(self) -> str:
        """Why there is no on-line estimate ("" when there is one, or not yet)."""
        if self.run is None:
            return ""
        return self.run.online_error or getattr(self.recorder, "online_error", "")

    @property
    def units(self) -> dict[str, str]:
        """Unit of every channel and signal recorded, by name."""
        rec = self.recorder
        out = {c.name: c.unit for c in getattr(rec, "channels", [])}
        out.update({s.name: s.unit for s in getattr(rec, "signals", [])})
        return out

    @property
    def path(self) -> Path:
        """The session file."""
        return Path(os.fspath(self.options.path))
