"""A force with memory of each reversal: a shape that names no physics, with a state."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from numba import njit

from fielddiag.effects.base import (
    INF,
    RATE_BOUND_MPS,
    TRAVEL_BOUND_M,
    Effect,
    ParamSpec,
    register_effect,
)
from fielddiag.effects.force_surface import SURFACE_SPEED_MPS, SURFACE_TRAVEL_M
from fielddiag.effects.hysteretic_spring import loading_state_m, yield_travel_start_m


@njit(cache=True, nogil=True)
def _memory_surface(r, rd, x2, z, p, c, dp, dz):  # pragma: no cover - compiled
    # state z[0]: travel since the last reversal, saturating at the memory travel p[3]:
    # dz/dt = rdot - |rdot| z / z_m. The force -z (a0 + a1 |w| + a2 q) / z_m with q, w
    # the surface's scaled travel and speed
    q = r / SURFACE_TRAVEL_M
    w = rd / SURFACE_SPEED_MPS
    aw = abs(w)
    u = z[0] / p[3]
    dz[0] = rd - abs(rd) * u
    dp[0] = -u
    dp[1] = -aw * u
    dp[2] = -q * u
    g = p[0] + p[1] * aw + p[2] * q
    dp[3] = g * u / p[3]  # directly through u = z / z_m (and through the state)
    sw = 1.0 if rd > 0.0 else -1.0 if rd < 0.0 else 0.0
    return -g * u, -p[2] * u / SURFACE_TRAVEL_M, -p[1] * sw * u / SURFACE_SPEED_MPS, 0.0


@njit(cache=True, nogil=True, error_model="numpy")
def _memory_surface_partials(r, rd, x2, z, p, c, dfz, dgs, dgz, dgp):  # pragma: no cover
    q = r / SURFACE_TRAVEL_M
    w = rd / SURFACE_SPEED_MPS
    g = p[0] + p[1] * abs(w) + p[2] * q
    sr = 1.0 if rd > 0.0 else -1.0 if rd < 0.0 else 0.0
    dfz[0] = -g / p[3]
    dgs[0, 0] = 0.0
    dgs[0, 1] = 1.0 - sr * z[0] / p[3]
    dgs[0, 2] = 0.0
    dgz[0, 0] = -abs(rd) / p[3]
    dgp[0, 0] = 0.0
    dgp[0, 1] = 0.0
    dgp[0, 2] = 0.0
    dgp[0, 3] = abs(rd) * z[0] / (p[3] * p[3])


_TERMS = ("loop", "loop_speed", "loop_travel")


@register_effect
class MemorySurface(Effect):
    """A force with memory of the last reversal that names no physics: the hidden travel
    ``z`` since the last reversal of the motion (``dz/dt = rdot - |rdot| z / z_m``, which
    saturates at ``+-z_m``, the memory travel) weighs a force smooth in the scaled travel
    ``q`` and speed ``w`` of :class:`~fielddiag.effects.force_surface.ForceSurface`::

        F = -(z / z_m) (a_loop + a_speed |w| + a_travel q)

    ``a_loop`` alone is a rounded hysteresis loop (Dahl); ``a_speed`` a damping force that
    is missing, or added, for about ``z_m`` of travel after each reversal (free play in a
    damper's mounting, a damper slow to build pressure); ``a_travel`` a loop whose height
    changes along the travel. The diagnosis fits it beside the force surface, as the
    shape of what no named effect describes where the force remembers the motion.
    """

    name = "memory_surface"
    names_physics = False
    n_states = 1
    linear_in_params = False
    description = "a force that remembers each reversal of the motion (no physical name)"
    params = tuple(
        ParamSpec(f"memory_{t}_n", "N", -INF, INF, 50.0, True, f"memory term {t}",
                  "drive over small ripples and larger bumps (many reversals)", default=0.0)
        for t in _TERMS
    ) + (
        ParamSpec("memory_travel_m", "m", 5e-5, 0.05, 2e-3, False, "memory travel",
                  "drive over small ripples (many small reversals)", default=2e-3,
                  valid_low=0.0, valid_strict=True, resolved_travel=True),
    )
    kernel = _memory_surface
    state_partials = _memory_surface_partials

    def static_states(self, r: float, values: Sequence[float]) -> np.ndarray:
        """``z`` reached when loaded slowly from r = 0 to ``r``.

        Parameters
        ----------
        r : float
            Suspension extension [m].
        values : sequence of float
            Parameter values in kernel order.

        Returns
        -------
        numpy.ndarray
            ``(1,)``: ``sign(r) z_m (1 - exp(-|r| / z_m))`` [m].
        """
        return np.array([loading_state_m(r, values[3])])

    def speed_bounds(self, values: Sequence[float]) -> tuple[float, float, float]:
        """Largest stiffness [N/m], damping [N s/m] and rate [1/s] the surface can add.

        Parameters
        ----------
        values : sequence of float
            Parameter values in kernel order.

        Returns
        -------
        (float, float, float)
            ``|dF/dz|`` bound as a stiffness, ``|dF/drdot|``, and the state's rate.
        """
        a = [abs(v) for v in values[:3]]
        z_m = values[3]
        q, w = TRAVEL_BOUND_M / SURFACE_TRAVEL_M, RATE_BOUND_MPS / SURFACE_SPEED_MPS
        stiff = (a[0] + a[1] * w + a[2] * q) / z_m + a[2] / SURFACE_TRAVEL_M
        return stiff, a[1] / SURFACE_SPEED_MPS, RATE_BOUND_MPS / z_m

    def start_values(self, r_m, start):
        """Start values of a fit: no force, a memory travel of 5 % of the travel's spread.

        Parameters
        ----------
        r_m : ndarray
            Measured suspension extension [m].
        start : mapping
            Values already known by model key; unused.

        Returns
        -------
        dict
        """
        out = {p.name: 0.0 for p in self.params[:3]}
        out["memory_travel_m"] = yield_travel_start_m(r_m)
        return out

    def explain(self, params: Mapping[str, float], per: str = "", hidden: str = "") -> str:
        """A sentence on what the surface is (the diagnosis describes its shape in words).

        Parameters
        ----------
        params : mapping
            Fitted values by name.
        per : str
            Unit suffix for per-unit-mass values or "".
        hidden : str
            How the linear fit distorted its parameters, or "".

        Returns
        -------
        str
        """
        return ("a force that remembers each reversal of the motion, which no named "
                f"effect describes{hidden}")
