"""Progressive (cubic) spring."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from numba import njit

from fielddiag.effects.base import INF, TRAVEL_BOUND_M, Effect, ParamSpec, register_effect


@njit(cache=True, nogil=True)
def _cubic_stiffness(r, rd, x2, p, c, dp):  # pragma: no cover - compiled
    r2 = r * r
    dp[0] = -r2 * r
    return -p[0] * r2 * r, -3.0 * p[0] * r2, 0.0, 0.0


@register_effect
class CubicStiffness(Effect):
    """Progressive spring: force on the body ``-k3 r^3``; negative ``k3`` is a softening
    spring (a diagnosis calls that, or a k3 within 2 std of zero, unphysical)."""

    name = "cubic_stiffness"
    diagnosable = True
    diagnosis_rank = 20
    description = "progressive spring"
    params = (
        ParamSpec("cubic_stiffness_n_per_m3", "N/m^3", -INF, INF, 1e6, True,
                  "progressive spring", "drive over larger bumps (large suspension travel)",
                  significant=True),
    )
    kernel = _cubic_stiffness

    def speed_bounds(self, values: Sequence[float]) -> tuple[float, float, float]:
        """Largest stiffness [N/m], damping [N s/m] and rate [1/s] the cubic spring can add.

        Parameters
        ----------
        values : sequence of float
            Parameter values in kernel order (cubic stiffness [N/m^3]).

        Returns
        -------
        (float, float, float)
            ``(3 |k3| TRAVEL_BOUND_M^2, 0, 0)``: its largest tangent stiffness.
        """
        return 3 * abs(values[0]) * TRAVEL_BOUND_M**2, 0.0, 0.0

    def start_values(self, r_m, start):
        """Start values of a screening fit.

        No cubic term (k3 = 0).

        Parameters
        ----------
        r_m : ndarray
            Measured suspension extension [m] (positive in rebound); unused.
        start : mapping
            Values already known by model key; unused.

        Returns
        -------
        dict
            ``{"cubic_stiffness_n_per_m3": 0.0}`` [N/m^3].
        """
        return {"cubic_stiffness_n_per_m3": 0.0}

    def explain(self, params: Mapping[str, float], per: str = "", hidden: str = "") -> str:
        """A sentence a technician can act on.

        It gives the cubic term [N/m^3] and what to check.

        Parameters
        ----------
        params : mapping
            Fitted physical parameters by name (``cubic_stiffness_n_per_m3``;
            ``_per_kg`` names in per-unit-mass mode).
        per : str
            Unit suffix for per-unit-mass values (`` per kg of sprung mass``) or "".
        hidden : str
            How the linear fit distorted its parameters to absorb the effect, or "".

        Returns
        -------
        str
        """
        k3 = next(iter(params.values()))
        return (
            f"progressive spring: the stiffness rises with travel (cubic term {k3:.3g} "
            f"N/m3{per}){hidden}. Expected for progressive-rate springs; otherwise check "
            "for a spring touching its seat or the helper spring engaging"
        )
