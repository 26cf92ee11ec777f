"""Dahl hysteresis: a spring with an internal deflection state (the one effect with memory)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
from numba import njit

from fielddiag.effects.base import INF, RATE_BOUND_MPS, Effect, ParamSpec, register_effect


@njit(cache=True, nogil=True)
def _hysteretic_spring(r, rd, x2, z, p, c, dp, dz):  # pragma: no cover - compiled
    # state z[0]: the hidden deflection; dz/dt = rdot - |rdot| z / z_y
    dz[0] = rd - abs(rd) * z[0] / p[1]
    dp[0] = -z[0]
    dp[1] = 0.0  # through the state only (its sensitivity: _hysteretic_spring_partials)
    return -p[0] * z[0], 0.0, 0.0, 0.0


@njit(cache=True, nogil=True, error_model="numpy")
def _hysteretic_spring_partials(r, rd, x2, z, p, c, dfz, dgs, dgz, dgp):  # pragma: no cover
    # F = -k z;  g = dz/dt = rdot - |rdot| z / z_y
    dfz[0] = -p[0]
    dgs[0, 0] = 0.0
    dgs[0, 1] = 1.0 - (1.0 if rd > 0.0 else -1.0 if rd < 0.0 else 0.0) * z[0] / p[1]
    dgs[0, 2] = 0.0
    dgz[0, 0] = -abs(rd) / p[1]
    dgp[0, 0] = 0.0
    dgp[0, 1] = abs(rd) * z[0] / (p[1] * p[1])


def loading_state_m(r_m: float, yield_m: float) -> float:
    """The Dahl state reached when loaded slowly and monotonically from 0 to ``r_m``:
    ``sign(r) z_y (1 - exp(-|r| / z_y))`` [m] (``dz/dr = 1 - z / z_y``).

    Parameters
    ----------
    r_m : float
        Suspension extension [m].
    yield_m : float
        The yield (memory) travel ``z_y`` [m].

    Returns
    -------
    float
    """
    return math.copysign(yield_m * -math.expm1(-abs(r_m) / yield_m), r_m)


def yield_travel_start_m(r_m: np.ndarray) -> float:
    """Start value of a hysteresis's yield travel [m]: 5 % of the travel's spread, 0.2-10 mm.

    Parameters
    ----------
    r_m : ndarray
        Measured suspension extension [m].

    Returns
    -------
    float
    """
    spread = float(np.std(r_m)) if np.size(r_m) else 0.0
    return float(np.clip(0.05 * spread, 2e-4, 0.01))


@register_effect
class HystereticSpring(Effect):
    """Dahl hysteresis (Bouc-Wen with n = 1, A = 1, beta = 1/z_y, gamma = 0).

    A hidden deflection ``z`` follows ``dz/dt = rdot - |rdot| z / yield_displacement_m``
    and the force on the body is ``-hysteretic_stiffness_n_per_m * z``: stiffness
    ``hysteretic_stiffness_n_per_m`` for small reversals, saturating at
    ``hysteretic_stiffness_n_per_m * yield_displacement_m`` (a rounded friction loop) for
    travel much larger than ``yield_displacement_m``.
    """

    name = "hysteretic_spring"
    diagnosable = True
    diagnosis_rank = 50
    description = "hysteresis (Dahl) in the suspension"
    n_states = 1
    linear_in_params = False
    params = (
        ParamSpec("hysteretic_stiffness_n_per_m", "N/m", 0.0, INF, 2e4, True,
                  "hysteretic stiffness", "drive over small ripples (many small reversals)",
                  valid_low=0.0, valid_strict=True, significant=True),
        ParamSpec("yield_displacement_m", "m", 5e-5, 0.05, 2e-3, False,
                  "hysteresis yield displacement",
                  "drive over small ripples (many small reversals)",
                  valid_low=0.0, valid_strict=True, resolved_travel=True),
    )
    kernel = _hysteretic_spring
    state_partials = _hysteretic_spring_partials

    def static_states(self, r: float, values: Sequence[float]) -> np.ndarray:
        """``z`` reached when loaded slowly and monotonically from r = 0 to ``r``.

        Parameters
        ----------
        r : float
            Suspension extension [m].
        values : sequence of float
            Parameter values in kernel order (stiffness [N/m], yield displacement [m]).

        Returns
        -------
        numpy.ndarray
            ``(1,)``: ``sign(r) z_y (1 - exp(-|r| / z_y))`` [m].
        """
        return np.array([loading_state_m(r, values[1])])

    def speed_bounds(self, values: Sequence[float]) -> tuple[float, float, float]:
        """Largest stiffness [N/m], damping [N s/m] and rate [1/s] the hysteretic spring can add.

        Parameters
        ----------
        values : sequence of float
            Parameter values in kernel order (stiffness [N/m], yield displacement [m]).

        Returns
        -------
        (float, float, float)
            ``(k_h, 0, RATE_BOUND_MPS / z_y)``: the rate is that of the state ``z``.
        """
        return values[0], 0.0, RATE_BOUND_MPS / values[1]

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
        k = params.get("hysteretic_stiffness_n_per_m",
                       params.get("hysteretic_stiffness_n_per_m_per_kg", math.nan))
        x = params.get("yield_displacement_m", math.nan)
        return (f"the suspension force lags its travel (Dahl hysteresis): after each reversal "
                f"it builds up with {k:.3g} N/m{per} over about {1e3 * x:.2g} mm to "
                f"{k * x:.3g} N{per}; typical of worn bushings or a binding strut{hidden}")
