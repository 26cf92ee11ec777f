"""Bouc-Wen hysteresis: a normalised hidden state whose loop sharpness is fitted."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
from numba import njit

from fielddiag.effects.base import INF, RATE_BOUND_MPS, Effect, ParamSpec, register_effect
from fielddiag.effects.hysteretic_spring import yield_travel_start_m


@njit(cache=True, nogil=True)
def _bouc_wen(r, rd, x2, z, p, c, dp, dz):  # pragma: no cover - compiled
    # state z[0] = w in [-1, 1]; dw/dt = (rdot / x_y) (1 - |w|^n (1 + sgn(rdot w)) / 2)
    # (a select, not a branch: the same numbers, and numba keeps the callers' loops lean)
    w = z[0]
    aw = abs(w)
    on = 1.0 if rd * w > 0.0 else 0.0
    dz[0] = rd / p[1] * (1.0 - on * aw ** p[2])
    dp[0] = -w
    dp[1] = 0.0  # through the state (its sensitivity: _bouc_wen_partials)
    dp[2] = 0.0
    return -p[0] * w, 0.0, 0.0, 0.0


@njit(cache=True, nogil=True, error_model="numpy")
def _bouc_wen_partials(r, rd, x2, z, p, c, dfz, dgs, dgz, dgp):  # pragma: no cover - compiled
    # F = -F_h w;  g = dw/dt = (rdot / x_y) (1 - on |w|^n), on = [rdot w > 0] as in
    # _bouc_wen. Written without branches (selects only): a branch around a division
    # keeps numba from pruning the reference counts of the callers' array views
    w = z[0]
    aw = abs(w)
    on = 1.0 if rd * w > 0.0 else 0.0
    wn = on * aw ** p[2]
    u = rd / p[1]
    dfz[0] = -p[0]
    dgs[0, 0] = 0.0
    dgs[0, 1] = (1.0 - wn) / p[1]
    dgs[0, 2] = 0.0
    dgz[0, 0] = -u * p[2] * wn / (w if w != 0.0 else 1.0)  # d|w|^n/dw = n |w|^n / w
    dgp[0, 0] = 0.0
    dgp[0, 1] = -u * (1.0 - wn) / p[1]
    dgp[0, 2] = -u * wn * math.log(aw if aw > 0.0 else 1.0)


def _loading_curve(r: float, yield_m: float, exponent: float) -> float:
    """w reached by loading monotonically from 0 to ``r``: dw/dr = (1 - |w|^n) / x_y."""
    if r == 0.0:
        return 0.0
    u = abs(r) / yield_m
    if u > 60.0 / min(exponent, 1.0):  # saturated to within exp(-30)
        return math.copysign(1.0, r)
    steps = 32
    h = u / steps
    w = 0.0
    for _ in range(steps):  # RK4 in u = |r| / x_y; w stays in [0, 1)
        k1 = 1.0 - w ** exponent
        k2 = 1.0 - min(w + 0.5 * h * k1, 1.0) ** exponent
        k3 = 1.0 - min(w + 0.5 * h * k2, 1.0) ** exponent
        k4 = 1.0 - min(w + h * k3, 1.0) ** exponent
        w = min(w + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4), 1.0)
    return math.copysign(w, r)


@register_effect
class BoucWen(Effect):
    """Bouc-Wen hysteresis (A = 1, beta = gamma = 1/2, normalised by the yield travel).

    A hidden state ``w`` follows ``dw/dt = (rdot / x_y) (1 - |w|^n (1 + sgn(rdot w)) / 2)``
    and the force on the body is ``-hysteretic_force_n * w``: after each reversal the force
    rises with stiffness ``F_h / x_y`` and saturates at ``+-F_h`` (a rounded dry-friction
    loop, the pre-yield behaviour of an MR damper or a rubber bushing); the exponent ``n``
    sets how sharply it yields (large ``n``: an elastic-perfectly-plastic corner; ``n`` = 1
    is close to Dahl, :class:`~fielddiag.effects.hysteretic_spring.HystereticSpring`).
    """

    name = "bouc_wen"
    diagnosable = True
    diagnosis_rank = 55
    description = "hysteresis (Bouc-Wen) in the suspension"
    n_states = 1
    linear_in_params = False
    params = (
        ParamSpec("hysteretic_force_n", "N", 0.0, INF, 60.0, True, "hysteretic force",
                  "drive over small ripples (many small reversals)",
                  valid_low=0.0, valid_strict=True, significant=True),
        ParamSpec("yield_displacement_m", "m", 5e-5, 0.05, 2e-3, False,
                  "hysteresis yield travel", "drive over small ripples (many small reversals)",
                  valid_low=0.0, valid_strict=True, resolved_travel=True),
        ParamSpec("yield_exponent", "1", 0.5, 6.0, 2.0, False, "yield sharpness",
                  "drive over small ripples (many small reversals)", shape=True,
                  default=2.0),
    )
    kernel = _bouc_wen
    state_partials = _bouc_wen_partials

    def static_states(self, r: float, values: Sequence[float]) -> np.ndarray:
        """``w`` reached when loaded slowly and monotonically from r = 0 to ``r``.

        Parameters
        ----------
        r : float
            Suspension extension [m].
        values : sequence of float
            Parameter values in kernel order (force [N], yield travel [m], exponent).

        Returns
        -------
        numpy.ndarray
            ``(1,)``: the normalised state in [-1, 1].
        """
        return np.array([_loading_curve(float(r), float(values[1]), float(values[2]))])

    def speed_bounds(self, values: Sequence[float]) -> tuple[float, float, float]:
        """Largest stiffness [N/m], damping [N s/m] and rate [1/s] the hysteresis can add.

        Parameters
        ----------
        values : sequence of float
            Parameter values in kernel order (force [N], yield travel [m], exponent).

        Returns
        -------
        (float, float, float)
            ``(F_h / x_y, 0, RATE_BOUND_MPS / x_y)``.
        """
        return values[0] / values[1], 0.0, RATE_BOUND_MPS / values[1]

    def start_values(self, r_m, start):
        """Start values of a screening fit: a yield travel of 5 % of the travel's spread.

        Parameters
        ----------
        r_m : ndarray
            Measured suspension extension [m].
        start : mapping
            Values already known by model key (unused).

        Returns
        -------
        dict
            ``yield_displacement_m`` [m].
        """
        return {"yield_displacement_m": yield_travel_start_m(r_m)}

    def explain(self, params: Mapping[str, float], per: str = "", hidden: str = "") -> str:
        """A sentence a technician can act on: the loop's height and its yield travel.

        Parameters
        ----------
        params : mapping
            Fitted physical parameters by name (``_per_kg`` names in per-unit-mass mode).
        per : str
            Unit suffix for per-unit-mass values (`` per kg of sprung mass``) or "".
        hidden : str
            How the linear fit distorted its parameters to absorb the effect, or "".

        Returns
        -------
        str
        """
        f = params.get("hysteretic_force_n", params.get("hysteretic_force_n_per_kg", math.nan))
        x = params.get("yield_displacement_m", math.nan)
        return (f"the suspension force lags its travel (hysteresis): after each reversal it "
                f"builds up over about {1e3 * x:.2g} mm of travel to {f:.3g} N{per} (a loop "
                f"{2 * f:.3g} N{per} high); typical of worn bushings, a binding strut or an "
                f"MR damper's pre-yield range{hidden}")
