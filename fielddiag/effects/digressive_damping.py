"""A digressive damper: above a blow-off knee velocity the damping drops (per direction)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

from numba import njit

from fielddiag.effects.base import Effect, ParamSpec, register_effect


@njit(cache=True, nogil=True)
def _hinge(u, w):  # pragma: no cover - compiled
    """(max(0, u) rounded by a softplus of width w, its derivative in u)."""
    if w <= 0.0:
        return (u, 1.0) if u > 0.0 else (0.0, 0.0)
    q = u / w
    if q > 30.0:
        return u, 1.0
    if q < -30.0:
        e = math.exp(q)
        return w * e, e
    return w * math.log1p(math.exp(q)), 1.0 / (1.0 + math.exp(-q))


@njit(cache=True, nogil=True)
def _digressive_damping(r, rd, x2, p, c, dp):  # pragma: no cover - compiled
    # p: compression knee [m/s], compression drop [N s/m], rebound knee, rebound drop;
    # force on the body +drop * hinge(|rdot| - knee) * sgn(rdot) (the damper's -c rdot
    # loses `drop` of its slope above the knee)
    dp[0] = 0.0
    dp[1] = 0.0
    dp[2] = 0.0
    dp[3] = 0.0
    if rd < 0.0:
        h, dh = _hinge(-rd - p[0], c[0])
        dp[0] = p[1] * dh
        dp[1] = -h
        return -p[1] * h, 0.0, p[1] * dh, 0.0
    h, dh = _hinge(rd - p[2], c[0])
    dp[2] = -p[3] * dh
    dp[3] = h
    return p[3] * h, 0.0, p[3] * dh, 0.0


#: The most a damper's slope can change at a knee [N s/m], either way: ten times a stiff
#: car damper's. Unbounded, a knee at the top of the speeds measured took a few peak
#: samples with a rise of 2e8 N s/m (seed 1795997625; 3e6 N s/m for Coulomb friction,
#: seed 1795986431), a finding no damper makes; at this bound such a fit is pinned, and
#: not chosen.
MAX_SLOPE_CHANGE_NS_PER_M = 3.0e4


#: A knee at this share of its upper bound or above is at the top of the range.
KNEE_AT_TOP = 0.98


@register_effect
class DigressiveDamping(Effect):
    """A digressive (blow-off) damper: above a knee velocity the damping drops, per direction.

    Added to the damper of the model (linear or asymmetric): in compression (``rdot < 0``)
    the slope of the damper's force falls by ``compression_drop_ns_per_m`` above
    ``compression_knee_mps``, in rebound by ``rebound_drop_ns_per_m`` above
    ``rebound_knee_mps``. In a fit the knee is rounded by a softplus of width
    ``width_mps`` (0.01 m/s); a simulated damper has the sharp knee unless given a width.
    """

    name = "digressive_damping"
    diagnosable = True
    diagnosis_rank = 45
    description = "digressive damper (blow-off above a knee velocity)"
    constants = {"width_mps": 0.01}
    truth_constants = {"width_mps": 0.0}
    params = (
        ParamSpec("compression_knee_mps", "m/s", 0.05, 2.0, 0.15, False,
                  "compression knee velocity", "drive over sharp bumps (fast compression)"),
        ParamSpec("compression_drop_ns_per_m", "N s/m", -MAX_SLOPE_CHANGE_NS_PER_M,
                  MAX_SLOPE_CHANGE_NS_PER_M, 600.0, True,
                  "compression damping drop", "drive over sharp bumps (fast compression)"),
        ParamSpec("rebound_knee_mps", "m/s", 0.05, 2.0, 0.15, False,
                  "rebound knee velocity", "drive over sharp dips (fast rebound)"),
        ParamSpec("rebound_drop_ns_per_m", "N s/m", -MAX_SLOPE_CHANGE_NS_PER_M,
                  MAX_SLOPE_CHANGE_NS_PER_M, 1200.0, True,
                  "rebound damping drop", "drive over sharp dips (fast rebound)"),
    )
    linear_in_params = False
    kernel = _digressive_damping

    def speed_bounds(self, values: Sequence[float]) -> tuple[float, float, float]:
        """Largest stiffness [N/m], damping [N s/m] and rate [1/s] the knee can add.

        Parameters
        ----------
        values : sequence of float
            Parameter values in kernel order.

        Returns
        -------
        (float, float, float)
            ``(0, max |drop|, 0)``: a negative drop (a progressive damper) adds damping.
        """
        return 0.0, max(abs(values[1]), abs(values[3])), 0.0

    def start_values(self, r_m, start):
        """Start values of a screening fit: knees at 0.1 m/s, no drop (a knee is bounded below
        at 0.05 m/s: slower, a step in the force is dry friction's job).

        Parameters
        ----------
        r_m : ndarray
            Measured suspension extension [m] (unused).
        start : mapping
            Values already known by model key (unused).

        Returns
        -------
        dict
        """
        return {"compression_knee_mps": 0.1, "compression_drop_ns_per_m": 0.0,
                "rebound_knee_mps": 0.1, "rebound_drop_ns_per_m": 0.0}

    def unphysical(self, values: Mapping[str, float], std: Mapping[str, float]) -> bool:
        """No knee after all: both drops within 2 std of zero; or a knee no drive reached: a
        drop that is there (beyond 2 std) at a knee at the top of its range
        (:data:`KNEE_AT_TOP`), where a few peak samples carry it (a knee at 1.9986 m/s
        with a rise of 2e8 N s/m, its std 2e-13 m/s: seed 1795997625).

        Parameters
        ----------
        values, std : mapping
            Fitted values and standard deviations by parameter name.

        Returns
        -------
        bool
        """
        out = True
        top = KNEE_AT_TOP * self.params[0].upper
        for side in ("compression", "rebound"):
            d = f"{side}_drop_ns_per_m"
            v = values.get(d, values.get(d + "_per_kg", 0.0))
            s = std.get(d, std.get(d + "_per_kg", 0.0))
            there = bool(abs(v) > 2.0 * s)
            if there and values.get(f"{side}_knee_mps", 0.0) >= top:
                return True
            out &= not there
        return out

    def explain(self, params: Mapping[str, float], per: str = "", hidden: str = "") -> str:
        """A sentence a technician can act on: where each direction's damping drops.

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
        parts = []
        for side in ("compression", "rebound"):
            knee = params.get(f"{side}_knee_mps", math.nan)
            drop = params.get(f"{side}_drop_ns_per_m",
                              params.get(f"{side}_drop_ns_per_m_per_kg", math.nan))
            word = "drops" if drop >= 0 else "rises"
            parts.append(f"in {side} the damping {word} by {abs(drop):.3g} N s/m{per} above "
                         f"{knee:.2g} m/s")
        return ("the damper is digressive (it blows off at speed): " + "; ".join(parts)
                + hidden)
