"""Dahl friction: hysteresis of dry friction (pre-yield), its level changing along the stroke."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
from numba import njit

from fielddiag.effects.base import INF, RATE_BOUND_MPS, Effect, ParamSpec, register_effect


@njit(cache=True, nogil=True)
def _dahl_friction(r, rd, x2, z, p, c, dp, dz):  # pragma: no cover - compiled
    # state z[0] = w in [-1, 1] (Dahl): dw/dt = (rdot / x_y) (1 - sgn(rdot) w)
    w = z[0]
    dz[0] = (rd - abs(rd) * w) / p[2]
    level = p[0] + p[1] * r
    dp[0] = -w
    dp[1] = -r * w
    dp[2] = 0.0  # through the state (its sensitivity: _dahl_friction_partials)
    return -level * w, -p[1] * w, 0.0, 0.0


@njit(cache=True, nogil=True, error_model="numpy")
def _dahl_friction_partials(r, rd, x2, z, p, c, dfz, dgs, dgz, dgp):  # pragma: no cover
    # F = -(F_f + g r) w;  dw/dt = (rdot - |rdot| w) / x_y
    w = z[0]
    sg = 1.0 if rd > 0.0 else -1.0 if rd < 0.0 else 0.0
    dfz[0] = -(p[0] + p[1] * r)
    dgs[0, 0] = 0.0
    dgs[0, 1] = (1.0 - sg * w) / p[2]
    dgs[0, 2] = 0.0
    dgz[0, 0] = -abs(rd) / p[2]
    dgp[0, 0] = 0.0
    dgp[0, 1] = 0.0
    dgp[0, 2] = -(rd - abs(rd) * w) / (p[2] * p[2])


@register_effect
class DahlFriction(Effect):
    """Dahl friction: the hysteresis of dry friction, its level changing along the stroke.

    A normalised state ``w`` follows ``dw/dt = (rdot / x_y) (1 - sgn(rdot) w)`` (Dahl: after
    each reversal the force builds up over about ``x_y`` of travel instead of jumping) and
    the force on the body is ``-(F_f + g r) w``: a friction loop of height ``2 (F_f + g r)``
    at extension ``r``. A seal whose normal force grows as the rod goes in (the gas
    pressure of a mono-tube damper), a magneto-rheological damper whose field is not
    uniform along the piston's travel, or a bore that is not quite straight give such a
    gradient ``g``; ``g = 0`` is plain Dahl friction. ``r`` is measured from the rig's (or
    the car's) zero, so ``F_f`` is the level there.
    """

    name = "dahl_friction"
    description = "hysteresis of dry friction (Dahl pre-yield), its level changing along the stroke"
    n_states = 1
    linear_in_params = False
    params = (
        ParamSpec("friction_force_n", "N", 0.0, INF, 50.0, True, "friction force at zero",
                  "drive slowly through the whole stroke in both directions",
                  significant=True),
        ParamSpec("friction_gradient_n_per_m", "N/m", -INF, INF, 0.0, True,
                  "friction gradient along the stroke",
                  "drive slowly through the whole stroke in both directions", default=0.0),
        ParamSpec("yield_displacement_m", "m", 0.0, INF, 1e-4, False, "pre-yield travel",
                  "drive over small ripples (many small reversals)",
                  valid_low=0.0, valid_strict=True, default=1e-4),
    )
    kernel = _dahl_friction
    state_partials = _dahl_friction_partials

    def static_states(self, r: float, values: Sequence[float]) -> np.ndarray:
        """``w`` reached when loaded slowly and monotonically from r = 0 to ``r``.

        Parameters
        ----------
        r : float
            Extension [m].
        values : sequence of float
            Parameter values in kernel order (force [N], gradient [N/m], yield travel [m]).

        Returns
        -------
        numpy.ndarray
            ``(1,)``: ``sign(r) (1 - exp(-|r| / x_y))``.
        """
        return np.array([math.copysign(-math.expm1(-abs(r) / values[2]), r)])

    def speed_bounds(self, values: Sequence[float]) -> tuple[float, float, float]:
        """Largest stiffness [N/m], damping [N s/m] and rate [1/s] the friction can add.

        Parameters
        ----------
        values : sequence of float
            Parameter values in kernel order (force [N], gradient [N/m], yield travel [m]).

        Returns
        -------
        (float, float, float)
            ``(|F_f| / x_y + |g|, 0, RATE_BOUND_MPS / x_y)``.
        """
        return abs(values[0]) / values[2] + abs(values[1]), 0.0, RATE_BOUND_MPS / values[2]

    def explain(self, params: Mapping[str, float], per: str = "", hidden: str = "") -> str:
        """A sentence a technician can act on: the friction level and how it changes.

        Parameters
        ----------
        params : mapping
            Fitted physical parameters by name.
        per : str
            Unit suffix for per-unit-mass values or "".
        hidden : str
            How the linear fit distorted its parameters to absorb the effect, or "".

        Returns
        -------
        str
        """
        f = params.get("friction_force_n", math.nan)
        g = params.get("friction_gradient_n_per_m", math.nan)
        x = params.get("yield_displacement_m", math.nan)
        return (f"friction hysteresis (Dahl): dry friction of {f:.3g} N{per} at the zero of "
                f"the stroke, changing by "
                f"{1e-3 * g:+.3g} N{per} per mm of extension, building up over about "
                f"{1e3 * x:.2g} mm after each reversal{hidden}")
