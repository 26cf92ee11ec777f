"""A damper with different compression and rebound coefficients."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

from numba import njit

from fielddiag.effects.base import INF, Effect, ParamSpec, register_effect


@njit(cache=True, nogil=True)
def _asymmetric_damping(r, rd, x2, p, c, dp):  # pragma: no cover - compiled
    if rd < 0.0:
        dp[0] = -rd
        dp[1] = 0.0
        return -p[0] * rd, 0.0, -p[0], 0.0
    dp[0] = 0.0
    dp[1] = -rd
    return -p[1] * rd, 0.0, -p[1], 0.0


@register_effect
class AsymmetricDamping(Effect):
    """Damper with different compression (``rdot < 0``) and rebound coefficients:
    force on the body ``-c rdot``. Replaces the linear damper in a model that has both.

    Parameters ``compression_damping_ns_per_m`` and ``rebound_damping_ns_per_m`` [N s/m]
    (see :class:`~fielddiag.effects.base.Effect` for the constructor).

    Examples
    --------
    A damper to simulate, and a model to fit with one::

        AsymmetricDamping(compression_damping_ns_per_m=1200.0, rebound_damping_ns_per_m=2400.0)
        model = LinearSpring() + AsymmetricDamping()   # replaces no damper: there is none
    """

    name = "asymmetric_damping"
    diagnosable = True
    diagnosis_rank = 40
    description = "asymmetric damper"
    params = (
        ParamSpec("compression_damping_ns_per_m", "N s/m", 0.0, INF, 1.2e3, True,
                  "compression damping", "drive over sharp bumps (fast compression strokes)"),
        ParamSpec("rebound_damping_ns_per_m", "N s/m", 0.0, INF, 2.4e3, True,
                  "rebound damping", "drive over sharp dips or potholes (fast rebound strokes)"),
    )
    replaces = ("linear_damper",)
    kernel = _asymmetric_damping

    def speed_bounds(self, values: Sequence[float]) -> tuple[float, float, float]:
        """Largest stiffness [N/m], damping [N s/m] and rate [1/s] the damper can add.

        Parameters
        ----------
        values : sequence of float
            Parameter values in kernel order (compression, rebound damping [N s/m]).

        Returns
        -------
        (float, float, float)
            ``(0, max(compression, rebound), 0)``.
        """
        return 0.0, max(values[0], values[1]), 0.0

    def start_values(self, r_m, start):
        """Start values of a screening fit.

        Both coefficients at the linear fit's damping.

        Parameters
        ----------
        r_m : ndarray
            Measured suspension extension [m] (positive in rebound); unused.
        start : mapping
            Values already known by model key (uses
            ``linear_damper.suspension_damping_ns_per_m`` [N s/m]).

        Returns
        -------
        dict
            Both damping coefficients [N s/m], or empty when no linear damping is known.
        """
        c = start.get("linear_damper.suspension_damping_ns_per_m")
        return {} if c is None else {"compression_damping_ns_per_m": c,
                                     "rebound_damping_ns_per_m": c}

    def unphysical(self, values: Mapping[str, float], std: Mapping[str, float]) -> bool:
        """Symmetric after all: the two coefficients within 2 std of each other.

        Parameters
        ----------
        values, std : mapping
            Fitted values and standard deviations by parameter name [N s/m].

        Returns
        -------
        bool
            ``|c_compression - c_rebound| <= 2 hypot(std_compression, std_rebound)``.
        """
        c = values.get("compression_damping_ns_per_m", math.nan)
        r = values.get("rebound_damping_ns_per_m", math.nan)
        sc = std.get("compression_damping_ns_per_m", 0.0)
        sr = std.get("rebound_damping_ns_per_m", 0.0)
        return bool(abs(c - r) <= 2.0 * math.hypot(sc, sr))

    def explain(self, params: Mapping[str, float], per: str = "", hidden: str = "") -> str:
        """A sentence a technician can act on.

        It gives the two coefficients [N s/m] and their ratio rebound/compression.

        Parameters
        ----------
        params : mapping
            Fitted physical parameters by name (``compression_damping_ns_per_m``,
            ``rebound_damping_ns_per_m``;
            ``_per_kg`` names in per-unit-mass mode).
        per : str
            Unit suffix for per-unit-mass values (`` per kg of sprung mass``) or "".
        hidden : str
            How the linear fit distorted its parameters to absorb the effect, or "".

        Returns
        -------
        str
        """
        cc = params.get("compression_damping_ns_per_m",
                        params.get("compression_damping_ns_per_m_per_kg", math.nan))
        cr = params.get("rebound_damping_ns_per_m",
                        params.get("rebound_damping_ns_per_m_per_kg", math.nan))
        return (
            f"the damper is asymmetric: {cc:.4g} N s/m{per} in compression, {cr:.4g} in "
            f"rebound (ratio {cr / cc:.2f}); a single damping value misrepresents it{hidden}"
        )
