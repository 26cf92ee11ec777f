"""Bump stop: a stiff spring that engages after a gap in compression."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
from numba import njit

from fielddiag.effects.base import INF, Effect, ParamSpec, register_effect


@njit(cache=True, nogil=True)
def _bump_stop(r, rd, x2, p, c, dp):  # pragma: no cover - compiled
    w = c[0]
    if w <= 0.0:  # the sharp hinge kb * max(0, -r - gap)
        pen = -r - p[0]
        if pen > 0.0:
            dp[0] = -p[1]
            dp[1] = pen
            return p[1] * pen, -p[1], 0.0, 0.0
        dp[0] = 0.0
        dp[1] = 0.0
        return 0.0, 0.0, 0.0, 0.0
    # rounded: kb * w * softplus((-r - gap) / w)
    z = (-r - p[0]) / w
    if z > 30.0:
        sp = z
        sig = 1.0
    elif z < -30.0:
        sp = math.exp(z)
        sig = sp
    else:
        sp = math.log1p(math.exp(z))
        sig = 1.0 / (1.0 + math.exp(-z))
    dp[0] = -p[1] * sig
    dp[1] = w * sp
    return p[1] * w * sp, -p[1] * sig, 0.0, 0.0


@register_effect
class BumpStop(Effect):
    """Bump stop: force on the body ``+kb (-r - gap)`` when compressed beyond ``gap``.

    In a fit the corner of the hinge is rounded by a softplus of width ``width_m`` (1 mm)
    so that the force has continuous derivatives for Gauss-Newton; a simulated bump stop
    has the sharp hinge (``width_m`` = 0) unless given a width.
    """

    name = "bump_stop"
    diagnosable = True
    diagnosis_rank = 30
    description = "bump stop"
    params = (
        ParamSpec("gap_m", "m", 0.0, INF, 0.06, False, "bump-stop gap",
                  "drive over a large bump or pothole that compresses the suspension fully"),
        ParamSpec("stiffness_n_per_m", "N/m", 0.0, INF, 1e5, True, "bump-stop stiffness",
                  "drive over a large bump or pothole that compresses the suspension fully",
                  valid_low=0.0, valid_strict=True, significant=True),
    )
    constants = {"width_m": 1e-3}
    truth_constants = {"width_m": 0.0}
    linear_in_params = False
    kernel = _bump_stop

    def speed_bounds(self, values: Sequence[float]) -> tuple[float, float, float]:
        """Largest stiffness [N/m], damping [N s/m] and rate [1/s] the bump stop can add.

        Parameters
        ----------
        values : sequence of float
            Parameter values in kernel order (gap [m], stiffness [N/m]).

        Returns
        -------
        (float, float, float)
            ``(stiffness, 0, 0)``.
        """
        return values[1], 0.0, 0.0

    def start_values(self, r_m, start):
        """Start values of a screening fit.

        The gap just inside the compression the data reach.

        Parameters
        ----------
        r_m : ndarray
            Measured suspension extension [m] (positive in rebound).
        start : mapping
            Values already known by model key; unused.

        Returns
        -------
        dict
            ``{"gap_m": 95th percentile of -r_m}`` [m]; the stiffness takes its typical value.
        """
        # just inside the travel the data reach: the stop may engage on the largest bumps
        return {"gap_m": float(np.quantile(-np.asarray(r_m), 0.95))}

    def explain(self, params: Mapping[str, float], per: str = "", hidden: str = "") -> str:
        """A sentence a technician can act on.

        It gives where the stop engages [mm into compression] and its stiffness [N/m].

        Parameters
        ----------
        params : mapping
            Fitted physical parameters by name (``gap_m``, ``stiffness_n_per_m``;
            ``_per_kg`` names in per-unit-mass mode).
        per : str
            Unit suffix for per-unit-mass values (`` per kg of sprung mass``) or "".
        hidden : str
            How the linear fit distorted its parameters to absorb the effect, or "".

        Returns
        -------
        str
        """
        gap = params.get("gap_m", math.nan)
        k = params.get("stiffness_n_per_m", params.get("stiffness_n_per_m_per_kg", math.nan))
        return (
            f"bump stop reached {1000 * gap:.0f} mm into compression from the unloaded ride "
            f"height, stiffness {k:.3g} N/m{per}; it acts only over the largest bumps{hidden}. "
            "Check ride height and the bump-stop rubber if it engages too early"
        )
