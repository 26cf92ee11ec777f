"""What the wheel rolls over and how fast: ISO 8608 profiles, road events, speed profiles."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, fields
from typing import Any, ClassVar

import numpy as np
from scipy import fft as sp_fft

from fielddiag.errors import FieldDiagError
from fielddiag.sim._common import check_number

#: ISO 8608 geometric-mean displacement PSD Gd(n0) at n0 = 0.1 cycles/m [m^3], classes A..H.
ISO8608_GD_M3 = {c: 16e-6 * 4.0**i for i, c in enumerate("ABCDEFGH")}
ISO8608_N0_CYCLES_PER_M = 0.1


def _band_power(g0: float, w: float, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Integral of Gd(n) = g0 (n/n0)^-w over [lo, hi] (zero where hi <= lo)."""
    n0 = ISO8608_N0_CYCLES_PER_M
    lo = np.minimum(lo, hi)
    if abs(w - 1.0) < 1e-12:
        return g0 * n0 * np.log(np.where(hi > lo, hi / np.maximum(lo, 1e-300), 1.0))
    return g0 * n0**w * (hi ** (1 - w) - lo ** (1 - w)) / (1 - w)


def iso8608_variance_m2(
    road_class: str, waviness: float = 2.0, band_cycles_per_m: tuple[float, float] = (0.01, 10.0)
) -> float:
    """Height variance of an ISO 8608 class over a spatial band: the integral of Gd(n)."""
    g0 = _class_gd(road_class)
    lo, hi = band_cycles_per_m
    return float(_band_power(g0, waviness, np.array(lo), np.array(hi)))


def _class_gd(road_class: str) -> float:
    key = str(road_class).strip().upper()
    if key not in ISO8608_GD_M3:
        raise FieldDiagError(
            f"unknown ISO 8608 road class {road_class!r}; use one of "
            f"{', '.join(ISO8608_GD_M3)} (A smoothest), or None for a flat road."
        )
    return ISO8608_GD_M3[key]


def iso8608_profile(
    road_class: str,
    length_m: float,
    spacing_m: float = 0.02,
    seed: int | np.random.Generator | np.random.SeedSequence | None = None,
    waviness: float = 2.0,
    band_cycles_per_m: tuple[float, float] = (0.01, 10.0),
) -> tuple[np.ndarray, np.ndarray]:
    """Random road of an ISO 8608 class by inverse FFT with random phases.

    Each spatial-frequency line ``k / L`` carries the power of the PSD integrated over its
    bin ``[(k - 1/2) / L, (k + 1/2) / L]`` intersected with the band, so the variance of
    every realisation equals the PSD integral over the band (for L >= 1 / (2 band[0])).

    Parameters
    ----------
    road_class : str
        'A' .. 'H'; Gd(n0) = 16e-6 m^3 for A, x4 per class.
    length_m : float
        Profile length [m].
    spacing_m : float
        Sample spacing [m]; the band is cut at 0.9 x the spatial Nyquist frequency.
    seed : int, Generator, SeedSequence or None
        Random phases.
    waviness : float
        Exponent w in Gd(n) = Gd(n0) (n / n0)^-w.
    band_cycles_per_m : (float, float)
        Spatial band kept [cycles/m].

    Returns
    -------
    distance_m, height_m : numpy.ndarray
        Sample positions from 0 and heights [m] (zero mean).
    """
    g0 = _class_gd(road_class)
    check_number("iso8608_profile", "length_m", length_m, low=0.0, strict=True)
    check_number("iso8608_profile", "spacing_m", spacing_m, low=0.0, strict=True)
    check_number("iso8608_profile", "waviness", waviness)
    n = sp_fft.next_fast_len(int(math.ceil(length_m / spacing_m)) + 1, real=True)
    while n % 2:
        n = sp_fft.next_fast_len(n + 1, real=True)
    total_m = n * spacing_m
    lo = max(band_cycles_per_m[0], 0.0)
    hi = min(band_cycles_per_m[1], 0.9 * 0.5 / spacing_m)
    k = np.arange(1, n // 2)
    dn = 1.0 / total_m
    power = _band_power(
        g0, waviness, np.clip((k - 0.5) * dn, lo, hi), np.clip((k + 0.5) * dn, lo, hi)
    )
    phase = np.random.default_rng(seed).uniform(0.0, 2 * np.pi, k.size)
    spec = np.zeros(n // 2 + 1, dtype=complex)
    spec[1 : n // 2] = np.sqrt(2.0 * power) * (n / 2) * np.exp(1j * phase)
    height = sp_fft.irfft(spec, n)
    return np.arange(n) * spacing_m, height


class RoadEvent:
    """Base of the discrete road events: a raised cosine of signed amplitude centred at
    ``position_m`` with base ``length_m``."""

    kind: ClassVar[str]
    position_m: float
    length_m: float

    def _amplitude_m(self) -> float:
        raise NotImplementedError

    def __post_init__(self) -> None:
        for f in fields(self):  # type: ignore[arg-type]
            check_number(self.kind, f.name, getattr(self, f.name))
        check_number(self.kind, "length_m", self.length_m, low=0.0, strict=True)

    def height_profile_m(self, distance_m: np.ndarray) -> np.ndarray:
        """Height added to the road at ``distance_m`` [m]."""
        x = (np.asarray(distance_m, float) - self.position_m) / self.length_m
        shape = 0.5 * (1.0 + np.cos(2 * np.pi * x))
        return np.where(np.abs(x) <= 0.5, self._amplitude_m() * shape, 0.0)

    def to_dict(self) -> dict[str, Any]:
        """``{"kind": ..., <fields>}``; inverse of :func:`road_event_from_dict`."""
        return {"kind": self.kind, **{k: float(v) for k, v in asdict(self).items()}}  # type: ignore


@dataclass(frozen=True)
class SpeedBump(RoadEvent):
    """Raised-cosine bump of ``height_m`` and base ``length_m`` centred at ``position_m``."""

    kind: ClassVar[str] = "speed_bump"
    position_m: float
    height_m: float = 0.07
    length_m: float = 0.5

    def _amplitude_m(self) -> float:
        return self.height_m


@dataclass(frozen=True)
class Pothole(RoadEvent):
    """Raised-cosine dip of ``depth_m`` (positive down) and base ``length_m`` at ``position_m``."""

    kind: ClassVar[str] = "pothole"
    position_m: float
    depth_m: float = 0.04
    length_m: float = 0.4

    def _amplitude_m(self) -> float:
        return -self.depth_m


ROAD_EVENTS: dict[str, type[RoadEvent]] = {c.kind: c for c in (SpeedBump, Pothole)}


def road_event_from_dict(d: dict[str, Any]) -> RoadEvent:
    """Inverse of ``event.to_dict()`` (a ``time_s`` key is ignored)."""
    d = {k: v for k, v in d.items() if k != "time_s"}
    cls = ROAD_EVENTS.get(d.pop("kind", None))
    if cls is None:
        raise FieldDiagError(f"unknown road event {d!r}; kind must be one of {list(ROAD_EVENTS)}.")
    try:
        return cls(**d)
    except TypeError as exc:
        raise FieldDiagError(f"road event {d!r}: {exc}; check the parameter names.") from None


class SpeedProfile:
    """Vehicle speed, piecewise linear between knots, held after the last knot.

    Parameters
    ----------
    time_s : array_like
        Knot times, strictly increasing, starting at 0 [s].
    speed_mps : array_like
        Speed at the knots, >= 0 [m/s].
    """

    def __init__(
        self, time_s: Sequence[float] | np.ndarray, speed_mps: Sequence[float] | np.ndarray
    ) -> None:
        t = np.array(time_s, dtype=float, ndmin=1)
        v = np.array(speed_mps, dtype=float, ndmin=1)
        if (
            t.ndim != 1
            or t.shape != v.shape
            or t.size < 1
            or t[0] != 0.0
            or not np.all(np.isfinite(t))
            or np.any(np.diff(t) <= 0)
        ):
            raise FieldDiagError(
                "SpeedProfile: knot times must be a 1-D, strictly increasing "
                "sequence starting at 0 s, one speed per time."
            )
        if not np.all(np.isfinite(v)) or np.any(v < 0):
            raise FieldDiagError("SpeedProfile: speeds must be finite and >= 0 m/s.")
        self._t, self._v = t, v
        self._a = np.zeros_like(t)
        self._a[:-1] = np.diff(v) / np.diff(t)
        self._d = np.concatenate(([0.0], np.cumsum(0.5 * (v[:-1] + v[1:]) * np.diff(t))))
        for arr in (self._t, self._v, self._a, self._d):
            arr.flags.writeable = False

    @property
    def knot_time_s(self) -> np.ndarray:
        """Knot times [s] (read-only)."""
        return self._t

    @property
    def knot_speed_mps(self) -> np.ndarray:
        """Knot speeds [m/s] (read-only)."""
        return self._v

    @property
    def knot_distance_m(self) -> np.ndarray:
        """Distance travelled at the knots [m] (read-only)."""
        return self._d

    @property
    def knot_accel_mps2(self) -> np.ndarray:
        """Acceleration from each knot to the next, 0 after the last [m/s^2] (read-only)."""
        return self._a

    def _segment(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        i = np.clip(np.searchsorted(self._t, t, side="right") - 1, 0, self._t.size - 1)
        return i, t - self._t[i]

    def speed_mps(self, t_s: np.ndarray | float) -> np.ndarray:
        """Speed [m/s] at times ``t_s``."""
        i, tau = self._segment(np.asarray(t_s, float))
        return self._v[i] + self._a[i] * tau

    def distance_m(self, t_s: np.ndarray | float) -> np.ndarray:
        """Distance travelled since t = 0 [m] (exact integral of the speed)."""
        i, tau = self._segment(np.asarray(t_s, float))
        return self._d[i] + (self._v[i] + 0.5 * self._a[i] * tau) * tau

    def time_at_distance_s(self, distance_m: float) -> float | None:
        """First time the distance reaches ``distance_m``, None if never."""
        if distance_m <= 0.0:
            return 0.0
        i = int(np.searchsorted(self._d, distance_m, side="right")) - 1
        rest, v, a = distance_m - self._d[i], self._v[i], self._a[i]
        root = v * v + 2.0 * a * rest
        if root < 0.0 or (v <= 0.0 and a <= 0.0):
            return None
        return float(self._t[i] + 2.0 * rest / (v + math.sqrt(root)))

    @classmethod
    def constant(cls, speed_mps: float, duration_s: float) -> SpeedProfile:
        """Constant speed for ``duration_s`` (and after)."""
        check_number("SpeedProfile.constant", "duration_s", duration_s, low=0.0, strict=True)
        return cls([0.0, duration_s], [speed_mps, speed_mps])

    @classmethod
    def random_drive(
        cls,
        duration_s: float,
        seed: int | np.random.Generator | None = None,
        min_speed_mps: float = 5.0,
        max_speed_mps: float = 25.0,
        max_accel_mps2: float = 2.0,
    ) -> SpeedProfile:
        """Cruise segments (5-40 s) at random speeds joined by ramps within ``max_accel_mps2``.

        Ramps use 25-100 % of the acceleration limit; speeds are uniform in
        [min_speed_mps, max_speed_mps].
        """
        check_number("random_drive", "duration_s", duration_s, low=0.0, strict=True)
        check_number("random_drive", "min_speed_mps", min_speed_mps, low=0.0)
        check_number("random_drive", "max_speed_mps", max_speed_mps, low=min_speed_mps)
        check_number("random_drive", "max_accel_mps2", max_accel_mps2, low=0.0, strict=True)
        rng = np.random.default_rng(seed)
        v = rng.uniform(min_speed_mps, max_speed_mps)
        t_k, v_k = [0.0], [v]
        while t_k[-1] < duration_s:
            t_k.append(t_k[-1] + rng.uniform(5.0, 40.0))
            v_k.append(v)
            v_new = rng.uniform(min_speed_mps, max_speed_mps)
            ramp_s = abs(v_new - v) / (max_accel_mps2 * rng.uniform(0.25, 1.0))
            if ramp_s > 1e-6:
                t_k.append(t_k[-1] + ramp_s)
                v_k.append(v_new)
            v = v_new
        full = cls(t_k, v_k)
        keep = [t for t in t_k if t < duration_s]
        return cls(keep + [duration_s], list(full.speed_mps(np.array(keep + [duration_s]))))

    def to_dict(self) -> dict[str, list[float]]:
        """``{"time_s": [...], "speed_mps": [...]}``."""
        return {"time_s": self._t.tolist(), "speed_mps": self._v.tolist()}

    @classmethod
    def from_dict(cls, d: dict[str, Sequence[float]]) -> SpeedProfile:
        """Inverse of :meth:`to_dict`."""
        return cls(d["time_s"], d["speed_mps"])

    def __eq__(self, other: object) -> bool:
        return (
            isinstance(other, SpeedProfile)
            and np.array_equal(self._t, other._t)
            and np.array_equal(self._v, other._v)
        )

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        return f"SpeedProfile({self._t.size} knots over {self._t[-1]:g} s)"
