"""Equations of motion: the numba RK4 kernel, the suspension force, the static equilibrium
and the choice of the internal step."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numba import njit
from scipy import optimize

from fielddiag.effects import Effect, ForceModel, LinearDamper, LinearSpring
from fielddiag.effects.compose import model_force_z
from fielddiag.errors import FieldDiagError
from fielddiag.sim._common import G_MPS2, MAX_LAMBDA_DT, MIN_INTERNAL_RATE_HZ
from fielddiag.sim.effects import check_effects
from fielddiag.sim.vehicle import DEFAULT_PARAMS, QuarterCarParams

_P_M1, _P_K1, _P_C1, _P_M2T, _P_K3, _P_DMG, _P_LEV = range(7)
#: Templates inlined into the templates that call them (:mod:`fielddiag.effects.compose`):
#: the right-hand side, called at every RK4 stage with its arrays.
INLINE_TEMPLATES = ("_rhs",)


def levelling_force_n(
    params: QuarterCarParams, added_mass_kg: float, ride_height_restored: bool
) -> float:
    """Static force of a levelling system between wheel and body [N] (up on the body).

    A self-levelling suspension (or a technician re-setting the ride height) carries the
    added mass's weight so that the suspension sits at the same static deflection as
    without it. With the coupling K3 the body also sinks by the tyre's extra deflection,
    which K3 partly carries: the force that restores the unloaded deflection exactly is
    ``dM g K1 / (K1 + K3)`` (``dM g`` without coupling). Zero for a passive car.
    """
    if not ride_height_restored or added_mass_kg == 0.0:
        return 0.0
    k1, k3 = params.tire_stiffness_n_per_m, params.coupling_stiffness_n_per_m
    return added_mass_kg * G_MPS2 * k1 / (k1 + k3)


def _phys_array(
    params: QuarterCarParams, added_mass_kg: float, ride_height_restored: bool = False
) -> np.ndarray:
    p = params
    return np.array(
        [
            p.wheel_mass_kg,
            p.tire_stiffness_n_per_m,
            p.tire_damping_ns_per_m,
            p.body_mass_kg + added_mass_kg,
            p.coupling_stiffness_n_per_m,
            added_mass_kg * G_MPS2,
            levelling_force_n(params, added_mass_kg, ride_height_restored),
        ]
    )


def suspension_model(
    params: QuarterCarParams, effects: Sequence[Effect] = ()
) -> tuple[ForceModel, np.ndarray]:
    """The suspension force of the car as a library model and its parameter vector.

    The car's linear spring K2 and damper C2 plus the effects (with their values; an
    asymmetric damper replaces C2). The coupling K3 is not part of it: it acts on the
    body only.

    Raises
    ------
    FieldDiagError
        Not an effect with values, or an effect given twice.
    """
    effects = check_effects(effects)
    names = [e.name for e in effects]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise FieldDiagError(
            f"effect {twice[0]!r} given twice; give it once with the combined parameters."
        )
    model = ForceModel([LinearSpring(params.suspension_stiffness_n_per_m),
                        LinearDamper(params.suspension_damping_ns_per_m), *effects])
    return model, model.values_of()


def _rhs(x1, v1, x2, v2, z, u, ud, phys, th, cs, dth, dz):  # pragma: no cover - template
    fs, _, _, _ = model_force_z(x2 - x1, v2 - v1, x2, z, th, cs, dth, dz)
    # a levelling system's static force _P_LEV acts between wheel and body, beside F_s
    a1 = (phys[_P_K1] * (u - x1) + phys[_P_C1] * (ud - v1) - fs - phys[_P_LEV]) / phys[_P_M1]
    a2 = (fs + phys[_P_LEV] - phys[_P_K3] * x2 - phys[_P_DMG]) / phys[_P_M2T]
    return a1, a2, fs


def _integrate(
    state0, z0, n_int, dt, k_dec, phys, th, cs, knot_t, knot_v, knot_d, knot_a, road_h, inv_dx
):  # pragma: no cover - numba template
    """Fixed-step RK4. Returns (a1, a2) at the internal rate and, every k_dec-th step,
    rows x1, v1, x2, v2, u, F_s, z[0] (0 without internal states)."""
    n_out = (n_int + k_dec - 1) // k_dec
    acc1 = np.empty(n_int)
    acc2 = np.empty(n_int)
    out = np.empty((7, n_out))
    nz = z0.shape[0]
    z = z0.copy()
    zt = np.empty(nz)
    kz1 = np.empty(nz)
    kz2 = np.empty(nz)
    kz3 = np.empty(nz)
    kz4 = np.empty(nz)
    dth = np.empty(max(th.shape[0], 1))
    x1, v1, x2, v2 = state0[0], state0[1], state0[2], state0[3]
    h2 = 0.5 * dt
    h6 = dt / 6.0
    u, ud, j = _road_at(0.0, 0, knot_t, knot_v, knot_d, knot_a, road_h, inv_dx)
    for n in range(n_int):
        t = n * dt
        a1, a2, fs = _rhs(x1, v1, x2, v2, z, u, ud, phys, th, cs, dth, kz1)
        acc1[n] = a1
        acc2[n] = a2
        if n % k_dec == 0:
            m = n // k_dec
            out[0, m] = x1
            out[1, m] = v1
            out[2, m] = x2
            out[3, m] = v2
            out[4, m] = u
            out[5, m] = fs
            out[6, m] = z[0] if nz > 0 else 0.0
        um, udm, j = _road_at(t + h2, j, knot_t, knot_v, knot_d, knot_a, road_h, inv_dx)
        w1, w2 = v1 + h2 * a1, v2 + h2 * a2
        for i in range(nz):
            zt[i] = z[i] + h2 * kz1[i]
        b1, b2, _ = _rhs(x1 + h2 * v1, w1, x2 + h2 * v2, w2, zt, um, udm, phys, th, cs, dth,
                         kz2)
        y1, y2 = v1 + h2 * b1, v2 + h2 * b2
        for i in range(nz):
            zt[i] = z[i] + h2 * kz2[i]
        c1, c2, _ = _rhs(x1 + h2 * w1, y1, x2 + h2 * w2, y2, zt, um, udm, phys, th, cs, dth,
                         kz3)
        u, ud, j = _road_at(t + dt, j, knot_t, knot_v, knot_d, knot_a, road_h, inv_dx)
        q1, q2 = v1 + dt * c1, v2 + dt * c2
        for i in range(nz):
            zt[i] = z[i] + dt * kz3[i]
        d1, d2, _ = _rhs(x1 + dt * y1, q1, x2 + dt * y2, q2, zt, u, ud, phys, th, cs, dth, kz4)
        x1 += h6 * (v1 + 2.0 * (w1 + y1) + q1)
        x2 += h6 * (v2 + 2.0 * (w2 + y2) + q2)
        v1 += h6 * (a1 + 2.0 * (b1 + c1) + d1)
        v2 += h6 * (a2 + 2.0 * (b2 + c2) + d2)
        for i in range(nz):
            z[i] += h6 * (kz1[i] + 2.0 * (kz2[i] + kz3[i]) + kz4[i])
    return acc1, acc2, out


def integrate(model: ForceModel, *args):
    """Run the RK4 kernel compiled for ``model`` (see :func:`_integrate` for the arguments)."""
    return model.compile(__name__, "_rhs", "_integrate", error_model="numpy")._integrate(*args)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _road_at(t, j, knot_t, knot_v, knot_d, knot_a, road_h, inv_dx):  # pragma: no cover
    """Road height and rate at time t; j is the current speed-knot index (t never decreases).

    Height is a Catmull-Rom cubic through the samples (C1), so udot = du/ds * v is continuous.
    """
    while j + 1 < knot_t.shape[0] and t >= knot_t[j + 1]:
        j += 1
    tau = t - knot_t[j]
    v = knot_v[j] + knot_a[j] * tau
    pos = (knot_d[j] + (knot_v[j] + 0.5 * knot_a[j] * tau) * tau) * inv_dx
    last = road_h.shape[0] - 1
    if pos <= 0.0:
        return road_h[0], 0.0, j
    if pos >= last:
        return road_h[last], 0.0, j
    i = int(math.floor(pos))
    if i < 1 or i > last - 2:  # first/last sample interval: linear
        slope = road_h[i + 1] - road_h[i]
        return road_h[i] + (pos - i) * slope, slope * inv_dx * v, j
    f = pos - i
    p0, p1, p2, p3 = road_h[i - 1], road_h[i], road_h[i + 1], road_h[i + 2]
    c1 = 0.5 * (p2 - p0)
    c2 = p0 - 2.5 * p1 + 2.0 * p2 - 0.5 * p3
    c3 = 0.5 * (p3 - p0) + 1.5 * (p1 - p2)
    u = p1 + f * (c1 + f * (c2 + f * c3))
    du = c1 + f * (2.0 * c2 + 3.0 * f * c3)
    return u, du * inv_dx * v, j


def suspension_force_n(
    r_m: np.ndarray | float,
    rdot_mps: np.ndarray | float,
    params: QuarterCarParams = DEFAULT_PARAMS,
    effects: Sequence[Effect] = (),
    hysteretic_state_m: np.ndarray | float = 0.0,
) -> np.ndarray:
    """Force of the suspension on the body, ``F_s(r, rdot)``, exactly as the simulator uses it.

    Parameters
    ----------
    r_m, rdot_mps : array_like
        Suspension extension from the unloaded ride height [m] and its rate [m/s].
    params : QuarterCarParams
        Supplies K2 and C2.
    effects : sequence of Effect
        Nonlinear effects added to the linear spring and damper.
    hysteretic_state_m : array_like
        Internal state of the effect that has one (the deflection z of a
        :class:`~fielddiag.effects.HystereticSpring`); ignored without one.

    Returns
    -------
    numpy.ndarray
        Force [N], positive up on the body, broadcast shape of the inputs.
    """
    r, rd, z = np.broadcast_arrays(
        np.asarray(r_m, float), np.asarray(rdot_mps, float), np.asarray(hysteretic_state_m, float)
    )
    model, th = suspension_model(params, effects)
    if model.n_states == 0:
        f = model.force(r.ravel(), rd.ravel(), 0.0, th)[0]
    else:
        states = np.repeat(z.reshape(-1, 1), model.n_states, axis=1)
        f = model.force(r.ravel(), rd.ravel(), 0.0, th, states=states)[0]
    return f.reshape(r.shape)


def internal_rate_factor(
    output_rate_hz: float,
    params: QuarterCarParams,
    effects: Sequence[Effect] = (),
    added_mass_kg: float = 0.0,
) -> int:
    """Integer k with k * output_rate >= 4000 Hz and |lambda| dt <= 0.5 for the fastest mode.

    The fastest mode is bounded by the tyre and suspension stiffness plus each effect's
    stiffness (cubic spring at 0.15 m travel, bump stop, hysteresis), the damping rates
    (C1 + C2 + friction F/v_s + ... over the wheel mass) and the hysteresis rate
    2 m/s / yield_displacement_m.
    """
    stiff = damp = rate = 0.0
    for e in check_effects(effects):
        s, d, q = e.speed_bounds(e.value_vector())
        stiff, damp, rate = stiff + s, damp + d, max(rate, q)
    p = params
    m_min = min(p.wheel_mass_kg, p.body_mass_kg + added_mass_kg)
    k_max = (
        p.tire_stiffness_n_per_m
        + p.suspension_stiffness_n_per_m
        + abs(p.coupling_stiffness_n_per_m)
        + stiff
    )
    c_max = p.tire_damping_ns_per_m + p.suspension_damping_ns_per_m + damp
    lam = max(math.sqrt(k_max / m_min), c_max / m_min, rate)
    need_hz = max(MIN_INTERNAL_RATE_HZ, lam / MAX_LAMBDA_DT)
    return max(1, math.ceil(need_hz / output_rate_hz - 1e-9))


def static_state(
    params: QuarterCarParams,
    effects: Sequence[Effect] = (),
    added_mass_kg: float = 0.0,
    road_height_m: float = 0.0,
    ride_height_restored: bool = False,
) -> np.ndarray:
    """Static equilibrium [x1, v1, x2, v2, z...] of the loaded car, effects included.

    The force balance ``F_s(r) + L = K3 x2 + dM g``, ``x1 = u - (F_s + L) / K1`` is
    solved for ``r`` by Brent's method (``L`` the levelling force,
    :func:`levelling_force_n`: 0 for a passive car, so the suspension sags under the
    added mass; with ``ride_height_restored`` it carries the added weight and ``r`` is
    the unloaded car's), with ``F_s`` the sum of the effects' static contributions
    (:meth:`~fielddiag.effects.base.Effect.static_force_n`: friction and dampers are zero
    at rest; a hysteretic spring is taken as loaded slowly from r = 0). The internal
    states follow ``x1, v1, x2, v2`` (one 0 when there are none).

    Raises
    ------
    FieldDiagError
        No stable equilibrium within 2 m of suspension travel.
    """
    phys = _phys_array(params, added_mass_kg, ride_height_restored)
    model, th = suspension_model(params, effects)
    k1, k3, wg = params.tire_stiffness_n_per_m, params.coupling_stiffness_n_per_m, phys[_P_DMG]
    lev = phys[_P_LEV]

    def fs(r: float) -> float:
        return model.static_force(r, 0.0, th)

    def h(r: float) -> float:  # net upward force on the body, decreasing in r when stable
        f = fs(r) + lev
        return f - k3 * (road_height_m - f / k1 + r) - wg

    h0 = h(0.0)
    r0 = 0.0
    if h0 != 0.0:
        step = math.copysign(1e-4, h0)
        a, b = 0.0, step
        while h(b) * h0 > 0:
            a, b = b, 2 * b
            if abs(b) > 2.0:
                raise FieldDiagError(
                    f"no static equilibrium within 2 m of suspension travel for added_mass_kg="
                    f"{added_mass_kg:g}: the springs cannot carry the load or "
                    "coupling_stiffness_n_per_m makes the corner unstable; reduce the "
                    "added mass or check the stiffness parameters."
                )
        r0 = optimize.brentq(h, min(a, b), max(a, b), xtol=1e-15, rtol=4 * np.finfo(float).eps)
    d = 1e-7
    if h(r0 + d) - h(r0 - d) >= 0:
        raise FieldDiagError(
            "the static equilibrium is unstable (K1 K2 + K3 (K1 + K2) <= 0 or a softening "
            "effect); make coupling_stiffness_n_per_m less negative."
        )
    f = fs(r0) + lev
    x1 = road_height_m - f / k1
    z = model.static_states(r0, th) if model.n_states else np.zeros(1)
    return np.array([x1, 0.0, x1 + r0, 0.0, *z])
