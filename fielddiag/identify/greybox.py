"""Grey-box fit of the body equation: simulation, sensitivity equations, bounded LM.

This module runs the fit (:func:`fit_greybox`, :func:`validation_runs`); its parts live
by concern in ``greybox_data`` (:class:`GreyBoxData`, units, default band),
``greybox_sensitivities`` (the numba integrator of the body and its sensitivities),
``greybox_model`` (:class:`GreyBoxProblem`: parametrisation, residuals, start values),
``greybox_solver`` (Levenberg-Marquardt, HAC covariance) and ``greybox_results`` (result
objects and the one NRMSE definition); the force terms come from :mod:`fielddiag.effects`.

Model (Serban & Freeman's time-domain fit, seed 000). The body of one car corner, driven
by the measured wheel motion ``x1(t), v1(t)``::

    (M2 + dM) a2 = F(r, rdot, x2; theta) - dM g,      r = x2 - x1

with ``F`` a :class:`~fielddiag.identify.terms.ForceModel` (linear spring, damper,
coupling, effects) and positions measured from the static equilibrium of the car without
added mass (the convention of :mod:`fielddiag.sim`). The simulation starts from the static
equilibrium ``F(x2 - x1(0), 0, x2) = dM g`` plus a fitted initial offset and velocity of the
body (two nuisance parameters per session), and is integrated by fixed-step RK4 at the
sample rate (or a sub-multiple) with the wheel input interpolated by cubic Hermite
polynomials through the samples of ``x1`` and ``v1``.

Jacobian: the sensitivity equations ``d/dt (dx2/dtheta) = ...`` are integrated with the
same RK4 steps as the state (direct differentiation), which makes them the exact
derivative of the discrete simulation; the initial sensitivities come from differentiating
the static equilibrium (Serban & Freeman eq. 18). State and sensitivities are integrated in
one numba-compiled loop that calls the model's assembled force kernel.

Fit: Levenberg-Marquardt with bounds on the body-acceleration residuals of one or several
sessions, each compared in the same band (zero-phase Butterworth on simulated and measured
acceleration alike; the measured one is already limited by the same band window as the
integrated wheel motion). Parameters are fitted per unit sprung mass (``theta / M2``) and,
when the sessions carry at least two different added masses, with the inverse sprung mass
``1 / M2`` as one more parameter (the acceleration is nearly linear in it); the absolute
values ``M2 * theta`` and ``M2`` are reported. Every parameter is normalised by its start
value so that the normal equations are well conditioned. Before the fit proper, short
continuation stages reset the simulated body to the measured (integrated) body state every
0 / 0.2 / 2 s: with short horizons the cost is nearly convex (at 0 s it is the equation
error), so starts several times off converge; the last stage is the plain simulation.

Uncertainty: the covariance is the sandwich ``A^-1 B A^-1`` with ``A = J^T J`` and ``B``
the long-run covariance of the score ``J^T e`` under the residuals' own autocovariance
(flat-top lag window at least ``2 / f_low`` wide, wider where the residual autocorrelation
lasts longer): honest for coloured residuals, where ``s^2 (J^T J)^-1`` is optimistic by
the factor reported as the variance inflation.

Limits: the model is exact for linear terms; effect terms are evaluated on band-limited
motion. What the band removes matters most for dry friction: the relative velocity above
the band's top (7-16 mm/s rms on class B-C roads with a 30 Hz top; below a 0.5 Hz bottom
only 0.5-2 mm/s) dithers the true friction across its zero crossings, so on the
band-limited velocity it switches more gently. With the smoothing velocity held at its
true 10 mm/s the fitted force comes out 7-11 % low; fitted (as
:class:`~fielddiag.identify.terms.CoulombFriction` does) it settles at an effective
15-30 mm/s and the force within a few per cent. Fixed-step RK4 at the sample rate is exact
to ~1e-7 for the linear model; stiff effects (friction with a small smoothing velocity)
want ``substeps`` 2-4.

Validation: the fitted model is run on data not used in the fit (another segment or
another drive; only the two initial-state nuisances are refitted) and the NRMSE
``rms(residual) / rms(measured)`` of the band-limited body acceleration is reported next
to the one on the fit data.
"""
from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from fielddiag.blas import single_threaded_blas
from fielddiag.effects import ForceModel, linear_model
from fielddiag.errors import FieldDiagError
from fielddiag.identify.greybox_data import (
    ACCEL_UNITS,
    GRAVITY_MPS2,
    GreyBoxData,
    accel_unit_factor,
    default_band_hz,
)
from fielddiag.identify.greybox_model import _NUISANCE_SCALE, GreyBoxProblem
from fielddiag.identify.greybox_results import GreyBoxResult, ParameterEstimate, SessionFit, nrmse
from fielddiag.identify.greybox_sensitivities import simulate_body
from fielddiag.identify.greybox_solver import (
    LMOutcome,
    _hac_meat,
    _psd_clip,
    hac_covariance,
    levenberg_marquardt,
    solve,
)

__all__ = [
    "ACCEL_UNITS",
    "GRAVITY_MPS2",
    "GreyBoxData",
    "GreyBoxProblem",
    "accel_unit_factor",
    "default_band_hz",
    "fit_greybox",
    "hac_covariance",
    "levenberg_marquardt",
    "simulate_body",
    "validate_greybox",
    "validation_runs",
]


# ---------------------------------------------------------------------------------------
# Fit
# ---------------------------------------------------------------------------------------


def _to_unit(model: ForceModel, values: Mapping[str, float], absolute: bool,
             mass: float | None) -> dict[int, float]:
    out = {}
    for k, v in values.items():
        if k == "body_mass_kg":
            continue
        i = model.index(k)
        out[i] = v / mass if (absolute and model.force_scaled[i] and mass) else float(v)
    return out


@single_threaded_blas
def fit_greybox(
    data: GreyBoxData | Sequence[GreyBoxData],
    model: ForceModel | None = None,
    *,
    initial: Mapping[str, float] | None = None,
    fixed: Mapping[str, float] | None = None,
    absolute: bool | None = None,
    body_mass_kg: float | None = None,
    validation: Sequence[GreyBoxData] = (),
    max_iterations: int = 50,
    xtol: float = 1e-8,
    ftol: float = 1e-8,
    fit_initial_state: bool = True,
    substeps: int = 1,
    horizons_s: Sequence[float] | None = (0.0, 0.2, 2.0),
    stage_iterations: int = 4,
    stage_xtol: float = 1e-3,
    callback: Any = None,
    solver: str = "lm",
    mass_bounds_kg: tuple[float, float] | None = None,
) -> GreyBoxResult:
    """Fit the model to one or more sessions by Levenberg-Marquardt on sensitivities.

    Parameters
    ----------
    data : GreyBoxData or sequence of them
        Fit data. Two or more different added masses give absolute parameters and the
        sprung mass; otherwise parameters per unit sprung mass.
    model : ForceModel or None
        Default: linear spring + linear damper.
    initial : mapping or None
        Start values by parameter key or name (absolute values plus ``body_mass_kg`` in
        absolute mode, per unit mass otherwise). Missing ones come from an equation-error
        least-squares fit (or typical values).
    fixed : mapping or None
        Parameters held constant (same units as ``initial``).
    absolute : bool or None
        Force or forbid the absolute fit; None decides from the added masses.
    body_mass_kg : float or None
        Sprung-mass guess (see :class:`GreyBoxProblem`).
    validation : sequence of GreyBoxData
        Held-out data (another segment or drive) for the validation NRMSE.
    max_iterations : int
        Levenberg-Marquardt iteration limit.
    xtol : float
        Relative step tolerance on the normalised parameters.
    ftol : float
        Relative cost-decrease tolerance of the final stage (an accepted step that lowers
        the cost by less, or a Gauss-Newton step that could not, ends the fit).
    fit_initial_state : bool
        Fit each session's initial body offset and velocity.
    substeps : int
        RK4 steps per sample interval.
    horizons_s : sequence of float or None
        Continuation: before the fit proper, short fits in which the simulated body is
        reset to the measured (integrated) body state every ``horizon`` seconds, with
        growing horizons (0: every sample, i.e. the equation error). Short horizons make
        the cost nearly convex, so starts far from the answer still converge; the last
        stage is always the plain simulation from static equilibrium. None or () to skip.
    stage_iterations : int
        Iteration limit of each continuation stage.
    stage_xtol : float
        Step tolerance of the continuation stages.
    callback : callable or None
        ``callback(iteration, reported_values_dict, cost)`` after each accepted step of the
        final stage.
    solver : str
        ``"lm"`` (:func:`~fielddiag.identify.greybox_solver.levenberg_marquardt`) or
        ``"trf"`` (``scipy.optimize.least_squares``, same Jacobian), see the measurement in
        :mod:`fielddiag.identify.greybox_solver`.
    mass_bounds_kg : (float, float) or None
        Range of the sprung mass in absolute mode (see :class:`GreyBoxProblem`).

    Returns
    -------
    GreyBoxResult

    Raises
    ------
    InsufficientDataError
        Too little data, or an absolute fit without two added masses.
    """
    t_start = time.perf_counter()
    data = [data] if isinstance(data, GreyBoxData) else list(data)
    model = model or linear_model()
    prob = GreyBoxProblem(model, data, absolute=absolute, fixed=fixed,
                          body_mass_kg=body_mass_kg, fit_initial_state=fit_initial_state,
                          substeps=substeps, mass_bounds_kg=mass_bounds_kg)
    initial = dict(initial or {})
    th0, m0 = prob.equation_error_start()
    if prob.absolute:
        m_init = initial.get("body_mass_kg", prob.fixed_mass or m0 or body_mass_kg or 380.0)
        m_init = float(m_init)
        # equation-error values are per unit mass of the session without added mass
    else:
        m_init = None
    for i, v in _to_unit(model, initial, prob.absolute, m_init).items():
        th0[i] = v
    for i, v in _to_unit(model, fixed or {}, prob.absolute,
                         prob.fixed_mass or m_init).items():
        th0[i] = v
    z0 = prob.pack(th0, m_init)
    prob.start_theta = np.array(th0, dtype=float)
    lo, hi = prob.bounds()
    z0 = np.clip(z0, lo, hi)
    # normalisation: every fitted quantity relative to its start value
    typ_u = model.vector(per_unit_mass_kg=(m_init or body_mass_kg or 380.0))
    scale = np.abs(z0)
    nominal = np.concatenate([typ_u[prob.free_model],
                              [1.0 / (m_init or 1.0)] if prob.has_mass else [],
                              np.tile(_NUISANCE_SCALE, len(data)) if fit_initial_state else []])
    scale = np.where(scale > 1e-6 * np.abs(nominal), scale, np.abs(nominal))
    scale = np.where(scale > 0, scale, 1.0)
    if fit_initial_state:
        scale[prob.nuis_index:] = np.tile(_NUISANCE_SCALE, len(data))

    def fun(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r, j = prob.residual_and_jacobian(q * scale)
        return r, j * scale

    cb = None
    if callback is not None:
        def cb(it: int, q: np.ndarray, cost: float) -> None:
            th, m, _ = prob.unpack(q * scale)
            callback(it, _reported_values(model, th, m), cost)

    q = q0 = z0 / scale
    stages: list[dict[str, Any]] = []
    total_it = total_ev = 0
    if horizons_s is None:
        horizons_s = ()
    can_reset = all(d.body_disp_m is not None and d.body_vel_mps is not None for d in data)
    shortest = min(d.duration_s for d in data)
    for hz in horizons_s if can_reset else ():
        if hz >= 0.5 * shortest:
            break
        prob.horizon_s = float(hz)
        st = solve(solver, fun, q, lo / scale, hi / scale,
                   max_iterations=stage_iterations, xtol=stage_xtol, ftol=stage_xtol)
        q = st.x
        total_it += st.iterations
        total_ev += st.evaluations
        stages.append({"horizon_s": float(hz), "iterations": st.iterations,
                       "cost": float(st.cost)})
    prob.horizon_s = None
    if stages:
        # the continuation is a way to the answer, not part of it: where it led somewhere
        # the whole simulation fits worse than the start, the last stage begins at the start
        cost_start, cost_led = (_simulation_cost(prob, v * scale) for v in (q0, q))
        if cost_start < cost_led:
            q = q0
            stages.append({"horizon_s": None, "iterations": 0, "cost": cost_start,
                           "restarted_from_start": True})
    out = solve(solver, fun, q, lo / scale, hi / scale,
                max_iterations=max_iterations, xtol=xtol, ftol=ftol, callback=cb)
    stages.append({"horizon_s": None, "iterations": out.iterations, "cost": float(out.cost)})
    out.iterations += total_it
    out.evaluations += total_ev
    z = out.x * scale
    theta_u, mass, nuis = prob.unpack(z)

    if not (np.all(np.isfinite(out.jacobian)) and np.all(np.isfinite(out.residual))):
        # LAPACK's SVD would loop on the non-finite values instead of failing
        raise np.linalg.LinAlgError(
            f"the model does not run at its start values ({out.message})")
    # ---- covariance (sandwich per session, summed), in z units
    jz = out.jacobian / scale  # d r / d z
    bmat = np.zeros((jz.shape[1], jz.shape[1]))
    white = np.zeros_like(bmat)
    lags = []
    for sl, pr in zip(prob.session_slices(), prob._prep, strict=True):
        band = pr.data.band_hz
        min_lag = 0 if band is None else int(round(2.0 * pr.data.sample_rate_hz / band[0]))
        b_s, w_s, lag = _hac_meat(jz[sl], out.residual[sl], min_lag=min_lag)
        bmat += b_s
        white += w_s
        lags.append(lag / pr.data.sample_rate_hz)
    normal = (jz.T @ jz) * np.outer(scale, scale)
    if not (np.all(np.isfinite(normal)) and np.all(np.isfinite(bmat))):
        # an overflowing Jacobian (a model at an extreme of its bounds): LAPACK's SVD
        # would loop on it instead of failing
        raise np.linalg.LinAlgError("the fit ended where the model's sensitivities "
                                    "overflow; its uncertainty cannot be computed")
    ainv = np.linalg.pinv(normal) * np.outer(scale, scale)
    cov_z = ainv @ _psd_clip(bmat) @ ainv
    cov_white = ainv @ white @ ainv

    result = _build_result(prob, out, z, theta_u, mass, nuis, cov_z, cov_white, lags)
    result.uncertainty["stages"] = stages
    if validation:
        result.sessions.extend(validate_greybox(result, validation, substeps=substeps))
    result.wall_time_s = time.perf_counter() - t_start
    return result


def _simulation_cost(prob: GreyBoxProblem, z: np.ndarray) -> float:
    """Half the sum of squares of the whole simulation's residual at ``z`` (inf where it
    does not run)."""
    with np.errstate(all="ignore"):
        try:
            r = prob.residual(z)
        except (FloatingPointError, np.linalg.LinAlgError):
            return np.inf
    cost = 0.5 * float(r @ r)
    return cost if np.isfinite(cost) else np.inf


def _reported_values(model: ForceModel, theta_u: np.ndarray, mass: float | None
                     ) -> dict[str, float]:
    vals = {}
    for i, key in enumerate(model.param_keys):
        vals[key] = float(theta_u[i] * mass if (mass and model.force_scaled[i]) else theta_u[i])
    if mass is not None:
        vals["body_mass_kg"] = float(mass)
    return vals


def _build_result(prob: GreyBoxProblem, out: LMOutcome, z: np.ndarray, theta_u: np.ndarray,
                  mass: float | None, nuis: np.ndarray, cov_z: np.ndarray,
                  cov_white: np.ndarray, lags: list[float]) -> GreyBoxResult:
    model = prob.model
    p = model.n_params
    nf = prob.free_model.size
    # Reported vector y = g(z_model_part): absolute values (theta_u * M) and M, or theta_u.
    # Jacobian T = dy / dz over the fitted non-nuisance entries.
    n_rep = p + (1 if prob.absolute else 0)
    t = np.zeros((n_rep, prob.n_fit))
    y = np.empty(n_rep)
    for i in range(p):
        sc = prob.absolute and model.force_scaled[i]
        y[i] = theta_u[i] * mass if sc else theta_u[i]
        pos = np.flatnonzero(prob.free_model == i)
        if pos.size:
            t[i, pos[0]] = mass if sc else 1.0
            if sc and prob.has_mass:  # y = theta_u / rho, rho = 1/M fitted
                t[i, nf] = -theta_u[i] * mass * mass
    if prob.absolute:
        y[p] = mass
        if prob.has_mass:
            t[p, nf] = -mass * mass
    cov_y = t @ cov_z @ t.T
    cov_yw = t @ cov_white @ t.T
    std = np.sqrt(np.maximum(np.diag(cov_y), 0.0))
    fixed_mask = np.array([i in prob.fixed_values for i in range(p)]
                          + ([prob.fixed_mass is not None] if prob.absolute else []))
    std[fixed_mask] = 0.0
    lo, hi = prob.bounds()
    at_bound_z = (z <= lo) | (z >= hi)
    params: list[ParameterEstimate] = []
    keys, terms = model.param_keys, model.param_terms
    for i, spec in enumerate(model.specs):
        absn = prob.absolute
        name = spec.name if (absn or not spec.scales_with_force) else spec.per_unit_mass_name()
        unit = spec.unit if (absn or not spec.scales_with_force) else spec.per_unit_mass_unit()
        pos = np.flatnonzero(prob.free_model == i)
        params.append(ParameterEstimate(
            name=name, key=keys[i], term=terms[i], unit=unit, value=float(y[i]),
            std=float(std[i]), rel_std_pct=_rel(std[i], y[i]), fixed=bool(fixed_mask[i]),
            at_bound=bool(pos.size and at_bound_z[pos[0]]), label=spec.label))
    if prob.absolute:
        params.append(ParameterEstimate(
            name="body_mass_kg", key="body_mass_kg", term="body", unit="kg", value=float(mass),
            std=float(std[p]), rel_std_pct=_rel(std[p], mass), fixed=bool(fixed_mask[p]),
            at_bound=bool(prob.has_mass and at_bound_z[nf]), label="sprung mass"))
    free_rep = np.flatnonzero(~fixed_mask)
    sub = cov_y[np.ix_(free_rep, free_rep)]
    d = np.sqrt(np.maximum(np.diag(sub), 1e-300))
    corr = sub / np.outer(d, d)
    # per unit mass values and their std (what the on-line estimator sees)
    t_u = np.zeros((p, prob.n_fit))
    for i in range(p):
        pos = np.flatnonzero(prob.free_model == i)
        if pos.size:
            t_u[i, pos[0]] = 1.0
    std_u = np.sqrt(np.maximum(np.diag(t_u @ cov_z @ t_u.T), 0.0))
    inflation = {}
    dw = np.diag(cov_yw)
    for i in free_rep:
        if dw[i] > 0:
            inflation[params[i].name] = float(cov_y[i, i] / dw[i])
    sessions = []
    for s, (sl, pr) in enumerate(zip(prob.session_slices(), prob._prep, strict=True)):
        res = out.residual[sl]
        sessions.append(SessionFit(
            name=pr.data.name, role="fit", added_mass_kg=float(pr.data.added_mass_kg),
            samples=int(pr.data.n_samples), duration_s=float(pr.data.duration_s),
            sample_rate_hz=float(pr.data.sample_rate_hz), nrmse=nrmse(res, pr.measured),
            residual_rms_mps2=float(np.sqrt(np.mean(res**2))),
            initial_offset_m=float(nuis[s, 0]), initial_velocity_mps=float(nuis[s, 1])))
    bands = [pr.data.band_hz for pr in prob._prep]
    band = None if bands[0] is None else [float(bands[0][0]), float(bands[0][1])]
    return GreyBoxResult(
        model=model.to_dict(),
        mode="absolute" if prob.absolute else "per_unit_mass",
        parameters=params,
        correlation=corr.tolist(),
        correlation_names=[params[i].name for i in free_rep],
        per_unit_mass={k: float(v) for k, v in zip(keys, theta_u, strict=True)},
        per_unit_mass_std={k: float(v) for k, v in zip(keys, std_u, strict=True)},
        sessions=sessions,
        iterations=out.iterations,
        model_evaluations=out.evaluations,
        converged=out.converged,
        message=out.message,
        cost_history=[float(c) for c in out.cost_history],
        band_hz=band,
        uncertainty={
            "method": "sandwich A^-1 B A^-1 with the residual autocovariance under a flat-top "
                      "lag window (HAC), per session",
            "lag_window_s": lags,
            "variance_inflation_over_white": inflation,
            "residuals": int(out.residual.size),
        },
    )


def _rel(std: float, value: float) -> float:
    return float(100.0 * std / abs(value)) if value != 0 else math.inf


def validate_greybox(result: GreyBoxResult, data: Sequence[GreyBoxData], *,
                     substeps: int = 1) -> list[SessionFit]:
    """NRMSE of a fitted model on data not used in the fit (see :func:`validation_runs`).

    Parameters
    ----------
    result : GreyBoxResult
        A fit.
    data : sequence of GreyBoxData
        Held-out sessions; only their initial body offset and velocity are fitted.
    substeps : int
        RK4 steps per sample interval.

    Returns
    -------
    list of SessionFit
        One per session, ``role="validation"``, with NRMSE and residual RMS [m/s^2].
    """
    return [run[0] for run in validation_runs(result, data, substeps=substeps)]


def validation_runs(result: GreyBoxResult, data: Sequence[GreyBoxData], *,
                    substeps: int = 1
                    ) -> list[tuple[SessionFit, np.ndarray, np.ndarray, np.ndarray]]:
    """NRMSE of a fitted model on data not used in the fit.

    Only each session's initial body offset and velocity are fitted (they are not model
    parameters); the model parameters stay as fitted.

    Parameters
    ----------
    result : GreyBoxResult
        A fit (absolute or per unit mass).
    data : sequence of GreyBoxData
        Held-out segments or drives. In per-unit-mass mode their added mass must equal the
        fit data's.
    substeps : int
        RK4 steps per sample interval.

    Returns
    -------
    list of (SessionFit, measured, residual, time_s)
        One per session, ``role="validation"``, with the band-limited measured body
        acceleration, the residual (measured - simulated) and the recording time of each
        residual sample (edges trimmed by the band filter are left out).

    Raises
    ------
    FieldDiagError
        A per-unit-mass fit validated on data with another added mass.
    """
    model = ForceModel.from_dict(result.model)
    theta_u = np.array([result.per_unit_mass[k] for k in model.param_keys])
    absolute = result.mode == "absolute"
    mass = result.body_mass_kg
    fit_dm = {round(s.added_mass_kg, 9) for s in result.fit_sessions()}
    out = []
    for d in data:
        if not absolute and round(d.added_mass_kg, 9) not in fit_dm:
            raise FieldDiagError(
                f"{d.name}: added mass {d.added_mass_kg:g} kg differs from the fit data; a "
                "per-unit-mass fit can only be validated on data with the same mass")
        if absolute:
            # per unit of the session's total mass M + dM, loaded by dM g
            m_tot = mass + d.added_mass_kg
            unit = np.where(model.force_scaled, theta_u * mass / m_tot, theta_u)
            guess = mass
        else:
            unit, guess = theta_u, None
        prob = GreyBoxProblem(model, [d], absolute=False,
                              fixed=dict(zip(model.param_keys, unit, strict=True)),
                              body_mass_kg=guess, substeps=substeps)
        sc = _NUISANCE_SCALE

        def fun(q: np.ndarray, _p: GreyBoxProblem = prob) -> tuple[np.ndarray, np.ndarray]:
            r, j = _p.residual_and_jacobian(q * _NUISANCE_SCALE)
            return r, j * _NUISANCE_SCALE

        lm = levenberg_marquardt(fun, np.zeros(2), np.full(2, -np.inf), np.full(2, np.inf),
                                 max_iterations=20)
        pr = prob._prep[0]
        out.append((SessionFit(
            name=d.name, role="validation", added_mass_kg=float(d.added_mass_kg),
            samples=int(d.n_samples), duration_s=float(d.duration_s),
            sample_rate_hz=float(d.sample_rate_hz), nrmse=nrmse(lm.residual, pr.measured),
            residual_rms_mps2=float(np.sqrt(np.mean(lm.residual**2))),
            initial_offset_m=float(lm.x[0] * sc[0]), initial_velocity_mps=float(lm.x[1] * sc[1])),
            # the solver's residual is simulated - measured; the runs hold measured - simulated
            np.asarray(pr.measured), -np.asarray(lm.residual),
            d.start_s + (np.arange(len(lm.residual)) + (pr.keep.start or 0)) / d.sample_rate_hz))
    return out

