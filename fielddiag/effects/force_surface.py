"""A restoring-force surface: a smooth force in travel and speed that names no physics."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from numba import njit

from fielddiag.effects.base import (
    INF,
    RATE_BOUND_MPS,
    TRAVEL_BOUND_M,
    Effect,
    ParamSpec,
    register_effect,
)

#: Travel [m] and speed [m/s] that scale the surface's variables (its coefficients are
#: forces at these values).
SURFACE_TRAVEL_M = 0.02
SURFACE_SPEED_MPS = 0.2


@njit(cache=True, nogil=True)
def _force_surface(r, rd, x2, p, c, dp):  # pragma: no cover - compiled
    q = r / SURFACE_TRAVEL_M
    w = rd / SURFACE_SPEED_MPS
    dp[0] = -q * q
    dp[1] = -q * w
    dp[2] = -w * w
    dp[3] = -q * q * q
    dp[4] = -q * q * w
    dp[5] = -q * w * w
    dp[6] = -w * w * w
    f = 0.0
    for k in range(7):
        f += p[k] * dp[k]
    dfdq = -(2.0 * p[0] * q + p[1] * w + 3.0 * p[3] * q * q + 2.0 * p[4] * q * w
             + p[5] * w * w)
    dfdw = -(p[1] * q + 2.0 * p[2] * w + p[4] * q * q + 2.0 * p[5] * q * w
             + 3.0 * p[6] * w * w)
    return f, dfdq / SURFACE_TRAVEL_M, dfdw / SURFACE_SPEED_MPS, 0.0


_TERMS = ("travel2", "travel_speed", "speed2", "travel3", "travel2_speed", "travel_speed2",
          "speed3")


@register_effect
class ForceSurface(Effect):
    """Restoring-force surface (Masri and Caughey's method, 1979): every monomial of
    degree 2 and 3 in the scaled travel ``q = r / 20 mm`` and speed ``w = rdot / 0.2 m/s``,
    force on the body ``-sum a_ij q^i w^j``, each coefficient a force [N].

    It names no physics. The diagnosis fits it beside the named effects: where it
    predicts held-out data better than all of them (by the selection's own rule, with its
    seven parameters counted), the mismatch is reported ``unexplained``, with its shape,
    rather than given the name of the effect that fits least badly.
    """

    name = "force_surface"
    names_physics = False
    description = "a smooth force in travel and speed (no physical name)"
    params = tuple(
        ParamSpec(f"surface_{t}_n", "N", -INF, INF, 50.0, True, f"surface term {t}",
                  "drive over larger bumps at several speeds", default=0.0)
        for t in _TERMS
    )

    kernel = _force_surface

    def speed_bounds(self, values: Sequence[float]) -> tuple[float, float, float]:
        """Largest stiffness [N/m], damping [N s/m] and rate [1/s] the surface can add.

        Parameters
        ----------
        values : sequence of float
            The seven coefficients [N] in kernel order.

        Returns
        -------
        (float, float, float)
            Bounds of ``|dF/dr|`` and ``|dF/drdot|`` at :data:`TRAVEL_BOUND_M` and
            :data:`RATE_BOUND_MPS`, and 0.
        """
        a = [abs(v) for v in values]
        q, w = TRAVEL_BOUND_M / SURFACE_TRAVEL_M, RATE_BOUND_MPS / SURFACE_SPEED_MPS
        stiff = (2 * a[0] * q + a[1] * w + 3 * a[3] * q * q + 2 * a[4] * q * w
                 + a[5] * w * w) / SURFACE_TRAVEL_M
        damp = (a[1] * q + 2 * a[2] * w + a[4] * q * q + 2 * a[5] * q * w
                + 3 * a[6] * w * w) / SURFACE_SPEED_MPS
        return stiff, damp, 0.0

    def start_values(self, r_m, start):
        """Start values of a fit: a flat surface (every coefficient 0).

        Parameters
        ----------
        r_m : ndarray
            Measured suspension extension [m]; unused.
        start : mapping
            Values already known by model key; unused.

        Returns
        -------
        dict
        """
        return {p.name: 0.0 for p in self.params}

    def explain(self, params: Mapping[str, float], per: str = "", hidden: str = "") -> str:
        """A sentence on what the surface is (the diagnosis describes its shape in words).

        Parameters
        ----------
        params : mapping
            Fitted coefficients by name.
        per : str
            Unit suffix for per-unit-mass values or "".
        hidden : str
            How the linear fit distorted its parameters, or "".

        Returns
        -------
        str
        """
        return ("a smooth force in travel and speed that no named effect describes"
                f"{hidden}")
