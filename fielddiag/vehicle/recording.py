"""A full-vehicle drive as measured: eight vertical accelerometers, speed and the car's
longitudinal and lateral accelerations, with the vehicle geometry; and its reader.

A full-vehicle session holds the DAQ channels with roles ``wheel_fl``, ``body_fl``, ...
(all eight, :data:`FULL_VEHICLE_ROLES`), the vehicle signals with roles ``speed``,
``accel_long`` (forward positive) and ``accel_lat`` (left positive), and the vehicle
file in the metadata (``extra["vehicle"]``, :mod:`fielddiag.vehicle.geometry`). A drive
with an added mass also says where it sits (``extra["added_mass_at_m"] = [x_m, y_m]``).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fielddiag.channels import CORNERS
from fielddiag.drive import accel_unit_factor, find_channel
from fielddiag.errors import ChannelNotFoundError
from fielddiag.vehicle.geometry import VehicleFileError, VehicleGeometry

__all__ = ["FULL_VEHICLE_ROLES", "VEHICLE_SIGNAL_ROLES", "VehicleRecording",
           "full_vehicle_extra", "is_full_vehicle_session", "read_vehicle_recording",
           "reading_notes"]

#: The eight accelerometer roles of a full-vehicle session.
FULL_VEHICLE_ROLES = tuple(f"{k}_{c}" for k in ("wheel", "body") for c in CORNERS)
#: The vehicle signals a full-vehicle session carries (roles).
VEHICLE_SIGNAL_ROLES = ("speed", "accel_long", "accel_lat")
#: Signal names the writers use for them.
SIGNAL_NAMES = {"speed": "vehicle_speed", "accel_long": "accel_long", "accel_lat": "accel_lat"}


@dataclass(eq=False)
class VehicleRecording:
    """One full-vehicle drive in SI units.

    Attributes
    ----------
    wheel_accel_mps2, body_accel_mps2 : ndarray, shape (4, n)
        Hub and body accelerometers (fl, fr, rl, rr) as read: vertical, up positive,
        gravity included [m/s^2]; body sensors at ``geometry.body_sensors``.
    sample_rate_hz : float
    geometry : VehicleGeometry
    speed_mps, accel_long_mps2, accel_lat_mps2 : ndarray (n,) or None
        On the DAQ time base; None when the drive has no such signal (taken as 0).
    added_mass_kg : float
        Mass added on the body for this drive [kg].
    added_mass_at_m : (float, float) or None
        Where it sits (x, y) [m], None when not recorded.
    label, name, path : str
        The drive's part in an analysis, its file name and path ("" for arrays).
    start_s : float
        Time of the first sample from the start of the recording [s] (0 but where the
        reader kept a later stretch).
    notes : tuple of str
        What the reader did that the analysis's user should know (the stretch of a drive
        with gaps it kept).
    """

    wheel_accel_mps2: np.ndarray
    body_accel_mps2: np.ndarray
    sample_rate_hz: float
    geometry: VehicleGeometry
    speed_mps: np.ndarray | None = None
    accel_long_mps2: np.ndarray | None = None
    accel_lat_mps2: np.ndarray | None = None
    added_mass_kg: float = 0.0
    added_mass_at_m: tuple[float, float] | None = None
    label: str = ""
    name: str = ""
    path: str = ""
    start_s: float = 0.0
    notes: tuple[str, ...] = ()

    @property
    def n(self) -> int:
        """Number of samples."""
        return int(np.shape(self.wheel_accel_mps2)[1])

    @property
    def duration_s(self) -> float:
        """Samples / rate [s]."""
        return self.n / self.sample_rate_hz

    @property
    def time_s(self) -> np.ndarray:
        """Sample times from 0 [s]."""
        return np.arange(self.n) / self.sample_rate_hz

    def signal_or_zero(self, which: str) -> np.ndarray:
        """``speed``, ``accel_long`` or ``accel_lat`` on the DAQ time base (zeros if absent)."""
        v = {"speed": self.speed_mps, "accel_long": self.accel_long_mps2,
             "accel_lat": self.accel_lat_mps2}[which]
        return np.zeros(self.n) if v is None else np.asarray(v, float)[: self.n]


def full_vehicle_extra(geometry: VehicleGeometry,
                       added_mass_at_m: tuple[float, float] | None = None) -> dict:
    """The metadata ``extra`` of a full-vehicle session (what its writers store).

    Parameters
    ----------
    geometry : VehicleGeometry
        The vehicle file (``extra["vehicle"]``).
    added_mass_at_m : (x_m, y_m) or None
        Where the added mass sits (``extra["added_mass_at_m"]``); None: not stored.

    Returns
    -------
    dict
        ``{"vehicle": ..., "full_vehicle": True[, "added_mass_at_m": [x, y]]}``.
    """
    extra: dict = {"vehicle": geometry.to_dict(), "full_vehicle": True}
    if added_mass_at_m is not None:
        extra["added_mass_at_m"] = [float(added_mass_at_m[0]), float(added_mass_at_m[1])]
    return extra


def is_full_vehicle_session(path: str | os.PathLike) -> bool:
    """True when the session holds all eight corner accelerometer roles.

    Parameters
    ----------
    path : str or PathLike
        A session file (must be readable).
    """
    from fielddiag.session import SessionReader

    with SessionReader(path) as s:
        roles = {c.role for c in s.channels}
    return all(r in roles for r in FULL_VEHICLE_ROLES)


def read_vehicle_recording(path: str | os.PathLike, *, label: str = "",
                           added_mass_kg: float | None = None,
                           added_mass_at_m: tuple[float, float] | None = None,
                           purpose: str = "identify") -> VehicleRecording:
    """Read a full-vehicle session.

    Parameters
    ----------
    path : str or PathLike
        The session.
    label : str
        Its part in the analysis (``before``, ``after``, ``validate``).
    added_mass_kg, added_mass_at_m : optional
        Override the session's metadata.
    purpose : str
        For the messages.

    Returns
    -------
    VehicleRecording

    Raises
    ------
    ChannelNotFoundError
        A corner accelerometer role is missing or given twice.
    VehicleFileError
        The session holds no (or a bad) vehicle geometry.
    SessionError
        Unreadable session or irregular time stamps (gaps are not an error: see
        ``notes``).
    """
    from fielddiag.drive import _time_base
    from fielddiag.session import SessionReader

    p = Path(path)
    with SessionReader(p) as s:
        name = s.path.name
        missing = [r for r in FULL_VEHICLE_ROLES if r not in {c.role for c in s.channels}]
        if missing:
            raise ChannelNotFoundError(
                f"{name} lacks the full-vehicle role(s) {', '.join(missing)}; {purpose} of the "
                "whole car needs all eight (import with --role wheel_fl=COL ... --role "
                "body_rr=COL)")
        _, fs, pieces = _time_base(s, 0, s.n_samples, purpose)
        i0, i1 = max(pieces, key=lambda p: p[1] - p[0])
        start_s = float(s.time_at(i0, i0 + 1)[0] - s.time_at(0, 1)[0])
        notes = () if len(pieces) == 1 else (
            _stretch_note(name, pieces, (i0, i1), start_s, fs, int(s.counters["samples_lost"])),)
        wheel, body = [], []
        for kind, dest in (("wheel", wheel), ("body", body)):
            for c in CORNERS:
                ch = find_channel(s.channels, kind, corner=c, source=name, purpose=purpose)
                dest.append(s.read(ch.name)[i0:i1] * accel_unit_factor(ch.unit, ch.name))
        sig: dict[str, np.ndarray | None] = {}
        for role in VEHICLE_SIGNAL_ROLES:
            try:
                spec = s.signal_for_role(role)
            except ChannelNotFoundError:
                sig[role] = None
                continue
            v = s.signal_on_daq_time(spec.name)[i0:i1]
            if role == "speed" and spec.unit.strip().lower() in ("km/h", "kmh", "kph"):
                v = v / 3.6
            sig[role] = None if np.all(np.isnan(v)) else np.nan_to_num(v)
        extra = dict(s.metadata.extra or {})
        if "vehicle" not in extra:
            raise VehicleFileError(
                f"{name} holds no vehicle geometry; import it with --vehicle VEHICLE.json "
                "(wheelbase, tracks and body-sensor positions)")
        geom = VehicleGeometry.from_dict(extra["vehicle"], source=f"{name} (vehicle)")
        at = added_mass_at_m
        if at is None and extra.get("added_mass_at_m") is not None:
            raw = extra["added_mass_at_m"]
            at = (float(raw[0]), float(raw[1]))
        dm = float(s.metadata.added_mass_kg if added_mass_kg is None else added_mass_kg)
    n = min(len(a) for a in wheel + body)
    return VehicleRecording(
        wheel_accel_mps2=np.array([a[:n] for a in wheel]),
        body_accel_mps2=np.array([a[:n] for a in body]),
        sample_rate_hz=float(fs), geometry=geom,
        speed_mps=None if sig["speed"] is None else sig["speed"][:n],
        accel_long_mps2=None if sig["accel_long"] is None else sig["accel_long"][:n],
        accel_lat_mps2=None if sig["accel_lat"] is None else sig["accel_lat"][:n],
        added_mass_kg=dm, added_mass_at_m=at, label=label, name=name, path=str(p),
        start_s=start_s, notes=notes)


def reading_notes(*recordings) -> list[str]:
    """The notes of the drives an analysis read (:attr:`VehicleRecording.notes`; none for a
    simulated drive), in order."""
    return [n for rec in recordings for n in getattr(rec, "notes", ())]


def _stretch_note(name: str, pieces: list[tuple[int, int]], kept: tuple[int, int],
                  start_s: float, fs: float, samples_lost: int) -> str:
    """Words for the longest gap-free stretch of a drive with gaps, which the whole-car
    analysis keeps (its equations need every corner at once, without a jump in time)."""
    n = sum(b - a for a, b in pieces)
    gaps = len(pieces) - 1
    return (f"{name} has {gaps} gap{'s' if gaps > 1 else ''} in its time base"
            + (f" ({samples_lost} samples lost while recording)" if samples_lost else "")
            + "; the whole-car analysis uses its longest gap-free stretch, "
            f"{start_s:.1f}-{start_s + (kept[1] - kept[0]) / fs:.1f} s "
            f"({100 * (kept[1] - kept[0]) / n:.0f} % of the samples)")
