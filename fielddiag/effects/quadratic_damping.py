"""Velocity-squared (orifice) damping."""

from __future__ import annotations

from collections.abc import Sequence

from numba import njit

from fielddiag.effects.base import INF, RATE_BOUND_MPS, Effect, ParamSpec, register_effect


@njit(cache=True, nogil=True)
def _quadratic_damping(r, rd, x2, p, c, dp):  # pragma: no cover - compiled
    a = abs(rd)
    dp[0] = -rd * a
    return -p[0] * rd * a, 0.0, -2.0 * p[0] * a, 0.0


@register_effect
class QuadraticDamping(Effect):
    """Quadratic (orifice) damping: force on the body ``-c_q rdot |rdot|``.

    Added to the linear damper: a damper whose force grows with the square of the speed
    (flow through a fixed orifice, no valve).
    """

    name = "quadratic_damping"
    diagnosable = True
    diagnosis_rank = 42
    description = "quadratic (orifice) damping"
    params = (
        ParamSpec("damping_ns2_per_m2", "N s^2/m^2", 0.0, INF, 500.0, True,
                  "quadratic damping", "drive over sharp bumps (fast suspension strokes)",
                  significant=True),
    )
    kernel = _quadratic_damping

    def speed_bounds(self, values: Sequence[float]) -> tuple[float, float, float]:
        """Largest stiffness [N/m], damping [N s/m] and rate [1/s] the orifice damping can add.

        Parameters
        ----------
        values : sequence of float
            Parameter values in kernel order (damping c_q [N s^2/m^2]).

        Returns
        -------
        (float, float, float)
            ``(0, 2 c_q RATE_BOUND_MPS, 0)``: its largest tangent damping.
        """
        return 0.0, 2 * values[0] * RATE_BOUND_MPS, 0.0
