"""The vehicle file and the rigid-body kinematics of the body (small angles).

Frame (the issue's contract): ``x`` metres behind the front axle (rear axle at
``x = wheelbase``), ``y`` metres left of the centre line, vertical positions up. Corners
``fl``, ``fr``, ``rl``, ``rr``; each wheel accelerometer is on its hub (front ``x = 0``,
rear ``x = wheelbase``, ``y = +-track/2``); the corner's suspension acts between the hub
and the body point straight above it.

The body is rigid. Its vertical motion is described at the origin (the centre of the
front axle) by three coordinates: ``heave`` (vertical displacement of the body point
above the origin), ``pitch`` (slope dz/dx, positive nose down: the rear rises) and
``roll`` (slope dz/dy, positive when the left side rises). The body point at ``(x, y)``
then moves by ``heave + x * pitch + y * roll`` (:func:`point_matrix`). Four body
accelerometers give the three coordinates by least squares (:meth:`VehicleGeometry.
body_dofs_from_sensors`); the fourth reading is redundant and its residual checks the
rigid-body assumption and the sensor positions.

Vehicle file (JSON)::

    {"wheelbase_m": 2.70, "track_front_m": 1.56, "track_rear_m": 1.55,
     "body_sensors": {"fl": [x_m, y_m], "fr": [...], "rl": [...], "rr": [...]}}
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from fielddiag.channels import CORNERS
from fielddiag.errors import FieldDiagError

__all__ = ["CORNERS", "VehicleFileError", "VehicleGeometry", "load_vehicle", "point_matrix"]

_KEYS = ("wheelbase_m", "track_front_m", "track_rear_m", "body_sensors")


class VehicleFileError(FieldDiagError):
    """A vehicle file (or vehicle description) is missing, unreadable or malformed."""


def point_matrix(x_m: np.ndarray, y_m: np.ndarray) -> np.ndarray:
    """Rows ``[1, x, y]``: the vertical motion of body points from (heave, pitch, roll).

    Parameters
    ----------
    x_m, y_m : array_like
        Point positions [m] (x behind the front axle, y left of the centre line).

    Returns
    -------
    numpy.ndarray
        ``(n, 3)``; ``z_points = point_matrix(x, y) @ [heave, pitch, roll]``.
    """
    x = np.atleast_1d(np.asarray(x_m, float))
    y = np.atleast_1d(np.asarray(y_m, float))
    return np.column_stack([np.ones_like(x), x, y])


def _number(where: str, name: str, value: Any, *, positive: bool = False) -> float:
    ok = isinstance(value, int | float) and not isinstance(value, bool)
    v = float(value) if ok else math.nan
    if not math.isfinite(v) or (positive and v <= 0):
        need = "a number > 0" if positive else "a finite number"
        raise VehicleFileError(f"{where}: {name}={value!r} is invalid; give {need} (metres).")
    return v


@dataclass(frozen=True)
class VehicleGeometry:
    """Axle and sensor geometry of a car (the vehicle file).

    Parameters
    ----------
    wheelbase_m : float
        Distance from the front to the rear axle [m] (> 0).
    track_front_m, track_rear_m : float
        Distance between the left and right wheels of each axle [m] (> 0).
    body_sensors : mapping corner -> (x_m, y_m)
        Position of each corner's body accelerometer [m], in the vehicle frame. Default:
        straight above the hubs.

    Raises
    ------
    VehicleFileError
        A value that is not a finite positive length, a missing corner, sensors that do
        not span the body (collinear: heave, pitch and roll cannot be separated).
    """

    wheelbase_m: float = 2.70
    track_front_m: float = 1.56
    track_rear_m: float = 1.55
    body_sensors: Mapping[str, tuple[float, float]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        w = "vehicle"
        for name in ("wheelbase_m", "track_front_m", "track_rear_m"):
            object.__setattr__(self, name, _number(w, name, getattr(self, name), positive=True))
        sensors = dict(self.body_sensors) or {c: self.corner_position(c) for c in CORNERS}
        missing = [c for c in CORNERS if c not in sensors]
        extra = [c for c in sensors if c not in CORNERS]
        if missing or extra:
            raise VehicleFileError(
                f"vehicle: body_sensors must give exactly the corners {', '.join(CORNERS)} "
                f"(missing {missing or 'none'}, unknown {extra or 'none'}).")
        clean: dict[str, tuple[float, float]] = {}
        for c in CORNERS:
            pos = sensors[c]
            if not isinstance(pos, list | tuple | np.ndarray) or len(pos) != 2:
                raise VehicleFileError(
                    f"vehicle: body_sensors.{c}={pos!r}; give [x_m, y_m] (metres behind the "
                    "front axle, metres left of the centre line).")
            clean[c] = (_number(w, f"body_sensors.{c}[0]", pos[0]),
                        _number(w, f"body_sensors.{c}[1]", pos[1]))
        object.__setattr__(self, "body_sensors", clean)
        g = self.sensor_matrix()
        if np.linalg.matrix_rank(g, tol=1e-3 * max(1.0, float(np.abs(g).max()))) < 3:
            raise VehicleFileError(
                "vehicle: the four body sensors lie on one line; place them so that they "
                "span the body (e.g. one near each corner) to separate heave, pitch and roll.")

    # ------------------------------------------------------------------ positions
    def track_m(self, corner: str) -> float:
        """Track of the corner's axle [m]."""
        return self.track_front_m if corner[0] == "f" else self.track_rear_m

    def corner_position(self, corner: str) -> tuple[float, float]:
        """(x, y) of the corner's hub and strut [m]."""
        if corner not in CORNERS:
            raise FieldDiagError(f"corner {corner!r} is not one of {', '.join(CORNERS)}")
        x = 0.0 if corner[0] == "f" else self.wheelbase_m
        y = 0.5 * self.track_m(corner) * (1.0 if corner[1] == "l" else -1.0)
        return x, y

    @property
    def corner_x_m(self) -> np.ndarray:
        """x of the four corners (fl, fr, rl, rr) [m]."""
        return np.array([self.corner_position(c)[0] for c in CORNERS])

    @property
    def corner_y_m(self) -> np.ndarray:
        """y of the four corners (fl, fr, rl, rr) [m]."""
        return np.array([self.corner_position(c)[1] for c in CORNERS])

    def corner_matrix(self) -> np.ndarray:
        """``(4, 3)`` :func:`point_matrix` of the strut points (fl, fr, rl, rr)."""
        return point_matrix(self.corner_x_m, self.corner_y_m)

    def sensor_matrix(self) -> np.ndarray:
        """``(4, 3)`` :func:`point_matrix` of the body sensors (fl, fr, rl, rr)."""
        xy = np.array([self.body_sensors[c] for c in CORNERS])
        return point_matrix(xy[:, 0], xy[:, 1])

    # ------------------------------------------------------------------ kinematics
    def body_motion_at(self, dofs: np.ndarray, x_m: float | np.ndarray,
                       y_m: float | np.ndarray) -> np.ndarray:
        """Vertical motion of body points from heave, pitch and roll (small angles).

        Parameters
        ----------
        dofs : array_like, shape (3,) or (3, n)
            Heave [m], pitch [rad, nose down positive], roll [rad, left up positive] at
            the origin (or their rates / accelerations).
        x_m, y_m : float or array_like
            Point positions [m].

        Returns
        -------
        numpy.ndarray
            ``(points,)`` or ``(points, n)``: the points' vertical motion (same unit).
        """
        return point_matrix(x_m, y_m) @ np.asarray(dofs, float)

    def body_dofs_from_sensors(self, readings: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Heave, pitch and roll at the origin from the four body sensors (least squares).

        Parameters
        ----------
        readings : array_like, shape (4, n)
            The body sensors' vertical motion (fl, fr, rl, rr), any consistent unit
            (accelerations, velocities or displacements).

        Returns
        -------
        dofs : numpy.ndarray, shape (3, n)
            Heave, pitch, roll (or their derivatives).
        residual : numpy.ndarray, shape (4, n)
            Readings minus the rigid-body fit (zero for a rigid body and exact sensor
            positions; 4 sensors, 3 unknowns: one redundancy).
        """
        g = self.sensor_matrix()
        y = np.asarray(readings, float)
        dofs = np.linalg.pinv(g) @ y
        return dofs, y - g @ dofs

    # ------------------------------------------------------------------ file
    def to_dict(self) -> dict[str, Any]:
        """The vehicle file's JSON object (the contract's keys)."""
        return {"wheelbase_m": self.wheelbase_m, "track_front_m": self.track_front_m,
                "track_rear_m": self.track_rear_m,
                "body_sensors": {c: list(self.body_sensors[c]) for c in CORNERS}}

    @classmethod
    def from_dict(cls, d: Any, source: str = "vehicle") -> VehicleGeometry:
        """Validate and build from the vehicle file's JSON object.

        Parameters
        ----------
        d : mapping
            ``{"wheelbase_m", "track_front_m", "track_rear_m", "body_sensors"}``.
        source : str
            Where it came from, for the messages.

        Raises
        ------
        VehicleFileError
            Not an object, a missing or unknown key, a bad value.
        """
        if not isinstance(d, Mapping):
            raise VehicleFileError(f"{source}: a vehicle file holds one JSON object with "
                                   f"{', '.join(_KEYS)}")
        missing = [k for k in _KEYS if k not in d]
        unknown = sorted(k for k in d if k not in _KEYS and k != "name")
        if missing or unknown:
            raise VehicleFileError(
                f"{source}: missing {missing or 'nothing'}, unknown {unknown or 'nothing'}; "
                f"a vehicle file has exactly {', '.join(_KEYS)} (SI units, metres)")
        if not isinstance(d["body_sensors"], Mapping):
            raise VehicleFileError(f"{source}: body_sensors must be an object "
                                   '{"fl": [x_m, y_m], "fr": ..., "rl": ..., "rr": ...}')
        try:
            return cls(d["wheelbase_m"], d["track_front_m"], d["track_rear_m"],
                       dict(d["body_sensors"]))
        except VehicleFileError as exc:
            raise VehicleFileError(str(exc).replace("vehicle:", f"{source}:", 1)) from None

    def to_json(self) -> str:
        """The vehicle file's text."""
        return json.dumps(self.to_dict(), indent=2)


def load_vehicle(path: str | os.PathLike) -> VehicleGeometry:
    """Read and validate a vehicle file.

    Parameters
    ----------
    path : str or PathLike
        The JSON file.

    Returns
    -------
    VehicleGeometry

    Raises
    ------
    VehicleFileError
        Missing, unreadable, not JSON, or invalid content (the message says which).
    """
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise VehicleFileError(f"cannot read the vehicle file {p} ({exc.__class__.__name__}); "
                               "give a JSON file with wheelbase_m, tracks and body_sensors"
                               ) from None
    try:
        d = json.loads(text)
    except json.JSONDecodeError as exc:
        raise VehicleFileError(f"{p.name} is not valid JSON (line {exc.lineno}: {exc.msg}); "
                               "fix the vehicle file") from None
    return VehicleGeometry.from_dict(d, source=p.name)
