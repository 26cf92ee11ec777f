"""A rubber top mount in series with the damper (a Maxwell element: one more state)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
from numba import njit

from fielddiag.effects.base import INF, Effect, ParamSpec, register_effect


@njit(cache=True, nogil=True)
def _series_top_mount(r, rd, x2, z, p, c, dp, dz):  # pragma: no cover - compiled
    # state z[0] = u, the mount's deflection; the damper carries k_m u = c (rdot - du/dt)
    dz[0] = rd - p[1] / max(p[0], 1e-9) * z[0]
    dp[0] = 0.0  # through the state (its sensitivity: _series_top_mount_partials)
    dp[1] = -z[0]
    return -p[1] * z[0], 0.0, 0.0, 0.0


@njit(cache=True, nogil=True, error_model="numpy")
def _series_top_mount_partials(r, rd, x2, z, p, c, dfz, dgs, dgz, dgp):  # pragma: no cover
    # F = -k_m u;  g = du/dt = rdot - k_m / c u  (c floored at 1e-9 as in the kernel;
    # selects, no branches: see _bouc_wen_partials)
    cc = max(p[0], 1e-9)
    dfz[0] = -p[1]
    dgs[0, 0] = 0.0
    dgs[0, 1] = 1.0
    dgs[0, 2] = 0.0
    dgz[0, 0] = -p[1] / cc
    dgp[0, 0] = p[1] / (cc * cc) * z[0] * (1.0 if p[0] > 1e-9 else 0.0)
    dgp[0, 1] = -z[0] / cc


@register_effect
class SeriesTopMount(Effect):
    """A damper of damping ``c`` acting through a rubber top mount of stiffness ``k_m``.

    The mount's deflection ``u`` follows ``du/dt = rdot - (k_m / c) u`` and the force on
    the body is ``-k_m u``: the damper's ``-c rdot`` at low frequency, a spring ``k_m`` at
    high frequency (corner ``k_m / (2 pi c)`` Hz), so the damping fades above it. Replaces
    the linear damper.
    """

    name = "series_top_mount"
    # below its corner the mount delays the damper's force by c / k_m: a late body channel
    data_twins = ("channel_time_offset",)
    diagnosable = True
    diagnosis_rank = 60
    description = "damper acting through a compliant top mount"
    n_states = 1
    linear_in_params = False
    replaces = ("linear_damper",)
    params = (
        ParamSpec("suspension_damping_ns_per_m", "N s/m", 1.0, INF, 1.8e3, True,
                  "damping", "drive over rough roads (broadband excitation)",
                  valid_low=0.0, valid_strict=True),
        ParamSpec("mount_stiffness_n_per_m", "N/m", 1e3, INF, 1.5e5, True,
                  "top-mount stiffness", "drive over rough roads (wheel-hop frequencies)",
                  valid_low=0.0, valid_strict=True),
    )
    kernel = _series_top_mount
    state_partials = _series_top_mount_partials

    def speed_bounds(self, values: Sequence[float]) -> tuple[float, float, float]:
        """Largest stiffness [N/m], damping [N s/m] and rate [1/s] of the mount and damper.

        Parameters
        ----------
        values : sequence of float
            Parameter values in kernel order (damping [N s/m], mount stiffness [N/m]).

        Returns
        -------
        (float, float, float)
            ``(k_m, c, k_m / c)``.
        """
        return values[1], values[0], values[1] / max(values[0], 1e-9)

    def relaxation_rate_per_s(self, values: Sequence[float]) -> float:
        """The mount's relaxation rate ``k_m / c`` [1/s], whatever the speed.

        Parameters
        ----------
        values : sequence of float
            Parameter values in kernel order (damping [N s/m], mount stiffness [N/m]).

        Returns
        -------
        float
        """
        return self.speed_bounds(values)[2]

    def resolved_upper(self, values: Sequence[float], shortest_time_s: float) -> np.ndarray:
        """The mount stiffness at which its time constant ``c / k_m`` is ``shortest_time_s``
        at the starting damping ``c`` (a stiffer mount would take more RK4 substeps than
        :data:`~fielddiag.effects.model.MAX_RELAXATION_STEPS` per sample; its delay is
        then far below what the data tell from zero).

        Parameters
        ----------
        values : sequence of float
            Damping [N s/m] and mount stiffness [N/m] where the fit starts.
        shortest_time_s : float
            Shortest relaxation time kept [s].

        Returns
        -------
        ndarray
            ``(inf, c / shortest_time_s)``.
        """
        return np.array([np.inf, values[0] / shortest_time_s])

    def start_values(self, r_m, start):
        """Start values: the linear damping and a mount 8x the spring's stiffness.

        Parameters
        ----------
        r_m : ndarray
            Measured suspension extension [m] (unused).
        start : mapping
            Values already known by model key.

        Returns
        -------
        dict
        """
        out = {}
        c = start.get("linear_damper.suspension_damping_ns_per_m")
        k = start.get("linear_spring.suspension_stiffness_n_per_m")
        if c is not None:
            out["suspension_damping_ns_per_m"] = c
        if k is not None:
            out["mount_stiffness_n_per_m"] = 8.0 * k
        return out

    def twin_start(self, kind, value, start):
        """A mount whose relaxation time ``c / k_m`` is the channel delay ``value`` [s]: to
        the body's response below the mount's corner the two are the same lag.

        Parameters
        ----------
        kind : str
            ``channel_time_offset`` (anything else: no start).
        value : float
            The body channel's delay [s].
        start : mapping
            Values already known by model key (the linear damping).

        Returns
        -------
        dict
        """
        c = start.get("linear_damper.suspension_damping_ns_per_m")
        if kind != "channel_time_offset" or c is None or not value:
            return {}
        return {"suspension_damping_ns_per_m": c, "mount_stiffness_n_per_m": c / abs(value)}

    @classmethod
    def looks_like_data(cls, kind: str, value: float) -> bool:
        """A mount lags the body's response behind the wheel's: it looks like a late body
        channel (``value`` > 0), never like a late wheel channel, which makes the body
        seem to lead.

        Parameters
        ----------
        kind : str
            The data problem.
        value : float
            The body channel's delay [s].

        Returns
        -------
        bool
        """
        return kind in cls.data_twins and value > 0

    def explain(self, params: Mapping[str, float], per: str = "", hidden: str = "") -> str:
        """A sentence a technician can act on: the mount's stiffness and where damping fades.

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
        c = params.get("suspension_damping_ns_per_m",
                       params.get("suspension_damping_ns_per_m_per_kg", math.nan))
        k = params.get("mount_stiffness_n_per_m",
                       params.get("mount_stiffness_n_per_m_per_kg", math.nan))
        corner = k / (2 * math.pi * c) if c > 0 else math.nan
        return (f"the damper acts through a compliant top mount ({k:.3g} N/m{per} in series "
                f"with {c:.3g} N s/m{per}): above about {corner:.2g} Hz the mount gives way "
                f"and the damping fades; a soft or torn top mount{hidden}")
