"""The linear part of the model: suspension spring ``-K2 r``, damper ``-C2 rdot`` and the
coupling of the corner to the rest of the body ``-K3 x2``."""

from __future__ import annotations

from collections.abc import Sequence

from numba import njit

from fielddiag.effects.base import INF, Effect, ParamSpec, register_effect

_ADVICE_STIFFNESS = "drive over long undulations or speed humps at moderate speed (body bounce)"
_ADVICE_DAMPING = "drive over sharper bumps (potholes, cobbles, expansion joints)"


@njit(cache=True, nogil=True)
def _linear_spring(r, rd, x2, p, c, dp):  # pragma: no cover - compiled
    dp[0] = -r
    return -p[0] * r, -p[0], 0.0, 0.0


@register_effect
class LinearSpring(Effect):
    """Suspension spring: force on the body ``-K2 r``."""

    name = "linear_spring"
    linear = True
    description = "suspension spring"
    params = (
        ParamSpec("suspension_stiffness_n_per_m", "N/m", 0.0, INF, 24e3, True, "stiffness",
                  _ADVICE_STIFFNESS),
    )
    kernel = _linear_spring

    def speed_bounds(self, values: Sequence[float]) -> tuple[float, float, float]:
        """Largest stiffness [N/m], damping [N s/m] and rate [1/s] the spring can add.

        Parameters
        ----------
        values : sequence of float
            Parameter values in kernel order (suspension stiffness K2 [N/m]).

        Returns
        -------
        (float, float, float)
            ``(|K2|, 0, 0)``.
        """
        return abs(values[0]), 0.0, 0.0


@njit(cache=True, nogil=True)
def _linear_damper(r, rd, x2, p, c, dp):  # pragma: no cover - compiled
    dp[0] = -rd
    return -p[0] * rd, 0.0, -p[0], 0.0


@register_effect
class LinearDamper(Effect):
    """Suspension damper: force on the body ``-C2 rdot``."""

    name = "linear_damper"
    linear = True
    description = "suspension damper"
    params = (
        ParamSpec("suspension_damping_ns_per_m", "N s/m", 0.0, INF, 1.8e3, True, "damping",
                  _ADVICE_DAMPING),
    )
    kernel = _linear_damper

    def speed_bounds(self, values: Sequence[float]) -> tuple[float, float, float]:
        """Largest stiffness [N/m], damping [N s/m] and rate [1/s] the damper can add.

        Parameters
        ----------
        values : sequence of float
            Parameter values in kernel order (suspension damping C2 [N s/m]).

        Returns
        -------
        (float, float, float)
            ``(0, |C2|, 0)``.
        """
        return 0.0, abs(values[0]), 0.0


@njit(cache=True, nogil=True)
def _coupling_spring(r, rd, x2, p, c, dp):  # pragma: no cover - compiled
    dp[0] = -x2
    return -p[0] * x2, 0.0, 0.0, -p[0]


@register_effect
class CouplingSpring(Effect):
    """Coupling of the corner to the rest of the body ``-K3 x2`` (may be negative)."""

    name = "coupling_spring"
    linear = True
    description = "coupling of the corner to the rest of the body"
    params = (
        ParamSpec("coupling_stiffness_n_per_m", "N/m", -INF, INF, 2e3, True,
                  "coupling stiffness", "drive over long, slow undulations (low-frequency body "
                  "motion)"),
    )
    kernel = _coupling_spring

    def start_values(self, r_m, start):
        """Start values of a screening fit.

        No coupling (K3 = 0).

        Parameters
        ----------
        r_m : ndarray
            Measured suspension extension [m] (positive in rebound); unused.
        start : mapping
            Values already known by model key; unused.

        Returns
        -------
        dict
            ``{"coupling_stiffness_n_per_m": 0.0}`` [N/m].
        """
        return {"coupling_stiffness_n_per_m": 0.0}
