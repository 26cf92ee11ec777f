"""Equations of motion of the full vehicle and their numba RK4 loop.

States (14): body heave, pitch, roll at the origin (:mod:`fielddiag.vehicle.geometry`),
the four hub positions (fl, fr, rl, rr), then their rates. Positions are deviations from
the static equilibrium of the car without added mass (so ``r = z_body_point - z_hub`` is
the suspension extension the effect library expects). With ``q = (heave, pitch, roll)``::

    M_q q''   = sum_i [1, x_i, y_i]^T F_i + [0, -S_z a_long, S_z a_lat] - dM g [1, x_a, y_a]
    m_i z_i'' = k_t,i (u_i - z_i) + c_t,i (u_i' - z_i') - F_i

``M_q`` is the body's mass matrix about the origin (mass, first moments, pitch and roll
inertias with the parallel-axis terms, the added point mass included), ``S_z`` the first
moment ``M h`` of the sprung mass about the roll/pitch axes (the added mass sits on the
floor, at the axes' height), ``F_i`` the force of corner i's suspension on the body (its
:class:`~fielddiag.effects.ForceModel` plus the axle's anti-roll bar
``F_left = -k (r_left - r_right)``, ``F_right = +k (r_left - r_right)``).

The four corners may carry different effects. One numba loop is compiled for the union
of their effect classes (cached on disk per combination, :mod:`fielddiag.effects.compose`);
a corner without an effect of the union gets it with a zero force (its force-scaled
parameters 0; an asymmetric damper at the corner's linear damping both ways).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from fielddiag.channels import CORNERS
from fielddiag.effects import Effect, ForceModel, LinearDamper, LinearSpring, get_effect
from fielddiag.effects.compose import model_force
from fielddiag.errors import FieldDiagError
from fielddiag.sim._common import MAX_LAMBDA_DT, MIN_INTERNAL_RATE_HZ
from fielddiag.vehicle.params import VehicleParams

__all__ = ["corner_models", "integrate_vehicle", "internal_rate_factor", "union_layout"]


# ---------------------------------------------------------------------- corner models
def corner_models(vehicle: VehicleParams,
                  effects: Mapping[str, Sequence[Effect] | ForceModel] | None = None
                  ) -> dict[str, ForceModel]:
    """Each corner's suspension force: its linear spring and damper plus its effects.

    Parameters
    ----------
    vehicle : VehicleParams
        Supplies each corner's K and C.
    effects : mapping corner -> sequence of Effect or ForceModel, or None
        Effects with values (``CoulombFriction(friction_force_n=80)``). A term named
        ``linear_spring`` or ``linear_damper`` among them replaces the corner's own; an
        asymmetric damper replaces the linear damper.

    Returns
    -------
    dict corner -> ForceModel

    Raises
    ------
    FieldDiagError
        Unknown corner, a term without values, a term given twice, or an effect with
        internal states (not simulated at full-vehicle level yet).
    """
    effects = dict(effects or {})
    unknown = [c for c in effects if c not in CORNERS]
    if unknown:
        raise FieldDiagError(f"effects given for {unknown}; corners are {', '.join(CORNERS)}")
    out = {}
    for c in CORNERS:
        extra = effects.get(c, ())
        terms = list(extra.terms if isinstance(extra, ForceModel) else extra)
        for t in terms:
            if not isinstance(t, Effect) or t.values is None:
                raise FieldDiagError(f"corner {c}: {t!r} is not an effect with values; give e.g."
                                     " CoulombFriction(friction_force_n=80.0)")
            if t.n_states:
                raise FieldDiagError(
                    f"corner {c}: effect {t.name!r} has internal states, which the "
                    "full-vehicle simulator does not integrate yet; use a memoryless effect "
                    "(friction, asymmetric damping, cubic stiffness, bump stop...)")
        names = [t.name for t in terms]
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:
            raise FieldDiagError(f"corner {c}: effect {twice[0]!r} given twice; give it once")
        p = vehicle.corner(c)
        base = [t for t in (LinearSpring(p.stiffness_n_per_m), LinearDamper(p.damping_ns_per_m))
                if t.name not in names]
        out[c] = ForceModel([*base, *terms])
    return out


def union_layout(models: Mapping[str, ForceModel]
                 ) -> tuple[ForceModel, np.ndarray, np.ndarray]:
    """One model holding every corner's terms, and each corner's values in it.

    Parameters
    ----------
    models : mapping corner -> ForceModel
        From :func:`corner_models` (with values).

    Returns
    -------
    union : ForceModel
        The union of the corners' terms (linear spring and damper first, then by name).
    theta : numpy.ndarray, shape (4, n_params)
        Each corner's parameter vector in the union's order.
    consts : numpy.ndarray, shape (4, n_constants)
        Each corner's constants (settings) in the union's order.
    """
    names = {t.name for m in models.values() for t in m.terms}
    order = [n for n in ("linear_spring", "linear_damper") if n in names]
    order += sorted(names - set(order))
    union = ForceModel([get_effect(n)() for n in order])
    n_p = union.n_params
    n_c = sum(len(t.constants) for t in union.terms)
    theta = np.zeros((4, max(n_p, 1)))
    consts = np.zeros((4, max(n_c, 1)))
    for i, c in enumerate(CORNERS):
        own = {t.name: t for t in models[c].terms}
        damp = own["linear_damper"].values["suspension_damping_ns_per_m"] \
            if "linear_damper" in own else 0.0
        p0 = c0 = 0
        for t in union.terms:
            p1, c1 = p0 + len(t.params), c0 + len(t.constants)
            mine = own.get(t.name)
            if mine is not None:
                theta[i, p0:p1] = mine.value_vector()
                consts[i, c0:c1] = mine.constant_values()
            else:
                if t.name == "asymmetric_damping":
                    theta[i, p0:p1] = damp
                else:
                    theta[i, p0:p1] = [0.0 if p.scales_with_force else
                                       (p.default if p.default is not None else p.typical)
                                       for p in t.params]
                defaults = {**type(t).constants, **type(t).truth_constants}
                consts[i, c0:c1] = [defaults[k] for k in type(t).constants]
            p0, c0 = p1, c1
    return union, theta, consts


def internal_rate_factor(vehicle: VehicleParams, models: Mapping[str, ForceModel],
                         sample_rate_hz: float) -> int:
    """Integer k with ``k * sample_rate_hz >= 4000 Hz`` and ``|lambda| dt <= 0.5`` for the
    fastest wheel mode (tyre + suspension + anti-roll bar stiffness and the effects'
    stiffness, damping and rate bounds over the unsprung mass)."""
    lam = 0.0
    for c in CORNERS:
        p = vehicle.corner(c)
        stiff = damp = rate = 0.0
        for t in models[c].terms:
            s, d, q = t.speed_bounds(t.value_vector())
            stiff, damp, rate = stiff + s, damp + d, max(rate, q)
        arb = 2.0 * vehicle.anti_roll_stiffness_n_per_m("front" if c[0] == "f" else "rear")
        k = p.tire_stiffness_n_per_m + stiff + arb
        lam = max(lam, math.sqrt(k / p.wheel_mass_kg),
                  (p.tire_damping_ns_per_m + damp) / p.wheel_mass_kg, rate)
    need = max(MIN_INTERNAL_RATE_HZ, lam / MAX_LAMBDA_DT)
    return max(1, math.ceil(need / sample_rate_hz - 1e-9))


# --------------------------------------------------------------------- numba templates
def _profile(pos_m, h, inv_dx, v):  # pragma: no cover - numba template
    """Road height and rate at ``pos_m`` (Catmull-Rom through the samples, speed v)."""
    x = pos_m * inv_dx
    last = h.shape[0] - 1
    if x <= 0.0:
        return h[0], 0.0
    if x >= last:
        return h[last], 0.0
    i = int(math.floor(x))
    if i < 1 or i > last - 2:
        slope = h[i + 1] - h[i]
        return h[i] + (x - i) * slope, slope * inv_dx * v
    f = x - i
    p0, p1, p2, p3 = h[i - 1], h[i], h[i + 1], h[i + 2]
    c1 = 0.5 * (p2 - p0)
    c2 = p0 - 2.5 * p1 + 2.0 * p2 - 0.5 * p3
    c3 = 0.5 * (p3 - p0) + 1.5 * (p1 - p2)
    return p1 + f * (c1 + f * (c2 + f * c3)), (c1 + f * (2.0 * c2 + 3.0 * f * c3)) * inv_dx * v


def _inputs(t, j, jl, knots, lat_t, lat_a, road_l, road_r, inv_dx, geo, u, ud):
    # pragma: no cover - numba template
    """Road under the four wheels, a_long, a_lat at time t; j, jl: current knot indices."""
    kt = knots[0]
    while j + 1 < kt.shape[0] and t >= kt[j + 1]:
        j += 1
    tau = t - kt[j]
    v = knots[1, j] + knots[3, j] * tau
    d = knots[2, j] + (knots[1, j] + 0.5 * knots[3, j] * tau) * tau
    along = knots[3, j] if j + 1 < kt.shape[0] else 0.0
    while jl + 1 < lat_t.shape[0] and t >= lat_t[jl + 1]:
        jl += 1
    if jl + 1 < lat_t.shape[0] and t >= lat_t[jl]:
        w = (t - lat_t[jl]) / (lat_t[jl + 1] - lat_t[jl])
        alat = lat_a[jl] + w * (lat_a[jl + 1] - lat_a[jl])
    elif t < lat_t[0]:
        alat = lat_a[0]
    else:
        alat = lat_a[lat_t.shape[0] - 1]
    front = d + geo[2, 0]  # geo[2]: road position offsets (front, rear) [m]
    rear = d + geo[2, 1]
    u[0], ud[0] = _profile(front, road_l, inv_dx, v)
    u[1], ud[1] = _profile(front, road_r, inv_dx, v)
    u[2], ud[2] = _profile(rear, road_l, inv_dx, v)
    u[3], ud[3] = _profile(rear, road_r, inv_dx, v)
    return j, jl, along, alat


def _deriv(s, u, ud, along, alat, geo, minv, wheel, karb, ext, th, cs, dth, f, ds):
    # pragma: no cover - numba template
    """ds/dt of the 14 states; f receives the corners' forces on the body (ARB included)."""
    q0 = 0.0
    q1 = 0.0
    q2 = 0.0
    for i in range(4):
        zb = s[0] + geo[0, i] * s[1] + geo[1, i] * s[2]
        vb = s[7] + geo[0, i] * s[8] + geo[1, i] * s[9]
        fi, _, _, _ = model_force(zb - s[3 + i], vb - s[10 + i], zb, th[i], cs[i], dth)
        f[i] = fi
    rf = (s[0] + geo[1, 0] * s[2] - s[3]) - (s[0] + geo[1, 1] * s[2] - s[4])
    rr = (s[0] + geo[0, 2] * s[1] + geo[1, 2] * s[2] - s[5]) - (
        s[0] + geo[0, 3] * s[1] + geo[1, 3] * s[2] - s[6])
    f[0] -= karb[0] * rf
    f[1] += karb[0] * rf
    f[2] -= karb[1] * rr
    f[3] += karb[1] * rr
    for i in range(4):
        q0 += f[i]
        q1 += geo[0, i] * f[i]
        q2 += geo[1, i] * f[i]
    q0 += ext[1]
    q1 += ext[2] - ext[0] * along
    q2 += ext[3] + ext[0] * alat
    for k in range(7):
        ds[k] = s[7 + k]
    for k in range(3):
        ds[7 + k] = minv[k, 0] * q0 + minv[k, 1] * q1 + minv[k, 2] * q2
    for i in range(4):
        ds[10 + i] = (wheel[1, i] * (u[i] - s[3 + i]) + wheel[2, i] * (ud[i] - s[10 + i])
                      - f[i]) / wheel[0, i]


def _integrate_vehicle(s0, n_int, dt, k_dec, geo, minv, wheel, karb, ext, th, cs, knots,
                       lat_t, lat_a, road_l, road_r, inv_dx):  # pragma: no cover - template
    """Fixed-step RK4. Returns body (3, n_int) and wheel (4, n_int) accelerations at the
    internal rate, and every k_dec-th step the rows: 14 states, 4 forces, 4 road heights,
    a_long, a_lat."""
    n_out = (n_int + k_dec - 1) // k_dec
    acc_b = np.empty((3, n_int))
    acc_w = np.empty((4, n_int))
    out = np.empty((24, n_out))
    s = s0.copy()
    st = np.empty(14)
    k1 = np.empty(14)
    k2 = np.empty(14)
    k3 = np.empty(14)
    k4 = np.empty(14)
    f = np.empty(4)
    fdum = np.empty(4)
    u = np.empty(4)
    ud = np.empty(4)
    um = np.empty(4)
    udm = np.empty(4)
    dth = np.empty(max(th.shape[1], 1))
    h2 = 0.5 * dt
    h6 = dt / 6.0
    j, jl, al, at = _inputs(0.0, 0, 0, knots, lat_t, lat_a, road_l, road_r, inv_dx, geo, u, ud)
    for n in range(n_int):
        t = n * dt
        _deriv(s, u, ud, al, at, geo, minv, wheel, karb, ext, th, cs, dth, f, k1)
        for k in range(3):
            acc_b[k, n] = k1[7 + k]
        for k in range(4):
            acc_w[k, n] = k1[10 + k]
        if n % k_dec == 0:
            m = n // k_dec
            for k in range(14):
                out[k, m] = s[k]
            for k in range(4):
                out[14 + k, m] = f[k]
                out[18 + k, m] = u[k]
            out[22, m] = al
            out[23, m] = at
        j, jl, alm, atm = _inputs(t + h2, j, jl, knots, lat_t, lat_a, road_l, road_r, inv_dx,
                                  geo, um, udm)
        for k in range(14):
            st[k] = s[k] + h2 * k1[k]
        _deriv(st, um, udm, alm, atm, geo, minv, wheel, karb, ext, th, cs, dth, fdum, k2)
        for k in range(14):
            st[k] = s[k] + h2 * k2[k]
        _deriv(st, um, udm, alm, atm, geo, minv, wheel, karb, ext, th, cs, dth, fdum, k3)
        j, jl, al, at = _inputs(t + dt, j, jl, knots, lat_t, lat_a, road_l, road_r, inv_dx,
                                geo, u, ud)
        for k in range(14):
            st[k] = s[k] + dt * k3[k]
        _deriv(st, u, ud, al, at, geo, minv, wheel, karb, ext, th, cs, dth, fdum, k4)
        for k in range(14):
            s[k] += h6 * (k1[k] + 2.0 * (k2[k] + k3[k]) + k4[k])
    return acc_b, acc_w, out


def _static_forces(s, geo, karb, th, cs):  # pragma: no cover - numba template
    """Corner forces on the body at rest (rates zero), anti-roll bars included."""
    f = np.empty(4)
    dth = np.empty(max(th.shape[1], 1))
    for i in range(4):
        zb = s[0] + geo[0, i] * s[1] + geo[1, i] * s[2]
        f[i], _, _, _ = model_force(zb - s[3 + i], 0.0, zb, th[i], cs[i], dth)
    rf = (s[0] + geo[1, 0] * s[2] - s[3]) - (s[0] + geo[1, 1] * s[2] - s[4])
    rr = (s[0] + geo[0, 2] * s[1] + geo[1, 2] * s[2] - s[5]) - (
        s[0] + geo[0, 3] * s[1] + geo[1, 3] * s[2] - s[6])
    f[0] -= karb[0] * rf
    f[1] += karb[0] * rf
    f[2] -= karb[1] * rr
    f[3] += karb[1] * rr
    return f


def integrate_vehicle(union: ForceModel, *args):
    """Run the RK4 loop compiled for ``union`` (arguments: see ``_integrate_vehicle``)."""
    ns = union.compile(__name__, "_profile", "_inputs", "_deriv", "_integrate_vehicle",
                       error_model="numpy")
    return ns._integrate_vehicle(*args)


def static_forces(union: ForceModel, *args) -> np.ndarray:
    """Corner forces at rest (arguments: see ``_static_forces``)."""
    ns = union.compile(__name__, "_static_forces", error_model="numpy")
    return ns._static_forces(*args)
