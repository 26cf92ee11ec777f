"""A position-sensitive damper: damping that grows away from the ride height."""

from __future__ import annotations

from collections.abc import Sequence

from numba import njit

from fielddiag.effects.base import (
    INF,
    RATE_BOUND_MPS,
    TRAVEL_BOUND_M,
    Effect,
    ParamSpec,
    register_effect,
)


@njit(cache=True, nogil=True)
def _travel_dependent_damping(r, rd, x2, p, c, dp):  # pragma: no cover - compiled
    q = r / p[1]
    dp[0] = -rd * q * q
    dp[1] = 2.0 * p[0] * rd * q * q / p[1]
    return -p[0] * rd * q * q, -2.0 * p[0] * rd * q / p[1], -p[0] * q * q, 0.0


@register_effect
class TravelDependentDamping(Effect):
    """Damping that grows with the square of the travel from the unloaded ride height:
    force on the body ``-c_p rdot (r / r_ref)^2`` (a position-sensitive damper, bypass
    grooves in the tube).

    Simulated and fittable, but not among the diagnosis's candidates: it stands for the
    physics outside the library that the diagnosis must report as ``unexplained`` with a
    description of its shape.
    """

    name = "travel_dependent_damping"
    description = "damping that grows with travel (position-sensitive damper)"
    params = (
        ParamSpec("extra_damping_ns_per_m", "N s/m", 0.0, INF, 1.8e3, True,
                  "extra damping at the reference travel",
                  "drive over large bumps (long strokes)"),
        ParamSpec("reference_travel_m", "m", 1e-3, 0.2, 0.03, False, "reference travel",
                  "drive over large bumps (long strokes)", default=0.03,
                  valid_low=0.0, valid_strict=True),
    )
    linear_in_params = False

    kernel = _travel_dependent_damping

    def speed_bounds(self, values: Sequence[float]) -> tuple[float, float, float]:
        """Largest stiffness [N/m], damping [N s/m] and rate [1/s] it can add.

        Parameters
        ----------
        values : sequence of float
            Parameter values in kernel order.

        Returns
        -------
        (float, float, float)
            At :data:`TRAVEL_BOUND_M` and :data:`RATE_BOUND_MPS`.
        """
        q = TRAVEL_BOUND_M / values[1]
        return 2.0 * values[0] * RATE_BOUND_MPS * q / values[1], values[0] * q * q, 0.0
