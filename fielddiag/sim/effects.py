"""Suspension effects N(r, rdot): small frozen dataclasses, a registry and the kernel slots.

Adding an effect: one class here (parameters, ``_write`` into its slots, ``_speed_bounds``
for the step-size check) plus one branch in :func:`fielddiag.sim.dynamics._suspension_force`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import MISSING, asdict, dataclass, fields
from typing import Any, ClassVar

import numpy as np

from fielddiag.errors import FieldDiagError
from fielddiag.sim._common import RATE_BOUND_MPS, TRAVEL_BOUND_M, check_number

# Slots of the flat float64 array the numba kernel reads (0 = effect off).
_S_FRIC_F, _S_FRIC_V = 0, 1
_S_CUBIC = 2
_S_BUMP_GAP, _S_BUMP_K = 3, 4
_S_ASYM_ON, _S_ASYM_COMP, _S_ASYM_REB = 5, 6, 7
_S_QUAD = 8
_S_HYST_K, _S_HYST_ZY = 9, 10
_N_SLOTS = 11


class Effect:
    """Base of the suspension effects. Subclasses are frozen dataclasses of SI parameters."""

    name: ClassVar[str]

    def to_dict(self) -> dict[str, Any]:
        """``{"name": ..., "params": {...}}``, JSON-serialisable; inverse of make_effect."""
        return {"name": self.name, "params": {k: float(v) for k, v in asdict(self).items()}}

    def _write(self, slots: np.ndarray) -> None:
        raise NotImplementedError

    def _speed_bounds(self) -> tuple[float, float, float]:
        """(extra stiffness N/m, extra damping Ns/m, rate 1/s) for the step-size check."""
        return 0.0, 0.0, 0.0

    def _check(self, **bounds: tuple[float | None, bool]) -> None:
        for name, (low, strict) in bounds.items():
            check_number(self.name, name, getattr(self, name), low=low, strict=strict)


@dataclass(frozen=True)
class CoulombFriction(Effect):
    """Dry friction: force on body ``-friction_force_n * tanh(rdot / smoothing_velocity_mps)``."""

    name: ClassVar[str] = "coulomb_friction"
    friction_force_n: float
    smoothing_velocity_mps: float = 0.01

    def __post_init__(self) -> None:
        self._check(friction_force_n=(0.0, False), smoothing_velocity_mps=(0.0, True))

    def _write(self, slots: np.ndarray) -> None:
        slots[_S_FRIC_F] = self.friction_force_n
        slots[_S_FRIC_V] = self.smoothing_velocity_mps

    def _speed_bounds(self) -> tuple[float, float, float]:
        return 0.0, self.friction_force_n / self.smoothing_velocity_mps, 0.0


@dataclass(frozen=True)
class CubicStiffness(Effect):
    """Progressive spring: force on body ``-cubic_stiffness_n_per_m3 * r**3``."""

    name: ClassVar[str] = "cubic_stiffness"
    cubic_stiffness_n_per_m3: float

    def __post_init__(self) -> None:
        self._check(cubic_stiffness_n_per_m3=(None, False))

    def _write(self, slots: np.ndarray) -> None:
        slots[_S_CUBIC] = self.cubic_stiffness_n_per_m3

    def _speed_bounds(self) -> tuple[float, float, float]:
        return 3 * abs(self.cubic_stiffness_n_per_m3) * TRAVEL_BOUND_M**2, 0.0, 0.0


@dataclass(frozen=True)
class BumpStop(Effect):
    """Bump stop: force on body ``+stiffness_n_per_m * (-r - gap_m)`` when -r > gap_m, else 0."""

    name: ClassVar[str] = "bump_stop"
    gap_m: float
    stiffness_n_per_m: float

    def __post_init__(self) -> None:
        self._check(gap_m=(0.0, False), stiffness_n_per_m=(0.0, True))

    def _write(self, slots: np.ndarray) -> None:
        slots[_S_BUMP_GAP] = self.gap_m
        slots[_S_BUMP_K] = self.stiffness_n_per_m

    def _speed_bounds(self) -> tuple[float, float, float]:
        return self.stiffness_n_per_m, 0.0, 0.0


@dataclass(frozen=True)
class AsymmetricDamping(Effect):
    """Replaces C2: force on body ``-c * rdot``, c = compression (rdot < 0) or rebound value."""

    name: ClassVar[str] = "asymmetric_damping"
    compression_damping_ns_per_m: float
    rebound_damping_ns_per_m: float

    def __post_init__(self) -> None:
        self._check(
            compression_damping_ns_per_m=(0.0, False), rebound_damping_ns_per_m=(0.0, False)
        )

    def _write(self, slots: np.ndarray) -> None:
        slots[_S_ASYM_ON] = 1.0
        slots[_S_ASYM_COMP] = self.compression_damping_ns_per_m
        slots[_S_ASYM_REB] = self.rebound_damping_ns_per_m

    def _speed_bounds(self) -> tuple[float, float, float]:
        return 0.0, max(self.compression_damping_ns_per_m, self.rebound_damping_ns_per_m), 0.0


@dataclass(frozen=True)
class QuadraticDamping(Effect):
    """Velocity-squared damping (outside the diagnosis library): ``-c_q * rdot * |rdot|``."""

    name: ClassVar[str] = "quadratic_damping"
    damping_ns2_per_m2: float

    def __post_init__(self) -> None:
        self._check(damping_ns2_per_m2=(0.0, False))

    def _write(self, slots: np.ndarray) -> None:
        slots[_S_QUAD] = self.damping_ns2_per_m2

    def _speed_bounds(self) -> tuple[float, float, float]:
        return 0.0, 2 * self.damping_ns2_per_m2 * RATE_BOUND_MPS, 0.0


@dataclass(frozen=True)
class HystereticSpring(Effect):
    """Dahl hysteresis (Bouc-Wen with n = 1, A = 1, beta = 1/z_y, gamma = 0).

    Outside the diagnosis library. A hidden deflection ``z`` follows
    ``dz/dt = rdot - |rdot| z / yield_displacement_m`` and the force on the body is
    ``-hysteretic_stiffness_n_per_m * z``: stiffness ``hysteretic_stiffness_n_per_m`` for
    small reversals, saturating at ``hysteretic_stiffness_n_per_m * yield_displacement_m``
    (a rounded friction loop) for travel much larger than ``yield_displacement_m``.
    """

    name: ClassVar[str] = "hysteretic_spring"
    hysteretic_stiffness_n_per_m: float
    yield_displacement_m: float

    def __post_init__(self) -> None:
        self._check(hysteretic_stiffness_n_per_m=(0.0, True), yield_displacement_m=(0.0, True))

    def _write(self, slots: np.ndarray) -> None:
        slots[_S_HYST_K] = self.hysteretic_stiffness_n_per_m
        slots[_S_HYST_ZY] = self.yield_displacement_m

    def _speed_bounds(self) -> tuple[float, float, float]:
        return self.hysteretic_stiffness_n_per_m, 0.0, RATE_BOUND_MPS / self.yield_displacement_m


#: Registry of effects by public name.
EFFECTS: dict[str, type[Effect]] = {
    cls.name: cls
    for cls in (
        CoulombFriction,
        CubicStiffness,
        BumpStop,
        AsymmetricDamping,
        QuadraticDamping,
        HystereticSpring,
    )
}


def _effect_usage() -> str:
    parts = []
    for name, cls in EFFECTS.items():
        ps = ", ".join(f.name if f.default is MISSING else f"[{f.name}]" for f in fields(cls))
        parts.append(f"{name}({ps})")
    return "; ".join(parts)


def make_effect(name: str, **params: Any) -> Effect:
    """Build an effect from its public name and parameters (strings are converted to float).

    Raises
    ------
    FieldDiagError
        Unknown name, unknown or missing parameter, or a value that is not a valid number.
    """
    cls = EFFECTS.get(name)
    if cls is None:
        raise FieldDiagError(
            f"unknown effect {name!r}; valid effects (optional params in "
            f"brackets): {_effect_usage()}."
        )
    valid = {f.name: f for f in fields(cls)}
    unknown = sorted(set(params) - set(valid))
    missing = sorted(n for n, f in valid.items() if n not in params and f.default is MISSING)
    if unknown or missing:
        raise FieldDiagError(
            f"effect {name!r}: unknown parameter(s) {unknown}, missing {missing}; "
            f"its parameters are {list(valid)} (SI units as named)."
        )
    values = {}
    for k, v in params.items():
        try:
            values[k] = float(v)
        except (TypeError, ValueError):
            raise FieldDiagError(
                f"effect {name!r}: {k}={v!r} is not a number; give e.g. {k}=100."
            ) from None
    return cls(**values)


def effects_from_dicts(items: Sequence[dict[str, Any]]) -> tuple[Effect, ...]:
    """Inverse of ``[e.to_dict() for e in effects]``."""
    return tuple(make_effect(d["name"], **d.get("params", {})) for d in items)


def _effect_slots(effects: Sequence[Effect]) -> np.ndarray:
    slots = np.zeros(_N_SLOTS)
    seen: set[str] = set()
    for e in effects:
        if not isinstance(e, Effect):
            raise FieldDiagError(f"effects must be Effect objects (see make_effect), got {e!r}.")
        if e.name in seen:
            raise FieldDiagError(
                f"effect {e.name!r} given twice; give it once with the combined parameters."
            )
        seen.add(e.name)
        e._write(slots)
    return slots
