"""Mismatch diagnosis of a car corner: fit, locate, name, refit, and check on held-out data.

1. **Fit** the linear model (spring, damper, and coupling when significant) to the first
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
5. **Check the data**: clipping, bias drift, a gain change between the drives, a time
   offset between the channels are reported as warnings about the data.
"""

from __future__ import annotations

import itertools
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy import optimize

from fielddiag import dsp
from fielddiag.blas import single_threaded_blas
from fielddiag.diagnose import data_checks
from fielddiag.diagnose.locate import (
    DepartureMap,
    departure_map,
    excess_band,
    residual_psd,
    residual_windows,
)
from fielddiag.diagnose.selection import (
    CandidateFit,
    Comparison,
    compare,
    confidence,
    nrmse,
    paired_block_t,
    select_model,
)
from fielddiag.drive import CornerDrive, read_corner_drive
from fielddiag.effects import EFFECTS, ForceModel, diagnosis_effects, get_effect, split_shape
from fielddiag.errors import FieldDiagError
from fielddiag.identify.greybox import (
    GreyBoxData,
    default_band_hz,
    fit_greybox,
    validation_runs,
)

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
    effects: tuple[str, ...]
    result: Any  # GreyBoxResult
    candidate: CandidateFit
    runs: list  # validation runs per drive: (SessionFit, measured, residual, time_s)


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


def _grey_fit(
    effects: Sequence[str],
    prepared: Sequence[_Prepared],
    coupling: bool,
    initial: dict[str, float] | None,
    substeps: int,
) -> _Fit:
    model = _model(effects, coupling)
    fits = [p.fit for p in prepared]
    if initial:
        allowed = set(model.param_keys) | {"body_mass_kg"}
        initial = {k: v for k, v in initial.items() if k in allowed}
    # trial steps of Levenberg-Marquardt may overflow before being rejected: not news
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        result = fit_greybox(fits, model, initial=initial, substeps=substeps, max_iterations=40)
        runs = validation_runs(result, [p.val for p in prepared], substeps=substeps)
    res_val = np.concatenate([r[2] for r in runs])
    meas_val = np.concatenate([r[1] for r in runs])
    vals, stds = _values(result)
    fit_sessions = result.fit_sessions()
    nr_fit = float(np.sqrt(np.mean([s.nrmse**2 for s in fit_sessions])))
    cand = CandidateFit(
        effects=tuple(effects),
        values=vals,
        std=stds,
        nrmse_fit=nr_fit,
        nrmse_validation=nrmse(res_val, meas_val),
        residual_validation=res_val,
        n_params=model.n_params,
        at_bound=_pinned(result, model, effects),
        extra={"model": model},
    )
    return _Fit(tuple(effects), result, cand, runs)


def _initial_from(fit: _Fit) -> dict[str, float]:
    vals, _ = _values(fit.result)
    return {k: v for k, v in vals.items() if np.isfinite(v)}


# ----------------------------------------------------------------------------- screening
def _states(p: GreyBoxData) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    r = p.body_disp_m - p.wheel_disp_m
    rdot = p.body_vel_mps - p.wheel_vel_mps
    return r, rdot, p.body_disp_m, p.body_accel_mps2


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
) -> _EquationErrorFit:
    """Fit (M + dM) a2 + dM g = F(r + r0, rdot, x2) on the fit part of every drive.

    ``r`` is the measured (integrated, band-limited) suspension extension; ``r0`` the static
    extension of each loaded drive (a free parameter per drive with added mass, fixed by
    the ``dM g`` balance), so nonlinear terms see the travel where they act. In absolute
    mode the mass is fitted too; otherwise everything is per unit mass (M = 1).
    """
    model = _model(effects, coupling)
    start = start or {}
    loaded = [k for k, p in enumerate(prepared) if p.fit.added_mass_kg != 0.0] if absolute else []

    def stack(part: str):
        cols = {"r": [], "v": [], "x": [], "a": [], "dm": [], "sess": []}
        for k, p in enumerate(prepared):
            d = getattr(p, part)
            r, rdot, x2, a2 = _states(d)
            cols["r"].append(r)
            cols["v"].append(rdot)
            cols["x"].append(x2)
            cols["a"].append(a2)
            cols["dm"].append(np.full(r.size, d.added_mass_kg))
            cols["sess"].append(np.full(r.size, k))
        return {key: np.concatenate(v) for key, v in cols.items()}

    fit, val = stack("fit"), stack("val")
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
    lo = np.concatenate([model.lower, [1.0] if absolute else [], np.full(len(loaded), -0.5)])
    hi = np.concatenate([model.upper, [1e5] if absolute else [], np.full(len(loaded), 0.5)])
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
        f, dst, dth = model.force(d["r"] + off, d["v"], d["x"], th)
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

    sol = optimize.least_squares(
        lambda z: residual(z, fit),
        z0,
        jac=lambda z: residual(z, fit, True)[1],
        bounds=(lo, hi),
        x_scale="jac",
        max_nfev=80,
    )
    th, m, _ = split(sol.x)
    values = dict(zip(model.param_keys, (float(v) for v in th), strict=True))
    if absolute:
        values["body_mass_kg"] = float(m)
    return _EquationErrorFit(values, residual(sol.x, val))


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

    @property
    def blocked(self) -> bool:
        """A data problem makes any suspension finding suspect."""
        return any(w.kind in BLOCKING_WARNINGS for w in self.warnings)

    @property
    def verdict(self) -> str:
        missing = self.chosen is not self.baseline or self.unexplained is not None
        return "missing_physics" if missing and not self.blocked else "adequate"

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
            "explanation": explain(effect, params, base.values, c.values, self.mode),
        }

    def plot_data(self, max_points: int = 1500) -> dict:
        """Compact arrays for a dashboard: held-out fits, residual spectrum, departure map."""
        fits = []
        aug_runs = {r[0].name: r for r in self.chosen.runs}
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
        return {"fit": fits, "residual_psd": self.residual_psd, "departure_map": dmap}

    def _where(self) -> dict:
        return {
            "band_hz": list(self.excess_band_hz) if self.excess_band_hz else None,
            "time_windows_s": self.windows,
            "region": self.region,
        }

    def to_dict(self) -> dict:
        base, chosen = self.baseline.candidate, self.chosen.candidate
        adequate = self.verdict == "adequate"
        findings = [] if chosen is base else [self._finding(e) for e in chosen.effects]
        if self.unexplained is not None:
            findings.append(
                {**self.unexplained, "where": {**self._where(), **self.unexplained["where"]}}
            )
        # drives that do not behave like one corner with the mass added: a competing
        # hypothesis that a finding (a progressive spring, friction...) explains
        warnings = [w.to_dict() for w in self.warnings
                    if not (w.kind == "pair_inconsistent" and findings)]
        if self.blocked and findings:
            withheld = ", ".join(f["effect"] for f in findings)
            warnings.append(
                {
                    "kind": "findings_withheld",
                    "message": f"the mismatch ({withheld}) is not blamed on the suspension while "
                    "the data problems above stand; fix the recording and diagnose again",
                }
            )
            findings = []
        aug = base if adequate or chosen is base else chosen
        return {
            "mode": self.mode,
            "verdict": self.verdict,
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
                for f in self.fits
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
    :meth:`fielddiag.effects.base.Effect.explain`)."""
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


def _transmissibility_warnings(drives: Sequence[Drive]) -> list[data_checks.DataWarning]:
    """Gain change between drives and channel time offset, from the identification's
    transmissibilities against its fitted linear model."""
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
    try:
        ident = identify_recordings(
            recs[0], recs[1], drives[1].added_mass_kg - drives[0].added_mass_kg
        )
    except FieldDiagError as exc:
        # Only a lack of excitation is a problem of the data; the linear identification
        # also refuses when the physics is not linear, which is the diagnosis's own subject.
        if "excitation" in str(exc):
            return [data_checks.DataWarning("too_little_excitation", str(exc))]
        return []
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
    start = {
        k: getattr(ident, k).value
        for k in (
            "sprung_mass_kg",
            "suspension_stiffness_n_per_m",
            "suspension_damping_ns_per_m",
            "coupling_stiffness_n_per_m",
        )
    }
    dm = drives[1].added_mass_kg - drives[0].added_mass_kg
    found = [
        data_checks.check_gain_change(trs, band, added_mass_kg=dm, start=start),
        data_checks.check_time_offset(trs, band),
    ]
    found += [data_checks.DataWarning("pair_inconsistent", w) for w in ident.warnings
              if w.startswith(PAIR_INCONSISTENT)]
    return [w for w in found if w is not None]


#: Data problems that make any physics found suspect: findings are withheld.
BLOCKING_WARNINGS = ("sensor_gain_changed", "channel_time_offset", "clipping")


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
        return float(model.force(r, 0.0, r, th)[0][0]) - load_n

    try:
        return float(brentq(net, -0.5, 0.5, xtol=1e-7))
    except ValueError:  # no sign change: fall back to the linear estimate
        k = th[model.index("linear_spring.suspension_stiffness_n_per_m")]
        return -load_n / k if k > 0 else 0.0


def _departure(
    fit: _Fit, prepared: Sequence[_Prepared], coupling: bool
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Equation-error departure of the fitted model on the measured states, all data."""
    model = fit.candidate.extra["model"]
    vals = fit.candidate.values
    th = np.array([vals.get(k, 0.0) for k in model.param_keys])
    mass = vals.get("body_mass_kg", 1.0)
    rs, vs, ds, is_val = [], [], [], []
    for p in prepared:
        for part, flag in ((p.fit, False), (p.val, True)):
            r, rdot, x2, a2 = _states(part)
            g = GRAVITY if "body_mass_kg" in vals else 0.0
            r = r + _model_static_offset(model, th, part.added_mass_kg * g)
            f, _, _ = model.force(r, rdot, x2, th)
            rs.append(r)
            vs.append(rdot)
            ds.append((mass + part.added_mass_kg) * a2 + part.added_mass_kg * GRAVITY - f)
            is_val.append(np.full(r.size, flag))
    return np.concatenate(rs), np.concatenate(vs), np.concatenate(ds), np.concatenate(is_val)


#: Structure left in the chosen model's residual is reported as ``unexplained`` only when
#: it is a material part of the mismatch the linear model had: a found effect that removes
#: 95 % of the misfit may leave a few % of shape error (a rounded friction switch) that is
#: not new physics.
UNEXPLAINED_MIN_SHARE_OF_LINEAR_MISFIT = 0.03


def _unexplained(
    fit: _Fit, prepared: Sequence[_Prepared], coupling: bool, baseline: _Fit | None = None,
    say: Callable[[str], None] = lambda _m: None, known: Sequence[str] = EFFECT_LIBRARY,
) -> tuple[dict | None, DepartureMap]:
    """Force left that depends on (r, rdot) but that the chosen model does not describe."""
    r, v, dep, is_val = _departure(fit, prepared, coupling)
    dmap = departure_map(r[~is_val], v[~is_val], dep[~is_val], bins=12)
    i = np.clip(np.searchsorted(dmap.r_edges_m, r[is_val]) - 1, 0, dmap.mean.shape[0] - 1)
    j = np.clip(np.searchsorted(dmap.rdot_edges_mps, v[is_val]) - 1, 0, dmap.mean.shape[1] - 1)
    ok = dmap.count[i, j] >= 30
    pred = np.where(ok, np.nan_to_num(dmap.mean[i, j]), 0.0)
    e = dep[is_val] - np.mean(dep[~is_val])
    t = paired_block_t(e, e - pred)
    gain = 1.0 - float(np.mean((e - pred) ** 2) / np.mean(e**2))
    full_map = departure_map(r, v, dep, bins=12)
    share = gain
    if baseline is not None and baseline is not fit:
        share = gain * fit.candidate.mse_validation / baseline.candidate.mse_validation
    if gain > 0:
        say(f"  structure left in the residual: {100 * gain:.1f} % of it (t = {t:.1f}), "
            f"{100 * share:.1f} % of the linear model's misfit")
    else:  # the map of the fitted part predicts the held-out residual no better than zero
        say("  structure left in the residual: none found")
    if t < 4.0 or gain < 0.08 or share < UNEXPLAINED_MIN_SHARE_OF_LINEAR_MISFIT:
        return None, full_map
    reg = dmap.region()
    names = ", ".join(EFFECTS[n].description for n in known if n in EFFECTS)
    return {
        "effect": "unexplained",
        "confidence": float(min(1.0, 2.0 * gain)),
        "parameters": {},
        "where": {"region": reg},
        "explanation": (
            f"{100 * gain:.0f} % of the force the model leaves unexplained depends on "
            f"suspension travel and speed in a way none of the known effects ({names}) "
            "describes; see the departure map for where it acts"
        ),
    }, full_map


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
    max_full_fits: int = 7,
    progress: Callable[[str], None] | None = None,
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
    max_full_fits : int
        Grey-box fits of candidates: every single effect, then pairs of the useful ones.
    progress : callable or None
        Called with a line of text at each step.
    """
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
    if mode == "pair":
        warnings += _transmissibility_warnings(drives)
    prepared = [_prepare(d, band, rate, holdout_fraction) for d in drives]
    fit_rate = prepared[0].full.sample_rate_hz

    say("fitting the linear model")
    base = _grey_fit((), prepared, True, None, substeps=2)
    k3 = base.candidate.values.get("coupling_spring.coupling_stiffness_n_per_m", 0.0)
    k3s = base.candidate.std.get("coupling_spring.coupling_stiffness_n_per_m", np.inf)
    coupling = bool(abs(k3) > 4.0 * k3s)
    if not coupling:
        base = _grey_fit((), prepared, False, _initial_from(base), substeps=2)
    windows, exband, psd = _locate(base, prepared, fit_rate)

    say("testing each effect against the residual's signature")
    absolute = mode == "pair"
    ee_base = _equation_error_fit((), prepared, coupling, absolute)
    combos = [(e,) for e in effects] + list(itertools.combinations(effects, 2))
    screening: dict[str, dict[str, float]] = {}
    ee_fits: dict[tuple[str, ...], _EquationErrorFit] = {}
    mse_b = float(np.mean(ee_base.residual_validation**2))
    for combo in combos:
        try:
            ee = _equation_error_fit(combo, prepared, coupling, absolute, ee_base.values)
        except (ValueError, np.linalg.LinAlgError):
            continue
        ee_fits[combo] = ee
        gain = 1.0 - float(np.mean(ee.residual_validation**2)) / mse_b
        t = paired_block_t(ee_base.residual_validation, ee.residual_validation)
        screening["+".join(combo)] = {"gain": gain, "t": t}
    fits = [base]

    def grey(combo: tuple[str, ...]) -> _Fit | None:
        say(f"fitting the model with {' + '.join(combo)}")
        start = ee_fits[combo].values if combo in ee_fits else _initial_from(base)
        try:
            return _grey_fit(combo, prepared, coupling, start, substeps=2)
        except (FieldDiagError, np.linalg.LinAlgError, FloatingPointError) as exc:
            say(f"  {' + '.join(combo)} could not be fitted: {exc}")
            return None

    # every single effect gets the full fit (started from its signature fit); pairs only
    # of the single effects that predict held-out data better than the linear model
    if any(w.kind in BLOCKING_WARNINGS for w in warnings):
        # the data are known bad (clipped, misaligned, rescaled): findings would be
        # withheld anyway, and fitting effects to corrupted data only wastes time
        say("data problems found: effects are not fitted")
        effects = ()
    singles = [f for f in (grey((e,)) for e in effects) if f is not None]
    fits += singles
    useful = sorted(
        (
            f
            for f in singles
            if f.candidate.physical and compare(base.candidate, f.candidate).t > 0.0
        ),
        key=lambda f: f.candidate.mse_validation,
    )[:3]
    pairs = [
        tuple(sorted(a.effects + b.effects, key=list(effects).index))
        for a, b in itertools.combinations(useful, 2)
    ]
    for combo in pairs[: max(0, max_full_fits - len(singles))]:
        f = grey(combo)
        if f is not None:
            fits.append(f)
    sel = select_model(base.candidate, [f.candidate for f in fits[1:]])
    chosen = next(f for f in fits if f.candidate is sel.chosen)
    say("looking for structure no effect explains")
    unexplained, _ = _unexplained(chosen, prepared, coupling, base, say, known=tried)
    # where the restoring force departs from the *linear* surface (what the findings fix)
    r, v, dep, _ = _departure(base, prepared, coupling)
    dmap = departure_map(r, v, dep, bins=12)
    region = dmap.region()
    return Diagnosis(
        mode=mode,
        drives=drives,
        band_hz=band,
        baseline=base,
        chosen=chosen,
        comparison=sel.comparison,
        fits=fits,
        screening=screening,
        windows=windows,
        excess_band_hz=exband,
        departure=dmap,
        region=region,
        unexplained=unexplained,
        warnings=warnings,
        residual_psd=psd,
    )


def diagnose_sessions(
    paths: Sequence[str | os.PathLike],
    *,
    added_mass_kg: float | None = None,
    progress: Callable[[str], None] | None = None,
    **kw: Any,
) -> Diagnosis:
    """Diagnose one session or a before/after pair of session files.

    ``added_mass_kg`` is the mass added for the second drive; None reads it from the
    sessions' ``added_mass_kg`` attributes.
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
