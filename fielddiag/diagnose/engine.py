"""Mismatch diagnosis of a car corner: fit, locate, name, refit, and check on held-out data.

1. **Fit** the linear model (spring, damper, and coupling when significant beside a smooth
   force surface, which takes up the physics the linear model leaves out) to the first
   part of every drive with the grey-box fit: the body simulated from the measured wheel
   motion, compared with the recorded body acceleration in the valid band.
2. **Locate** the residual of that fit: the time windows where it stands out, the band
   where it exceeds the noise, the region of (r, rdot) where the restoring force departs
   from the linear surface.
3. **Name**: every effect of the library is tried against the residual's signature (a
   quick equation-error fit of the model plus that effect on the measured states); the
   most promising effects and their pairs are then fitted with the full grey-box fit.
4. **Choose** on the held-out last part of every drive (:mod:`.selection`): an effect is
   reported only if it predicts unseen data significantly better, with physical values.
   Structure left over that no effect explains is reported as ``unexplained``.
5. **Data problems compete** with the physics (:mod:`.data_hypotheses`): a gain change
   between the drives and a wheel/body time offset are estimated, the drives corrected,
   the models refitted and scored on the same held-out data; clipping competes by
   leaving out what it corrupts. A data problem is reported where it explains the data
   better, beside any finding; it never hides one.
6. **Ride height**: every position-dependent effect is fitted under passive sag (the
   loaded drive moves about the sagged equilibrium) and under a restored ride height
   (self-levelling); the report says which the data support.
"""

from __future__ import annotations

import itertools
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from scipy import optimize

from fielddiag import dsp
from fielddiag.blas import single_threaded_blas
from fielddiag.diagnose import data_checks
from fielddiag.diagnose.clipping import ClippedPeaks
from fielddiag.diagnose.data_hypotheses import (
    DECISIVE_Z,
    GAIN_CHANGE,
    MIN_T_SIGNIFICANT,
    MIN_TIME_OFFSET_S,
    MIN_Z,
    DataHypothesis,
    correct_drives,
    from_transmissibility,
    moved_text,
    residual_scale,
)
from fielddiag.diagnose.data_hypotheses import (
    KINDS as DATA_KINDS,
)
from fielddiag.diagnose.gravity_gain import GravityGain, gain_from_gravity
from fielddiag.diagnose.locate import (
    DepartureMap,
    departure_map,
    excess_band,
    residual_psd,
    residual_windows,
)
from fielddiag.diagnose.selection import (
    MIN_GAIN_PER_PARAM,
    MIN_T,
    CandidateFit,
    Comparison,
    block_log_ratios,
    compare,
    confidence,
    nrmse,
    paired_block_t,
    select_model,
)
from fielddiag.diagnose.shape import fit_shape_model, travel_since_reversal
from fielddiag.diagnose.surface_words import describe_force_surface, describe_memory_surface
from fielddiag.drive import CornerDrive, read_corner_drive
from fielddiag.effects import EFFECTS, ForceModel, diagnosis_effects, get_effect, split_shape
from fielddiag.effects.base import TRAVEL_BOUND_M
from fielddiag.errors import FieldDiagError
from fielddiag.identify.greybox import (
    GreyBoxData,
    default_band_hz,
    fit_greybox,
    validation_runs,
)
from fielddiag.threads import map_threads, thread_budget

#: The effects the diagnosis tries by default when this module was imported (the
#: library's ``diagnosable`` effects; names are part of the JSON interface).
#: :func:`diagnose_drives` asks the registry at each call, so an effect registered later
#: is tried too.
EFFECT_LIBRARY = diagnosis_effects()
GRAVITY = dsp.GRAVITY_MPS2


# ----------------------------------------------------------------------------- inputs
#: One recorded drive as the diagnosis takes it: the wheel and body readings in m/s^2
#: (gravity included) with the label, rate, start and added mass.
Drive = CornerDrive


def read_drive(path: str | os.PathLike, label: str, added_mass_kg: float | None = None) -> Drive:
    """Read the wheel and body channels of a session (by role), refusing gaps.

    :func:`fielddiag.drive.read_corner_drive` with ``require_continuous=True``.

    Parameters
    ----------
    path : str or PathLike
        The session file.
    label : str
        ``before``, ``after`` or ``drive``.
    added_mass_kg : float or None
        Overrides the session's ``added_mass_kg`` attribute [kg].

    Returns
    -------
    Drive

    Raises
    ------
    ChannelNotFoundError, InsufficientDataError, SessionError
        As :func:`~fielddiag.drive.read_corner_drive`.
    """
    return read_corner_drive(path, label=label, added_mass_kg=added_mass_kg,
                             require_continuous=True, purpose="diagnose")


@dataclass
class _Prepared:
    drive: Drive
    full: GreyBoxData
    fit: GreyBoxData
    val: GreyBoxData


def _prepare(drive: Drive, band: tuple[float, float], rate_hz: float, holdout: float) -> _Prepared:
    w, b = dsp.integrate_pair(
        drive.wheel_accel_mps2,
        drive.body_accel_mps2,
        drive.sample_rate_hz,
        band,
        output_rate_hz=rate_hz,
    )
    full = GreyBoxData(
        sample_rate_hz=w.sample_rate_hz,
        wheel_disp_m=w.displacement_m,
        wheel_vel_mps=w.velocity_mps,
        body_accel_mps2=b.acceleration_mps2,
        added_mass_kg=drive.added_mass_kg,
        name=drive.label,
        body_disp_m=b.displacement_m,
        body_vel_mps=b.velocity_mps,
        band_hz=band,
        start_s=drive.start_s,
    )
    fit, val = full.split(1.0 - holdout)
    return _Prepared(drive, full, fit, val)


# ----------------------------------------------------------------------------- fitting
def _model(effects: Sequence[str], coupling: bool) -> ForceModel:
    names = ["linear_spring", "linear_damper"] + (["coupling_spring"] if coupling else [])
    return ForceModel(get_effect(n)() for n in [*names, *effects])


def _effect_params(model: ForceModel, effects: Sequence[str]) -> list[tuple[str, Any]]:
    return [
        (key, spec)
        for key, spec in zip(model.param_keys, model.specs, strict=True)
        if key.split(".")[0] in effects
    ]


@dataclass
class _Fit:
    effects: tuple[str, ...]  # physical effects, then a data hypothesis's kind if any
    result: Any  # GreyBoxResult
    candidate: CandidateFit
    runs: list  # validation runs per drive: (SessionFit, measured, residual, time_s)
    prepared: Sequence[_Prepared] = ()  # the data it was fitted to (corrected ones for data)
    data: DataHypothesis | None = None

    @property
    def physics(self) -> tuple[str, ...]:
        return tuple(e for e in self.effects if e not in DATA_KINDS)

    @property
    def restored(self) -> bool:
        """Fitted with the ride height restored for the loaded drive (self-levelling)."""
        return any(p.fit.ride_height_restored for p in self.prepared)


def _with_ride_height(prepared: Sequence[_Prepared], restored: bool) -> list[_Prepared]:
    """The drives with the loaded ones' ride height restored (or passive sag)."""
    def flag(d: GreyBoxData) -> GreyBoxData:
        return replace(d, ride_height_restored=restored and d.added_mass_kg > 0)
    return [replace(p, fit=flag(p.fit), val=flag(p.val), full=flag(p.full)) for p in prepared]


def _values(result) -> tuple[dict[str, float], dict[str, float]]:
    vals = {p.key: float(p.value) for p in result.parameters}
    stds = {p.key: float(p.std) for p in result.parameters}
    return vals, stds


def _pinned(result, model: ForceModel, effects: Sequence[str]) -> tuple[str, ...]:
    """Effect parameters that are not clearly physical (at a bound, or not significantly
    positive where the effect says so), and effects unphysical as a whole."""
    vals, stds = _values(result)
    out = []
    for key, spec in _effect_params(model, effects):
        v, s = vals.get(key, np.nan), stds.get(key, np.nan)
        if not np.isfinite(v):
            out.append(key)
            continue
        s = s if np.isfinite(s) else 0.0
        if spec.shape:
            # a shape parameter, often loosely determined: only its upper end is telling
            # (there friction's smoothing has turned it into a linear damper Ff / v_s)
            if v >= 0.98 * spec.upper:
                out.append(key)
            continue
        for bound in (spec.lower, spec.upper):
            if np.isfinite(bound) and abs(v - bound) <= max(2.0 * s, 1e-9 * max(1.0, abs(bound))):
                out.append(key)
        if spec.significant and v <= 2.0 * s:
            out.append(key)  # not there (or softening) within its uncertainty
    for t in model.terms:
        if t.name in effects:
            pre = t.name + "."
            own = {k[len(pre):]: v for k, v in vals.items() if k.startswith(pre)}
            own_s = {k[len(pre):]: v for k, v in stds.items() if k.startswith(pre)}
            if t.unphysical(own, own_s):
                out.append(t.name)  # e.g. an asymmetric damper that is symmetric after all
    return tuple(dict.fromkeys(out))


#: A grey-box fit of the diagnosis ends when a step lowers the sum of squared residuals by
#: less than this many times their variance (the chi-square in noise units): what is left
#: moves the parameters by a small fraction of their standard deviation, and the held-out
#: comparisons by a small fraction of what any decision needs, while the last iterations
#: of a fit crawling along a flat valley are most of its time. As a relative tolerance of
#: the cost: this divided by the number of residuals (about 2e-6 for a 2 x 300 s pair at
#: the analysis rate, 1e-5 for 2 x 60 s). FIELDDIAG_FIT_CHI2_STEP overrides it, to measure.
FIT_CHI2_STEP = float(os.environ.get("FIELDDIAG_FIT_CHI2_STEP", "0.1"))


#: A coupling spring is in the model where its estimate is this many standard errors from
#: zero.
COUPLING_MIN_Z = 4.0
_COUPLING_KEY = "coupling_spring.coupling_stiffness_n_per_m"


def _coupling_z(fit: _Fit) -> float:
    """The coupling spring's estimate over its standard error in ``fit``."""
    k3 = fit.candidate.values.get(_COUPLING_KEY, 0.0)
    return abs(k3) / fit.candidate.std.get(_COUPLING_KEY, np.inf)


def _coupling_significant(base: _Fit, prepared: Sequence[_Prepared],
                          mass_bounds_kg: tuple[float, float] | None) -> bool:
    """Whether the coupling spring belongs in every model: where the linear model with it
    (``base``) reads it as significant, or else the force surface fitted with it (the
    linear model, the coupling and a smooth force in travel and speed; :data:`SURFACE`)
    does. The linear model's misfit of physics it leaves out bends the coupling's
    estimate: seed 1795976902, a progressive spring beside a 3148 N/m coupling, the
    linear model read -803 N/m at 3.6 std and it was left out; the surface reads 3581 N/m
    at 18 std. Without it the cubic spring was fitted 12 % low and the surface predicted
    15 % better than it: a shape no named effect describes, for the library's own effect.

    Either suffices, as a spurious coupling costs a parameter fitted near zero and a
    missed one biases every model. On 70 drawn cases (session 48) the two part on 7: the
    surface alone sees one on 2, both true (1004 and 7824 N/m); the linear model alone on
    5 (three true, two of 0 and -169 N/m)."""
    if _coupling_z(base) > COUPLING_MIN_Z:
        return True
    try:
        surface = _grey_fit((SURFACE,), prepared, True, _initial_from(base), 2, mass_bounds_kg)
    except (FieldDiagError, np.linalg.LinAlgError, FloatingPointError):
        return False
    return bool(surface.candidate.physical and _coupling_z(surface) > COUPLING_MIN_Z)


def _coupling_beside_state(physics_fit: _Fit, mass_bounds_kg: tuple[float, float] | None,
                           say: Callable[[str], None]) -> bool:
    """Whether the physics chosen without the coupling spring, where it holds an internal
    state (a top mount, hysteresis: what neither the linear model nor the memoryless force
    surface of :func:`_coupling_significant` describes), reads the coupling at
    :data:`COUPLING_MIN_Z` when fitted with it. Beside soft mounts couplings of 4-10 % of
    the suspension's stiffness were left out of every model and their misfit read as
    0.27-0.38 ms of wheel lag (seeds 1795986445, 1795986494, 1795997634)."""
    if not any(EFFECTS[e].n_states for e in physics_fit.physics):
        return False
    try:
        fit = _grey_fit(physics_fit.physics, physics_fit.prepared, True,
                        _initial_from(physics_fit), 2, mass_bounds_kg)
    except (FieldDiagError, np.linalg.LinAlgError, FloatingPointError):
        return False
    if not (fit.candidate.physical and _coupling_z(fit) > COUPLING_MIN_Z):
        return False
    say(f"  beside {' + '.join(physics_fit.physics)} the coupling spring reads "
        f"{fit.candidate.values[_COUPLING_KEY]:.0f} N/m at {_coupling_z(fit):.1f} std: "
        "every model fitted again with it")
    return True


def _grey_fit(
    effects: Sequence[str],
    prepared: Sequence[_Prepared],
    coupling: bool,
    initial: dict[str, float] | None,
    substeps: int,
    mass_bounds_kg: tuple[float, float] | None = None,
    data: DataHypothesis | None = None,
    fit_parts: Sequence[GreyBoxData] | None = None,
    warm: bool = False,
) -> _Fit:
    """Grey-box fit of the linear model plus ``effects`` on the fit part of every drive
    (or on ``fit_parts``: stretches of them), scored on the held-out part. With a data
    hypothesis, ``prepared`` holds the corrected drives and the held-out residuals are
    returned in the recording's units. ``warm``: ``initial`` is where a fit of the same
    model to nearly the same drives ended, so the continuation over short horizons (a way
    to the answer from afar) is skipped."""
    model = _model(effects, coupling)
    fits = [p.fit for p in prepared] if fit_parts is None else list(fit_parts)
    if initial:
        allowed = set(model.param_keys) | {"body_mass_kg"}
        initial = {k: v for k, v in initial.items() if k in allowed}
    absolute = len({f.added_mass_kg for f in fits}) > 1
    # trial steps of Levenberg-Marquardt may overflow before being rejected: not news
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        result = fit_greybox(fits, model, initial=initial, substeps=substeps, max_iterations=40,
                             ftol=FIT_CHI2_STEP / sum(f.n_samples for f in fits),
                             **({"horizons_s": None} if warm else {}),
                             mass_bounds_kg=mass_bounds_kg if absolute else None)
        runs = validation_runs(result, [p.val for p in prepared], substeps=substeps)
    if data is not None:
        runs = [(sf, meas * k, res * k, t) for i, (sf, meas, res, t) in enumerate(runs)
                for k in [residual_scale(data, i, len(runs))]]
    res_val = np.concatenate([r[2] for r in runs])
    meas_val = np.concatenate([r[1] for r in runs])
    vals, stds = _values(result)
    fit_sessions = result.fit_sessions()
    nr_fit = float(np.sqrt(np.mean([s.nrmse**2 for s in fit_sessions])))
    names = (*effects, *(h.kind for h in data.chain)) if data is not None else tuple(effects)
    cand = CandidateFit(
        effects=names,
        values=vals,
        std=stds,
        nrmse_fit=nr_fit,
        nrmse_validation=nrmse(res_val, meas_val),
        residual_validation=res_val,
        n_params=model.n_params + (len(data.chain) if data is not None else 0),
        at_bound=_pinned(result, model, effects),
        extra={"model": model, "data": data},
        corrections=tuple(h.kind for h in data.chain) if data is not None else (),
    )
    return _Fit(names, result, cand, runs, prepared, data)


def _initial_from(fit: _Fit) -> dict[str, float]:
    vals, _ = _values(fit.result)
    return {k: v for k, v in vals.items() if np.isfinite(v)}


# ----------------------------------------------------------------------------- screening
def _states(p: GreyBoxData) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    r = p.body_disp_m - p.wheel_disp_m
    rdot = p.body_vel_mps - p.wheel_vel_mps
    return r, rdot, p.body_disp_m, p.body_accel_mps2


def _cost(combo: tuple[str, ...]) -> float:
    """A guess of a fit's relative run time, to start the dearest first: effects with
    internal states integrate them (and their sensitivities) on substeps."""
    return 1.0 + sum(4.0 * EFFECTS[e].n_states for e in combo)


def _static_offset(base_vals: dict[str, float], added_mass_kg: float) -> float:
    """Static suspension extension under the added mass for the linear model [m]."""
    k = base_vals.get("linear_spring.suspension_stiffness_n_per_m", np.nan)
    if "body_mass_kg" not in base_vals or not np.isfinite(k) or k <= 0:
        return 0.0
    return -added_mass_kg * GRAVITY / k


@dataclass
class _EquationErrorFit:
    """A model fitted to the body equation on the measured states (fast, for screening)."""

    values: dict[str, float]  # model keys, plus body_mass_kg in pair mode
    residual_validation: np.ndarray


def _equation_error_fit(
    effects: Sequence[str],
    prepared: Sequence[_Prepared],
    coupling: bool,
    absolute: bool,
    start: dict[str, float] | None = None,
    fit_limit_s: float | None = None,
) -> _EquationErrorFit:
    """Fit (M + dM) a2 + dM g = F(r + r0, rdot, x2) on the fit part of every drive (its
    first ``fit_limit_s`` seconds where given), scored on the whole held-out part.

    ``r`` is the measured (integrated, band-limited) suspension extension; ``r0`` the static
    extension of each loaded drive (a free parameter per drive with added mass, fixed by
    the ``dM g`` balance), so nonlinear terms see the travel where they act. In absolute
    mode the mass is fitted too; otherwise everything is per unit mass (M = 1).
    """
    model = _model(effects, coupling)
    start = start or {}
    loaded = [k for k, p in enumerate(prepared) if p.fit.added_mass_kg != 0.0] if absolute else []

    def stack(part: str, limit_s: float | None = None):
        cols = {"r": [], "v": [], "x": [], "a": [], "dm": [], "sess": [], "fs": []}
        for k, p in enumerate(prepared):
            d = getattr(p, part)
            n = None if limit_s is None else max(int(limit_s * d.sample_rate_hz), 1)
            r, rdot, x2, a2 = (v[:n] for v in _states(d))
            cols["r"].append(r)
            cols["v"].append(rdot)
            cols["x"].append(x2)
            cols["a"].append(a2)
            cols["dm"].append(np.full(r.size, d.added_mass_kg))
            cols["sess"].append(np.full(r.size, k))
            cols["fs"].append(np.full(r.size, d.sample_rate_hz))
        return {key: np.concatenate(v) for key, v in cols.items()}

    fit, val = stack("fit", fit_limit_s), stack("val")
    n_th = model.n_params
    th0 = []
    own_start: dict[str, float] = {}
    for t in model.terms:
        own_start.update({f"{t.name}.{k}": v for k, v in t.start_values(fit["r"], start).items()})
    for key, spec in zip(model.param_keys, model.specs, strict=True):
        v = start.get(key)
        if v is None or not np.isfinite(v):
            v = own_start.get(key, spec.typical)
            if not absolute and spec.scales_with_force:
                v = v / 380.0 if key not in start else v
        th0.append(v)
    m0 = start.get("body_mass_kg", 380.0) if absolute else 1.0
    k0 = start.get("linear_spring.suspension_stiffness_n_per_m", 2.4e4)
    r00 = [-prepared[k].fit.added_mass_kg * GRAVITY / max(k0, 1.0) for k in loaded]
    z0 = np.array([*th0, *([m0] if absolute else []), *r00], float)
    # a yield travel or a relaxation time the data cannot resolve is out of reach (as in the
    # grey-box fit): there the states' substeps grow without bound
    lo_th, hi_th = model.resolved_bounds(
        min(p.fit.travel_per_sample_m for p in prepared),
        max(1.0 / p.fit.sample_rate_hz for p in prepared), np.asarray(th0, float),
        per_unit_mass_kg=None if absolute else (1.0, 1e5))
    lo = np.concatenate([lo_th, [1.0] if absolute else [], np.full(len(loaded), -0.5)])
    hi = np.concatenate([hi_th, [1e5] if absolute else [], np.full(len(loaded), 0.5)])
    step = 1e-6 * np.maximum(np.abs(z0), 1.0)
    z0 = np.where(np.isfinite(lo) & (z0 <= lo), lo + step, z0)
    z0 = np.where(np.isfinite(hi) & (z0 >= hi), hi - step, z0)

    def split(z):
        th = z[:n_th]
        m = z[n_th] if absolute else 1.0
        r0 = np.zeros(len(prepared))
        for j, k in enumerate(loaded):
            r0[k] = z[n_th + (1 if absolute else 0) + j]
        return th, m, r0

    def residual(z, d, want_jac=False):
        # in acceleration units: a2 + dM g / (M + dM) - F / (M + dM). (In force units the
        # measured a2 would multiply the fitted mass: errors in variables, and a fit that
        # shrinks the mass to shrink the residual.)
        th, m, r0 = split(z)
        off = r0[d["sess"]]
        f, dst, dth = _path_force(model, d["r"] + off, d["v"], d["x"], th, d["sess"],
                                  d["fs"], want_jac)
        g = GRAVITY if absolute else 0.0
        mt = m + d["dm"]
        e = d["a"] + (d["dm"] * g - f) / mt
        if not want_jac:
            return e
        cols = [-dth / mt[:, None]]
        if absolute:
            cols.append((-(d["dm"] * g - f) / mt**2)[:, None])
        for k in loaded:
            cols.append((-dst[:, 0] / mt * (d["sess"] == k))[:, None])
        return e, np.hstack(cols)

    # the residual and its Jacobian in one pass over the path, kept for the Jacobian call
    # at the same point (with internal states the pass integrates them: the dear part)
    last: dict[str, Any] = {}

    def both(z):
        if "z" not in last or not np.array_equal(last["z"], z):
            last.update(z=np.array(z, copy=True), out=residual(z, fit, True))
        return last["out"]

    sol = optimize.least_squares(
        lambda z: both(z)[0],
        z0,
        jac=lambda z: both(z)[1],
        bounds=(lo, hi),
        x_scale="jac",
        max_nfev=80,
    )
    th, m, _ = split(sol.x)
    values = dict(zip(model.param_keys, (float(v) for v in th), strict=True))
    if absolute:
        values["body_mass_kg"] = float(m)
    return _EquationErrorFit(values, residual(sol.x, val))


def _path_force(model: ForceModel, r: np.ndarray, rdot: np.ndarray, x2: np.ndarray,
                th: np.ndarray, session: np.ndarray, rate_hz: np.ndarray,
                state_jacobian: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The model's force on stacked drives; internal states integrated per drive (from
    rest at its first sample), their parameters' derivatives only if ``state_jacobian``."""
    if model.n_states == 0:
        return model.force(r, rdot, x2, th)
    f = np.empty(r.size)
    dst = np.empty((r.size, 3))
    dth = np.empty((r.size, model.n_params))
    bounds = np.flatnonzero(np.diff(session)) + 1
    for sl in np.split(np.arange(r.size), bounds):
        if sl.size == 0:
            continue
        a, b, c, _ = model.force_along_path(r[sl], rdot[sl], x2[sl], th, float(rate_hz[sl[0]]),
                                            state_jacobian=state_jacobian, follow_rate=True)
        f[sl], dst[sl], dth[sl] = a, b, c
    return f, dst, dth


# ----------------------------------------------------------------------------- result
@dataclass
class Diagnosis:
    """Everything ``fielddiag diagnose`` reports; :meth:`to_dict` is its JSON."""

    mode: str  # "pair" or "single"
    drives: list[Drive]
    band_hz: tuple[float, float]
    baseline: _Fit
    chosen: _Fit
    comparison: Comparison | None
    fits: list[_Fit]
    screening: dict[str, dict[str, float]]
    windows: list[dict]
    excess_band_hz: tuple[float, float] | None
    departure: DepartureMap | None
    region: dict | None
    unexplained: dict | None
    warnings: list[data_checks.DataWarning]
    residual_psd: dict[str, list[float]] = field(default_factory=dict)
    ride_height: dict | None = None  # passive sag vs restored, when an effect acts on position
    linear_inadequate: str | None = None  # words when the linear model is hopeless
    loops: list[dict] = field(default_factory=list)  # restoring force on held-out data
    # data problems that tie with physics that looks like them: told in one
    # ``data_problem_or_physics`` warning, not as a bare data problem
    undecided: frozenset[str] = frozenset()
    # the force surface, where it predicts better than the named effects and is reported
    surface: _Fit | None = None
    # words when the recording cannot show whether physics is missing (clipped readings
    # near most of the held-out data): the verdict is then ``inconclusive``, not adequate
    inconclusive: str | None = None

    @property
    def described(self) -> _Fit:
        """The model that carries the first finding: the chosen one, or the force surface
        (the linear model with it) where only that is reported or it is told before the
        named effects (it predicts better than they do: the traces, loops and held-out
        NRMSE "with the findings" show what it explains, not the closest name's part)."""
        if self.surface is not None and (
                self.chosen is self.baseline
                or (self.unexplained or {}).get("outranks_named")):
            return self.surface
        return self.chosen

    @property
    def verdict(self) -> str:
        """``missing_physics`` when a physical effect is chosen or structure is left;
        ``inconclusive`` when nothing is and the recording cannot show it (the clipped
        readings corrupt most of it); a data problem alone leaves the suspension
        ``adequate``."""
        if bool(self.chosen.physics) or self.unexplained is not None:
            return "missing_physics"
        return "inconclusive" if self.inconclusive else "adequate"

    def data_problems(self) -> list[data_checks.DataWarning]:
        """The data hypotheses the held-out comparison chose, as warnings with sizes.

        Returns
        -------
        list of DataWarning
            ``sensor_gain_changed`` or ``channel_time_offset`` with the value (gain - 1,
            or the body channel's delay [s]), its std and how correcting it moved M/K/C;
            empty when no data problem was chosen.
        """
        if self.chosen.data is None:
            return []
        moved = self.chosen.candidate.extra.get("moved", "")
        out = []
        for hyp in self.chosen.data.chain:
            if hyp.kind == "sensor_gain_changed":
                out.append(data_checks.gain_warning(self.drives[0].label, self.drives[-1].label,
                                                    hyp.value, hyp.std, moved, hyp.evidence))
            else:
                out.append(data_checks.time_offset_warning(hyp.value, hyp.std, moved,
                                                           self._lag_physics(hyp)))
        return out

    def _lag_physics(self, hyp: DataHypothesis) -> str:
        """How the suspension's own lag (an effect whose
        :attr:`~fielddiag.effects.base.Effect.data_twins` hold a time offset: a stiff top
        mount) fared against the late channel ``hyp``, in words; "" where none was fitted.
        """
        chosen = self.chosen
        twins = [f for f in self.fits if f.data is None and f.candidate.physical
                 and set(f.physics) > set(chosen.physics)
                 and any(hyp.kind in EFFECTS[e].data_twins
                         for e in set(f.physics) - set(chosen.physics))]
        if not twins or hyp.value <= 0:
            return ""
        twin = min(twins, key=lambda f: f.candidate.mse_validation)
        t = compare(twin.candidate, chosen.candidate).t  # > 0: the late channel is better
        names = " + ".join(e.replace("_", " ") for e in set(twin.physics) - set(chosen.physics))
        key = "linear_damper.suspension_damping_ns_per_m"
        c = chosen.candidate.values.get(key, self.baseline.candidate.values.get(key))
        size = ""
        if c and self.mode == "pair":
            size = (f" (this lag would be a mount of about {c / hyp.value:.3g} N/m: the "
                    "damping over the delay)")
        return (f"A {names}{size} was fitted instead and predicted the held-out data "
                f"{'worse' if t > 0 else 'as well'} (t = {t:.1f} for the late channel). ")

    def physics_by_share(self) -> tuple[str, ...]:
        """The chosen model's effects, the one whose removal costs the held-out fit most
        first: each is ranked by how much better the whole model predicts than the rest of
        it fitted to the same drives (a top mount 5x the noise floor beside a quadratic
        damping of 40 N s2/m2 it needed a little of was reported quadratic damping first,
        seed 1795989805). In the chosen order where a rest was not fitted."""
        physics = self.chosen.physics
        if len(physics) < 2:
            return physics
        c = self.chosen
        cost = {}
        for e in physics:
            rest = tuple(x for x in physics if x != e)
            alone = [f for f in self.fits if f.physics == rest and f.data is c.data
                     and f.restored == c.restored]
            if not alone:
                return physics
            cost[e] = min(f.candidate.mse_validation for f in alone)
        return tuple(sorted(physics, key=lambda e: -cost[e]))

    def _finding(self, effect: str) -> dict:
        c = self.chosen.candidate
        prefix = effect + "."
        params = {k[len(prefix) :]: v for k, v in c.values.items() if k.startswith(prefix)}
        stds = {k[len(prefix) :]: v for k, v in c.std.items() if k.startswith(prefix)}
        if self.mode == "single":  # per unit sprung mass
            params = {_per_kg(k): v for k, v in params.items()}
            stds = {_per_kg(k): v for k, v in stds.items()}
        params, shape = split_shape(params)
        base = self.baseline.candidate
        explained = 1.0 - c.mse_validation / base.mse_validation
        return {
            "effect": effect,
            "confidence": confidence(self.comparison, explained / max(explained, 0.25)),
            "parameters": params,
            "shape": shape,
            "std": stds,
            "where": self._where(),
            "explanation": explain(effect, params, {} if self.linear_inadequate else base.values,
                                   c.values, self.mode),
        }

    def plot_data(self, max_points: int = 1500) -> dict:
        """Compact arrays for a dashboard: held-out fits, residual spectrum, departure map.

        Parameters
        ----------
        max_points : int
            At most this many samples per held-out trace (every k-th sample kept).

        Returns
        -------
        dict
            ``fit``: per drive ``session``, ``time_s``, ``recorded``, ``simulated_linear``,
            ``simulated_augmented`` (body acceleration [m/s^2], in the band);
            ``residual_psd``: ``freq_hz``, ``psd``, ``noise_psd``; ``departure_map``:
            bin edges in ``r`` [m] and ``rdot`` [m/s], mean force departure [N] and
            counts, or None.
            ``restoring_force``: per drive the held-out suspension travel ``r_m`` [m]
            (from the unloaded ride height, as the linear model places it) against the
            restoring force ``measured`` (mass times acceleration plus the added weight),
            ``linear`` and ``augmented`` (the models' forces; the augmented one shifted by
            the difference its own mass makes to the measured force, so that each
            curve's miss is that model's residual) [N, or N/kg per unit mass].
        """
        fits = []
        aug_runs = {r[0].name: r for r in self.described.runs}
        for sf, measured, residual, t in self.baseline.runs:
            step = max(1, t.size // max_points)
            aug = aug_runs.get(sf.name)
            sim_aug = (aug[1] - aug[2]) if aug is not None else measured - residual
            fits.append(
                {
                    "session": sf.name,
                    "time_s": t[::step].tolist(),
                    "recorded": measured[::step].tolist(),
                    "simulated_linear": (measured - residual)[::step].tolist(),
                    "simulated_augmented": sim_aug[::step].tolist(),
                }
            )
        dmap = None
        if self.departure is not None:
            dmap = {
                "r_edges_m": self.departure.r_edges_m.tolist(),
                "rdot_edges_mps": self.departure.rdot_edges_mps.tolist(),
                "mean": [
                    [None if not np.isfinite(v) else float(v) for v in row]
                    for row in self.departure.mean
                ],
                "count": self.departure.count.tolist(),
            }
        return {"fit": fits, "residual_psd": self.residual_psd, "departure_map": dmap,
                "restoring_force": self.loops}

    def _where(self) -> dict:
        return {
            "band_hz": list(self.excess_band_hz) if self.excess_band_hz else None,
            "time_windows_s": self.windows,
            "region": self.region,
        }

    def to_dict(self) -> dict:
        """The JSON of ``fielddiag diagnose`` (keys in docs/diagnosis.md).

        Returns
        -------
        dict
            Plain JSON-serialisable values, SI units in the key names.
        """
        base = self.baseline.candidate
        findings = [self._finding(e) for e in self.physics_by_share()]
        if self.unexplained is not None:
            # first where a shape that names nothing predicts better than the named effects
            findings.insert(
                0 if self.unexplained.get("outranks_named") else len(findings),
                {**self.unexplained, "where": {**self._where(), **self.unexplained["where"]}}
            )
        # drives that do not behave like one corner with the mass added: a competing
        # hypothesis that a finding (a progressive spring, friction...) explains
        problems = [w for w in self.data_problems() if w.kind not in self.undecided]
        warnings = [w.to_dict() for w in [*self.warnings, *problems]
                    if not (w.kind == "pair_inconsistent" and (findings or problems))]
        # nothing named: the model with the finding is the linear one with the surface
        aug = self.described.candidate
        return {
            "mode": self.mode,
            "verdict": self.verdict,
            "inconclusive": self.inconclusive if self.verdict == "inconclusive" else None,
            "baseline": {"nrmse": base.nrmse_fit, "nrmse_validation": base.nrmse_validation},
            "augmented": {"nrmse": aug.nrmse_fit, "nrmse_validation": aug.nrmse_validation},
            "findings": findings,
            "warnings": warnings,
            "linear_model": _linear_summary(base.values, self.mode),
            "linear_model_std": _linear_summary(base.std, self.mode),
            "augmented_model": _linear_summary(aug.values, self.mode),
            "augmented_model_std": _linear_summary(aug.std, self.mode),
            "band_hz": list(self.band_hz),
            "candidates": [
                {
                    "effects": list(f.effects),
                    "nrmse_validation": f.candidate.nrmse_validation,
                    "t_vs_linear": compare(base, f.candidate).t,
                    "physical": f.candidate.physical,
                    "parameters": {
                        k: v for k, v in f.candidate.values.items() if k.split(".")[0] in f.effects
                    },
                }
                for f in [*self.fits, *([self.surface] if self.surface else [])]
                if f is not self.baseline
            ],
            "screening": self.screening,
            "sessions": [
                {
                    "label": d.label,
                    "name": d.name,
                    "added_mass_kg": d.added_mass_kg,
                    "duration_s": d.wheel_accel_mps2.size / d.sample_rate_hz,
                }
                for d in self.drives
            ],
            "holdout": "last 30 % of every drive",
            "ride_height": self.ride_height,
            "data_problems": [
                {"kind": h.kind, "value": h.value, "std": h.std,
                 "undecided": h.kind in self.undecided}
                for h in (self.chosen.data.chain if self.chosen.data else [])
            ],
            "linear_model_adequate": self.linear_inadequate is None,
            **self.plot_data(),
        }


def _per_kg(name: str) -> str:
    """Per-unit-mass name (parameters that do not scale with force keep their name)."""
    fixed = {p.name for cls in EFFECTS.values() for p in cls.params if not p.scales_with_force}
    return name if name in fixed else f"{name}_per_kg"


def _linear_summary(vals: dict[str, float], mode: str) -> dict[str, float]:
    keys = {
        "linear_spring.suspension_stiffness_n_per_m": "suspension_stiffness_n_per_m",
        "linear_damper.suspension_damping_ns_per_m": "suspension_damping_ns_per_m",
        "coupling_spring.coupling_stiffness_n_per_m": "coupling_stiffness_n_per_m",
        "body_mass_kg": "sprung_mass_kg",
    }
    out = {}
    for k, name in keys.items():
        if k in vals:
            out[name if mode == "pair" or name == "sprung_mass_kg" else _per_kg(name)] = vals[k]
    return out


_LINEAR_NAMES = {
    "linear_damper.suspension_damping_ns_per_m": "damping",
    "linear_spring.suspension_stiffness_n_per_m": "stiffness",
    "body_mass_kg": "sprung mass",
}


def _absorbed(base: dict[str, float], chosen: dict[str, float]) -> str:
    """How the linear fit distorted its own parameters to absorb the effect."""
    parts = []
    for key, label in _LINEAR_NAMES.items():
        b, c = base.get(key), chosen.get(key)
        if b and c and np.isfinite(b) and np.isfinite(c) and abs(b / c - 1) >= 0.03:
            parts.append(f"{100 * (b / c - 1):+.0f} % {label}")
    return ": the linear fit was hiding it as " + ", ".join(parts) if parts else ""


def explain(
    effect: str,
    params: dict[str, float],
    base: dict[str, float],
    chosen: dict[str, float],
    mode: str,
) -> str:
    """A sentence a technician can act on (the effect's own words, see
    :meth:`fielddiag.effects.base.Effect.explain`).

    Parameters
    ----------
    effect : str
        Effect name of the library.
    params : dict
        Its fitted physical parameters (``_per_kg`` names in single-drive mode).
    base, chosen : dict
        Values of the linear fit and of the chosen model (to say what the linear fit was
        hiding); an empty ``base`` says nothing about it.
    mode : {"pair", "single"}

    Returns
    -------
    str
    """
    per = "" if mode == "pair" else " per kg of sprung mass"
    cls = EFFECTS.get(effect)
    if cls is None:
        return effect
    return cls().explain(params, per, _absorbed(base, chosen))


# ----------------------------------------------------------------------------- main
def _data_warnings(drives: Sequence[Drive]) -> list[data_checks.DataWarning]:
    out = []
    for d in drives:
        for ch, x in (
            ("wheel accelerometer", d.wheel_accel_mps2),
            ("body accelerometer", d.body_accel_mps2),
        ):
            for w in (
                data_checks.check_clipping(x, channel=ch, session=d.label),
                data_checks.check_bias_drift(d.time_s, x, channel=ch, session=d.label),
            ):
                if w is not None:
                    out.append(w)
    return out


@dataclass
class _FrequencyDomain:
    """What the linear frequency-domain identification of a pair tells the diagnosis."""

    linear: dict[str, float]  # sprung_mass_kg, stiffness, damping, coupling (SI); {} refused
    warnings: list[data_checks.DataWarning]
    transmissibility: list[dict] = field(default_factory=list)
    band_hz: tuple[float, float] = (0.0, 0.0)
    added_mass_kg: float = 0.0

    def hypotheses(self, start: dict[str, float], gravity: GravityGain | None = None
                   ) -> list[DataHypothesis]:
        """The data hypotheses worth fitting (gain change, time offset), the gain's linear
        fit started from ``start`` (SI values of the linear model) and combined with the
        accelerometers' gravity levels (``gravity``, None: not available)."""
        return from_transmissibility(self.transmissibility, self.band_hz,
                                     self.added_mass_kg, start, gravity)


def _frequency_domain(drives: Sequence[Drive]) -> _FrequencyDomain:
    """Identify the pair in the frequency domain (:func:`fielddiag.identify.identify_recordings`):
    its linear values start the grey-box fit and bound its mass, its transmissibilities
    estimate the data hypotheses (a gain change between the drives, a channel time offset)
    that then compete with the physics."""
    from fielddiag.identify import Recording, identify_recordings
    from fielddiag.identify.pipeline import PAIR_INCONSISTENT

    recs = [
        Recording(
            d.wheel_accel_mps2,
            d.body_accel_mps2,
            d.sample_rate_hz,
            added_mass_kg=d.added_mass_kg,
            label=d.label,
        )
        for d in drives
    ]
    dm = drives[1].added_mass_kg - drives[0].added_mass_kg
    refused = False
    try:
        ident = identify_recordings(recs[0], recs[1], dm)
    except FieldDiagError as exc:
        # Only a lack of excitation is a problem of the data; the linear identification
        # also refuses when the physics is not linear, which is the diagnosis's own subject,
        # or when a data problem (a gain change, a delay) makes the drives look like two
        # cars: its spectra still estimate those
        if "excitation" in str(exc):
            return _FrequencyDomain({}, [data_checks.DataWarning("too_little_excitation",
                                                                 str(exc))])
        try:
            from fielddiag.identify import IdentifyConfig
            ident = identify_recordings(recs[0], recs[1], dm,
                                        config=IdentifyConfig(refuse=False))
        except Exception:  # noqa: BLE001 - no spectra: the physics competes alone
            return _FrequencyDomain({}, [])
        refused = True
    trs = [
        {
            "freq_hz": tr.freq_hz,
            "measured": tr.hv.array(),
            "model": tr.model.array(),
            "coherence": tr.coherence,
            "label": tr.label,
        }
        for tr in ident.transmissibility
    ]
    band = (ident.band_hz.low_hz, ident.band_hz.high_hz)
    linear = {
        k: float(getattr(ident, k).value)
        for k in (
            "sprung_mass_kg",
            "suspension_stiffness_n_per_m",
            "suspension_damping_ns_per_m",
            "coupling_stiffness_n_per_m",
        )
    }
    warnings = [data_checks.DataWarning("pair_inconsistent", w) for w in ident.warnings
                if w.startswith(PAIR_INCONSISTENT) and not refused]
    return _FrequencyDomain({} if refused else linear, warnings, trs, band, dm)


def _linear_start(fd: _FrequencyDomain | None) -> tuple[dict[str, float] | None,
                                                        tuple[float, float] | None]:
    """Start values and sprung-mass range of the linear grey-box fit from the frequency
    domain: the mass may move a factor of 4 either way, never to absurd values."""
    if fd is None or not fd.linear:
        return None, (5.0, 2.0e4)
    m = fd.linear["sprung_mass_kg"]
    if not (np.isfinite(m) and m > 0):
        return None, (5.0, 2.0e4)
    lin = fd.linear
    start = {"body_mass_kg": m,
             "linear_spring.suspension_stiffness_n_per_m": lin["suspension_stiffness_n_per_m"],
             "linear_damper.suspension_damping_ns_per_m": lin["suspension_damping_ns_per_m"]}
    start = {k: v for k, v in start.items() if np.isfinite(v) and v > 0}
    return start, (max(m / 4.0, 1.0), min(m * 4.0, 1e5))


def _linear_hopeless(base: _Fit, bounds: tuple[float, float] | None) -> str | None:
    """Words instead of absurd numbers when the linear model cannot describe the pair."""
    m = base.candidate.values.get("body_mass_kg")
    if m is None:
        return None
    ms = base.candidate.std.get("body_mass_kg", np.nan)
    at_bound = bounds is not None and (m <= bounds[0] * 1.02 or m >= bounds[1] * 0.98)
    vague = not np.isfinite(ms) or ms > 0.5 * m
    if not (at_bound or vague):
        return None
    return (
        "the linear model cannot describe these drives with one sprung mass: the body does "
        "not respond to the added mass the way a linear spring and damper would "
        f"(the fitted mass runs to {'its limit' if at_bound else 'no definite value'}). "
        "Its values are not meaningful; read the suspension from the findings"
    )


def _locate(
    base: _Fit, prepared: Sequence[_Prepared], rate_hz: float
) -> tuple[list[dict], tuple[float, float] | None, dict[str, list[float]]]:
    windows = []
    psds = []
    for (_, _measured, residual, t), p in zip(base.runs, prepared, strict=True):
        for w in residual_windows(t, residual, rate_hz, window_s=1.0, threshold=2.5, max_windows=4):
            windows.append(
                {
                    "session": p.drive.label,
                    "start_s": w.start_s,
                    "end_s": w.end_s,
                    "rms_ratio": w.rms_ratio,
                }
            )
        psds.append(residual_psd(residual, rate_hz))
    windows.sort(key=lambda w: -w["rms_ratio"])
    f = psds[0][0]
    mean_psd = np.mean([np.interp(f, fp, pp) for fp, pp in psds], axis=0)
    # the noise floor of the residual: its level at the top of the band
    band = base.result.band_hz or [f[1], f[-1]]
    top = (f > 0.7 * band[1]) & (f <= band[1])
    noise = float(np.median(mean_psd[top])) if np.any(top) else 0.0
    exb = excess_band(f, mean_psd, 3.0 * noise, band_hz=(band[0], band[1]))
    return (
        windows[:8],
        exb,
        {"freq_hz": f.tolist(), "psd": mean_psd.tolist(), "noise_psd": [noise] * len(f)},
    )


def _model_static_offset(model: ForceModel, th: np.ndarray, load_n: float) -> float:
    """Static suspension extension r0 where the model's force carries ``load_n``."""
    from scipy.optimize import brentq

    if load_n == 0.0:
        return 0.0

    def net(r: float) -> float:
        return model.static_force(r, r, th) - load_n

    try:
        return float(brentq(net, -0.5, 0.5, xtol=1e-7))
    except ValueError:  # no sign change: fall back to the linear estimate
        k = th[model.index("linear_spring.suspension_stiffness_n_per_m")]
        return -load_n / k if k > 0 else 0.0


def _drop(part: GreyBoxData, mask: np.ndarray) -> GreyBoxData:
    """The samples of ``part`` outside ``mask`` (states only: for the departure map)."""
    keep = ~mask
    return replace(part, wheel_disp_m=part.wheel_disp_m[keep],
                   wheel_vel_mps=part.wheel_vel_mps[keep],
                   body_accel_mps2=part.body_accel_mps2[keep],
                   body_disp_m=part.body_disp_m[keep], body_vel_mps=part.body_vel_mps[keep])


#: What the clipped peaks lost is taken out of a part's departure only where it has at
#: least this many samples per shape fitted (else the shapes could fit anything).
LOST_PEAK_SAMPLES_PER_SHAPE = 20


def _travel_force_shapes(peaks: ClippedPeaks, time_s: np.ndarray, vals: dict[str, float]
                         ) -> np.ndarray:
    """The shapes of what ``peaks`` lost in the force read on the measured travel and
    speed at ``time_s``, through the linear spring and damper of ``vals`` (the columns
    that reach ``time_s``)."""
    basis = peaks.travel_force_basis(
        time_s, vals.get("linear_spring.suspension_stiffness_n_per_m", np.nan),
        vals.get("linear_damper.suspension_damping_ns_per_m", np.nan))
    return basis[:, np.any(basis != 0.0, axis=0)]


def _too_many_lost_peaks(fit: _Fit, prepared: Sequence[_Prepared],
                         lost: dict[str, ClippedPeaks]) -> bool:
    """Whether some part of the drives holds fewer than
    :data:`LOST_PEAK_SAMPLES_PER_SHAPE` samples per shape of what its clipped peaks lost:
    then their loss cannot be taken out of the departure (:func:`_lost_peak_force`)."""
    vals = fit.candidate.values
    for p in prepared:
        peaks = lost.get(p.drive.label)
        if peaks is None:
            continue
        for part in (p.fit, p.val):
            t = part.start_s + np.arange(part.n_samples) / part.sample_rate_hz
            n = _travel_force_shapes(peaks, t, vals).shape[1]
            if t.size < LOST_PEAK_SAMPLES_PER_SHAPE * n:
                return True
    return False


def _lost_peak_force(peaks: ClippedPeaks, time_s: np.ndarray, departure: np.ndarray,
                     vals: dict[str, float]) -> np.ndarray:
    """The part of ``departure`` (at ``time_s``) that what the clipped peaks lost
    explains, by least squares on their shapes through the linear spring and damper of
    ``vals`` (zeros where there are no shapes or too few samples for them)."""
    basis = _travel_force_shapes(peaks, time_s, vals)
    if basis.shape[1] == 0 or time_s.size < LOST_PEAK_SAMPLES_PER_SHAPE * basis.shape[1]:
        return np.zeros_like(departure)
    design = np.column_stack([basis, np.ones(time_s.size)])
    scale = np.linalg.norm(design, axis=0)
    coef = np.linalg.lstsq(design / scale, departure, rcond=None)[0] / scale
    return basis @ coef[:-1]


def _departure(
    fit: _Fit, prepared: Sequence[_Prepared], coupling: bool,
    exclude: Callable[[Drive, np.ndarray], np.ndarray] | None = None,
    lost: dict[str, ClippedPeaks] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Equation-error departure of the fitted model on the measured states, all data
    (held-out samples where ``exclude(drive, time_s)`` is True left out): travel, speed,
    departure, held-out flag and a segment number per sample (drive and part).

    With ``lost`` (the drives' clipped peaks) what each lost peak does to the force read
    from the measured travel and speed is fitted in every part and taken out
    (:meth:`ClippedPeaks.travel_force_basis`): a lost wheel peak is a ramp in the
    integrated travel for seconds, a force k dr the map would read as structure."""
    model = fit.candidate.extra["model"]
    vals = fit.candidate.values
    th = np.array([vals.get(k, 0.0) for k in model.param_keys])
    mass = vals.get("body_mass_kg", 1.0)
    rs, vs, ds, is_val, segs = [], [], [], [], []
    for p in prepared:
        peaks = (lost or {}).get(p.drive.label)
        for part, flag in ((p.fit, False), (p.val, True)):
            t = part.start_s + np.arange(part.n_samples) / part.sample_rate_hz
            if exclude is not None and flag:  # held-out samples a data problem corrupts
                drop = exclude(p.drive, t)
                part, t = _drop(part, drop), t[~drop]
            r, rdot, x2, a2 = _states(part)
            g = GRAVITY if "body_mass_kg" in vals else 0.0
            load = 0.0 if part.ride_height_restored else part.added_mass_kg * g
            r = r + _model_static_offset(model, th, load)
            f = model.force_along_path(r, rdot, x2, th, part.sample_rate_hz,
                                       state_jacobian=False)[0]
            dep = (mass + part.added_mass_kg) * a2 + part.added_mass_kg * GRAVITY - f
            if peaks is not None:
                dep = dep - _lost_peak_force(peaks, t, dep, vals)
            rs.append(r)
            vs.append(rdot)
            ds.append(dep)
            is_val.append(np.full(r.size, flag))
            segs.append(np.full(r.size, len(segs)))
    return (np.concatenate(rs), np.concatenate(vs), np.concatenate(ds),
            np.concatenate(is_val), np.concatenate(segs))


#: An unphysical single effect (a parameter pinned at a bound) joins the pairs where it
#: predicts held-out data better than the linear model by this paired-block t.
MIN_T_PINNED_PARTNER = 2.0
#: An effect with internal states gets the full (grey-box) fit only where its equation-
#: error signature beats the linear model on held-out data by this paired-block t (and a
#: pair with one only where its signature beats its better single's by it).
STATEFUL_SCREEN_T = 1.0
#: ... and where the pair's signature gains over its better single's at least this share
#: of what the other effect's signature gains alone over the linear model's (held-out
#: mean square): 0.4 % for Dahl and Bouc-Wen hysteresis together, two models of one loop.
STATEFUL_PAIR_MIN_SHARE = 0.1
#: A pair's signature is fitted on at most this much of each drive's fit part [s] (and
#: scored on the whole held-out part): two effects with internal states may take tens of
#: RK4 substeps a sample (a stiff top mount beside hysteresis: 14 s of a 2 x 300 s
#: diagnosis on 200 s a drive), and a signature only decides whether the pair is fitted.
PAIR_SCREEN_FIT_S = 100.0


def _pair_screen(combo: tuple[str, ...], ee_fits: dict, ee_base: _EquationErrorFit
                 ) -> tuple[float, float]:
    """How a pair's equation-error signature improves on its better single's on held-out
    data: the paired-block t, and the gain in mean square as a share of the other single's
    own gain over the linear model (nan, nan when one of them could not be screened)."""
    pair = ee_fits.get(combo)
    singles = [ee_fits.get((e,)) for e in combo]
    if pair is None or any(s is None for s in singles):
        return float("nan"), float("nan")
    mse = [float(np.mean(s.residual_validation**2)) for s in singles]
    best, other = (singles[0], mse[1]) if mse[0] <= mse[1] else (singles[1], mse[0])
    t = paired_block_t(best.residual_validation, pair.residual_validation)
    own = float(np.mean(ee_base.residual_validation**2)) - other
    gain = min(mse) - float(np.mean(pair.residual_validation**2))
    return t, gain / own if own > 0 else float("inf")


#: The partner found forward from a lead single (:func:`_forward_pairs`) is fitted where
#: the pair's signature beats the lead's by this paired-block t (and by
#: :data:`STATEFUL_PAIR_MIN_SHARE` of what the partner gains alone).
FORWARD_PAIR_T = 2.0


def _forward_pairs(useful: Sequence[_Fit], effects: Sequence[str],
                  paired: set[tuple[str, ...]],
                  screen: Callable[[Sequence[tuple[str, ...]]], None],
                  pair_screen: Callable[[tuple[str, ...]], tuple[float, float]]
                  ) -> list[tuple[tuple[str, ...], float]]:
    """The pairs, beyond the pairs of the best singles, that a forward step from the two
    best singles (passive sag) finds: each joined with every other effect (one of the two
    at most with internal states), its signature screened, and of the pairs without and
    with internal states, the one whose signature beats its lead's most
    (:data:`FORWARD_PAIR_T`, :data:`STATEFUL_PAIR_MIN_SHARE`), with its t. (Signatures of
    hysteresis pairs promise more than their full fits keep: Bouc-Wen beside friction
    t = 9.5 against asymmetric damping's 6.1, and the latter predicted better.)

    A weak effect beside a strong one ranks low alone, so the pairs of the best singles
    miss it: asymmetric damping 12 % apart beside dry friction ranked fifth alone (seed
    1795922758), and a digressive damper, whose per-direction drops stand for both, was
    named; its signature beside the friction's gained t = 6.1."""
    order = list(effects).index
    combos = [tuple(sorted(a.effects + (e,), key=order))
              for a in [f for f in useful if not f.restored and f.candidate.physical][:2]
              for e in effects if e not in a.effects
              and sum(EFFECTS[x].n_states > 0 for x in (*a.effects, e)) <= 1]
    combos = [c for c in dict.fromkeys(combos) if c not in paired]
    screen(combos)
    scored = [(c, t) for c, t, share in ((c, *pair_screen(c)) for c in combos)
              if t >= FORWARD_PAIR_T and share >= STATEFUL_PAIR_MIN_SHARE]
    found = []
    for stateful in (False, True):
        kind = [ct for ct in scored if any(EFFECTS[e].n_states for e in ct[0]) == stateful]
        if kind:
            found.append(max(kind, key=lambda ct: ct[1]))
    return found


#: Structure left in the chosen model's residual is reported as ``unexplained`` only when
#: it is a material part of the mismatch the linear model had: a found effect that removes
#: 95 % of the misfit may leave a few % of shape error (a rounded friction switch) that is
#: not new physics.
UNEXPLAINED_MIN_SHARE_OF_LINEAR_MISFIT = 0.03
#: ... and only where it predicts held-out data surely: the paired-block t of a departure
#: map's held-out prediction, and of the smooth model of the shape that is the finding.
UNEXPLAINED_MIN_T = 4.0


def _linear_trend(r: np.ndarray, v: np.ndarray, force: np.ndarray, on: np.ndarray
                  ) -> np.ndarray:
    """The least-squares plane ``a + b r + c v`` through ``force`` on the samples ``on``,
    evaluated at every sample."""
    basis = np.column_stack([np.ones_like(r), r, v])
    coef = np.linalg.lstsq(basis[on], force[on], rcond=None)[0]
    return basis @ coef


def _unexplained(
    fit: _Fit, prepared: Sequence[_Prepared], coupling: bool, baseline: _Fit | None = None,
    say: Callable[[str], None] = lambda _m: None, known: Sequence[str] = EFFECT_LIBRARY,
    exclude: Callable[[Drive, np.ndarray], np.ndarray] | None = None,
    reason: str | None = None, lost: dict[str, ClippedPeaks] | None = None,
) -> tuple[dict | None, DepartureMap]:
    """Force left that depends on (r, rdot) but that the chosen model does not describe
    (judged on held-out samples outside ``exclude``: what a data problem corrupts).

    With ``reason`` (other evidence that the model misses physics: the linear model
    cannot describe the pair with one sprung mass) the finding is made whatever the
    held-out structure, its shape modelled all the same. ``lost``: the drives' clipped
    peaks, whose loss is taken out of the departure (:func:`_departure`)."""
    r, v, dep, is_val, segments = _departure(fit, prepared, coupling, exclude, lost)
    full_map = departure_map(r, v, dep, bins=12)
    # the decision: does the departure map of the fit part predict the held-out residual?
    # (coarse bins, each with >= 30 samples: structure a short or noisy drive cannot fake)
    # What is linear in travel and speed is left out first: the fitted model's stiffness
    # and damping are its simulation's, while the travel and speed here are read from
    # noisy integrated signals, whose errors tilt the force left along them (low-frequency
    # sensor noise, 1/f, made a linear car's departure 20 % "structure" on the
    # independent simulator's cases: benchmarks/foreign_cases.py). New physics is not a
    # tilt of the linear model's own terms.
    dec = dep - _linear_trend(r, v, dep, ~is_val)
    dmap, gain, t = _map_predicts(r, v, dec, is_val)
    # and over the travel since the motion last reversed: force that depends on the
    # history since the reversal (a damper idle in a free play, a slack mounting) spreads
    # thin over travel and speed, but not over that
    _, gain_rev, t_rev = _map_predicts(travel_since_reversal(r, v, segments), v, dec, is_val)
    since_reversal = gain_rev > gain and t_rev >= UNEXPLAINED_MIN_T
    if since_reversal:
        say(f"  over the travel since each reversal the structure is clearer: "
            f"{100 * gain_rev:.1f} % of the residual (t = {t_rev:.1f}), "
            f"{100 * gain:.1f} % over travel and speed")
        gain, t = gain_rev, t_rev
    share = gain
    if baseline is not None and baseline is not fit:
        share = gain * fit.candidate.mse_validation / baseline.candidate.mse_validation
    if gain > 0:
        say(f"  structure left in the residual: {100 * gain:.1f} % of it (t = {t:.1f}), "
            f"{100 * share:.1f} % of the linear model's misfit")
    else:  # the map of the fitted part predicts the held-out residual no better than zero
        say("  structure left in the residual: none found")
    if reason is None and (t < UNEXPLAINED_MIN_T or gain < 0.08
                           or share < UNEXPLAINED_MIN_SHARE_OF_LINEAR_MISFIT):
        return None, full_map
    reg = dmap.region()
    names = ", ".join(EFFECTS[n].description for n in known if n in EFFECTS)
    # what it is: a smooth model of its shape, fitted on the fit part, scored held out
    vals = fit.candidate.values
    shape = fit_shape_model(r, v, dep, is_val, prepared[0].fit.sample_rate_hz, segments,
                            stiffness_n_per_m=vals.get(
                                "linear_spring.suspension_stiffness_n_per_m"),
                            damping_ns_per_m=vals.get(
                                "linear_damper.suspension_damping_ns_per_m"))
    unit = "N" if "body_mass_kg" in vals else "N/kg"
    words = "; ".join(shape.description)
    if reason is not None:
        return {
            "effect": "unexplained",
            "confidence": float(min(1.0, max(0.5, 2.0 * gain))),
            "parameters": {},
            "where": {"region": reg, "between_drives": True},
            "shape_description": shape.description,
            "model": {**shape.to_dict(), "force_unit": unit},
            "held_out_gain": shape.held_out_gain,
            "explanation": (
                f"{reason[0].upper()}{reason[1:]}. None of the known effects ({names}) "
                "explains it: something in the suspension acts differently with the added "
                "mass on (the car sits lower on its travel: a spring or damper whose "
                f"behaviour changes along the travel). Shape of the force left: {words}. A "
                f"smooth model of that shape is attached (it predicts "
                f"{100 * shape.held_out_gain:.0f} % of the force left on held-out data)"
            ),
        }, full_map
    return {
        "effect": "unexplained",
        "confidence": float(min(1.0, 2.0 * gain)),
        "parameters": {},
        "where": {"region": reg},
        "shape_description": shape.description,
        "model": {**shape.to_dict(), "force_unit": unit},
        "held_out_gain": shape.held_out_gain,
        "explanation": (
            f"{100 * gain:.0f} % of the force the model leaves unexplained depends on "
            + ("the travel since each reversal of the motion and the speed"
               if since_reversal else "suspension travel and speed")
            + f" in a way none of the known effects ({names}) "
            f"describes. Its shape: {words}. A smooth model of that shape is attached "
            f"(it predicts {100 * shape.held_out_gain:.0f} % of the force left on held-out "
            "data); see the departure map for where it acts"
        ),
    }, full_map


def _map_predicts(x: np.ndarray, v: np.ndarray, dec: np.ndarray, is_val: np.ndarray
                  ) -> tuple[DepartureMap, float, float]:
    """A departure map over (``x``, ``v``) of the fit samples, and how well it predicts
    the held-out ones: (map, share of the held-out residual it predicts, paired-block t).
    Coarse bins, each with >= 30 samples: structure a short or noisy drive cannot fake."""
    dmap = departure_map(x[~is_val], v[~is_val], dec[~is_val], bins=12)
    i = np.clip(np.searchsorted(dmap.r_edges_m, x[is_val]) - 1, 0, dmap.mean.shape[0] - 1)
    j = np.clip(np.searchsorted(dmap.rdot_edges_mps, v[is_val]) - 1, 0, dmap.mean.shape[1] - 1)
    pred = np.where(dmap.count[i, j] >= 30, np.nan_to_num(dmap.mean[i, j]), 0.0)
    e = dec[is_val] - np.mean(dec[~is_val])
    t = paired_block_t(e, e - pred)
    return dmap, 1.0 - float(np.mean((e - pred) ** 2) / np.mean(e**2)), t


#: The effect that names no physics (:mod:`fielddiag.effects.force_surface`).
SURFACE = "force_surface"
#: The shape with memory of each reversal that names no physics
#: (:mod:`fielddiag.effects.memory_surface`): what a memoryless surface cannot describe
#: where the force depends on the travel since the last reversal (free play in a damper's
#: mounting, a damper slow to build pressure, a loop of unknown shape).
MEMORY_SURFACE = "memory_surface"
#: The shapes that name no physics, fitted beside the named effects; the one that predicts
#: held-out data best competes with them (:func:`_surface_wins`).
SURFACES = ((SURFACE,), (MEMORY_SURFACE,))


def _surface_label(fit: _Fit) -> str:
    """Words for the shape ``fit`` holds (a memoryless surface or one with memory)."""
    return ("a force with memory of each reversal" if MEMORY_SURFACE in fit.physics
            else "a smooth force surface")


def _best_surface(fits: Sequence[_Fit | None]) -> _Fit | None:
    """The surface fit (of :data:`SURFACES`) that predicts held-out data best among the
    physical ones (else the first fitted)."""
    done = [f for f in fits if f is not None]
    physical = [f for f in done if f.candidate.physical]
    if physical:
        return min(physical, key=lambda f: f.candidate.mse_validation)
    return done[0] if done else None


@dataclass
class _SurfaceWin:
    """A force surface that predicts held-out data better than the named effects."""

    fit: _Fit
    against: _Fit  # the chosen named physics (or the linear model)
    comparison: Comparison


def _surface_wins(surface: _Fit | None, physics_fit: _Fit, base: _Fit,
                  say: Callable[[str], None]) -> _SurfaceWin | None:
    """The force surface against the chosen physics and the linear model: against the
    linear model by the selection's own rule (its extra parameters counted), against
    named physics that passed that rule itself as two explanations are told apart
    (:data:`TWIN_T` standard errors, and the selection's gain for each extra parameter).

    Both then predict better than the linear model; which one describes the recording is
    a choice between two explanations, not a third model added to nothing, and the name
    has no claim to the benefit of the doubt the linear model has: travel-dependent
    damping (seed 1795981380) was named quadratic damping where the surface predicted the
    held-out data 68 % better (NRMSE 0.049 -> 0.028, the floor), at t = 2.3 only because
    the three blocks with the bumps, 12x better, widen the blocks' spread."""
    if surface is None or not surface.candidate.physical:
        return None
    s, ref = surface.candidate, physics_fit.candidate
    vs_ref = compare(ref, s)
    vs_base = compare(base.candidate, s)
    named = " + ".join(physics_fit.physics) or "the linear model"
    t_ref = TWIN_T if physics_fit.physics else MIN_T
    if (vs_ref.t >= t_ref
            and vs_ref.gain() >= MIN_GAIN_PER_PARAM * max(1, s.n_params - ref.n_params)
            and vs_base.beats(s.n_params - base.candidate.n_params)):
        say(f"  {_surface_label(surface)} predicts held-out data better than {named} (NRMSE "
            f"{s.nrmse_validation:.4f} against {ref.nrmse_validation:.4f}, t = "
            f"{vs_ref.t:.1f}): a shape no named effect describes")
        return _SurfaceWin(surface, physics_fit, vs_ref)
    say(f"  {_surface_label(surface)} predicts held-out data no better than {named} (t = "
        f"{vs_ref.t:.1f})")
    return None


def _surface_finding(win: _SurfaceWin, chosen: _Fit, base: _Fit, coupling: bool,
                     say: Callable[[str], None], known: Sequence[str],
                     hopeless: str | None = None) -> dict:
    """The ``unexplained`` finding of a winning force surface: the shape of the force the
    linear model leaves, described in words, first among the findings (``hopeless``: the
    words of a linear model that cannot describe both drives, told first)."""
    s = win.fit.candidate
    gain = 1.0 - s.mse_validation / base.candidate.mse_validation
    reason = hopeless.split(" (")[0] if hopeless else None
    finding, _ = _unexplained(base, base.prepared, coupling, base, say, known=known,
                              reason=reason or f"{_surface_label(win.fit)} predicts "
                                               "better than the named effects")
    names = ", ".join(EFFECTS[n].description for n in known if n in EFFECTS)
    form = win.fit.physics[0]
    vals = {k.split(".", 1)[1]: v for k, v in s.values.items() if k.startswith(form + ".")}
    r, v, _, _, _ = _departure(base, base.prepared, coupling)
    unit = "N" if "body_mass_kg" in s.values else "N/kg"
    memory = form == MEMORY_SURFACE
    if memory:
        damping = next((x for k, x in s.values.items() if k.endswith(".suspension_damping"
                                                                      "_ns_per_m")), None)
        told = describe_memory_surface(vals, r, v, unit, damping)
        what_surface = "A force with memory of each reversal of the motion"
    else:
        told = describe_force_surface(vals, r, v, unit)
        what_surface = "A smooth force surface in travel and speed"
    if told:  # the surface's own shape (the smooth model of the departure stays attached)
        finding["shape_description"] = told
    finding["shape_model_held_out_gain"] = finding["held_out_gain"]
    finding["held_out_gain"] = gain
    words = "; ".join(finding["shape_description"])
    closest = ""
    if chosen.physics:
        what = " + ".join(EFFECTS[e].description for e in chosen.physics)
        closest = (f" The closest named effect, {what}, describes only part of it (it is "
                   "listed after this finding).")
    finding.update(
        confidence=float(min(1.0, max(0.5, confidence(win.comparison, gain)))),
        outranks_named=bool(chosen.physics),
        force_surface={
            "form": "memory_of_reversals" if memory else "travel_and_speed",
            "coefficients_n": {k: x for k, x in vals.items() if k.endswith("_n")},
            **({"memory_travel_m": vals.get("memory_travel_m")} if memory else {}),
            "nrmse_validation": s.nrmse_validation,
            "held_out_gain_over_linear": gain,
            "t_vs_named": win.comparison.t,
        },
        explanation=(
            (f"{reason[0].upper()}{reason[1:]}. " if reason else "")
            + f"{what_surface} predicts held-out data "
            f"{100 * gain:.0f} % better than the linear model (held-out NRMSE "
            f"{base.candidate.nrmse_validation:.3f} -> {s.nrmse_validation:.3f}) and better "
            f"than any named effect ({names}; t = {win.comparison.t:.1f}): the suspension "
            f"does something none of them describes.{closest} Shape of the force the linear "
            f"model leaves: {words}. The surface (it predicts {100 * gain:.0f} % of the "
            "linear model's held-out misfit) and a smooth model of that shape are attached"),
    )
    if reason is None:
        finding["where"] = {k: v for k, v in finding["where"].items()
                            if k != "between_drives"}
    return finding


def _model_force_on(fit: _Fit, part: GreyBoxData) -> tuple[np.ndarray, np.ndarray,
                                                            np.ndarray]:
    """(travel from the unloaded ride height, the measured restoring force, the model's
    force) of a fitted model on one part of a drive (the measured states)."""
    model = fit.candidate.extra["model"]
    vals = fit.candidate.values
    th = np.array([vals.get(k, 0.0) for k in model.param_keys])
    mass = vals.get("body_mass_kg", 1.0)
    g = GRAVITY if "body_mass_kg" in vals else 0.0
    r, rdot, x2, a2 = _states(part)
    load = 0.0 if part.ride_height_restored else part.added_mass_kg * g
    r = r + _model_static_offset(model, th, load)
    f = model.force_along_path(r, rdot, x2, th, part.sample_rate_hz, state_jacobian=False)[0]
    measured = (mass + part.added_mass_kg) * a2 + part.added_mass_kg * g
    return r, measured, f


def _restoring_loops(base: _Fit, chosen: _Fit, prepared: Sequence[_Prepared],
                     max_points: int = 1500) -> list[dict]:
    """Per drive, the held-out restoring force against travel: measured, linear model and
    the model with the findings (see :meth:`Diagnosis.plot_data`)."""
    out = []
    aug_prepared = {p.drive.label: p for p in chosen.prepared}
    for p in prepared:
        r, measured, lin = _model_force_on(base, p.val)
        q = aug_prepared.get(p.drive.label, p)
        r_a, measured_a, aug = _model_force_on(chosen, q.val)
        step = max(1, r.size // max_points)
        n = min(r.size, r_a.size)
        out.append({"session": p.drive.label, "r_m": r[:n:step].tolist(),
                    "measured": measured[:n:step].tolist(), "linear": lin[:n:step].tolist(),
                    "augmented": (aug[:n:step] + (measured[:n:step] - measured_a[:n:step])
                                  ).tolist()})
    return out


def _band_and_rate(
    drives: Sequence[Drive],
    band_hz: tuple[float, float] | None,
    holdout_fraction: float,
    analysis_rate_hz: float,
) -> tuple[tuple[float, float], float]:
    fs = min(d.sample_rate_hz for d in drives)
    n = min(d.wheel_accel_mps2.size for d in drives)
    band = band_hz or default_band_hz(fs, int(n * (1 - holdout_fraction)))
    rate = max(analysis_rate_hz, 4.0 * band[1])
    return band, min(rate, fs)


def known_model_nrmse(
    drives: Sequence[Drive],
    effects: Sequence[str],
    *,
    initial: dict[str, float] | None = None,
    coupling: bool = False,
    band_hz: tuple[float, float] | None = None,
    holdout_fraction: float = 0.3,
    analysis_rate_hz: float = 125.0,
) -> float:
    """Held-out NRMSE of a model whose structure is known, fitted like the candidates.

    With the true effects (and the true values as ``initial``) this is the floor a
    diagnosis can reach on these data: measurement noise plus what the band and the
    analysis rate leave out. Benchmarks divide the linear model's held-out NRMSE by it
    to say how far an effect stands above the noise.

    Parameters
    ----------
    drives : sequence of Drive
        One drive, or a before/after pair (as for :func:`diagnose_drives`).
    effects : sequence of str
        Effect names of :data:`EFFECT_LIBRARY` in the model (empty: the linear model).
    initial : dict or None
        Start values by parameter key (``body_mass_kg`` included in pair mode).
    coupling : bool
        Include the coupling spring.

    Returns
    -------
    float
        Held-out NRMSE of the body acceleration (0 = perfect, 1 = no better than zero).
    """
    drives = list(drives)
    band, rate = _band_and_rate(drives, band_hz, holdout_fraction, analysis_rate_hz)
    prepared = [_prepare(d, band, rate, holdout_fraction) for d in drives]
    fit = _grey_fit(tuple(effects), prepared, coupling, initial, substeps=2)
    return fit.candidate.nrmse_validation


@single_threaded_blas
def diagnose_drives(
    drives: Sequence[Drive],
    *,
    effects: Sequence[str] | None = None,
    band_hz: tuple[float, float] | None = None,
    holdout_fraction: float = 0.3,
    analysis_rate_hz: float = 125.0,
    max_pair_fits: int = 3,
    progress: Callable[[str], None] | None = None,
    workers: int | None = None,
) -> Diagnosis:
    """Diagnose one drive (per unit mass) or a before/after pair (absolute).

    Parameters
    ----------
    drives : sequence of Drive
        One drive, or two with different added masses.
    effects : sequence of str or None
        The candidate effects; None: every ``diagnosable`` effect of the library
        (:func:`fielddiag.effects.diagnosis_effects`).
    band_hz : (lo, hi) or None
        Valid band; default from the sample rate and length.
    holdout_fraction : float
        Last part of every drive held out from the fits and used to choose.
    analysis_rate_hz : float
        The integrated signals are resampled to this rate (>= 4x the band's top).
    max_pair_fits : int
        Grey-box fits of pairs: every single effect is fitted, then pairs of the (at most
        three) singles that predict held-out data best, up to this many.
    progress : callable or None
        Called with a line of text at each step.
    workers : int or None
        Threads for the fits that do not depend on each other (the effects' screenings
        and fits, the pairs, the fits that compete with a data problem); None:
        ``$FIELDDIAG_THREADS``, else one per usable CPU. The result does not depend on
        it. Give 1 where diagnoses already run one per core.

    Returns
    -------
    Diagnosis
        The chosen model, its evidence and the data problems; ``to_dict()`` is the JSON.

    Raises
    ------
    FieldDiagError
        Not one or two drives, or two drives with the same added mass.
    """
    with thread_budget(workers):
        return _diagnose(drives, effects, band_hz, holdout_fraction, analysis_rate_hz,
                         max_pair_fits, progress)


def _diagnose(
    drives: Sequence[Drive],
    effects: Sequence[str] | None,
    band_hz: tuple[float, float] | None,
    holdout_fraction: float,
    analysis_rate_hz: float,
    max_pair_fits: int,
    progress: Callable[[str], None] | None,
    with_coupling: bool = False,
) -> Diagnosis:
    say = progress or (lambda _msg: None)
    drives = list(drives)
    effects = diagnosis_effects() if effects is None else tuple(effects)
    tried = effects
    if len(drives) not in (1, 2):
        raise FieldDiagError("diagnose takes one drive or a before/after pair")
    mode = "pair" if len(drives) == 2 else "single"
    if mode == "pair" and drives[0].added_mass_kg == drives[1].added_mass_kg:
        raise FieldDiagError(
            "both drives have the same added mass; give --added-mass (the mass added for the "
            "second drive) or diagnose one drive at a time"
        )
    band, rate = _band_and_rate(drives, band_hz, holdout_fraction, analysis_rate_hz)
    say("checking the data")
    warnings = _data_warnings(drives)
    fd = _frequency_domain(drives) if mode == "pair" else None
    if fd is not None:
        warnings += fd.warnings
    prepared = [_prepare(d, band, rate, holdout_fraction) for d in drives]
    fit_rate = prepared[0].full.sample_rate_hz

    say("fitting the linear model")
    start, mass_bounds = _linear_start(fd)
    base = _grey_fit((), prepared, True, start, 2, mass_bounds)
    coupling = with_coupling or _coupling_significant(base, prepared, mass_bounds)
    if not coupling:
        base = _grey_fit((), prepared, False, _initial_from(base), 2, mass_bounds)
    hopeless = _linear_hopeless(base, mass_bounds) if mode == "pair" else None
    if hopeless:
        say("  " + hopeless)
        warnings.append(data_checks.DataWarning("linear_model_inadequate", hopeless))
    windows, exband, psd = _locate(base, prepared, fit_rate)

    say("testing each effect against the residual's signature")
    absolute = mode == "pair"
    ee_base = _equation_error_fit((), prepared, coupling, absolute)
    screening: dict[str, dict[str, float]] = {}
    ee_fits: dict[tuple[str, ...], _EquationErrorFit] = {}
    mse_b = float(np.mean(ee_base.residual_validation**2))

    # seconds each signature fit took: the full fits' scheduling order (dearest first) reads
    # them beside the states' count (a knee or a step costs iterations in both)
    screen_s: dict[tuple[str, ...], float] = {}

    def screen_one(combo: tuple[str, ...]) -> tuple[_EquationErrorFit, dict] | None:
        start = dict(ee_base.values)
        for e in combo:
            start.update(ee_fits[(e,)].values if (e,) in ee_fits else {})
        t0 = time.perf_counter()
        try:
            ee = _equation_error_fit(combo, prepared, coupling, absolute, start,
                                     PAIR_SCREEN_FIT_S if len(combo) > 1 else None)
        except (ValueError, np.linalg.LinAlgError):
            return None
        finally:
            screen_s[combo] = time.perf_counter() - t0
        gain = 1.0 - float(np.mean(ee.residual_validation**2)) / mse_b
        t = paired_block_t(ee_base.residual_validation, ee.residual_validation)
        return ee, {"gain": gain, "t": t}

    def screen(combos: Sequence[tuple[str, ...]]) -> None:
        """The equation-error fits of ``combos`` (on threads): their signatures and the
        grey fits' starts. Every single effect is screened; a pair only when it may be
        fitted (the library's pairs grow as its square)."""
        combos = [c for c in dict.fromkeys(combos) if c not in ee_fits]
        for combo, out in zip(combos, map_threads(screen_one, combos, cost=_cost),
                              strict=True):
            if out is not None:
                ee_fits[combo], screening["+".join(combo)] = out

    # beside the library, a smooth force surface that names nothing: where it predicts
    # held-out data better than every named effect, the mismatch is not given the name
    # that fits least badly (fitted with the single effects, never chosen as physics)
    screen([(e,) for e in effects] + list(SURFACES))
    fits = [base]

    def cost(combo: tuple[str, ...]) -> float:
        return _cost(combo) + screen_s.get(combo, 0.0)

    def grey(combo: tuple[str, ...], on: Sequence[_Prepared] = prepared,
             start: dict[str, float] | None = None,
             data: DataHypothesis | None = None, warm: bool = False) -> _Fit | None:
        what = " + ".join(combo) if combo else "the linear model"
        say(f"fitting {what}" + (f" to drives corrected for a {_DATA_LABEL[data.kind]}"
                                 if data is not None else ""))
        if start is None:
            if len(combo) > 1 and combo not in ee_fits:
                screen([combo])
            start = ee_fits[combo].values if combo in ee_fits else _initial_from(base)
        try:
            return _grey_fit(combo, on, coupling, start, 2, bounds_for(data), data, warm=warm)
        except (FieldDiagError, np.linalg.LinAlgError, FloatingPointError) as exc:
            say(f"  {what} could not be fitted: {exc}")
            return None

    gain_bounds: dict[float, tuple[float, float] | None] = {}

    def bounds_for(data: DataHypothesis | None) -> tuple[float, float] | None:
        """The sprung mass's range for a fit to the drives corrected for ``data``. A gain
        change between the drives moves the frequency-domain estimate that bounds it as
        much as the added mass does (a wheel gain 4.9 % down beside 5.3 % of added mass:
        5216 kg for 431, the range from 1304 kg), so drives corrected for one are
        identified again for their own range."""
        gain = next((h for h in (data.chain if data is not None else [])
                     if h.kind == GAIN_CHANGE), None)
        if gain is None or mode != "pair":
            return mass_bounds
        if gain.value not in gain_bounds:
            try:
                own = _linear_start(_frequency_domain(
                    correct_drives(drives, replace(gain, prior=None))))[1]
            except (FieldDiagError, ValueError, np.linalg.LinAlgError, FloatingPointError):
                own = None
            gain_bounds[gain.value] = own or mass_bounds
        return gain_bounds[gain.value]

    # every single effect gets the full fit (started from its signature fit); pairs only
    # of the single effects that predict held-out data better than the linear model
    # passive sag (the contract) and, in pair mode, a ride height restored after the mass
    # was added (self-levelling) compete for every effect that acts on position
    restored_on = _with_ride_height(prepared, True)
    # the data problems the recording suggests (tested against the physics below); an
    # effect that looks like one of them is fitted whatever its signature says
    hypotheses = []
    # the clipped readings (times by drive): a delay is measured away from them
    clipped = _clipped_times(drives)
    any_clipped = any(t.size for t in clipped.values())
    # ... and their runs, whose lost area reaches far into the integrated motion
    lost = {d.label: peaks for d in drives if any_clipped and (
        peaks := ClippedPeaks.of(d.wheel_accel_mps2, d.body_accel_mps2, d.sample_rate_hz,
                                 band, rate, d.start_s)) is not None}
    gravity = gain_from_gravity(drives) if mode == "pair" else None
    if fd is not None:
        lin = fd.linear or {_LINEAR_SI[k]: v for k, v in base.candidate.values.items()
                            if k in _LINEAR_SI}
        hypotheses = fd.hypotheses(lin, gravity)
    if not any(h.kind == "channel_time_offset" for h in hypotheses):
        found = _time_domain_offset(base, clipped)
        if found is not None:
            hypotheses.append(found)
    suggested = {h.kind for h in hypotheses}
    to_fit = []
    for e in effects:
        sig = screening.get(e)
        twin = sorted(suggested & set(EFFECTS[e].data_twins))
        if twin:
            say(f"  {e}: looks like a {_DATA_LABEL[twin[0]]}; fitted to compete with it")
        elif EFFECTS[e].n_states and (sig is None or sig["t"] < STATEFUL_SCREEN_T):
            # an effect with internal states costs one simulation per parameter and step
            # in the full fit: it is fitted where its signature predicts held-out data
            # better than the linear model at all
            say(f"  {e}: its signature does not improve held-out data (t = "
                f"{sig['t'] if sig else float('nan'):.1f}); not fitted")
            continue
        to_fit.append((e,))

    def fit_single(combo: tuple[str, ...], on: Sequence[_Prepared] = prepared,
                   lin: _Fit = base) -> list[_Fit]:
        """``combo`` fitted to the drives ``on`` (corrected for ``lin``'s data problem, if
        any) and, where it acts on position and predicts better than ``lin``, to them with
        the ride height restored too: also where the passive fit is unphysical, which is
        what a wrong ride height does to an effect that acts on position (seed
        1795919950: a self-levelled bump stop fitted under passive sag predicted 5x
        better than the linear model with its mass pinned at 20 t, and a cubic spring was
        named)."""
        f = grey(combo, on, None, lin.data)
        if f is None:
            return []
        if (mode == "pair" and _acts_on_position(f)
                and compare(lin.candidate, f.candidate).t > 0.0):
            fr = grey(combo, _with_ride_height(on, True),
                      _initial_from(f) if f.candidate.physical else None, lin.data)
            if fr is not None:
                return [f, fr]
        return [f]

    done = map_threads(lambda c: [grey(c)] if c in SURFACES else fit_single(c),
                       [*to_fit, *SURFACES], cost=cost)
    surface_fit = _best_surface([out[0] for out in done[-len(SURFACES):]])
    # the shape with memory on the drives as recorded: a lag that changes with amplitude,
    # the rival of a late channel whose delay differs in quiet and lively stretches
    memory_fit = next((out[0] for out in done[-len(SURFACES):]
                       if out and out[0] is not None and MEMORY_SURFACE in out[0].physics),
                      None)
    singles = [f for out in done[:-len(SURFACES)] for f in out]
    fits += singles
    best: dict[tuple[str, ...], _Fit] = {}
    for f in singles:
        known = best.get(f.effects)
        if known is None or f.candidate.mse_validation < known.candidate.mse_validation:
            best[f.effects] = f
    useful = sorted(
        (
            f
            for f in best.values()
            if f.candidate.physical and compare(base.candidate, f.candidate).t > 0.0
        ),
        key=lambda f: f.candidate.mse_validation,
    )[:3]
    # ... and the best unphysical single that predicts clearly better than the linear
    # model: a parameter pinned at a bound is often a second effect the single cannot take
    # up alone (seed 1795919995: asymmetric damping beside quadratic damping, its
    # compression damping pinned; the pair was never fitted and a digressive damper with
    # negative drops named)
    pinned = sorted((f for f in best.values() if not f.candidate.physical
                     and compare(base.candidate, f.candidate).t >= MIN_T_PINNED_PARTNER),
                    key=lambda f: f.candidate.mse_validation)[:1]
    useful += pinned
    pairs = [
        (tuple(sorted(a.effects + b.effects, key=list(effects).index)), a.restored or b.restored)
        for a, b in itertools.combinations(useful, 2)
    ]
    pairs = pairs[:max_pair_fits]
    for combo, t in _forward_pairs(useful, effects, {c for c, _ in pairs}, screen,
                                   lambda c: _pair_screen(c, ee_fits, ee_base)):
        say(f"  {' + '.join(combo)}: its signature adds most to its lead's (t = {t:.1f}); "
            "fitted beside the pairs of the best singles")
        pairs.append((combo, False))
    # a pair with internal states costs its singles' fits together and more (the states'
    # substeps follow the faster of them): fitted where its signature predicts held-out
    # data better than its better single's, by a material part of what the other effect
    # explains alone (two hysteresis models describe the same loop: the second adds
    # nothing)
    screen([combo for combo, _ in pairs if any(EFFECTS[e].n_states for e in combo)])
    to_fit = []
    for combo, restored in pairs:
        if any(EFFECTS[e].n_states for e in combo):
            t_pair, share = _pair_screen(combo, ee_fits, ee_base)
            if t_pair < STATEFUL_SCREEN_T or share < STATEFUL_PAIR_MIN_SHARE:
                say(f"  {' + '.join(combo)}: its signature adds {100 * share:.1f} % of what "
                    f"the second effect explains alone to its better single's (t = "
                    f"{t_pair:.1f}); not fitted")
                continue
        to_fit.append((combo, restored))
    screen([combo for combo, _ in to_fit])
    done = map_threads(lambda cr: grey(cr[0], restored_on) if cr[1] else grey(cr[0]),
                       to_fit, cost=lambda cr: cost(cr[0]))
    fits += [f for f in done if f is not None]
    twins = frozenset(e for e in effects if EFFECTS[e].data_twins)
    physics = select_model(base.candidate, [f.candidate for f in fits[1:]], data_twins=twins)
    physics_fit = next(f for f in fits if f.candidate is physics.chosen)
    if not coupling and _coupling_beside_state(physics_fit, mass_bounds, say):
        # every model again, with the coupling
        return _diagnose(drives, effects, band_hz, holdout_fraction, analysis_rate_hz,
                         max_pair_fits, progress, with_coupling=True)
    surface_wins = _surface_wins(surface_fit, physics_fit, base, say)

    def signature_left(combo: tuple[str, ...], on: Sequence[_Prepared]) -> float:
        """Paired-block t of ``combo``'s equation-error signature against the linear
        model's on the drives ``on`` (inf where either cannot be fitted: not screened)."""
        try:
            lin_ee = _equation_error_fit((), on, coupling, absolute, dict(ee_base.values))
            start = dict(lin_ee.values)
            for e in combo:
                start.update(ee_fits[(e,)].values if (e,) in ee_fits else {})
            ee = _equation_error_fit(combo, on, coupling, absolute, start)
        except (ValueError, np.linalg.LinAlgError):
            return float("inf")
        return paired_block_t(lin_ee.residual_validation, ee.residual_validation)

    def corrected(hyp: DataHypothesis, restored: bool) -> list[_Prepared]:
        """The drives corrected for ``hyp``, prepared, at the ride height ``restored``."""
        return _with_ride_height([_prepare(d, band, rate, holdout_fraction)
                                  for d in correct_drives(drives, hyp)], restored)

    def moved_by(lin: _Fit) -> str:
        """Words for how far correcting the drives moved the linear model's M, K and C
        (``lin``: the linear model fitted to the corrected drives)."""
        return moved_text(_linear_summary(base.candidate.values, mode),
                          _linear_summary(lin.candidate.values, mode))

    def test_data(hyp: DataHypothesis, lin: _Fit | None = None,
                  known: Sequence[_Fit] = ()) -> _Fit | None:
        """Correct the drives for ``hyp`` and refit the linear model (unless ``lin`` is
        its fit to them already) and the physics (but what ``known`` holds: fits to the
        same corrected drives made already)."""
        on = corrected(hyp, physics_fit.restored)
        lin = lin or grey((), on, _initial_from(base), hyp)
        if lin is None:
            return None
        lin.candidate.extra["moved"] = moved_by(lin)
        fits.append(lin)
        if physics_fit is not base:
            # (combo, drives, start, data problem) of the fits that compete, on threads
            refit = [(physics_fit.effects, on, _initial_from(physics_fit), hyp)]
            if any(EFFECTS[e].n_states for e in physics_fit.effects):
                # physics with internal states is fitted to the corrected drives where its
                # signature still beats the corrected linear model's there (as every single
                # effect's must before its full fit): a top mount whose delay the
                # correction took would otherwise be fitted stiff, at its dearest (20-30 s)
                t_left = signature_left(physics_fit.effects, on)
                if t_left < STATEFUL_SCREEN_T:
                    say(f"  {' + '.join(physics_fit.effects)}: its signature does not "
                        f"improve held-out data once the drives are corrected (t = "
                        f"{t_left:.1f}); not fitted to them")
                    refit = []
            if hyp.prior is None and len(physics_fit.effects) > 1:
                # part of the chosen physics may be there only to absorb the data problem
                # (a hysteretic spring takes up a late channel's lag): each part of it is
                # fitted to the corrected drives too, and competes with the whole
                for e in physics_fit.effects:
                    part = tuple(x for x in physics_fit.effects if x != e)
                    if (any(EFFECTS[x].n_states for x in part)
                            and signature_left(part, on) < STATEFUL_SCREEN_T):
                        continue
                    refit.append((part, on, _initial_from(physics_fit), hyp))
            tasks = list(refit)
            if hyp.prior is None:
                # the physics that looks like the data problem competes on top of the
                # chosen physics too (a lag left by a hysteresis model is a time offset
                # or a top mount as much as the lag of a linear car is)
                for e in effects:
                    if hyp.kind not in EFFECTS[e].data_twins or e in physics_fit.effects:
                        continue
                    combo = tuple(sorted(physics_fit.effects + (e,), key=list(effects).index))
                    if any(f.effects == combo and f.data is None for f in fits):
                        continue
                    if len(combo) == 2 and combo in ee_fits:
                        _, share = _pair_screen(combo, ee_fits, ee_base)
                        if share < STATEFUL_PAIR_MIN_SHARE:
                            # its signature adds nothing to the physics' (the lag is not
                            # a mount's): the full fit would not compete
                            say(f"  {' + '.join(combo)}: its signature adds "
                                f"{100 * share:.1f} % to {physics_fit.effects[0]}'s; not "
                                "fitted to compete with the time offset")
                            continue
                    start = _initial_from(physics_fit)
                    near = get_effect(e)().twin_start(hyp.kind, hyp.value, start)
                    start.update({f"{e}.{k}": v for k, v in near.items()})
                    tasks.append((combo, _with_ride_height(prepared, physics_fit.restored),
                                  start if near else None, None))
            screen([t[0] for t in tasks[len(refit):] if t[2] is None and len(t[0]) > 1])
            made = {f.physics for f in known}
            done = list(known) + map_threads(
                lambda t: grey(*t), [t for t in tasks if t[0] not in made],
                cost=lambda t: _cost(t[0]))
            for f in done:
                if f is not None and f.physics == physics_fit.physics and f.data is hyp:
                    f.candidate.extra["moved"] = lin.candidate.extra["moved"]
            fits.extend(f for f in done if f is not None)
        return lin

    def delay_against_physics(hyp: DataHypothesis, against: _Fit | None = None,
                              own_std: bool = False, with_twins: bool = False
                              ) -> tuple[DataHypothesis, _Fit] | None:
        """The channel time offset ``hyp`` (refined against the linear model) refined
        against the physics of ``against`` (the chosen physics by default) instead, less
        what looks like a delay itself (a top mount), and that physics' fit to the drives
        corrected for it; None where the two estimates agree within two standard
        deviations, or the physics cannot be fitted.

        Physics the linear model leaves out pulls a delay measured against it: hysteresis
        lags like a late channel, a bump stop's misfit in its events leans the estimate.

        With ``own_std``, the steps are told by the least-squares std of the delay seen
        against the physics where that is finer than ``hyp``'s, and the estimate carries
        it: for a delay whose first estimate two data problems at once bent (its std from
        a transmissibility's phase, +-2.7 ms; against the physics +-0.2 ms). Not for every
        delay: against physics that leaves a hysteresis's lag (Coulomb friction for Dahl
        friction) the finer std lets that lag through as a late channel (seed 1795884161,
        1.28 +- 0.20 ms where the estimate's own std, 1.07 ms, kept it "the same"; the
        physics on the recorded drives saw more delay there than at the first estimate).

        The steps start at the first estimate or with no correction (the physics fitted to
        the drives as recorded), where the delay the physics still sees is smaller; from
        the latter, with its own std.

        With ``with_twins``, against the whole physics, a top mount included: a mount
        delays the damper's force only, and a late channel every force, so a mount fitted
        to the drives as recorded leaves a late channel beside it in part (1.0 ms of a
        2.74 ms late body channel, seed 1795955142; none where no channel is late). The
        steps then start from the drives as recorded, by their own std: from the first
        estimate they settle where the delay takes up the mount's lag too (8.7 ms there,
        the mount gone soft)."""
        against = against or physics_fit
        phys = tuple(e for e in against.physics
                     if with_twins or hyp.kind not in EFFECTS[e].data_twins)
        if not phys:
            return None
        say(f"refining the {_DATA_LABEL[hyp.kind]} against {' + '.join(phys)}")
        # ... and to the drives as recorded, where it was
        recorded = next((f for f in fits if f.data is None and f.physics == phys
                         and f.restored == against.restored and f.candidate.physical), None)
        # the physics fitted to the drives corrected for ``hyp`` already, where it was
        refined = hyp
        fit = next((f for f in fits if f.data is hyp and f.physics == phys
                    and f.restored == against.restored), None)
        if with_twins:
            # from the drives as recorded only (no fit to the drives corrected for the
            # first estimate: a soft mount is dearest there, and its lag was taken)
            if recorded is None:
                return None
            return delay_profiled(hyp, phys, recorded, against.restored)
        last = None
        std = hyp.std
        for i in range(DELAY_REFINE_STEPS):
            if fit is None or i > 0:
                on = corrected(refined, against.restored)
                # started where the fit to the drives corrected for the last estimate ended
                fit = grey(phys, on, _initial_from(fit or against), refined, warm=True)
            if fit is None or not fit.candidate.physical:
                return None
            seen, seen_std = _residual_delay_s(fit, substeps=2, clipped=clipped,
                                               with_std=True)
            if i == 0 and recorded is not None and not with_twins:
                # the steps start where the delay left is smaller: at the first estimate,
                # or with none (the physics on the drives as recorded). Physics beside two
                # problems can bend the first estimate beyond the linearised steps' reach
                # (-60 ms for a 1.69 ms late wheel channel beside strong friction and a
                # clipped body channel, seed 1795928049: the steps swung between -43 and
                # +13 ms; from the recorded drives' +1.26 ms they settle at 2.05 ms)
                seen0, std0 = _residual_delay_s(recorded, substeps=2, clipped=clipped,
                                                with_std=True)
                if abs(seen0) < abs(seen):
                    # (the estimate refined is then the physics' own, and so is its std:
                    # 1.42 +- 0.11 ms against Coulomb friction for a 1.45 ms late wheel
                    # channel whose first estimate, -0.05 +- 1.13 ms, kept it "the same",
                    # seed 1795922709)
                    refined, fit, seen, seen_std = (replace(hyp, value=0.0), recorded,
                                                    seen0, std0)
                    own_std = True
            if i == 0 and own_std:
                std = min(hyp.std, seen_std)
            step = _delay_step_s(refined.value, seen, last)
            if abs(refined.value + step) > MAX_TIME_OFFSET_S:
                return None  # beyond any channel skew (see refine_delay)
            last = (refined.value, seen)
            # the physics on the drives as recorded sees the delay elsewhere than the first
            # estimate: the steps go on to where the physics sees none, though the first
            # is small (1.96 ms late wheel channel beside Coulomb friction, seed
            # 1795968869: measured 2.87 ms against the linear model, the friction on the
            # recorded drives sees 1.96 and on the corrected drives 0.48 ms, within two
            # std of the first; the steps settle at 2.31 ms)
            disputed = (i == 0 and recorded is not None and not with_twins
                        and abs(seen0 - hyp.value) > 2.0 * std)
            if abs(step) <= (2.0 if i == 0 else DELAY_REFINED_STD) * std and not disputed:
                # (at once within two std of the linear model's estimate: the same)
                break
            refined = replace(refined, value=refined.value + step, std=std,
                              refined_with=phys)
            say(f"  refined against {' + '.join(phys)} to {_data_size(refined)}")
            if refined.z < MIN_Z and abs(refined.value) < abs(refined.value - step):
                # on its way to none and not told from it already: it cannot compete
                break
        else:
            if abs(step) > std:
                return None
            # steps that hover within a std (the delay seen against friction wanders by
            # 0.03 ms about 2.05 ms, seed 1795922709): the estimate stands, to its std
        return (refined, fit) if refined_stands(refined, hyp, std, phys) else None

    def refined_stands(refined: DataHypothesis, hyp: DataHypothesis, std: float,
                       phys: tuple[str, ...]) -> bool:
        """Whether a delay refined against ``phys`` competes: more than two std from the
        first estimate ``hyp`` (else it is the same), and told from none (else the
        physics takes up the whole delay: no data problem left to compete)."""
        if abs(refined.value - hyp.value) <= 2.0 * std:
            return False
        if refined.z < MIN_Z or abs(refined.value) < MIN_TIME_OFFSET_S:
            say(f"  against {' + '.join(phys)} the delay is {_data_size(refined)}: "
                "not told from none")
            return False
        return True

    # shares of a lag between a late channel and a top mount that the profile found
    # but could not tell from the delay alone: (the delay alone, the share's fit, its
    # delay, the comparison of the two), told where the delay alone is chosen
    unsettled: list[tuple[_Fit, _Fit, DataHypothesis, Comparison]] = []

    def delay_profiled(hyp: DataHypothesis, phys: tuple[str, ...], recorded: _Fit,
                       restored: bool, beyond_s: float = 0.0, alone: _Fit | None = None
                       ) -> tuple[DataHypothesis, _Fit] | None:
        """The channel time offset ``hyp`` where the fit of ``phys`` (a top mount among
        it) to the drives corrected for it misfits its fit part least: a profile of the
        fit's cost over the delay (:func:`_profile_minimum`), each point a fit started
        where the nearest one ended (``recorded``: the fit to the drives as recorded).

        A mount's lag takes up a late channel's to first order, so the delay the refitted
        model still sees in its residual is a small part of what is left and steps
        crawl (seed 1795986469, a 2.2 ms mount and a 1.51 ms late body channel: 0.10,
        0.99, 1.02 ... 1.08 ms in six steps, not settled); the cost tells the two apart
        by what they do beyond first order (its minimum there at 1.55 ms, the mount's
        stiffness within 4 % of the truth). None where the share the profile finds does
        not beat the mount alone and the delay alone by the selection's rule, lags
        differently in the quiet and lively halves, lies within two std of the first
        estimate, or is not told from none.

        ``beyond_s`` widens the profile below the estimate (a mount lags the strut's
        force as a late body channel does, so it hides that much of a late wheel
        channel); ``alone``: the delay alone to beat (else the fit of the rest of
        ``phys`` to the drives corrected for the delay alone)."""
        std = min(hyp.std, _residual_delay_s(recorded, substeps=2, clipped=clipped,
                                             with_std=True)[1])
        lo = min(0.0, hyp.value) - 2.0 * std - beyond_s
        hi = max(0.0, hyp.value) + 2.0 * std
        done: dict[float, _Fit] = {0.0: recorded}

        def cost(tau: float) -> float:
            near = done[min(done, key=lambda t: abs(t - tau))]
            h = replace(hyp, value=tau, std=std, refined_with=phys)
            try:
                f = _grey_fit(phys, corrected(h, restored), coupling, _initial_from(near), 2,
                              bounds_for(h), h, warm=True)
            except (FieldDiagError, np.linalg.LinAlgError, FloatingPointError):
                return np.inf
            done[tau] = f
            return f.candidate.nrmse_fit

        say(f"  profiling the fit of {' + '.join(phys)} over the delay "
            f"({1000 * lo:+.2f} to {1000 * hi:+.2f} ms)")
        tau = _profile_minimum(cost, lo, hi, DELAY_REFINED_STD * std)
        fit = done.get(tau)
        if tau is None or fit is None or not fit.candidate.physical:
            return None
        refined = replace(hyp, value=tau, std=std, refined_with=phys)
        say(f"  the fit of {' + '.join(phys)} misfits least at {_data_size(refined)}")
        if abs(tau) < PROFILED_DELAY_FLOOR_S:
            say(f"  within {1000 * PROFILED_DELAY_FLOOR_S:g} ms of none, where a model's own "
                "misfit beside a mount reads as a delay: not told")
            return None
        # a share between the two explanations is told only where it beats each alone by
        # the selection's rule: the mount added to the delay as physics is, the delay
        # added to the mount as a correction is (seed 1795953005: friction and a 1.33 ms
        # late body channel, no mount; the profile's floor, flat between the two, at
        # 0.64 ms beside a mount that took the rest, better than the delay alone at t =
        # 2.2 only)
        # (the delay alone at its best: refined against the rest of the physics already,
        # where it was; else the profile's end)
        rest = {e for e in phys if hyp.kind not in EFFECTS[e].data_twins}
        delay_alone = alone or min(
            (f for f in fits if f.data is not None and f.data.prior is None
             and f.data.kind == hyp.kind and set(f.physics) == rest
             and f.restored == restored and f.candidate.physical),
            key=lambda f: f.candidate.mse_validation, default=done.get(hi))
        if delay_alone is None or delay_alone is fit:
            return None
        vs_mount = compare(recorded.candidate, fit.candidate)
        vs_delay = compare(delay_alone.candidate, fit.candidate)
        told = (vs_mount.beats(1, everywhere=True)
                and vs_delay.beats(fit.candidate.n_params - delay_alone.candidate.n_params))
        say(f"  against {' + '.join(phys)} alone t = {vs_mount.t:.1f}, against the delay "
            f"alone t = {vs_delay.t:.1f}" + ("" if told else ": not told from either"))
        if not told:
            if (vs_mount.beats(1, everywhere=True) and vs_delay.t >= MIN_T_SIGNIFICANT
                    and vs_delay.gain() >= MIN_GAIN_PER_PARAM):
                # better than the delay alone by what a parameter must earn, short of
                # significance: told beside the delay (not where it merely ties, t = 0.0
                # and 1.2 % on seed 1796022340, no mount: the delay is then reported)
                unsettled.append((delay_alone, fit, refined, vs_delay))
            return None
        # a late channel is late by the same in the quiet and the lively stretches; what
        # is left of a lag that changes with amplitude beside the mount belongs to the
        # suspension (free play in the damper's mounting, from the independent simulator,
        # seed 1795907660: quadratic damping + a soft mount + 1.86 ms beat the mount alone
        # at t = 3.2; no channel was late)
        split = _delay_by_amplitude_s(fit, substeps=2, clipped=clipped)
        if split is not None and _halves_apart(split, tau):
            (quiet, _), (lively, _) = split
            say(f"  beside it the channels are {1000 * (tau + quiet):+.2f} ms apart in "
                f"the quieter half and {1000 * (tau + lively):+.2f} ms in the livelier: "
                "a lag that changes with amplitude, not told as a late channel")
            return None
        return (refined, fit) if refined_stands(refined, hyp, std, phys) else None

    behind: dict[int, _Fit | None] = {}

    def physics_behind(lin: _Fit) -> _Fit | None:
        """The physics a data problem hid: on the drives corrected for it (``lin``: the
        linear model fitted to them), every effect whose signature predicts held-out data
        better than the linear model's there is fitted; the one with the lowest held-out
        error among those that beat ``lin`` by the selection's rule (None when none does).
        Looked for once per ``lin``."""
        if id(lin) not in behind:
            behind[id(lin)] = _physics_behind(lin)
        return behind[id(lin)]

    def _physics_behind(lin: _Fit) -> _Fit | None:
        problems = " and the ".join(_DATA_LABEL[h.kind] for h in lin.data.chain)
        say(f"looking for physics behind the {problems}")
        sig = map_threads(lambda e: signature_left((e,), lin.prepared), list(effects),
                          cost=lambda e: _cost((e,)))
        hopeful = [(e,) for e, t in zip(effects, sig, strict=True) if t >= STATEFUL_SCREEN_T]
        if not hopeful:
            return None
        found = [f for out in map_threads(lambda c: fit_single(c, lin.prepared, lin),
                                          hopeful, cost=cost) for f in out]
        fits.extend(found)
        wins = [f for f in found if f.candidate.physical and compare(
            lin.candidate, f.candidate).beats(f.candidate.n_params - lin.candidate.n_params)]
        if not wins:
            return None
        best = min(wins, key=lambda f: f.candidate.mse_validation)
        say(f"  {' + '.join(best.physics)} on the drives corrected for the {problems}")
        return best

    def _mount_beside_delay(lone: _Fit) -> _Fit | None:
        """A late channel's twin (a top mount) beside the delay the chosen ``lone``
        correction holds, by a profile of the mount's fit over the delay
        (:func:`delay_profiled`) that reaches beyond the estimate: a mount lags the strut
        force as a late body channel does, so beside a late wheel channel the two cancel
        in part and the delay read off the phase is the difference (a 2.79 ms late wheel
        channel beside a 1.64 ms mount read as 1.17 ms, the mount's remainder no signature
        found, seed 1795989853). None where no twin is in the library, or the profile's
        share is not told from the delay alone."""
        hyp = next((h for h in lone.data.chain if h.kind == "channel_time_offset"), None)
        twins_of = tuple(e for e in effects if hyp is not None
                         and hyp.kind in EFFECTS[e].data_twins)
        if hyp is None or not twins_of:
            return None
        if hyp is not lone.data:
            # the delay last, the other corrections before it (they commute with it)
            prior = None
            for h in lone.data.chain:
                if h is not hyp:
                    prior = replace(h, prior=prior)
            hyp = replace(hyp, prior=prior)
        phys = twins_of[:1]
        recorded = next((f for f in fits if f.physics == phys and f.data is hyp.prior
                         and f.restored == lone.restored and f.candidate.physical), None)
        if recorded is None:
            # the mount on the drives corrected for the rest of the chain only
            on = (corrected(hyp.prior, lone.restored) if hyp.prior is not None
                  else _with_ride_height(prepared, lone.restored))
            recorded = grey(phys, on, _initial_from(lone), hyp.prior)
            if recorded is None or not recorded.candidate.physical:
                return None
            fits.append(recorded)
        found = delay_profiled(hyp, phys, recorded, lone.restored,
                               beyond_s=max(2.0 * abs(hyp.value), MOUNT_LAG_REACH_S),
                               alone=lone)
        if found is None:
            return None
        refined, fit = found
        fits.append(fit)
        say(f"  a {' + '.join(phys).replace('_', ' ')} beside the "
            f"{_DATA_LABEL[hyp.kind]} refined to {_data_size(refined)}")
        return fit

    def _delay_refined_behind(hidden: _Fit) -> _Fit | None:
        """The physics found behind a lone channel time offset, fitted to the drives
        corrected for the delay refined against it (not against the linear model, whose
        misfit of that physics leaned the estimate: 1.31 ms for a 2.02 ms late wheel
        channel beside a progressive spring, seed 1795973140, its k3 32 % low), where that
        predicts the held-out data better; None where the refinement leaves the delay as
        it was, or predicts no better."""
        hyp = hidden.data
        if hyp is None or hyp.kind != "channel_time_offset" or hyp.prior is not None:
            return None
        again = delay_against_physics(hyp, hidden, own_std=hyp.z >= DECISIVE_Z)
        if again is None:
            return None
        refined, fit = again
        if not _competes(fit) or fit.candidate.mse_validation >= hidden.candidate.mse_validation:
            say(f"  the {_DATA_LABEL[hyp.kind]} refined against {' + '.join(hidden.physics)} "
                f"({_data_size(refined)}) predicts held-out data no better: kept at "
                f"{_data_size(hyp)}")
            return None
        # the linear model on the same corrected drives (what the correction moved)
        lin = grey((), corrected(refined, hidden.restored), _initial_from(base), refined)
        if lin is not None:
            lin.candidate.extra["moved"] = fit.candidate.extra["moved"] = moved_by(lin)
            fits.append(lin)
        fits.append(fit)
        say(f"  with the {_DATA_LABEL[hyp.kind]} refined against "
            f"{' + '.join(hidden.physics)}: {_data_size(refined)}")
        return fit

    def refine_delay(hyp: DataHypothesis) -> tuple[DataHypothesis, _Fit | None]:
        """The channel time offset ``hyp`` refined against the linear model: the
        transmissibility's phase slope is measured against a linear model that absorbed
        part of the delay, so the delay is refined on the fit part of the corrected drives
        (away from clipped readings, where a clipped peak's misfit pulls the linear model
        and hides the delay). Returns the refined delay, the linear model's fit to the
        drives corrected for it where that is the whole drives' (else None: not fitted,
        or the steps did not settle within a quarter std in :data:`DELAY_REFINE_STEPS`)."""
        last = None
        for _ in range(DELAY_REFINE_STEPS):
            on = corrected(hyp, False)  # on passive sag, as the refinement assumes
            clean = _clean_fit_parts(on, clipped) if any_clipped else None
            if clean is None:
                trial = grey((), on, _initial_from(base), hyp)
            else:
                try:
                    trial = _grey_fit((), on, coupling, _initial_from(base), 2,
                                      mass_bounds, hyp, fit_parts=clean)
                except (FieldDiagError, np.linalg.LinAlgError, FloatingPointError):
                    trial = None
            if trial is None:
                break
            seen = _residual_delay_s(trial, substeps=2, clipped=clipped)
            step = _delay_step_s(hyp.value, seen, last)
            last = (hyp.value, seen)
            if abs(step) <= DELAY_REFINED_STD * hyp.std:
                # the linear model on the drives corrected for it is fitted already (on
                # passive sag, as the refinement assumes; on the whole drives)
                return hyp, None if physics_fit.restored or clean is not None else trial
            if abs(hyp.value + step) > MAX_TIME_OFFSET_S:
                # steps that leave the range of a channel skew: no delay they settle at
                # would be one (seed 1795999381: -33, -24, -11, +77 ms, then 3e14 ms
                # beside a wheel channel clipped on 1.3 % of its samples)
                return replace(hyp, value=hyp.value + step), None
            hyp = replace(hyp, value=hyp.value + step)
            say(f"  refined to {_data_size(hyp)}")
        return hyp, None

    def say_if_beyond_a_skew(hyp: DataHypothesis) -> None:
        """Says so where the delay ``hyp`` is beyond a channel skew's range
        (:data:`MAX_TIME_OFFSET_S`): its fits do not compete (:func:`_competes`), though
        the physics may refine it into the range."""
        if abs(hyp.value) > MAX_TIME_OFFSET_S:
            say(f"  a delay of {1000 * hyp.value:+.0f} ms is beyond any channel skew "
                f"({1000 * MAX_TIME_OFFSET_S:g} ms): it does not compete as it is")

    def estimated_again(fit: _Fit, grav: GravityGain | None) -> list[DataHypothesis]:
        """The data hypotheses the transmissibilities of the drives corrected for
        ``fit``'s data problem suggest (the gain's linear fit started from the frequency
        domain's values there, else from ``fit``'s)."""
        fd2 = _frequency_domain(correct_drives(drives, fit.data))
        start = fd2.linear or {_LINEAR_SI[k]: v for k, v in fit.candidate.values.items()
                               if k in _LINEAR_SI}
        return fd2.hypotheses(start, grav)

    def look_behind_chain(lin: _Fit | None) -> None:
        """Where two data problems are corrected together and the physics first chosen
        holds what looks like one of them (a top mount beside a late channel and a gain
        change), that physics was fitted to the corrected drives, not the physics the
        mount stood in for: every effect is looked for behind the two (its fits join the
        selection)."""
        if lin is None or physics_fit is base or not any(
                h.kind in EFFECTS[e].data_twins for h in lin.data.chain
                for e in physics_fit.physics):
            return
        hidden = physics_behind(lin)
        if hidden is not None and lin.data.kind == "channel_time_offset":
            # the delay (last corrected) refined against the physics found behind it
            again = delay_against_physics(lin.data, hidden, own_std=True)
            if again is not None:
                say(f"testing a {_DATA_LABEL[lin.data.kind]} ({_data_size(again[0])}) "
                    f"against {' + '.join(hidden.physics)}")
                test_data(*again[:1], known=again[1:])

    # data problems compete with the physics: each is corrected and the models refitted
    offset_fit = None
    for hyp in hypotheses:
        say(f"testing a {_DATA_LABEL[hyp.kind]} ({_data_size(hyp)}) against the physics")
        converged = None
        if hyp.kind == "channel_time_offset":
            hyp, converged = refine_delay(hyp)
            say_if_beyond_a_skew(hyp)
        lin = test_data(hyp, converged)
        if lin is not None and hyp.kind == "channel_time_offset":
            offset_fit = lin
            if physics_fit is not base:
                # the delay measured against the physics competes too; where the physics
                # holds its twin (a top mount) beside other effects, the delay competes
                # with the mount on the rest of the physics, refined to the fineness the
                # mount's stiffness is fitted to (its own least-squares std): held at the
                # first estimate's, 1.66 +- 0.79 ms for a 1.33 ms late body channel beside
                # friction, it lost to friction + a mount (seed 1795953005)
                twin_beside = (any(hyp.kind in EFFECTS[e].data_twins
                                   for e in physics_fit.physics)
                               and any(hyp.kind not in EFFECTS[e].data_twins
                                       for e in physics_fit.physics))
                again = delay_against_physics(hyp, own_std=twin_beside)
                if again is not None:
                    say(f"testing a {_DATA_LABEL[hyp.kind]} ({_data_size(again[0])}) "
                        "against the physics")
                    test_data(*again[:1], known=again[1:])
            if physics_fit is not base and any(hyp.kind in EFFECTS[e].data_twins
                                               for e in physics_fit.physics):
                # the physics chosen is only what looks like a late channel (a top mount):
                # physics beside a real late channel (a hysteresis's lag, friction) is
                # then taken up by the mount's lag on the drives as recorded, and the
                # delay alone loses to the mount. The physics behind the delay competes,
                # with the delay refined against it, where some other effect fitted to the
                # drives as recorded removed as large a share of the linear model's error
                # as the mount's lead over the delay is of the delay's (a soft mount's lag,
                # which no delay matches, is not looked behind)
                need = 1.0 - physics_fit.candidate.mse_validation / lin.candidate.mse_validation
                other = max((1.0 - f.candidate.mse_validation / base.candidate.mse_validation
                             for f in fits if f.data is None and len(f.physics) == 1
                             and f.candidate.physical
                             and hyp.kind not in EFFECTS[f.physics[0]].data_twins),
                            default=0.0)
                # the delay the mount fitted to the drives as recorded leaves beside it:
                # the channel is late by more than the mount's lag can take (a mount and a
                # late channel together, the delay estimated first took up both)
                beside = delay_against_physics(hyp, physics_fit, with_twins=True)
                if beside is not None:
                    say(f"testing a {_DATA_LABEL[hyp.kind]} ({_data_size(beside[0])}) "
                        f"beside {' + '.join(physics_fit.physics)}")
                    test_data(*beside[:1], known=beside[1:])
                hidden = None
                if other >= need:
                    hidden = physics_behind(lin)
                else:
                    say(f"  {' + '.join(physics_fit.physics)} leaves {100 * need:.0f} % "
                        f"less held-out error than the {_DATA_LABEL[hyp.kind]}, no other "
                        f"effect took that share from the linear model's ({100 * other:.0f}"
                        " %): no physics looked for behind the delay")
                if hidden is not None:
                    # a decisive delay is refined against it by its own least-squares std
                    # (a stiff mount beside it leans less than the transmissibility's
                    # std tells apart: seed 1795895765, 2.57 +- 0.38 ms for 2.02)
                    again = delay_against_physics(hyp, hidden,
                                                  own_std=hyp.z >= DECISIVE_Z)
                    if again is not None:
                        say(f"testing a {_DATA_LABEL[hyp.kind]} ({_data_size(again[0])}) "
                            f"against {' + '.join(hidden.physics)}")
                        test_data(*again[:1], known=again[1:])
    if fd is not None and offset_fit is not None:
        # a gain change hides behind a delay in the transmissibilities: estimated again
        # on the drives corrected for the delay, and tested on top of it
        for g in estimated_again(offset_fit, gravity):
            if g.kind == "sensor_gain_changed":
                g = replace(g, prior=offset_fit.data)
                say(f"testing a {_DATA_LABEL[g.kind]} ({_data_size(g)}) on top of the "
                    "time offset")
                look_behind_chain(test_data(g))
    gain_first = next((f for f in fits if not f.physics and f.data is not None
                       and f.data.prior is None and f.data.kind == "sensor_gain_changed"
                       and f.data.z >= DECISIVE_Z), None)
    if fd is not None and offset_fit is not None and gain_first is not None:
        # and the other way round: physics beside the two throws the delay's estimate off
        # (the transmissibility's phase and the linear model bend to it), while the gravity
        # levels and the transmissibility's level measure the gain whatever the delay:
        # where the gain is decisive, the delay is estimated again on the drives corrected
        # for it, and tested on top of it (seed 1795847530: a hysteretic spring beside a
        # 2.33 ms late body channel and a 3.6 % wheel gain change, a hysteretic spring and
        # a top mount with no word of the delay before; now 2.35 ms, refined against the
        # Bouc-Wen loop found behind the two, and the gain)
        d = next((h for h in estimated_again(gain_first, None)
                  if h.kind == "channel_time_offset"), None) \
            or _time_domain_offset(gain_first, clipped)
        if d is not None:
            d = replace(d, prior=gain_first.data)
            say(f"testing a {_DATA_LABEL[d.kind]} ({_data_size(d)}) on top of the gain "
                "change")
            d, converged = refine_delay(d)
            say_if_beyond_a_skew(d)
            look_behind_chain(test_data(d, converged))
    # a data problem whose refined estimate is within MIN_Z standard deviations of zero is
    # not told from none: its corrected fits do not compete
    sel = select_model(base.candidate, [f.candidate for f in fits[1:] if _competes(f)],
                       data_twins=twins)
    chosen = next(f for f in fits if f.candidate is sel.chosen)
    gain = (_decisive_gain_elsewhere(chosen, physics_fit, fits)
            # a gain that stood on the physics, left out beside a delay refined against
            # it (seed 1795973094: a 4.8 % gain change beside a top mount and a 2.70 ms
            # late body channel; the mount's c and k 65-72 % high without it)
            or _gain_beside_the_data(chosen, physics_fit, fits))
    if gain is not None:
        # a decisive gain change was tested on the physics first chosen, and the selection
        # went on to other physics (a top mount beside it): the gain is the sensor's, not
        # the physics', so the chosen physics is fitted to the drives corrected for it too
        on = corrected(gain, chosen.restored)
        refit = grey(chosen.physics, on, _initial_from(chosen), gain)
        if refit is not None:
            fits.append(refit)
    chosen, rival_note = _decisive_data_problem(chosen, fits)
    if rival_note is not None:
        say("  " + rival_note)
        warnings.append(data_checks.DataWarning("data_problem_or_physics", rival_note))
    twin = _physics_twin(chosen, fits)
    undecided: frozenset[str] = frozenset()
    twin_warning = None
    if twin is not None:
        # a data problem and physics that looks like it predict alike: the better one is
        # kept and the user is told both
        chosen, note, kind = twin
        if chosen.data is not None:
            # the data problem is kept, but not told as one that no suspension produces
            undecided = frozenset({kind})
            note += chosen.candidate.extra.get("moved", "")
        say("  " + note)
        twin_warning = data_checks.DataWarning("data_problem_or_physics", note)
        warnings.append(twin_warning)
        twin_warning = twin_warning if kind == "channel_time_offset" else None
    lag = _lag_not_a_late_channel(chosen, fits, clipped)
    if lag is None:
        lag = _lag_changes_with_amplitude(chosen, fits, clipped, memory_fit)
    share = None if twin is not None or lag is not None else _unsettled_share(chosen, unsettled)
    if share is not None:
        # the delay alone kept, where a top mount beside a smaller delay predicted better
        # by less than a finding must: both told, the delay not as a bare data problem
        undecided = undecided | {"channel_time_offset"}
        say("  " + share)
        warnings.append(data_checks.DataWarning("data_problem_or_physics", share))
    if lag is not None:
        # the delay kept (alone, or as the twin of physics) is the suspension's lag: what
        # was said of it as a data problem is withdrawn
        chosen, note = lag
        undecided = frozenset()
        if twin_warning is not None:
            warnings.remove(twin_warning)
        say("  " + note)
        warnings.append(data_checks.DataWarning("lag_of_the_suspension", note))
        if chosen.data is None and chosen is not physics_fit:
            # the physics on the drives as recorded is now another than the one the
            # shapes competed with: they compete with it (the independent simulator's
            # damper free play, seed 1795952154: a hysteretic spring told alone, the shape
            # with memory predicting 41 % better, NRMSE 0.070 against 0.118)
            surface_wins = _surface_wins(surface_fit, chosen, base, say)
    if chosen.data is not None and not chosen.physics and chosen.candidate.physical:
        # a data problem that acts on every block can hide physics that acts in a few
        # events (a late channel's misfit everywhere, a bump stop's in five bumps): on the
        # drives corrected for it, each effect is screened and fitted again
        hidden = physics_behind(chosen)
        if hidden is not None:
            chosen = _delay_refined_behind(hidden) or hidden
        else:
            chosen = _mount_beside_delay(chosen) or chosen
    if chosen.physics and chosen.physics != physics_fit.physics and chosen.data is not None:
        # a data problem plus physics the uncorrected data did not choose: fine, but say so
        say(f"  with the {_DATA_LABEL[chosen.data.kind]} corrected: "
            f"{' + '.join(chosen.physics)}")
    clip_note = None
    if chosen.physics and any_clipped:
        # the physics against the clipping: both models fitted again away from the
        # clipped readings, and compared there (where the stretches left are too short,
        # the fits on the whole drives are compared away from them)
        say("fitting the linear model and the finding with what the clipped peaks lost "
            "fitted alongside" if lost else
            "fitting the linear model and the finding away from the clipped readings")
        away = _fits_beside_clipping([(), chosen.physics], chosen, coupling, clipped, lost,
                                     mass_bounds)
        pair = away if all(f is not None for f in away) else (base, chosen)
        clip_note = _clipping_competes(*pair, clipped, lost)
    elif chosen is not base and any_clipped:
        clip_note = _clipping_competes(base, chosen, clipped, lost)
    if clip_note is not None:
        say("  " + clip_note[1])
        # clipped peaks can fake physics and a late channel, not a gain change: that is
        # read from each drive's gravity reading too, which lost peaks leave alone
        kept = next((f for f in fits if not f.physics and f.data is not None
                     and f.data.prior is None and f.data.kind == "sensor_gain_changed"
                     and f.data.evidence
                     and any(h.kind == f.data.kind for h in chosen.data.chain)), base) \
            if chosen.data is not None else base
        if not clip_note[0] and chosen.physics:
            # the physics falls to the clipping, not the data problems tested beside it
            # (where the clipped peaks dominate the held-out misfit, physics that absorbs
            # them beat every correction there): each decisive one, the linear model
            # fitted to the drives corrected for it, competes with the clipping on its own
            stands = _data_beside_clipping(base, fits, clipped, lost, coupling,
                                            mass_bounds)
            if stands is not None:
                kept, words = stands
                say("  " + words)
        chosen = chosen if clip_note[0] else kept
        warnings.append(data_checks.DataWarning("clipping_explains", clip_note[1]))
    knee_words = _friction_as_wide_as_the_speeds(chosen)
    if knee_words is not None:
        # a friction switch as wide as the speeds the damper works at is a damper's knee:
        # the same physics with a digressive damper for the friction, where that beats the
        # linear model by the selection's rule
        swapped = tuple(KNEE if e == FRICTION else e for e in chosen.physics)
        knee = None
        # the knee in the friction's place; where that is not physical (a partner pinned
        # at a bound: a bump stop with no gap that stood in for the knee's other side),
        # the knee alone
        for combo in [swapped] + ([(KNEE,)] if len(swapped) > 1 else []):
            start = {k: v for k, v in _knee_start(chosen).items()
                     if "." not in k or k.split(".")[0] in (*combo, *_LINEAR_EFFECTS)}
            # fitted from the friction's curve, and against a fit of it made before (from
            # its signature, which may have settled in a friction-like minimum)
            tried_knee = [f for f in fits if set(f.physics) == set(combo)
                          and f.data is chosen.data and f.restored == chosen.restored]
            tried_knee.append(grey(combo, chosen.prepared, start, chosen.data))
            physical = [f for f in tried_knee if f is not None and f.candidate.physical]
            trial = min(physical, key=lambda f: f.candidate.mse_validation, default=None)
            if trial is not None and compare(
                    base.candidate, trial.candidate).beats(
                    trial.candidate.n_params - base.candidate.n_params):
                knee = trial
                break
        if knee is not None:
            if knee not in fits:
                fits.append(knee)
            chosen = knee
            swapped = knee.physics
            knee_words += f"; the findings are {' + '.join(swapped).replace('_', ' ')}"
        else:
            knee_words += ("; a damper knee could not be fitted within its bounds (knees "
                           "from 0.05 m/s) or fitted no better than the linear model, so the "
                           "finding stays a friction-like force that levels off with speed")
        say("  " + knee_words)
        warnings.append(data_checks.DataWarning("friction_read_as_damper_knee", knee_words))
    if (surface_wins is not None and clip_note is None and chosen.data is None
            and chosen.physics == physics_fit.physics):
        gain_fit = _gain_judged_by_the_surface(chosen, fits, surface_wins.fit, coupling,
                                               mass_bounds, say)
        if gain_fit is not None:
            chosen = gain_fit
    ride = None
    if mode == "pair" and chosen.physics and _acts_on_position(chosen):
        ride, other = _ride_height(chosen, fits, grey, say)
        if other is not None and other not in fits:
            fits.append(other)
    if hopeless and chosen.data is not None:
        # the linear model was hopeless on the drives as recorded; a gain change between
        # them confounds the added mass (seed 1795941194: 1304 kg at its limit, 440 kg
        # for 431 once corrected): where the correction chosen makes it describe the
        # pair, it is not inadequate
        lin = next((f for f in fits if not f.physics and f.data is chosen.data), None)
        if lin is not None and _linear_hopeless(lin, bounds_for(chosen.data)) is None:
            say(f"  on the drives corrected for the {_DATA_LABEL[chosen.data.kind]}, the "
                "linear model describes the pair")
            warnings[:] = [w for w in warnings if w.kind != "linear_model_inadequate"]
            hopeless = None
    say("looking for structure no effect explains")
    surface_reported, base_for_surface = None, base
    if chosen.data is not None and clip_note is None:
        # a data problem chosen (with physics or without): the surface competes on the
        # same corrected drives, against the linear model corrected alike (a correction
        # never hides a shape the library cannot name)
        # (where no linear model was fitted to drives corrected alike, a delay refined
        # against the physics, against the linear model as recorded)
        lin = next((f for f in fits if not f.physics and f.data is chosen.data), None)
        recorded_win = surface_wins
        # the form of surface that predicted best on the drives as recorded
        form = surface_fit.physics if surface_fit is not None else (SURFACE,)
        say(f"fitting {'the force with memory' if MEMORY_SURFACE in form else 'the force surface'}"
            f" to the drives corrected for the {_DATA_LABEL[chosen.data.kind]}")
        try:
            corrected = _grey_fit(form, chosen.prepared, coupling,
                                  _initial_from(surface_fit if form != (SURFACE,) or lin is None
                                                else lin),
                                  2, mass_bounds, chosen.data)
        except (FieldDiagError, np.linalg.LinAlgError, FloatingPointError):
            corrected = None
        base_for_surface = lin or base
        lag = next((h for h in chosen.data.chain if h.kind == "channel_time_offset"), None)
        without = None if lag is None else _without_delay(chosen, lag, fits)
        if (recorded_win is not None and without is not None
                and not (corrected is not None and corrected.candidate.physical
                         and compare(surface_fit.candidate, corrected.candidate)
                         .beats(1, everywhere=True))):
            # a late channel competes with the shape as it does with named physics: where
            # the shape, which predicted better than the names on the drives as recorded,
            # predicts no better with the delay corrected, and predicts better without it
            # than the names with it (as two explanations are told apart), the delay is the
            # misfit of what the names leave. Free play lags a stroke like a late channel
            # (the independent simulator's seed 1796009222: +4.4 ms told beside a digressive
            # damper and a top mount); a shape with a fraction of a millimetre of memory
            # mimics a late channel too (seed 1796009857: a linear car's 1.1 ms late wheel
            # channel read as "the damping is 1.76e+03 N s/m stronger for the first 0.61 mm
            # after each reversal", t = -27 against the delay's correction)
            against = (_surface_wins(surface_fit, without, base, say)
                       if _surface_wins(surface_fit, chosen, base, lambda _m: None) is not None
                       else None)
            if against is not None:
                note = _lag_note(lag, without, (
                    f"{_surface_label(surface_fit)} predicts held-out data as well without it"
                    f" as with it, and better than "
                    f"{' + '.join(chosen.physics) or 'the linear model'} corrected for it "
                    "(t = "
                    f"{compare(chosen.candidate, surface_fit.candidate).t:.1f}): a lag of the "
                    "suspension the named effects leave, not of the channels"))
                say("  " + note)
                warnings.append(data_checks.DataWarning("lag_of_the_suspension", note))
                chosen, surface_wins, base_for_surface = without, against, base
        if chosen.data is not None and chosen.data.chain and surface_wins is recorded_win:
            # the delay stands (or there is none): the shape on the corrected drives
            surface_wins = _surface_wins(corrected, chosen, base_for_surface, say)
    if surface_wins is not None and (
            (chosen.data is None and chosen.physics == physics_fit.physics)
            or surface_wins.against is chosen):
        unexplained = _surface_finding(surface_wins, chosen, base_for_surface, coupling, say,
                                       tried, hopeless if mode == "pair" else None)
        surface_reported = surface_wins.fit
    else:
        unexplained, _ = _unexplained(chosen, chosen.prepared, coupling, base, say,
                                      known=tried)
    if (unexplained is None and hopeless and not chosen.physics
            and (chosen.data is None or _linear_hopeless(chosen, bounds_for(chosen.data)))):
        # one linear car cannot describe both drives and no effect of the library does:
        # that is missing physics, not an adequate model
        say("  the linear model cannot describe the pair and no effect explains it")
        unexplained, _ = _unexplained(chosen, chosen.prepared, coupling, base, say,
                                      known=tried, reason=hopeless.split(" (")[0])
    too_many_peaks = False
    if unexplained is not None and any(w.kind == "clipping" for w in warnings):
        # clipping competes: is the structure still there away from the clipped readings?
        share = float(_near_clipping(chosen.runs, clipped).mean())
        away = unexplained
        surface_note = None
        if surface_reported is not None and share <= CLIP_DOMINATES:
            # a force surface that predicts better competes with the clipping as physics
            # does: it and the linear model fitted again away from the clipped readings,
            # and compared there (its held-out gain, not the residual's structure, is
            # what it stands on: a strong effect clips the peaks where it acts most)
            say("fitting the linear model and the force surface away from the clipped "
                "readings")
            ref = base_for_surface
            pair = _fits_beside_clipping([(), surface_reported.physics], ref, coupling,
                                         clipped, lost,
                                         mass_bounds)
            surface_note = _clipping_competes(
                *(pair if all(f is not None for f in pair) else (ref, surface_reported)),
                clipped, lost)
        if surface_note is not None:
            say("  " + surface_note[1])
            warnings.append(data_checks.DataWarning("clipping_explains", surface_note[1]))
            away = unexplained if surface_note[0] else None
        elif surface_reported is None and share <= CLIP_DOMINATES:
            # the chosen model fitted away from the clipped readings too: fitted to them,
            # its values are biased by what the clipping took, a misfit that follows
            # travel and speed everywhere, not only near the clipped readings (a surface
            # with no held-out reading near a clipped one keeps its finding: the
            # comparison it won is the clipping's in no part)
            say("  again, away from the clipped readings, with the model fitted there and what "
                "the clipped peaks lost taken out")
            clean = _fit_away_from_clipping(chosen.physics, chosen, coupling, clipped,
                                            mass_bounds)
            if lost and _too_many_lost_peaks(clean or chosen, chosen.prepared, lost):
                # what the peaks lost reaches the travel everywhere and cannot be fitted:
                # the structure cannot be told from it (nor shown absent)
                say("  too many clipped peaks to take what they lost out of the travel: "
                    "the structure cannot be told from the clipping")
                away, too_many_peaks = None, True
            else:
                away, _ = _unexplained(clean or chosen, chosen.prepared, coupling, base,
                                       say, known=tried,
                                       exclude=lambda d, t: _near(clipped[d.label], t),
                                       lost=lost)
        if away is None or share > CLIP_DOMINATES:
            unexplained = surface_reported = None
            where = ("sits near the clipped readings ({:.0f} % of the held-out data are "
                     "near them) and cannot be told from the clipping, the simpler "
                     "explanation" if share > CLIP_DOMINATES else
                     "cannot be told from what the clipped peaks lost ({:.0f} % of the "
                     "held-out data are near them, but a lost wheel peak ramps the "
                     "integrated travel for seconds, and they are too many to fit)"
                     if too_many_peaks else
                     "is not found away from the clipped readings ({:.0f} % of the "
                     "held-out data are near them) with what each clipped peak lost taken "
                     "out (a lost wheel peak ramps the integrated travel for seconds)"
                     ).format(100 * share)
            said = any(w.kind == "clipping_explains" for w in warnings)
            warnings += [] if said else [data_checks.DataWarning(
                "clipping_explains", f"the structure left in the residual {where}: the "
                + ("clipping may explain it" if too_many_peaks else
                   "clipping explains the mismatch")
                + ". Record again with a larger measuring range")]
            if share > CLIP_DOMINATES:
                hopeless = hopeless or (
                    "the values of the linear model are not reliable: the clipped readings "
                    "corrupt most of the recording")
    if (unexplained is not None and surface_reported is None
            and not unexplained["where"].get("between_drives")
            and not (unexplained["held_out_gain"] > 0.0
                     and unexplained["model"]["held_out_t"] >= UNEXPLAINED_MIN_T)):
        # the finding is the model of the force left, and it must predict held-out data as
        # surely as the map did: a map's coarse bins can catch what no smooth shape carries
        # over (the independent simulator's linear cars 1795956848: 8.4 % of the residual
        # at t = 4.5 by the map, the shape model -3 %, "the damping fades by 19 % above
        # 0.85 m/s"; 1795964974: 8.7 % at t = 4.6, the shape 0.7 % at t = -3.6, "the force
        # rises 40 % softer than the linear spring beyond 23 mm"). Judged after the
        # clipping's account, which tells the user of structure near clipped readings
        # whatever the shape
        say(f"  a smooth model of the structure left predicts "
            f"{100 * unexplained['held_out_gain']:.1f} % of the held-out force (t = "
            f"{unexplained['model']['held_out_t']:.1f}): not reported")
        unexplained = None
    # a car judged on a recording the clipping corrupts is not judged adequate
    inconclusive = None
    if too_many_peaks:
        inconclusive = (
            "structure is left in the residual, but the clipped peaks are too many to tell "
            "it from what they lost (a lost wheel peak ramps the integrated travel for "
            "seconds): the recording cannot show whether physics is missing. Record again "
            "with a larger measuring range")
    elif any_clipped and (near := float(_near_clipping(base.runs, clipped).mean())
                          ) > CLIP_DOMINATES:
        inconclusive = (
            f"{100 * near:.0f} % of the held-out "
            f"data lie within {CLIP_REACH_S:g} s of clipped readings: no physics can be told "
            "apart from the clipping there, so the recording cannot show whether the linear "
            "model is adequate. Record again with a larger measuring range")
    # where the restoring force departs from the *linear* surface (what the findings fix)
    r, v, dep, _, _ = _departure(base, prepared, coupling)
    dmap = departure_map(r, v, dep, bins=12)
    region = dmap.region()
    loops = _restoring_loops(base, chosen if surface_reported is None or chosen is not base
                             else surface_reported, prepared)
    return Diagnosis(
        loops=loops,
        mode=mode,
        drives=drives,
        band_hz=band,
        baseline=base,
        chosen=chosen,
        comparison=sel.comparison if chosen.candidate is sel.chosen else compare(
            base.candidate, chosen.candidate),
        fits=fits,
        screening=screening,
        windows=windows,
        excess_band_hz=exband,
        departure=dmap,
        region=region,
        unexplained=unexplained,
        warnings=warnings,
        residual_psd=psd,
        ride_height=ride,
        linear_inadequate=hopeless,
        undecided=undecided,
        surface=surface_reported,
        inconclusive=inconclusive,
    )


_LINEAR_SI = {
    "body_mass_kg": "sprung_mass_kg",
    "linear_spring.suspension_stiffness_n_per_m": "suspension_stiffness_n_per_m",
    "linear_damper.suspension_damping_ns_per_m": "suspension_damping_ns_per_m",
    "coupling_spring.coupling_stiffness_n_per_m": "coupling_stiffness_n_per_m",
}

_DATA_LABEL = {
    "sensor_gain_changed": "sensor gain change between the drives",
    "channel_time_offset": "time offset between the wheel and body channels",
}


def _competes(fit: _Fit) -> bool:
    """Whether ``fit`` competes in the selection: a data problem whose estimate is within
    MIN_Z standard deviations of zero is not told from none, one refined below the size
    worth correcting is none (a 0.16 ms delay, seed 1795966240), and one refined against
    physics (:attr:`DataHypothesis.refined_with`) holds only beside that physics."""
    return fit.data is None or all(
        h.z >= MIN_Z and h.worth_correcting and set(h.refined_with) <= set(fit.physics)
        and (h.kind != "channel_time_offset" or abs(h.value) <= MAX_TIME_OFFSET_S)
        for h in fit.data.chain)


def _decisive_data_problem(chosen: _Fit, fits: Sequence[_Fit]) -> tuple[_Fit, str | None]:
    """A data problem estimated decisively (:data:`~.data_hypotheses.DECISIVE_Z`), on top
    of what the chosen model corrects, that also predicts the held-out data better; and
    words for a late channel that physics predicts as well (then not chosen).

    A gain change's estimate rests on the gravity levels too, which no suspension moves; a
    delay's rests on the residual's phase, which any lag the model leaves out moves alike
    (hysteresis, a top mount). So a late channel is decisive only where it also predicts
    better (t >= :data:`MIN_T_SIGNIFICANT`) than the best physics added to the chosen
    model, whether or not that physics passed the selection itself."""
    note = None
    for f in fits:
        # one more data problem on top of what the chosen model corrects already
        if (f.data is None or f.data.prior != chosen.data or f.physics != chosen.physics
                or f.restored != chosen.restored or f.data.z < DECISIVE_Z
                or not f.candidate.physical or not _competes(f)):
            continue
        cmp = compare(chosen.candidate, f.candidate)
        if f.data.kind == "sensor_gain_changed":
            # the linear model absorbs a gain in its mass (the bias it causes), so held-out
            # data hardly tell; a gain is what breaks |T| -> 1 below the body resonance,
            # which no passive suspension does: decisive, unless it predicts worse
            if _gain_stands(f.data, cmp.t):
                return f, None
        elif cmp.t >= MIN_T_SIGNIFICANT and cmp.gain(everywhere=True) > 0:
            found = _physics_rival(chosen, f, fits)
            if found is None:
                return f, None
            rival, t = found
            names = " + ".join(e.replace("_", " ") for e in rival.physics
                               if e not in chosen.physics)
            alike = ("predict the held-out data alike" if t > -TWIN_T else
                     f"the {names} predicts the held-out data better, though not by "
                     "enough to be reported")
            note = (f"a {_DATA_LABEL[f.data.kind]} ({_data_size(f.data)}) and a {names}: "
                    f"{alike} (t = {t:.1f} for the data problem). A delay read off the "
                    "residual's phase is also what a lag of the suspension left out of "
                    "the model shows, so neither is reported. Check the recording (both "
                    "channels on one DAQ clock with the same filter) to rule the data "
                    "problem out")
    return chosen, note


def _physics_rival(chosen: _Fit, f: _Fit, fits: Sequence[_Fit]
                   ) -> tuple[_Fit, float] | None:
    """The physics added to ``chosen`` that predicts best, with the paired-block t of the
    data problem ``f`` against it, where ``f`` does not predict better than it
    (t < :data:`MIN_T_SIGNIFICANT`); else None."""
    rivals = [g for g in fits if g.data is None and g.candidate.physical
              and set(g.physics) > set(chosen.physics)
              and compare(chosen.candidate, g.candidate).t > 0.0]
    if not rivals:
        return None
    best = min(rivals, key=lambda g: g.candidate.mse_validation)
    t = compare(best.candidate, f.candidate).t
    return (best, t) if t < MIN_T_SIGNIFICANT else None


#: How far below a lone delay's estimate a top mount's profile reaches at least [s]
#: (:func:`delay_profiled`'s ``beyond_s``): the lag of a mount 60x the suspension's
#: stiffness, with a damping ratio of 0.3 at 1.3 Hz.
MOUNT_LAG_REACH_S = 2.0e-3

#: Two explanations of equal size (a top mount's lag, a late channel) are told apart only
#: when one predicts the held-out data better by two standard errors of the difference
#: (the usual 95 % level) and by the selection's gain for a parameter
#: (:data:`~.selection.MIN_GAIN_PER_PARAM`); a closer call keeps the better one and names
#: the other. (A 0.6 ms mount's own model lost to a delay refined to 0.61 ms by 0.7 %, at
#: t = 2.2: no difference a technician could act on.)
TWIN_T = 2.0


def _decisive_gain_elsewhere(chosen: _Fit, physics_fit: _Fit, fits: Sequence[_Fit]
                             ) -> DataHypothesis | None:
    """A gain change estimated decisively, on top of what the chosen model corrects, and
    not made worse by its correction on the physics it was tested with (``physics_fit``),
    where the selection chose other physics that was not fitted to the drives corrected
    for it (a top mount beside the physics; a part of it, once a late channel is
    corrected): the gain to fit that physics with."""
    if not chosen.physics or chosen.physics == physics_fit.physics:
        return None
    # the physics it was tested with, corrected for what the chosen model corrects
    ref = physics_fit if chosen.data is None else next(
        (g for g in fits if g.data == chosen.data and g.physics == physics_fit.physics
         and g.restored == physics_fit.restored), None)
    if ref is None:
        return None
    for f in fits:
        if (f.data is not None and f.data.prior == chosen.data
                and f.data.kind == GAIN_CHANGE and f.data.z >= DECISIVE_Z
                and f.physics == physics_fit.physics and f.restored == physics_fit.restored
                and f.candidate.physical
                and not any(g.data == f.data and g.physics == chosen.physics for g in fits)
                and _gain_stands(f.data, compare(ref.candidate, f.candidate).t)):
            return f.data
    return None


def _gain_beside_the_data(chosen: _Fit, physics_fit: _Fit, fits: Sequence[_Fit]
                          ) -> DataHypothesis | None:
    """A gain change estimated decisively and standing on the physics first chosen (the
    drives corrected for it alone), where the selection then chose a delay beside that
    physics without it (no gain was tested on top of that delay: the delays the gain was
    tested with were the linear model's): the gain, on top of the chosen correction, to
    fit the chosen physics with. None where the chosen model corrects a gain already."""
    if (chosen.data is None or not chosen.physics or chosen.physics != physics_fit.physics
            or any(h.kind == GAIN_CHANGE for h in chosen.data.chain)
            or any(f.data is not None and f.data.prior == chosen.data for f in fits)):
        return None
    for f in fits:
        if (f.data is not None and f.data.prior is None and f.data.kind == GAIN_CHANGE
                and f.data.z >= DECISIVE_Z and f.physics == physics_fit.physics
                and f.restored == physics_fit.restored and f.candidate.physical
                and _gain_stands(f.data, compare(physics_fit.candidate, f.candidate).t)):
            return replace(f.data, prior=chosen.data)
    return None


def _gain_judged_by_the_surface(chosen: _Fit, fits: Sequence[_Fit], surface: _Fit,
                                coupling: bool, mass_bounds_kg: tuple[float, float] | None,
                                say: Callable[[str], None]) -> _Fit | None:
    """``chosen`` corrected for a gain change read off the gravity levels, where the held-out
    comparison that turned the gain down was made with named physics the force surface
    (``surface``, on the drives as recorded) predicts significantly better than: a model
    that misses physics judges a correction by its own misfit (seed 1795919933, quadratic
    damping for quadratic and travel-dependent damping: the wheel's 1.5 +- 0.3 % gain
    change predicted worse at t = -4.2 with it, better at t = 5.5 with the surface and at
    7.1 with the true physics). The gain is judged again with the surface fitted to the
    drives corrected for it; the fit of ``chosen``'s physics corrected for it where it
    predicts better there by :data:`MIN_T_SIGNIFICANT`, else None."""
    gain_fit = next((f for f in fits if f.data is not None and f.data.prior is None
                     and f.data.kind == GAIN_CHANGE and f.data.z >= DECISIVE_Z
                     and f.data.evidence and f.physics == chosen.physics
                     and f.restored == chosen.restored and f.candidate.physical), None)
    if gain_fit is None:
        return None
    try:
        corrected = _grey_fit(surface.physics, gain_fit.prepared, coupling, _initial_from(surface),
                              2, mass_bounds_kg, gain_fit.data)
    except (FieldDiagError, np.linalg.LinAlgError, FloatingPointError):
        return None
    cmp = compare(surface.candidate, corrected.candidate)
    stands = cmp.t >= MIN_T_SIGNIFICANT and cmp.relative_gain > 0.0
    say(f"  the {_DATA_LABEL[GAIN_CHANGE]} ({_data_size(gain_fit.data)}) judged with the "
        f"force surface, which predicts better than {' + '.join(chosen.physics)}: "
        + (f"its correction predicts held-out data better (t = {cmp.t:.1f})" if stands
           else f"not better (t = {cmp.t:.1f})"))
    return gain_fit if stands else None


def _gain_stands(gain: DataHypothesis, t: float) -> bool:
    """Whether a decisive gain change stands against held-out data whose paired-block
    ``t`` (positive: the correction predicts better) says little either way. Read off the
    gravity levels too (``evidence``), a measurement no suspension moves, it falls only
    where its correction predicts worse by two standard errors (:data:`TWIN_T`); from the
    transmissibility alone, by one. Measured twice with the same result (``confirmed``:
    the gravity levels and the transmissibility's level, each significant on its own), it
    falls only at :data:`~.data_hypotheses.DECISIVE_Z` standard errors: the held-out data
    are predicted by physics that may be only near the truth (Dahl friction fitted as
    Coulomb friction and a hysteretic spring), and such physics can predict the drives as
    recorded a little better than the corrected ones (seed 1795791228: a +1.8 % gain,
    gravity +1.8 +- 0.2 %, transmissibility +4.1 +- 1.4 %, t = -2.2)."""
    if gain.confirmed:
        return t > -DECISIVE_Z
    return t > (-TWIN_T if gain.evidence else -MIN_T_SIGNIFICANT)


def _physics_twin(chosen: _Fit, fits: Sequence[_Fit]) -> tuple[_Fit, str, str] | None:
    """A data problem and physics that looks like it
    (:attr:`~fielddiag.effects.base.Effect.data_twins`) that predict the held-out data
    within :data:`TWIN_T` standard errors of each other: the better of the two (which the
    selection chose, unless it chose the data problem over physics that predicts better)
    words saying both explain the recording, and the data problem's kind. None when one is
    clearly better or nothing looks like the chosen model."""
    def kinds(f: _Fit) -> set[str]:
        return {h.kind for h in f.data.chain} if f.data is not None else set()

    def looks_like(f: _Fit, g: _Fit) -> bool:
        """``f`` adds to ``g``'s physics an effect that looks like the one data problem
        ``g`` corrects beyond what ``f`` corrects (both corrected alike for the rest: a
        top mount beside a gain change, the twin of a late body channel beside the same
        gain change; not of a late wheel channel, which no mount makes: seed 1795975666,
        a 1.72 ms late wheel channel told tied with a mount)."""
        extra = [h for h in g.data.chain if h.kind not in kinds(f)] if g.data else []
        return (len(extra) == 1 and kinds(f) <= kinds(g) and f.candidate.physical
                and set(g.physics) < set(f.physics)
                and any(EFFECTS[e].looks_like_data(h.kind, h.value) for h in extra
                        for e in set(f.physics) - set(g.physics)))

    pairs = ([(f, chosen) for f in fits if looks_like(f, chosen)]
             + [(chosen, g) for g in fits if looks_like(chosen, g)])
    if not pairs:
        return None
    twin, data = min(pairs, key=lambda p: p[1 - (chosen is p[1])].candidate.mse_validation)
    # the data problem the two tell apart (the other corrections they share)
    told = next(h for h in data.data.chain if h.kind not in kinds(twin))
    cmp = compare(twin.candidate, data.candidate)
    t = cmp.t  # > 0: the data problem predicts better
    better = cmp if t >= 0 else compare(data.candidate, twin.candidate)
    if abs(t) >= TWIN_T and better.relative_gain >= MIN_GAIN_PER_PARAM:
        return None
    pick = chosen if (chosen is data) == (t >= 0) else (data if chosen is twin else twin)
    names = " + ".join(e.replace("_", " ") for e in set(twin.physics) - set(data.physics))
    problem = f"a {_DATA_LABEL[told.kind]} ({_data_size(told)})"
    ahead = "data problem" if t >= 0 else names
    both = (f"{problem} and a {names} explain the held-out data within two standard errors "
            f"(t = {abs(t):.1f} for the {ahead}): these data cannot tell the two apart. "
            if abs(t) < TWIN_T else
            # significant, but by less than a parameter must earn (seed 1795941185: the
            # late channel ahead at t = 6.5 was worded "within two standard errors")
            f"{problem} and a {names} explain the held-out data alike: the {ahead} "
            f"predicts them only {100 * better.relative_gain:.1f} % better (t = "
            f"{abs(t):.1f}), under the {100 * MIN_GAIN_PER_PARAM:.0f} % a parameter must "
            "earn: by what they predict, these data cannot tell the two apart. ")
    if pick is data:
        note = both + (f"The findings assume the {problem[2:]}; a {names} would explain it "
                       "as well")
    else:
        note = both + (f"The findings assume the {names}; check the recording (both "
                       "channels on one DAQ clock with the same filter) to rule the data "
                       "problem out")
    return pick, note, told.kind


def _unsettled_share(chosen: _Fit,
                     unsettled: Sequence[tuple[_Fit, _Fit, DataHypothesis, Comparison]]
                     ) -> str | None:
    """Words telling that a top mount beside a smaller late channel predicted the held-out
    data better than the chosen delay alone, by less than a finding must (``unsettled``:
    from the profile of the mount's fit over the delay); None where no such share was
    found beside the chosen model (better by :data:`MIN_GAIN_PER_PARAM` and at least
    :data:`MIN_T_SIGNIFICANT` standard errors).

    A mount's lag and a late body channel's add up; where the data tell their sum but
    not its split, the simpler model is kept and the other told: a 1.2 ms mount beside a
    0.84 ms late body channel (seed 1796011178) read as a 2.01 ms late channel, the
    profile's share (the mount and 0.93 ms) better at t = 2.3; friction beside a 1.33 ms
    late channel and no mount (seed 1795953005) gave such a share at t = 2.2."""
    hyp = next((h for h in (chosen.data.chain if chosen.data else [])
                if h.kind == "channel_time_offset"), None)
    if hyp is None:
        return None
    for alone, fit, refined, cmp in unsettled:
        same = (alone is chosen or (
            alone.data is not None and set(alone.physics) == set(chosen.physics)
            and alone.restored == chosen.restored
            and abs(alone.data.value - hyp.value) <= 2.0 * max(hyp.std, alone.data.std)))
        if not same:
            continue
        mounts = [e for e in fit.physics if "channel_time_offset" in EFFECTS[e].data_twins]
        names = " + ".join(e.replace("_", " ") for e in mounts)
        return (f"a {_DATA_LABEL[hyp.kind]} alone ({_data_size(hyp)}), or a {names} beside "
                f"a smaller one ({_data_size(refined)}): the {names} predicts the held-out "
                f"data {100 * cmp.gain():.1f} % better (NRMSE "
                f"{fit.candidate.nrmse_validation:.4f} against "
                f"{alone.candidate.nrmse_validation:.4f}), at t = {cmp.t:.1f}, short of the "
                f"{MIN_T:g} a finding must reach: these data cannot tell the two apart (a "
                "longer drive, or a rougher road, would). The findings assume the "
                f"{_DATA_LABEL[hyp.kind]} alone; a {names} would explain part of it")
    return None


def _data_size(hyp: DataHypothesis) -> str:
    if hyp.kind == "channel_time_offset":
        return f"{1000 * hyp.value:+.2f} +- {1000 * hyp.std:.2f} ms"
    return f"{100 * hyp.value:+.1f} +- {100 * hyp.std:.1f} %"


#: Held-out samples this close to a clipped reading are "where the clipping acts" [s].
CLIP_REACH_S = 0.25
#: A fit that leaves the clipped readings out keeps the stretches between them that hold
#: at least this long [s] once their band filter's edges are cut (each stretch costs its
#: own initial state) ...
CLEAN_STRETCH_MIN_S = 2.0
#: ... and is made only where they hold at least this share of every drive's fit part.
CLEAN_SHARE_MIN = 0.25
#: When more of the held-out data than this lies near clipped readings, what is left
#: cannot show physics apart from the clipping (and the wheel motion, integrated from a
#: clipped input, is wrong in between too): the known data problem explains the mismatch.
CLIP_DOMINATES = 0.5


def _clipped_times(drives: Sequence[Drive]) -> dict[str, np.ndarray]:
    """Times of the clipped readings (either channel) of every drive, by drive label:
    one pass over the recordings, shared by every comparison that leaves them out."""
    return {d.label: d.time_s[data_checks.clipped_mask(d.wheel_accel_mps2)
                              | data_checks.clipped_mask(d.body_accel_mps2)] for d in drives}


def _near_clipping(runs: list, clipped: dict[str, np.ndarray]) -> np.ndarray:
    """Per held-out residual sample: near a clipped reading."""
    return np.concatenate([_near(clipped[label], t) for (_sf, _m, _r, t), label in zip(
        runs, clipped, strict=True)])


def _near(times: np.ndarray, time_s: np.ndarray) -> np.ndarray:
    """True at ``time_s`` within :data:`CLIP_REACH_S` of any of ``times`` (sorted)."""
    if times.size == 0:
        return np.zeros(np.size(time_s), bool)
    i = np.clip(np.searchsorted(times, time_s), 1, times.size) - 1
    j = np.clip(i + 1, 0, times.size - 1)
    return np.minimum(np.abs(time_s - times[i]), np.abs(time_s - times[j])) <= CLIP_REACH_S


def _clean_stretches(part: GreyBoxData, times: np.ndarray) -> tuple[list[GreyBoxData], float]:
    """The stretches of ``part`` farther than :data:`CLIP_REACH_S` from every clipped
    reading (``times``) that hold at least :data:`CLEAN_STRETCH_MIN_S` once the band
    filter's edges (a period of the band's low corner at each end) are cut, and the share
    of ``part`` their kept samples hold."""
    fs = part.sample_rate_hz
    edges_s = 2.0 / part.band_hz[0] if part.band_hz is not None else 0.0
    good = ~_near(times, part.start_s + np.arange(part.n_samples) / fs)
    edge = np.diff(np.concatenate([[0], good.astype(np.int8), [0]]))
    out = [part.segment(i0 / fs, i1 / fs)
           for i0, i1 in zip(np.flatnonzero(edge == 1), np.flatnonzero(edge == -1),
                             strict=True)
           if (i1 - i0) / fs >= CLEAN_STRETCH_MIN_S + edges_s]
    return out, sum(c.duration_s - edges_s for c in out) / part.duration_s


def _clean_fit_parts(prepared: Sequence[_Prepared], clipped: dict[str, np.ndarray]
                     ) -> list[GreyBoxData] | None:
    """The stretches of every drive's fit part away from the clipped readings
    (:func:`_clean_stretches`); None where one drive keeps less than
    :data:`CLEAN_SHARE_MIN` of its fit part."""
    parts = []
    for p in prepared:
        clean, share = _clean_stretches(p.fit, clipped.get(p.drive.label, np.empty(0)))
        if share < CLEAN_SHARE_MIN:
            return None
        parts += clean
    return parts


def _fit_away_from_clipping(effects: tuple[str, ...], fit: _Fit, coupling: bool,
                            clipped: dict[str, np.ndarray],
                            mass_bounds_kg: tuple[float, float] | None) -> _Fit | None:
    """The linear model plus ``effects`` fitted to ``fit``'s drives (corrected as they
    are for its data problems) on the stretches away from the clipped readings: modelling
    the clipping means leaving out what it corrupts, from the fit (where it biases the
    linear model's values) as much as from the comparison. None where too little is left
    (less than :data:`CLEAN_SHARE_MIN` of a drive's fit part) or the fit fails."""
    parts = _clean_fit_parts(fit.prepared, clipped)
    if parts is None:
        return None
    try:
        return _grey_fit(effects, fit.prepared, coupling, _initial_from(fit), 2,
                         mass_bounds_kg, fit.data, fit_parts=parts)
    except (FieldDiagError, np.linalg.LinAlgError, FloatingPointError):
        return None


def _body_per_kg(vals: dict[str, float], added_mass_kg: float) -> tuple[float, float]:
    """A fit's linear stiffness and damping per kg of the body with ``added_mass_kg``."""
    mass = vals.get("body_mass_kg")
    per = 1.0 / (mass + added_mass_kg) if mass else 1.0
    return (vals.get("linear_spring.suspension_stiffness_n_per_m", np.nan) * per,
            vals.get("linear_damper.suspension_damping_ns_per_m", np.nan) * per)


def _with_lost_peaks(prepared: Sequence[_Prepared], lost: dict[str, ClippedPeaks],
                     vals: dict[str, float]) -> list[_Prepared]:
    """The drives with what each clipped peak lost as disturbances of unknown size
    (``GreyBoxData.disturbance_basis``), a wheel peak's shapes through the linear body of
    ``vals``."""
    out = []
    for p in prepared:
        peaks = lost.get(p.drive.label)
        if peaks is None:
            out.append(p)
            continue
        body = _body_per_kg(vals, p.drive.added_mass_kg)
        parts = {name: replace(d, disturbance_basis=peaks.basis(
            d.start_s + np.arange(d.n_samples) / d.sample_rate_hz, *body))
            for name, d in (("fit", p.fit), ("val", p.val))}
        out.append(replace(p, **parts))
    return out


def _fits_beside_clipping(combos: Sequence[tuple[str, ...]], ref: _Fit, coupling: bool,
                          clipped: dict[str, np.ndarray], lost: dict[str, ClippedPeaks],
                          mass_bounds_kg: tuple[float, float] | None) -> list[_Fit | None]:
    """The linear model plus each of ``combos`` fitted to ``ref``'s drives with the
    clipping modelled: what each clipped peak lost fitted alongside
    (:func:`_with_lost_peaks`; a wheel peak's shapes through the linear body fitted so,
    twice, from ``ref``'s), on the stretches away from the clipped readings where they
    hold enough (:func:`_clean_fit_parts`: a lost peak's response is not all linear),
    else on the whole drives; where no run of clipped readings is known (``lost``
    empty), on those stretches alone (:func:`_fit_away_from_clipping`). None where a fit
    fails."""
    if not lost:
        return map_threads(lambda eff: _fit_away_from_clipping(
            eff, ref, coupling, clipped, mass_bounds_kg), list(combos), cost=_cost)
    vals = _initial_from(ref)
    lin = None
    try:
        for _ in range(2):
            on = _with_lost_peaks(ref.prepared, lost, vals)
            parts = _clean_fit_parts(on, clipped)
            lin = _grey_fit((), on, coupling, vals, 2, mass_bounds_kg, ref.data,
                            fit_parts=parts)
            vals = {**vals, **_initial_from(lin)}
    except (FieldDiagError, np.linalg.LinAlgError, FloatingPointError):
        return [None] * len(combos)

    def fit(combo: tuple[str, ...]) -> _Fit | None:
        if not combo:
            return lin
        try:
            return _grey_fit(combo, on, coupling, _initial_from(ref), 2, mass_bounds_kg,
                             ref.data, fit_parts=parts)
        except (FieldDiagError, np.linalg.LinAlgError, FloatingPointError):
            return None
    return map_threads(fit, list(combos), cost=_cost)


def _clipping_competes(base: _Fit, chosen: _Fit, clipped: dict[str, np.ndarray],
                       lost: dict[str, ClippedPeaks] | None = None
                       ) -> tuple[bool, str] | None:
    """Clipping as the competing explanation of a physical finding.

    Modelling the clipping means leaving out what it corrupts: the held-out samples near
    clipped readings, and, where ``base`` and ``chosen`` were fitted with them
    (:func:`_fits_beside_clipping`), what each clipped peak lost (a lost wheel peak's
    error reaches seconds into the wheel's integrated displacement). If the finding
    still predicts the rest significantly better than the linear model, it stands, with
    the clipping named beside it; if not, the clipping explains the mismatch. Returns
    (finding stands, words), or None without clipping (``lost``: the drives' clipped
    peaks, which act on held-out data far from them).

    Where most held-out data lie near clipped readings (:data:`CLIP_DOMINATES`), physics
    cannot be told from the clipping; a correction of the recording alone (a late
    channel, at every sample alike) is still judged on what is left away from them: a
    wheel channel 2.95 ms late, 58 % of the held-out data near its clipped readings, was
    withheld as the clipping's (seed 1795941144), though it predicts the rest far better.
    """
    eb, ec = base.candidate.residual_validation, chosen.candidate.residual_validation
    near = _near_clipping(base.runs, clipped)
    if not (near.any() or lost):
        return None
    found = (_surface_label(chosen) if chosen.physics in SURFACES else
             " + ".join(e.replace("_", " ") for e in chosen.effects)
             or f"the model corrected for the {_DATA_LABEL[chosen.data.kind]}")
    share_e = float(np.sum(eb[near] ** 2) / np.sum(eb**2))
    share_n = float(near.mean())
    head = (f"{100 * share_e:.0f} % of the linear model's held-out misfit lies within "
            f"{CLIP_REACH_S:g} s of clipped readings ({100 * share_n:.0f} % of the time)"
            if share_n > 0 else "no held-out reading lies near the clipped ones")
    if any(p.val.disturbance_basis is not None for p in base.prepared):
        head += "; with what each clipped peak lost fitted alongside both models" + (
            " (a wheel peak's reaches seconds into the wheel's integrated motion)"
            if any(v.wheel_runs_s.size for v in (lost or {}).values()) else "")
    if share_n > CLIP_DOMINATES and chosen.physics:
        return False, (f"{head}: the mismatch ({' + '.join(chosen.effects)}) cannot be "
                       "told from the clipping, which is the simpler explanation. Record "
                       "again with a larger measuring range")
    t = paired_block_t(eb[~near], ec[~near])
    if chosen.physics:
        gain = 1.0 - float(np.mean(ec[~near] ** 2) / np.mean(eb[~near] ** 2))
    else:
        # a correction of the recording acts alike in every block: its gain is the
        # typical block's, as in the selection (a 1.16 ms late wheel channel beside 0.25 %
        # clipped wheel readings: t = 7.7 away from them, the mean square 7 % worse for a
        # few events the corrected model still misfits; withheld as the clipping's, seed
        # 1795976905)
        gain = 1.0 - float(np.exp(-block_log_ratios(eb[~near], ec[~near]).mean()))
    # physics must show there what it had to show to be chosen (selection's rule: t and
    # a gain per parameter it adds; a data problem's correction, decided by its estimate's
    # size, any gain)
    extra = chosen.candidate.n_params - base.candidate.n_params
    least = MIN_GAIN_PER_PARAM * max(1, extra) if chosen.physics else 0.0
    if t >= MIN_T and gain > least:
        return True, (f"{head}; away from them {found} still predicts {100 * gain:.0f} % "
                      f"better (t = {t:.1f}), so it is not the clipping's")
    short = ("no better than the linear model" if gain <= 0 or t < MIN_T else
             f"only {100 * gain:.0f} % better than the linear model, under the "
             f"{100 * least:.0f} % its {extra} parameters must earn")
    return False, (f"{head}; away from them {found} predicts {short} (t = {t:.1f}): the "
                   "clipping explains the mismatch, not the suspension. Record again with "
                   "a larger measuring range")


def _data_beside_clipping(base: _Fit, fits: Sequence[_Fit], clipped: dict[str, np.ndarray],
                          lost: dict[str, ClippedPeaks],
                          coupling: bool, mass_bounds_kg: tuple[float, float] | None
                          ) -> tuple[_Fit, str] | None:
    """Of the linear models fitted to drives corrected for a decisive data problem (every
    estimate of its chain at least MIN_Z std from none), the one that predicts the held-out
    data away from the clipped readings best, where it beats the uncorrected linear model
    there (:func:`_clipping_competes`; both fitted again away from the clipped readings,
    as the physics is); with its words. None where none does."""
    cands = [f for f in fits if not f.physics and f.data is not None and _competes(f)]
    if not cands:
        return None
    away = map_threads(lambda f: _fits_beside_clipping([()], f, coupling, clipped, lost,
                                                       mass_bounds_kg)[0], [base, *cands])
    best = None
    for f, a in zip(cands, away[1:], strict=True):
        # both refitted away from the clipping, or (where either cannot be) both as fitted
        ref, a = (away[0], a) if away[0] is not None and a is not None else (base, f)
        note = _clipping_competes(ref, a, clipped, lost)
        if note is None or not note[0]:
            continue
        near = _near_clipping(ref.runs, clipped)
        mse = float(np.mean(a.candidate.residual_validation[~near] ** 2))
        if best is None or mse < best[0]:
            best = (mse, f, note[1])
    return None if best is None else (best[1], best[2])


#: A channel time offset is refined (its delay read off the residual of the model fitted
#: to the drives corrected for it, and corrected again) until the next step is under this
#: share of its std, in at most :data:`DELAY_REFINE_STEPS` fits. Tighter than the std:
#: at a high signal-to-noise ratio a delay off by one std (0.27 ms of 2.27 ms, seed
#: 1795865160) predicts held-out data 80 % worse than a top mount's continuous lag, and
#: the mount was named for a late channel.
DELAY_REFINED_STD = 0.25
DELAY_REFINE_STEPS = 6
#: Points of a delay's profile across its range before the parabolas refine its minimum.
PROFILE_POINTS = 5
#: The largest delay between the channels that competes as a data problem [s] (a larger
#: estimate may still be refined into the range against the physics): a DAQ's skew is a
#: sample or a filter's group delay (a few ms at >= 100 Hz); 20 ms is a fifth of a wheel
#: hop's period, where a delay no longer reads as a phase slope.
MAX_TIME_OFFSET_S = 0.02
#: A delay a profile beside a top mount finds is told only from this size [s]: beside soft
#: mounts (5.8-6.9 ms of lag) the profile found 0.27-0.38 ms of wheel lag where no channel
#: is late (seeds 1795986445, 1795986494, 1795997634). Those cars have a coupling spring
#: (2670-3628 N/m, 4-10 % of the suspension's) that neither the linear model nor the force
#: surface read at COUPLING_MIN_Z beside the mount, so every model left it out and its
#: misfit read as a delay: the mount's profile with the coupling is least at 0 (seed
#: 1795997634, the mount's stiffness within 0.5 %). The coupling is now decided beside
#: the chosen physics too where it holds a state (:func:`_coupling_beside_state`); this
#: floor keeps what such a misfit may still leave from being told as a late channel.
PROFILED_DELAY_FLOOR_S = 5e-4
#: Spacings a delay's profile steps on below its range where its least is at the edge.
PROFILE_STEPS_BELOW = 3


def _profile_minimum(cost: Callable[[float], float], lo: float, hi: float, tol: float
                     ) -> float | None:
    """Where ``cost`` is least on ``[lo, hi]``: :data:`PROFILE_POINTS` evenly spaced
    points, then parabolas through the least and its two neighbours, each vertex
    evaluated, until a vertex moves less than ``tol`` (at most three). A fixed number of
    points first (not golden sections): the cost is a fit each, and a smooth profile's
    minimum is found from few. None where no point could be evaluated.

    The least at ``lo`` is no minimum: the profile steps on below it, a spacing at a
    time, up to :data:`PROFILE_STEPS_BELOW` times (a top mount hides part of a late
    wheel channel: a 1.45 ms late wheel channel beside a mount read as a 4.80 ms late
    body channel, the profile over [0, 4.8] ms least at its edge, seed 1795988239)."""
    xs = list(np.linspace(lo, hi, PROFILE_POINTS))
    ys = [cost(x) for x in xs]
    spacing = (hi - lo) / (PROFILE_POINTS - 1)
    below = 0
    for _ in range(3 + PROFILE_STEPS_BELOW):
        finite = [(x, y) for x, y in zip(xs, ys, strict=True) if np.isfinite(y)]
        if not finite:
            return None
        finite.sort()
        i = min(range(len(finite)), key=lambda k: finite[k][1])
        if i == 0 and below < PROFILE_STEPS_BELOW and spacing > 0:
            below += 1
            xs.append(finite[0][0] - spacing)
            ys.append(cost(xs[-1]))
            continue
        if i == 0 or i == len(finite) - 1:
            return finite[i][0]  # at the range's edge: the edge
        (x0, y0), (x1, y1), (x2, y2) = finite[i - 1:i + 2]
        den = (x1 - x0) * (y1 - y2) - (x1 - x2) * (y1 - y0)
        if den == 0.0:
            return x1
        vertex = x1 - 0.5 * ((x1 - x0) ** 2 * (y1 - y2) - (x1 - x2) ** 2 * (y1 - y0)) / den
        vertex = float(np.clip(vertex, x0, x2))
        if any(abs(vertex - x) < tol for x in xs):
            return min(zip(xs, ys, strict=True), key=lambda p: p[1])[0]
        xs.append(vertex)
        ys.append(cost(vertex))
    return min(zip(xs, ys, strict=True), key=lambda p: p[1])[0]


def _delay_step_s(value_s: float, seen_s: float, last: tuple[float, float] | None) -> float:
    """The next step of a delay's refinement from ``value_s``, where the model fitted to
    the drives corrected for it still sees ``seen_s``; ``last`` the previous
    ``(value_s, seen_s)``.

    Refitted to the corrected drives, the model absorbs part of what is left of the delay,
    so ``seen_s`` is a fraction of it and plain steps crawl (4.22, 2.99, 2.54 ms towards
    2.27 ms). With a previous step, the secant through the two (the root of the seen delay
    as a function of the correction) where their slope says the model absorbed between
    none and nine tenths of it; the plain step otherwise."""
    if last is None or last[0] == value_s:
        return seen_s
    slope = (seen_s - last[1]) / (value_s - last[0])
    if -1.5 < slope < -0.1:
        return -seen_s / slope
    return seen_s


def _delay_parts(fit: _Fit, substeps: int, clipped: dict[str, np.ndarray] | None = None,
                 above_hz: float | None = None) -> list[tuple[np.ndarray, np.ndarray,
                                                              np.ndarray, float]]:
    """Per drive, the recorded body acceleration's misfit against the fitted model's
    simulation, the simulation's time derivative and the simulation itself on the fit
    part (samples near ``clipped`` readings left out; with ``above_hz``, residual and
    derivative high-passed alike), with the sample rate: what :func:`_delay_ls` reads a
    delay from."""
    parts = []
    runs = validation_runs(fit.result, [p.fit for p in fit.prepared], substeps=substeps)
    for (sf, measured, residual, t), p in zip(runs, fit.prepared, strict=True):
        sim = measured - residual
        ds = np.gradient(sim) * sf.sample_rate_hz
        if above_hz is not None:
            residual, ds = (dsp.zero_phase_filter(x, sf.sample_rate_hz, low_hz=above_hz)
                            for x in (residual, ds))
        if clipped is not None:
            keep = ~_near(clipped.get(p.drive.label, np.empty(0)), t)
            residual, ds, sim = residual[keep], ds[keep], sim[keep]
        parts.append((residual, ds, sim, float(sf.sample_rate_hz)))
    return parts


def _delay_ls(parts: Sequence[tuple[np.ndarray, np.ndarray]]) -> tuple[float, float]:
    """Least squares on ``m(t) = s(t - tau)`` linearised (residual = -tau ds/dt) over the
    (residual, derivative) pairs: ``(tau, std)``, the std inflated 3x for the residual's
    correlation in time (a pre-selection only: held-out data decide)."""
    num = sum(float(r @ d) for r, d in parts)
    den = sum(float(d @ d) for _, d in parts)
    tau = -num / den if den > 0 else 0.0
    rss = sum(float(np.sum((r + tau * d) ** 2)) for r, d in parts)
    n = sum(r.size for r, _ in parts)
    std = 3.0 * float(np.sqrt(rss / max(n - 1, 1) / den)) if den > 0 else np.inf
    return tau, std


def _residual_delay_s(fit: _Fit, substeps: int, with_std: bool = False,
                      clipped: dict[str, np.ndarray] | None = None,
                      above_hz: float | None = None):
    """Delay of the recorded body acceleration against the fitted model's simulation on
    the fit part of every drive (least squares on ``m(t) = s(t - tau)``, linearised),
    leaving out the samples near ``clipped`` readings (times by drive label): a clipped
    peak's misfit is not a delay, and where it dominates the residual it hides one.
    With ``above_hz``, read off the frequencies above it only (both high-passed alike).

    With ``with_std``, ``(tau, std)`` (:func:`_delay_ls`)."""
    tau, std = _delay_ls([(r, d) for r, d, _, _ in
                          _delay_parts(fit, substeps, clipped, above_hz)])
    return (tau, std) if with_std else tau


#: Windows over which the amplitude of the motion is told (s): a drive's windows are split
#: at the median of the simulated body acceleration's rms in them.
AMPLITUDE_WINDOW_S = 1.0


def _delay_by_amplitude_s(fit: _Fit, substeps: int,
                          clipped: dict[str, np.ndarray] | None = None
                          ) -> tuple[tuple[float, float], tuple[float, float]] | None:
    """The delay of :func:`_residual_delay_s` read off the quieter and the livelier half
    of the drives apart: ``((tau, std) of the windows under the median rms, (tau, std) of
    the rest)``, windows of :data:`AMPLITUDE_WINDOW_S`. None where the drives hold fewer
    than four windows. A late channel is late by the same at any amplitude; the lag of
    physics left out (free play, friction, hysteresis) is not."""
    cut = []
    for r, d, sim, rate in _delay_parts(fit, substeps, clipped):
        n = max(int(AMPLITUDE_WINDOW_S * rate), 1)
        k = sim.size // n
        if k:
            cut.append((np.sqrt(np.mean(sim[:k * n].reshape(k, n) ** 2, axis=1)),
                        r[:k * n].reshape(k, n), d[:k * n].reshape(k, n)))
    rms = np.concatenate([c[0] for c in cut]) if cut else np.empty(0)
    if rms.size < 4:
        return None
    median = float(np.median(rms))
    quiet = _delay_over_windows(np.concatenate([r[a < median] for a, r, _ in cut]),
                                np.concatenate([d[a < median] for a, _, d in cut]))
    lively = _delay_over_windows(np.concatenate([r[a >= median] for a, r, _ in cut]),
                                 np.concatenate([d[a >= median] for a, _, d in cut]))
    return quiet, lively


def _delay_over_windows(residual: np.ndarray, derivative: np.ndarray) -> tuple[float, float]:
    """:func:`_delay_ls` over windows (rows of ``residual`` and ``derivative``), its std
    from the scatter of the windows' least-squares scores (a cluster-robust sandwich: the
    residual's correlation within a window is measured, not assumed). ``(tau, std)``.

    The quiet and lively halves are compared by this std: :func:`_delay_ls`'s fixed
    inflation (3x) over-stated it by 2-4x on the random benchmark's cases (session 44:
    the windows' std hardly changes between 0.5 and 2 s windows there, and matches the
    spread of the estimate within 15 % on band-limited misfits), and hid a lag of Dahl
    friction that shrinks from 0.35 ms in the quiet half to 0.24 ms in the lively (seed
    1795938609); true late channels differ there by 0.00-0.02 of themselves. The delay
    itself is :func:`_delay_ls`'s (the same sums, over all windows)."""
    num = np.sum(residual * derivative, axis=1)
    den = np.sum(derivative * derivative, axis=1)
    total = float(den.sum())
    if total <= 0 or num.size < 2:
        return 0.0, float("inf")
    tau = -float(num.sum()) / total
    score = num + tau * den
    return tau, float(np.sqrt(np.sum(score ** 2) * num.size / (num.size - 1))) / total


#: Above the middle of the analysis band (geometric) a suspension's parameters can hardly
#: absorb a delay between the channels, so a late channel shows there at nearly its full
#: size; the phase lag of physics the model leaves out does not: hysteresis and the
#: pre-yield of friction lag by about a constant phase, a delay that shrinks as
#: 1 / frequency. A delay whose part above the middle is under this share of it (or of the
#: other sign) is physics, not a late channel. Wide of both: on the random benchmark's
#: cases (session 34) true delays of 0.8-2.7 ms showed 0.85-1.0 of themselves there, the
#: lags of Dahl friction, build-up hysteresis and a hysteretic spring 0.24-0.42.
DELAY_ABOVE_MIDDLE_SHARE = 0.5


def _lag_not_a_late_channel(chosen: _Fit, fits: Sequence[_Fit],
                            clipped: dict[str, np.ndarray] | None
                            ) -> tuple[_Fit, str] | None:
    """Where the chosen model corrects a channel time offset whose delay the recording
    does not show above the middle of the band (:data:`DELAY_ABOVE_MIDDLE_SHARE`): the
    same physics with the other corrections only, and words saying why. None where the
    delay holds there too, or no such fit was made."""
    if chosen.data is None:
        return None
    chain = chosen.data.chain
    hyp = next((h for h in chain if h.kind == "channel_time_offset"), None)
    band = chosen.result.band_hz
    if hyp is None or not band:
        return None
    if any(hyp.kind in EFFECTS[e].data_twins for e in chosen.physics):
        # a top mount delays the damper's force at every frequency: fitted to the drives
        # as recorded it takes up a late channel above the middle too, and says nothing
        return None
    ref = _without_delay(chosen, hyp, fits)
    if ref is None:
        return None
    # read off the same physics fitted to the drives without the delay's correction: fitted
    # to the corrected drives, the physics takes up part of a lag of its own kind
    middle_hz = float(np.sqrt(band[0] * band[1]))
    try:
        seen = _residual_delay_s(ref, substeps=2, clipped=clipped, above_hz=middle_hz)
    except (ValueError, FieldDiagError):
        return None
    if seen * hyp.value > 0 and abs(seen) >= DELAY_ABOVE_MIDDLE_SHARE * abs(hyp.value):
        return None
    # fitted to the drives as recorded, a hysteresis takes up part of a real late channel
    # beside it above the middle too (2.17 ms late beside Bouc-Wen: 1.20 ms seen there);
    # the chosen fit, to the corrected drives, cannot undo a correction that is too large
    # there (its lag cannot lead): the delay above the middle is the correction plus what
    # is left of it. Only where both say the delay does not hold there is it the lag's
    try:
        left = _residual_delay_s(chosen, substeps=2, clipped=clipped, above_hz=middle_hz)
    except (ValueError, FieldDiagError):
        left = None  # not read: the drives as recorded decide alone
    held = None if left is None else hyp.value + left
    if (held is not None and held * hyp.value > 0
            and abs(held) >= DELAY_ABOVE_MIDDLE_SHARE * abs(hyp.value)):
        return None
    return ref, _lag_note(hyp, chosen, (
        f"above {middle_hz:.1f} Hz, where a late channel shows in full, the recording's "
        f"channels are {1000 * seen:+.2f} ms apart: a lag that shrinks with frequency belongs "
        "to the suspension (hysteresis, the pre-yield of friction), not to the channels"))


def _lag_note(hyp: DataHypothesis, chosen: _Fit, why: str) -> str:
    """The words withdrawing the late channel ``hyp`` as the suspension's lag (``why``)."""
    named = " + ".join(e.replace("_", " ") for e in chosen.physics) or "the linear model"
    return (f"a {_DATA_LABEL[hyp.kind]} ({_data_size(hyp)}) fits the residual's phase, but "
            f"{why}. Not reported as a data problem; the findings are {named} on the drives "
            "as recorded")


def _without_delay(chosen: _Fit, hyp: DataHypothesis, fits: Sequence[_Fit]) -> _Fit | None:
    """The chosen physics fitted with the chosen data corrections but the delay ``hyp``
    (None where no such physical fit was made)."""
    rest = [h.kind for h in chosen.data.chain if h is not hyp]
    return next((f for f in fits if f.physics == chosen.physics and f.restored == chosen.restored
                 and [h.kind for h in (f.data.chain if f.data else [])] == rest
                 and f.candidate.physical), None)


#: A late channel is late by the same in quiet and lively stretches of a drive. Where the
#: delay held in the quieter half of the one-second windows and in the livelier half
#: differ by this share of the delay corrected, and by two standard deviations, the lag is
#: the suspension's (free play in a damper's mounting lags a stroke by a larger share the
#: shorter it is; friction and hysteresis likewise). Wide of both: on the independent
#: simulator's damper free play (benchmarks/foreign_cases.py, session 41) 0.25-0.42 of
#: 0.75-2.8 ms; on true late channels of 2.0-3.1 ms beside linear cars, Coulomb friction
#: and Bouc-Wen hysteresis 0.00-0.13.
AMPLITUDE_LAG_SHARE = 0.2


def _lags_with_amplitude(effect: str) -> bool:
    """Whether ``effect`` stands for physics whose lag changes with the size of the
    motion: dry friction (a Dahl friction's pre-yield, fitted as Coulomb's) and effects
    with an internal state (hysteresis), but not a state that lags alike at any amplitude
    (a top mount's, the twin of a late channel)."""
    cls = EFFECTS[effect]
    return effect == FRICTION or (cls.n_states > 0
                                  and "channel_time_offset" not in cls.data_twins)


def _halves_apart(split: tuple[tuple[float, float], tuple[float, float]], delay_s: float
                  ) -> bool:
    """Whether the delays read off the quiet and lively halves (:func:`_delay_by_amplitude_s`)
    beside a correction of ``delay_s`` differ by :data:`AMPLITUDE_LAG_SHARE` of it and by
    two standard errors of the difference: a lag that changes with amplitude."""
    (quiet, quiet_std), (lively, lively_std) = split
    return abs(quiet - lively) >= max(AMPLITUDE_LAG_SHARE * abs(delay_s),
                                      2.0 * float(np.hypot(quiet_std, lively_std)))


def _lag_changes_with_amplitude(chosen: _Fit, fits: Sequence[_Fit],
                                clipped: dict[str, np.ndarray] | None,
                                memory: _Fit | None = None
                                ) -> tuple[_Fit, str] | None:
    """Where the chosen model corrects a channel time offset that the recording holds by
    different amounts in quiet and lively stretches (:data:`AMPLITUDE_LAG_SHARE`): the
    same physics without the delay's correction, and words saying why. None where the
    delay holds alike, or no such fit was made.

    The halves are evidence, not a verdict: what the chosen physics leaves of a lag that
    changes with amplitude parts them beside a true late channel as well (Dahl friction
    fitted as Coulomb friction and a hysteretic spring beside a 1.46 ms late wheel
    channel, seed 1796006454: -1.08 and -1.41 ms). Its rival is the force with memory of
    each reversal fitted to the drives as recorded (``memory``): a lag that changes with
    amplitude and names nothing. Where the chosen model, late channel and all, predicts
    held-out data better than it as two explanations are told apart (:data:`TWIN_T` and
    the gain of a parameter), the words say a late channel is not ruled out. Measured:
    true late channels beside Dahl friction or build-up hysteresis t = +4.7 to +12.6 for
    the late channel against the shape, the independent simulator's damper free play
    t = -4.4 to -12.7 for the shape; but Dahl friction and build-up hysteresis without a
    late channel favour the delay as well (their pre-yield and pressure lags nearly are
    one: five of five cases), so the findings stay on the drives as recorded (a DAQ
    samples its channels together far more often than not).
    """
    if chosen.data is None or not chosen.physics:
        # beside the linear model alone, physics left out everywhere can make the halves
        # differ (a bump stop struck only in the lively half: seed 1795817438's true
        # 2.6 ms late wheel channel, held 2.86 and 2.07 ms): the physics behind the delay
        # is looked for next, on the drives corrected for it
        return None
    if not any(_lags_with_amplitude(e) for e in chosen.physics):
        # nor beside physics without memory: its model cannot stand for a lag that changes
        # with amplitude, while what it leaves out parts the halves as well (a progressive
        # spring missed beside asymmetric damping: a true 1.80 ms late wheel channel held
        # 1.98 ms in the quiet half, 1.37 in the lively, seed 1795974827; its correction
        # took the held-out NRMSE from 0.134 to 0.071)
        return None
    hyp = next((h for h in chosen.data.chain if h.kind == "channel_time_offset"), None)
    if hyp is None:
        return None
    ref = _without_delay(chosen, hyp, fits)
    if ref is None:
        return None
    try:
        split = _delay_by_amplitude_s(chosen, substeps=2, clipped=clipped)
    except (ValueError, FieldDiagError):
        return None
    if split is None:
        return None
    if not _halves_apart(split, hyp.value):
        return None
    (quiet, quiet_std), (lively, lively_std) = split
    held_quiet, held_lively = hyp.value + quiet, hyp.value + lively
    halves = (f"the recording's channels are {1000 * held_quiet:+.2f} +- "
              f"{1000 * quiet_std:.2f} ms apart in its quieter half and "
              f"{1000 * held_lively:+.2f} +- {1000 * lively_std:.2f} ms in its livelier half")
    vs = (compare(memory.candidate, chosen.candidate)
          if memory is not None and memory.candidate.physical else None)
    rival = ""
    if vs is not None and vs.t >= TWIN_T and vs.gain() >= MIN_GAIN_PER_PARAM:
        named = " + ".join(e.replace("_", " ") for e in chosen.physics)
        rival = (f"; yet {named} with the delay corrected predicts held-out data better than "
                 "a force with memory of each reversal without it (NRMSE "
                 f"{chosen.candidate.nrmse_validation:.4f} against "
                 f"{memory.candidate.nrmse_validation:.4f}, t = {vs.t:.1f}), so a late "
                 "channel beside that lag is not ruled out: check that both channels are "
                 "sampled together")
    return ref, _lag_note(hyp, chosen, (
        f"{halves}: a lag that changes with the size of the motion belongs to "
        "the suspension (free play, friction, hysteresis), not to the channels, which are "
        f"late by the same at any amplitude{rival}"))


def _time_domain_offset(base: _Fit, clipped: dict[str, np.ndarray] | None = None
                        ) -> DataHypothesis | None:
    """A channel time offset estimated against the linear model's simulation (away from
    ``clipped`` readings), for when the transmissibilities give none (the identification
    refused the pair: a large offset makes the drives look like two different cars)."""
    tau, std = _residual_delay_s(base, substeps=2, with_std=True, clipped=clipped)
    if abs(tau) >= MIN_TIME_OFFSET_S and abs(tau) >= MIN_Z * std:
        return DataHypothesis("channel_time_offset", tau, std)
    return None


FRICTION = "coulomb_friction"
KNEE = "digressive_damping"
#: The linear model's own effects (their parameters start every fit).
_LINEAR_EFFECTS = ("linear_spring", "linear_damper", "coupling_spring")
#: Dry friction switches within a few mm/s (the band-limited speed the fit sees rounds it
#: to 15-35 mm/s: a fitted switch width of 0.10-0.20 of the rms suspension speed on the
#: random benchmark's friction cases, session 41). A "friction" whose switch is wider than
#: this share of the rms speed levels off over the speeds the damper works at: a damper's
#: knee (the independent simulator's smooth digressive dampers: 0.25-0.89, named friction).
KNEE_SHARE_OF_SPEED = 0.35


def _knee_start(fit: _Fit) -> dict[str, float]:
    """Start values of the digressive damper that stands for ``fit``'s wide friction
    switch ``Ff tanh(v / v_s)``: knees at ``v_s`` both ways, the damping below them the
    linear damper's plus ``Ff / v_s``, dropping by ``Ff / v_s`` above."""
    start = _initial_from(fit)
    width = start.pop(f"{FRICTION}.smoothing_velocity_mps")
    slope = start.pop(f"{FRICTION}.friction_force_n", 0.0) / width
    damper = "linear_damper.suspension_damping_ns_per_m"
    if damper in start:
        start[damper] += slope
    for way in ("compression", "rebound"):
        start[f"{KNEE}.{way}_knee_mps"] = width
        start[f"{KNEE}.{way}_drop_ns_per_m"] = slope
    return start


def _friction_as_wide_as_the_speeds(fit: _Fit) -> str | None:
    """Words saying why ``fit``'s dry friction is a damper knee (its switch width is at
    least :data:`KNEE_SHARE_OF_SPEED` of the rms suspension speed), or None."""
    if FRICTION not in fit.physics or KNEE in fit.physics:
        return None
    width = fit.candidate.values.get(f"{FRICTION}.smoothing_velocity_mps")
    if width is None:
        return None
    speed = float(np.sqrt(np.mean(np.concatenate(
        [_states(p.fit)[1] for p in fit.prepared]) ** 2)))
    if not speed > 0 or width < KNEE_SHARE_OF_SPEED * speed:
        return None
    return (f"the dry friction fitted switches over {1000 * width:.0f} mm/s, "
            f"{100 * width / speed:.0f} % of the suspension's rms speed ({speed:.2f} m/s): "
            "dry friction switches within a few mm/s, so a force that levels off over the "
            "speeds the damper works at is a damper's knee (blow-off), not friction")


def _acts_on_position(fit: _Fit) -> bool:
    """Whether the chosen physics depends on where the suspension sits (its static force
    is not linear in the travel): then passive sag and restored ride height differ."""
    model = fit.candidate.extra["model"]
    vals = fit.candidate.values
    th = np.array([vals.get(k, 0.0) for k in model.param_keys])
    r = np.linspace(-TRAVEL_BOUND_M, TRAVEL_BOUND_M, 41)
    f = np.array([model.static_force(x, x, th) for x in r])
    line = np.polyval(np.polyfit(r, f, 1), r)
    return bool(np.max(np.abs(f - line)) > 1e-3 * max(np.max(np.abs(f)), 1e-9))


def _ride_height(chosen: _Fit, fits: Sequence[_Fit], grey: Callable[..., _Fit | None],
                 say: Callable[[str], None]) -> tuple[dict | None, _Fit | None]:
    """Passive sag (the contract) against a restored ride height for the loaded drive.

    A self-levelling suspension, or a technician re-setting the ride height after adding
    the mass, makes the loaded drive move about the unloaded deflection; a
    position-dependent effect (a bump stop, a progressive spring) then acts at other
    travels than under passive sag. The chosen model is compared with the same model
    under the other assumption (fitted here if the candidates did not include it).
    Returns the report and the other fit.
    """
    other = next((f for f in fits if f.effects == chosen.effects and f.data == chosen.data
                  and f.restored != chosen.restored), None)
    if other is None:
        say("testing passive sag against a restored ride height")
        other = grey(chosen.physics, _with_ride_height(chosen.prepared, not chosen.restored),
                     _initial_from(chosen), chosen.data)
    if other is None:
        return None, None
    sag, lev = (other, chosen) if chosen.restored else (chosen, other)
    t_lev = compare(sag.candidate, lev.candidate).t
    t_sag = compare(lev.candidate, sag.candidate).t
    if chosen.restored and t_lev >= 3.0:
        words = ("the data support a ride height restored after the mass was added "
                 f"(self-levelling or re-set; t = {t_lev:.1f} against passive sag): the "
                 "effects are given about the unloaded ride height, which both drives share")
    elif chosen.restored:
        words = ("a ride height restored after the mass was added (self-levelling or re-set) "
                 f"fits a little better than passive sag (t = {t_lev:.1f}, not decisive): the "
                 "travel at which the effects act is uncertain by the sag under the added mass")
    elif t_sag >= 3.0:
        words = ("the data support passive sag (the added mass lowered the body; t = "
                 f"{t_sag:.1f} against a restored ride height): the effects are given about "
                 "the unloaded ride height")
    else:
        words = ("assumed passive sag (the added mass lowers the body); a restored ride "
                 "height fits as well, so the travel at which the effects act is uncertain "
                 "by the sag under the added mass")
    say("  " + words)
    return {"assumed": "restored" if chosen.restored else "passive_sag",
            "t_restored_vs_sag": float(t_lev), "message": words}, other


def diagnose_sessions(
    paths: Sequence[str | os.PathLike],
    *,
    added_mass_kg: float | None = None,
    progress: Callable[[str], None] | None = None,
    **kw: Any,
) -> Diagnosis:
    """Diagnose one session or a before/after pair of session files.

    Parameters
    ----------
    paths : sequence of path
        One session, or the before and after sessions of a pair.
    added_mass_kg : float or None
        Mass added for the second drive [kg]; None reads it from the sessions'
        ``added_mass_kg`` attributes.
    progress : callable or None
        Called with a line of text at each step.
    **kw
        Passed to :func:`diagnose_drives`.

    Returns
    -------
    Diagnosis

    Raises
    ------
    FieldDiagError
        A missing channel, gaps, or a pair that is not one (see
        :func:`fielddiag.pairs.check_pair_files`).
    """
    paths = [Path(p) for p in paths]
    if len(paths) == 1:
        return diagnose_drives([read_drive(paths[0], "drive", 0.0)], progress=progress, **kw)
    from fielddiag.pairs import check_pair_files

    before = read_drive(paths[0], "before")  # a missing channel is said first
    after = read_drive(paths[1], "after")
    pair = check_pair_files(paths[0], paths[1], added_mass_kg)
    after.added_mass_kg = before.added_mass_kg + pair.added_mass_kg
    result = diagnose_drives([before, after], progress=progress, **kw)
    result.warnings[:0] = [data_checks.DataWarning("pair", w) for w in pair.warnings]
    return result
