"""Manoeuvres of a full-vehicle drive: speed (hence longitudinal acceleration) and lateral
acceleration over time. The road under them is set separately (ISO 8608 class).

* ``rough_road``: a random drive (cruise segments joined by gentle ramps), no steering;
* ``ramp_steer``: constant speed, lateral acceleration ramped slowly up to a peak, held,
  released, alternately to the left and to the right;
* ``braking``: cruise, brake hard to a low speed, accelerate back, repeated.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from fielddiag.errors import FieldDiagError
from fielddiag.sim._common import check_number
from fielddiag.sim.road import SpeedProfile

__all__ = ["MANOEUVRES", "Manoeuvre", "braking", "make_manoeuvre", "ramp_steer", "rough_road"]


@dataclass(frozen=True, eq=False)
class Manoeuvre:
    """What the driver does: speed over time and lateral acceleration over time.

    Parameters
    ----------
    name : str
        ``rough_road``, ``ramp_steer``, ``braking`` or any label.
    speed : SpeedProfile
        Vehicle speed (piecewise linear); the longitudinal acceleration is its slope.
    lateral_time_s, lateral_accel_mps2 : sequence of float
        Knots of the lateral acceleration (left positive), piecewise linear, held after
        the last knot; empty for none.
    """

    name: str
    speed: SpeedProfile
    lateral_time_s: tuple[float, ...] = ()
    lateral_accel_mps2: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        t, a = np.asarray(self.lateral_time_s, float), np.asarray(self.lateral_accel_mps2, float)
        if t.shape != a.shape or (t.size and (np.any(np.diff(t) <= 0) or not np.all(
                np.isfinite(t)) or not np.all(np.isfinite(a)))):
            raise FieldDiagError("Manoeuvre: lateral knots must be increasing finite times "
                                 "with one finite acceleration each.")

    def accel_long_mps2(self, t_s: np.ndarray | float) -> np.ndarray:
        """Longitudinal acceleration (forward positive) [m/s^2] at ``t_s``."""
        sp = self.speed
        i = np.clip(np.searchsorted(sp.knot_time_s, np.asarray(t_s, float), side="right") - 1,
                    0, sp.knot_time_s.size - 1)
        return sp.knot_accel_mps2[i]

    def accel_lat_mps2(self, t_s: np.ndarray | float) -> np.ndarray:
        """Lateral acceleration (left positive) [m/s^2] at ``t_s``."""
        t = np.asarray(t_s, float)
        if not self.lateral_time_s:
            return np.zeros_like(t)
        return np.interp(t, self.lateral_time_s, self.lateral_accel_mps2)

    def lateral_knots(self) -> tuple[np.ndarray, np.ndarray]:
        """(time_s, accel_mps2) knots, at least one (0 m/s^2 at t = 0 when none)."""
        if not self.lateral_time_s:
            return np.zeros(1), np.zeros(1)
        return (np.asarray(self.lateral_time_s, float),
                np.asarray(self.lateral_accel_mps2, float))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready description."""
        return {"name": self.name, "speed": self.speed.to_dict(),
                "lateral_time_s": list(self.lateral_time_s),
                "lateral_accel_mps2": list(self.lateral_accel_mps2)}


def rough_road(duration_s: float, seed: int | np.random.Generator | None = None, *,
               min_speed_mps: float = 8.0, max_speed_mps: float = 25.0,
               max_accel_mps2: float = 1.5) -> Manoeuvre:
    """Straight drive at random speeds (:meth:`SpeedProfile.random_drive`), no steering."""
    sp = SpeedProfile.random_drive(duration_s, seed, min_speed_mps, max_speed_mps,
                                   max_accel_mps2)
    return Manoeuvre("rough_road", sp)


def ramp_steer(duration_s: float, seed: int | np.random.Generator | None = None, *,
               speed_mps: float = 20.0, peak_lateral_mps2: float = 4.0,
               ramp_s: float = 6.0, hold_s: float = 2.0, release_s: float = 2.0,
               pause_s: float = 2.0) -> Manoeuvre:
    """Constant speed; lateral acceleration ramped to +-``peak_lateral_mps2`` and back.

    Each cycle: ramp up over ``ramp_s``, hold ``hold_s``, release over ``release_s``,
    pause ``pause_s``; left and right alternate. ``seed`` varies the peaks by +-20 %.
    """
    check_number("ramp_steer", "duration_s", duration_s, low=0.0, strict=True)
    check_number("ramp_steer", "peak_lateral_mps2", peak_lateral_mps2, low=0.0)
    rng = np.random.default_rng(seed)
    t, a, side = [0.0], [0.0], 1.0
    while t[-1] < duration_s:
        peak = side * peak_lateral_mps2 * rng.uniform(0.8, 1.2)
        for dt, val in ((pause_s, 0.0), (ramp_s, peak), (hold_s, peak), (release_s, 0.0)):
            t.append(t[-1] + dt)
            a.append(val)
        side = -side
    return Manoeuvre("ramp_steer", SpeedProfile.constant(speed_mps, duration_s),
                     tuple(t), tuple(a))


def braking(duration_s: float, seed: int | np.random.Generator | None = None, *,
            high_speed_mps: float = 22.0, low_speed_mps: float = 6.0,
            decel_mps2: float = 5.0, accel_mps2: float = 2.0, cruise_s: float = 6.0
            ) -> Manoeuvre:
    """Cruise at ``high_speed_mps``, brake at ``decel_mps2`` to ``low_speed_mps``, accelerate
    back at ``accel_mps2``; repeated. ``seed`` varies the decelerations by +-20 %."""
    check_number("braking", "duration_s", duration_s, low=0.0, strict=True)
    check_number("braking", "decel_mps2", decel_mps2, low=0.0, strict=True)
    check_number("braking", "accel_mps2", accel_mps2, low=0.0, strict=True)
    rng = np.random.default_rng(seed)
    t, v = [0.0], [high_speed_mps]
    dv = high_speed_mps - low_speed_mps
    while t[-1] < duration_s:
        d = decel_mps2 * rng.uniform(0.8, 1.2)
        for dt, val in ((cruise_s, high_speed_mps), (dv / d, low_speed_mps),
                        (1.0, low_speed_mps), (dv / accel_mps2, high_speed_mps)):
            t.append(t[-1] + dt)
            v.append(val)
    full = SpeedProfile(t, v)
    keep = [x for x in t if x < duration_s] + [duration_s]
    return Manoeuvre("braking", SpeedProfile(keep, full.speed_mps(np.array(keep))))


MANOEUVRES = {"rough_road": rough_road, "ramp_steer": ramp_steer, "braking": braking}


def make_manoeuvre(name: str, duration_s: float, seed: int | np.random.Generator | None = None,
                   **options: float) -> Manoeuvre:
    """A manoeuvre by name (``rough_road``, ``ramp_steer``, ``braking``).

    Raises
    ------
    FieldDiagError
        Unknown name or option.
    """
    fn = MANOEUVRES.get(name)
    if fn is None:
        raise FieldDiagError(f"unknown manoeuvre {name!r}; use one of {', '.join(MANOEUVRES)}")
    try:
        return fn(duration_s, seed, **options)
    except TypeError as exc:
        raise FieldDiagError(f"manoeuvre {name}: {exc}") from None

