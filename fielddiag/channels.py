"""Descriptions of what a session holds: DAQ channels, vehicle signals, events, gaps.

These small value types are shared by the drivers (which produce data), the session
writer and reader (which store it) and the importers. They carry no data arrays.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

#: The corners of a car: front left, front right, rear left, rear right.
CORNERS = ("fl", "fr", "rl", "rr")
#: Roles a DAQ channel can play. ``wheel`` is below the suspension (unsprung side),
#: ``body`` above it (sprung side); a full-vehicle session has ``wheel_fl``, ``body_fl``...
#: per corner instead. Rig tests use ``force``, ``displacement`` and ``acceleration``.
#: Anything else is ``other``.
CHANNEL_ROLES = ("wheel", "body", "force", "displacement", "acceleration", "speed", "other",
                 *(f"{kind}_{c}" for c in CORNERS for kind in ("wheel", "body")))

#: Counters a recording keeps (frames received, lost, CRC errors, ...). A session stores
#: every counter here; drivers that do not produce one leave it at zero.
COUNTER_NAMES = (
    "frames_received",
    "frames_lost",
    "crc_errors",
    "samples_lost",
    "bytes_discarded",
    "reconnects",
    "can_frames_received",
    "can_decode_errors",
)


@dataclass(frozen=True)
class ChannelSpec:
    """One DAQ channel.

    Parameters
    ----------
    name : str
        Unique name inside the session (``wheel_z``, ``ch3``...). Letters, digits, ``_``, ``-``.
    unit : str
        Physical unit of the calibrated value (``m/s2``, ``N``, ``m``).
    role : str
        One of :data:`CHANNEL_ROLES`.
    axis : str
        Sensor axis that was recorded (``z`` = vertical, up positive).
    sensor : str
        Free text: sensor model and serial number.
    scale : float
        Calibration: physical value = raw * scale + offset.
    offset : float
        Calibration offset in the physical unit.
    dtype : str
        numpy dtype of the stored raw samples (``float64``, ``int16``...). Raw samples
        are stored bit for bit as the device sent them; calibration is applied on read.
    """

    name: str
    unit: str = "m/s2"
    role: str = "other"
    axis: str = "z"
    sensor: str = ""
    scale: float = 1.0
    offset: float = 0.0
    dtype: str = "float64"

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class SignalSpec:
    """A vehicle signal with its own time stamps (CAN, GNSS, a CSV column...).

    Parameters
    ----------
    name : str
        Unique name (``vehicle_speed``, ``WHEEL_SPEED_FL``).
    unit : str
        Physical unit (``m/s``, ``km/h``).
    source : str
        Where it came from: ``can``, ``gnss``, ``csv``, ``sim``.
    message : str
        Source message (CAN message name, NMEA sentence...), empty if not applicable.
    role : str
        ``speed`` for the vehicle speed, otherwise ``other``.
    """

    name: str
    unit: str = ""
    source: str = ""
    message: str = ""
    role: str = "other"

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class Event:
    """A labelled instant on the session time axis (a speed bump, a button press)."""

    time_s: float
    label: str


@dataclass(frozen=True)
class Gap:
    """A stretch of the DAQ time axis with no samples, and why."""

    start_s: float
    end_s: float
    samples_lost: int
    cause: str


@dataclass
class SessionMetadata:
    """Root attributes of a session (see docs/session-format.md)."""

    vehicle: str = ""
    corner: str = ""
    operator: str = ""
    added_mass_kg: float = 0.0
    notes: str = ""
    created: str = ""  # UTC ISO 8601; filled in by the writer when empty
    software_version: str = ""  # filled in by the writer
    t0_unix_s: float = 0.0  # wall-clock time of session time zero (0 when unknown)
    extra: dict[str, Any] = field(default_factory=dict)  # anything else, JSON-serialisable

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)
