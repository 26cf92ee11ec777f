"""Dry (Coulomb) friction in the strut, smoothed by a tanh."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

from numba import njit

from fielddiag.effects.base import INF, Effect, ParamSpec, register_effect


@njit(cache=True, nogil=True)
def _coulomb_friction(r, rd, x2, p, c, dp):  # pragma: no cover - compiled
    u = rd / p[1]
    th = math.tanh(u)
    s = 1.0 - th * th
    dp[0] = -th
    dp[1] = p[0] * s * u / p[1]
    return -p[0] * th, 0.0, -p[0] * s / p[1], 0.0


@register_effect
class CoulombFriction(Effect):
    """Dry friction: force on the body ``-Ff tanh(rdot / v_s)``.

    The smoothing velocity ``v_s`` is fitted, not a constant: what a fit sees is dry
    friction driven by the *modelled* relative velocity, which lacks the vibration above
    the fit band (and between the samples of the analysis rate). That unmodelled ripple
    dithers the real friction across its zero crossings, so on the band-limited velocity
    the force switches more gently than the true one: an effective ``v_s`` of 15-30 mm/s
    on a class B-C road for a true 10 mm/s. With ``v_s`` held at the true value the fit
    explains the gentler switching with a smaller force (7-11 % low); fitting ``v_s``
    lets the data set the knee and keeps ``Ff``, the force at speed, unbiased. Hold it
    with ``fixed={"coulomb_friction.smoothing_velocity_mps": ...}`` when the model sees
    the full-band motion (simulator truth). Not force-scaled; bounded to 1-200 mm/s in a
    fit (below 1 mm/s the switching cannot be resolved at analysis rates; towards
    200 mm/s the term turns into a linear damper ``Ff / v_s``). A simulated effect takes
    any ``v_s`` > 0 (10 mm/s by default).
    """

    name = "coulomb_friction"
    diagnosable = True
    diagnosis_rank = 10
    description = "dry friction"
    params = (
        ParamSpec("friction_force_n", "N", 0.0, INF, 50.0, True, "friction",
                  "drive slowly over small ripples (small, slow suspension strokes)",
                  significant=True),
        ParamSpec("smoothing_velocity_mps", "m/s", 1e-3, 0.2, 0.01, False,
                  "friction smoothing velocity",
                  "drive slowly over small ripples (many slow reversals of the suspension)",
                  shape=True, default=0.01, valid_low=0.0, valid_strict=True),
    )
    # linear in the force once the smoothing velocity is fixed
    linear_in_params = True
    kernel = _coulomb_friction

    def speed_bounds(self, values: Sequence[float]) -> tuple[float, float, float]:
        """Largest stiffness [N/m], damping [N s/m] and rate [1/s] the friction can add.

        Parameters
        ----------
        values : sequence of float
            Parameter values in kernel order (friction force [N], smoothing velocity [m/s]).

        Returns
        -------
        (float, float, float)
            ``(0, Ff / v_s, 0)``: the slope of the tanh at rdot = 0 [N s/m].
        """
        return 0.0, values[0] / values[1], 0.0

    def start_values(self, r_m, start):
        """Start values of a screening fit.

        A small friction force, which the fit grows only where the data want it.

        Parameters
        ----------
        r_m : ndarray
            Measured suspension extension [m] (positive in rebound); unused.
        start : mapping
            Values already known by model key; unused.

        Returns
        -------
        dict
            ``{"friction_force_n": 2 % of the typical force}`` [N].
        """
        # a small friction: the screening fit grows it only where the data want it
        return {"friction_force_n": 0.02 * self.params[0].typical}

    def explain(self, params: Mapping[str, float], per: str = "", hidden: str = "") -> str:
        """A sentence a technician can act on.

        It gives the friction force [N] and what to check.

        Parameters
        ----------
        params : mapping
            Fitted physical parameters by name (``friction_force_n``;
            ``_per_kg`` names in per-unit-mass mode).
        per : str
            Unit suffix for per-unit-mass values (`` per kg of sprung mass``) or "".
        hidden : str
            How the linear fit distorted its parameters to absorb the effect, or "".

        Returns
        -------
        str
        """
        f = params.get("friction_force_n", params.get("friction_force_n_per_kg", math.nan))
        return (
            f"dry friction of about {f:.3g} N{per} in the strut{hidden}. Check the strut "
            "top mount, bushings and damper seals for binding"
        )
