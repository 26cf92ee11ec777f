"""Build-up hysteresis: friction hysteresis plus a force that keeps building up with the
travel since the last reversal, separately in each direction (a rig effect)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
from numba import njit

from fielddiag.effects.base import INF, RATE_BOUND_MPS, Effect, ParamSpec, register_effect


@njit(cache=True, nogil=True)
def _buildup_hysteresis(r, rd, x2, z, p, c, dp, dz):  # pragma: no cover - compiled
    # z[0] = w in [-1, 1] (Dahl friction state): dw/dt = (rdot - |rdot| w) / x_y
    # z[1] = a >= 0: travel built up while compressing (rdot < 0), saturating at h_y,
    #        released over x_r of extension
    # z[2] = b >= 0: the same while extending (rdot > 0)
    w, a, b = z[0], z[1], z[2]
    x_y = p[1]
    x_r = p[2]
    h_y = p[5]
    ard = abs(rd)
    dz[0] = (rd - ard * w) / x_y
    if rd < 0.0:
        dz[1] = ard * (1.0 - a / h_y)
        dz[2] = -ard * b / x_r
    else:
        dz[1] = -ard * a / x_r
        dz[2] = ard * (1.0 - b / h_y)
    dp[0] = -w
    dp[1] = 0.0  # x_y, x_r and h_y act through the states (forward differences)
    dp[2] = 0.0
    dp[3] = a
    dp[4] = -b
    dp[5] = 0.0
    return -p[0] * w + p[3] * a - p[4] * b, 0.0, 0.0, 0.0


@register_effect
class BuildupHysteresis(Effect):
    """Friction hysteresis whose force keeps building up along the stroke after a reversal.

    Three states follow the motion. ``w`` is Dahl friction's: ``dw/dt = (rdot - |rdot| w)
    / x_y``, a friction loop of height ``2 F_f`` that builds up over about ``x_y`` after
    each reversal. ``a`` is the travel since the motion turned to compression
    (``rdot < 0``): ``da/dt = |rdot| (1 - a / h_y)`` while compressing, released as
    ``da/dt = -|rdot| a / x_r`` while extending; ``b`` is the same for extension. The force
    on the body is::

        F = -F_f w + k_c a - k_e b

    so that in compression the resisting force grows by ``k_c`` per metre of travel since
    the reversal (saturating after about ``h_y``), in extension by ``k_e``, and both fall
    back within ``x_r`` once the motion turns. Unlike a spring, the force depends on where
    the stroke turned, not on the absolute position: a long stroke ends with a larger loop
    than a short one at the same place and speed. This is what the magneto-rheological
    damper of ``shared/data/mr_damper`` shows in compression (its loop grows by about 2 N
    per mm of stroke, which a friction level that depends on the absolute position cannot
    reproduce across strokes). A chamber pressurised through a compliance during one
    direction of travel and vented at the reversal would behave so (a guess at the
    mechanism; the data show only the force).

    It is a rig effect (``diagnosable`` False): six parameters and three states for a
    phenomenon of dampers on a test rig; the quarter-car diagnosis has the plain Dahl
    and Bouc-Wen hysteresis.
    """

    name = "buildup_hysteresis"
    description = ("friction hysteresis whose force keeps building up with the travel since "
                   "the last reversal")
    n_states = 3
    linear_in_params = False
    params = (
        ParamSpec("friction_force_n", "N", 0.0, INF, 50.0, True, "friction force",
                  "drive slowly through the whole stroke in both directions",
                  significant=True),
        ParamSpec("yield_displacement_m", "m", 0.0, INF, 1e-4, False, "pre-yield travel",
                  "drive over small ripples (many small reversals)",
                  valid_low=0.0, valid_strict=True, default=1e-4),
        ParamSpec("release_displacement_m", "m", 1e-5, 0.05, 2e-4, False, "release travel",
                  "drive over small ripples (many small reversals)", shape=True,
                  valid_low=0.0, valid_strict=True, default=2e-4),
        ParamSpec("compression_buildup_n_per_m", "N/m", 0.0, INF, 3000.0, True,
                  "build-up in compression", "drive strokes of different lengths",
                  default=0.0),
        ParamSpec("extension_buildup_n_per_m", "N/m", 0.0, INF, 500.0, True,
                  "build-up in extension", "drive strokes of different lengths",
                  default=0.0),
        ParamSpec("buildup_travel_m", "m", 1e-3, 1.0, 0.05, False, "build-up travel",
                  "drive strokes of different lengths", shape=True,
                  valid_low=0.0, valid_strict=True, default=0.05),
    )
    kernel = _buildup_hysteresis

    def static_states(self, r: float, values: Sequence[float]) -> np.ndarray:
        """States reached when loaded slowly and monotonically from r = 0 to ``r``.

        Parameters
        ----------
        r : float
            Extension [m].
        values : sequence of float
            Parameter values in kernel order.

        Returns
        -------
        numpy.ndarray
            ``(3,)``: ``w = sign(r) (1 - exp(-|r| / x_y))``; the build-up
            ``h_y (1 - exp(-|r| / h_y))`` in ``a`` (``r < 0``) or ``b`` (``r > 0``).
        """
        w = math.copysign(-math.expm1(-abs(r) / values[1]), r)
        h = -values[5] * math.expm1(-abs(r) / values[5])
        return np.array([w, h if r < 0 else 0.0, h if r > 0 else 0.0])

    def speed_bounds(self, values: Sequence[float]) -> tuple[float, float, float]:
        """Largest stiffness [N/m], damping [N s/m] and rate [1/s] the effect can add.

        Parameters
        ----------
        values : sequence of float
            Parameter values in kernel order.

        Returns
        -------
        (float, float, float)
            ``(|F_f| / x_y + |k_c| + |k_e|, 0, RATE_BOUND_MPS / min(x_y, x_r, h_y))``.
        """
        f, x_y, x_r, k_c, k_e, h_y = (abs(float(v)) for v in values)
        shortest = min(x_y, x_r, h_y)
        return f / x_y + k_c + k_e, 0.0, RATE_BOUND_MPS / shortest

    def start_values(self, r_m, start):
        """Start values of a screening fit: a build-up travel of the stroke's span.

        Parameters
        ----------
        r_m : ndarray
            Measured suspension extension [m].
        start : mapping
            Values already known by model key (unused).

        Returns
        -------
        dict
            ``buildup_travel_m`` [m].
        """
        span = float(np.ptp(r_m)) if np.size(r_m) else 0.05
        return {"buildup_travel_m": float(np.clip(span, 2e-3, 0.5))}

    def explain(self, params: Mapping[str, float], per: str = "", hidden: str = "") -> str:
        """A sentence a technician can act on: friction, and how the force builds up.

        Parameters
        ----------
        params : mapping
            Fitted physical (and shape) parameters by name.
        per : str
            Unit suffix for per-unit-mass values or "".
        hidden : str
            How the linear fit distorted its parameters to absorb the effect, or "".

        Returns
        -------
        str
        """
        f = params.get("friction_force_n", math.nan)
        x = params.get("yield_displacement_m", math.nan)
        kc = params.get("compression_buildup_n_per_m", math.nan)
        ke = params.get("extension_buildup_n_per_m", math.nan)
        h = params.get("buildup_travel_m", math.nan)
        return (f"hysteresis: dry friction of {f:.3g} N{per} building up over about "
                f"{1e3 * x:.2g} mm after each reversal, then a force that keeps growing with "
                f"the travel since the reversal, by {1e-3 * kc:+.3g} N{per} per mm in "
                f"compression and {1e-3 * ke:+.3g} N{per} per mm in extension (levelling "
                f"off after about {1e3 * h:.3g} mm): the loop grows with the stroke, which "
                f"a spring or a friction that depends on the position cannot do{hidden}")
