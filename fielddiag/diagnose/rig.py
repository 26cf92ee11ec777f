"""Rig mode: diagnose one degree of freedom driven by a measured force.

On a damper or spring test rig (or a shaker) a load cell measures the force and a sensor
the displacement (or the acceleration) of the moving end. The model is::

    force = F0 + m a - F(r, rdot)          r = displacement, rdot its rate

with ``F`` the same force-term library as the vehicle model (linear spring ``-k r``,
linear damper ``-c rdot`` and the candidate effects), ``m`` the moving mass and ``F0`` a
preload or load-cell offset. The model is linear in every parameter but a bump stop's
gap, so fits are quick; held-out data (the last part of the recording) decide which
effects are real, with the rule of :mod:`fielddiag.diagnose.selection`.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy import optimize, signal

from fielddiag.blas import single_threaded_blas
from fielddiag.diagnose.locate import departure_map
from fielddiag.diagnose.selection import (
    CandidateFit,
    Selection,
    confidence,
    nrmse,
    select_model,
)
from fielddiag.errors import InsufficientDataError
from fielddiag.identify.terms import ForceModel, make_term, split_shape

#: Effect terms tried by default, in the diagnosis library's names.
RIG_EFFECTS = ("coulomb_friction", "cubic_stiffness", "bump_stop", "asymmetric_damping")


@dataclass(frozen=True)
class RigData:
    """Synchronous rig samples on a uniform time base (SI or the units recorded)."""

    sample_rate_hz: float
    time_s: np.ndarray
    force: np.ndarray
    displacement: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    force_unit: str = "N"
    displacement_unit: str = "m"

    def part(self, start: int, stop: int) -> RigData:
        sl = slice(start, stop)
        return RigData(
            self.sample_rate_hz,
            self.time_s[sl],
            self.force[sl],
            self.displacement[sl],
            self.velocity[sl],
            self.acceleration[sl],
            self.force_unit,
            self.displacement_unit,
        )

    @property
    def n(self) -> int:
        return int(self.force.size)


def _lowpass(x: np.ndarray, fs: float, cutoff_hz: float) -> np.ndarray:
    sos = signal.butter(4, cutoff_hz, fs=fs, output="sos")
    return signal.sosfiltfilt(sos, x)


def rig_data_from_displacement(
    time_s: np.ndarray,
    force: np.ndarray,
    displacement: np.ndarray,
    sample_rate_hz: float,
    *,
    cutoff_hz: float | None = None,
    force_unit: str = "N",
    displacement_unit: str = "m",
) -> RigData:
    """Velocity and acceleration by differentiating the displacement.

    Only the displacement is low-passed (zero phase, ``cutoff_hz``, default a tenth of the
    sample rate) to keep differentiation noise down; the force is left as measured, since
    filtering it would smear the steps of dry friction or a bump stop that the model, fed
    with the smooth motion, reproduces sharply (a 25 Hz filter biases a friction force
    about 15 % low). The displacement keeps its absolute zero (a bump stop's gap is
    measured from the rig's zero).
    """
    fs = float(sample_rate_hz)
    fc = cutoff_hz or 0.1 * fs
    x = _lowpass(np.asarray(displacement, float), fs, fc)
    f = np.asarray(force, float)
    v = np.gradient(x, 1.0 / fs)
    a = np.gradient(v, 1.0 / fs)
    return RigData(fs, np.asarray(time_s, float), f, x, v, a, force_unit, displacement_unit)


def rig_data_from_acceleration(
    time_s: np.ndarray,
    force: np.ndarray,
    acceleration: np.ndarray,
    sample_rate_hz: float,
    *,
    band_hz: tuple[float, float] | None = None,
    force_unit: str = "N",
) -> RigData:
    """Velocity and displacement by integrating the acceleration in ``band_hz``.

    The absolute position is lost: ``r`` is measured from the mean position.
    """
    from fielddiag.dsp import integrate_acceleration

    fs = float(sample_rate_hz)
    band = band_hz or (0.2, 0.1 * fs)
    motion = integrate_acceleration(acceleration, fs, band, method="frequency")
    f = np.asarray(force, float)
    return RigData(
        fs,
        np.asarray(time_s, float),
        f,
        motion.displacement_m,
        motion.velocity_mps,
        motion.acceleration_mps2,
        force_unit,
        "m",
    )


# ----------------------------------------------------------------------------- fitting
def _model_for(effects: Sequence[str]) -> ForceModel:
    names = ["linear_spring", "linear_damper", *effects]
    model = ForceModel(make_term(n) for n in names)
    return model


def _residual_and_jac(model: ForceModel, z: np.ndarray, data: RigData):
    f0, m, theta = z[0], z[1], z[2:]
    zeros = np.zeros_like(data.displacement)
    fm, _, dth = model.force(data.displacement, data.velocity, zeros, theta)
    pred = f0 + m * data.acceleration - fm
    res = data.force - pred
    jac = np.empty((data.n, z.size))
    jac[:, 0] = -1.0
    jac[:, 1] = -data.acceleration
    jac[:, 2:] = dth
    return res, jac


def _start_values(model: ForceModel, data: RigData, linear: dict[str, float]) -> list[np.ndarray]:
    """Start vectors: the linear fit's values plus typical/ data-scaled effect values."""
    base = []
    for key, spec in zip(model.param_keys, model.specs, strict=True):
        if key in linear:
            base.append(linear[key])
        elif spec.name == "friction_force_n":
            base.append(0.1 * float(np.std(data.force)))
        elif spec.name == "compression_damping_ns_per_m" or spec.name == "rebound_damping_ns_per_m":
            base.append(linear.get("linear_damper.suspension_damping_ns_per_m", spec.typical))
        elif spec.name == "cubic_stiffness_n_per_m3":
            base.append(0.0)
        elif spec.name == "stiffness_n_per_m":
            base.append(5.0 * linear.get("linear_spring.suspension_stiffness_n_per_m", 2e4))
        elif spec.name == "gap_m":
            base.append(float(np.quantile(-data.displacement, 0.9)))
        else:
            base.append(spec.typical)
    starts = [np.array([linear.get("f0", 0.0), linear.get("m", 0.0), *base])]
    if "bump_stop.gap_m" in model.param_keys:
        j = 2 + model.index("bump_stop.gap_m")
        for q in (0.7, 0.97):
            s = starts[0].copy()
            s[j] = max(float(np.quantile(-data.displacement, q)), 1e-4)
            starts.append(s)
    return starts


def _inside(z0: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """Move a start vector strictly inside finite bounds (least_squares needs it)."""
    z = np.array(z0, float)
    step = 1e-6 * np.maximum(np.abs(z), 1.0)
    z = np.where(np.isfinite(lower) & (z <= lower), lower + step, z)
    z = np.where(np.isfinite(upper) & (z >= upper), upper - step, z)
    return z


def fit_rig_model(
    effects: Sequence[str], data: RigData, linear: dict[str, float] | None = None
) -> tuple[ForceModel, np.ndarray, np.ndarray, float]:
    """Least-squares fit of ``F0, m`` and the model's parameters to the force.

    Returns (model, z, covariance, residual variance); ``z = [F0, m, theta...]``.
    """
    model = _model_for(effects)
    lower = np.concatenate(([-np.inf, 0.0], model.lower))
    upper = np.concatenate(([np.inf, np.inf], model.upper))
    linear = linear or {}
    best = None
    for z0 in _start_values(model, data, linear):
        z0 = _inside(z0, lower, upper)
        sol = optimize.least_squares(
            lambda z: _residual_and_jac(model, z, data)[0],
            z0,
            jac=lambda z: _residual_and_jac(model, z, data)[1],
            bounds=(lower, upper),
            x_scale="jac",
            method="trf",
        )
        if best is None or sol.cost < best.cost:
            best = sol
    res, jac = _residual_and_jac(model, best.x, data)
    dof = max(data.n - best.x.size, 1)
    s2 = float(res @ res) / dof
    try:
        cov = np.linalg.pinv(jac.T @ jac) * s2
    except np.linalg.LinAlgError:
        cov = np.full((best.x.size, best.x.size), np.nan)
    return model, best.x, cov, s2


def _named(model: ForceModel, z: np.ndarray) -> dict[str, float]:
    out = {"preload_n": float(z[0]), "moving_mass_kg": float(z[1])}
    for key, v in zip(model.param_keys, z[2:], strict=True):
        out[key] = float(v)
    return out


def _at_bound(
    model: ForceModel, z: np.ndarray, std: np.ndarray, effects: Sequence[str]
) -> tuple[str, ...]:
    """Effect parameters not significantly away from a bound (a physical limit)."""
    pinned = []
    for i, (key, spec) in enumerate(zip(model.param_keys, model.specs, strict=True)):
        if key.split(".")[0] not in effects:
            continue
        v, s = z[2 + i], std[2 + i]
        if spec.name == "smoothing_velocity_mps":
            # a loosely determined shape parameter: only its upper end (friction turned
            # into a linear damper) is telling
            if v >= 0.98 * spec.upper:
                pinned.append(key)
            continue
        for b in (spec.lower, spec.upper):
            if np.isfinite(b) and abs(v - b) <= max(2.0 * s, 1e-9 * max(abs(b), 1.0)):
                pinned.append(key)
        if spec.name == "cubic_stiffness_n_per_m3" and v < 0:
            pinned.append(key)  # a softening spring is not a progressive spring
    return tuple(pinned)


def _candidate(
    effects: Sequence[str], fit: RigData, val: RigData, linear: dict[str, float]
) -> CandidateFit:
    model, z, cov, _ = fit_rig_model(effects, fit, linear)
    std = np.sqrt(np.clip(np.diag(cov), 0, None))
    res_fit, _ = _residual_and_jac(model, z, fit)
    res_val, _ = _residual_and_jac(model, z, val)
    names = _named(model, z)
    stds = dict(zip(names, std.tolist(), strict=True))
    return CandidateFit(
        effects=tuple(effects),
        values=names,
        std=stds,
        nrmse_fit=nrmse(res_fit, fit.force),
        nrmse_validation=nrmse(res_val, val.force),
        residual_validation=res_val,
        n_params=z.size,
        at_bound=_at_bound(model, z, std, effects),
        extra={"model": model, "z": z},
    )


@dataclass
class RigDiagnosis:
    """Outcome of :func:`diagnose_rig`; ``to_dict`` gives the JSON of ``fielddiag diagnose``."""

    selection: Selection
    data: RigData
    split_index: int
    unexplained: dict | None

    def to_dict(self) -> dict:
        sel = self.selection
        base, chosen = sel.baseline, sel.chosen
        verdict = "adequate" if (chosen is base and self.unexplained is None) else "missing_physics"
        unit_k = f"{self.data.force_unit}/{self.data.displacement_unit}"
        findings = []
        if chosen is not base:
            explained = 1.0 - chosen.mse_validation / base.mse_validation
            for eff in chosen.effects:
                params, shape = split_shape({
                    k.split(".", 1)[1]: v
                    for k, v in chosen.values.items()
                    if k.startswith(eff + ".")
                })
                findings.append(
                    {
                        "effect": eff,
                        "confidence": confidence(sel.comparison, explained / max(explained, 0.3)),
                        "parameters": params,
                        "shape": shape,
                        "std": {
                            k.split(".", 1)[1]: v
                            for k, v in chosen.std.items()
                            if k.startswith(eff + ".")
                        },
                        "where": {"region": self._region(chosen)},
                        "explanation": _rig_explanation(eff, params, self.data),
                    }
                )
        if self.unexplained is not None:
            findings.append(self.unexplained)
        lin = {**base.values, **chosen.values}
        lin_std = {**base.std, **chosen.std}
        return {
            "mode": "rig",
            "verdict": verdict,
            "baseline": {"nrmse": base.nrmse_fit, "nrmse_validation": base.nrmse_validation},
            "augmented": {"nrmse": chosen.nrmse_fit, "nrmse_validation": chosen.nrmse_validation},
            "parameters": {
                "stiffness": {
                    "value": lin.get("linear_spring.suspension_stiffness_n_per_m"),
                    "std": lin_std.get("linear_spring.suspension_stiffness_n_per_m"),
                    "unit": unit_k,
                },
                "damping": {
                    "value": lin.get("linear_damper.suspension_damping_ns_per_m"),
                    "std": lin_std.get("linear_damper.suspension_damping_ns_per_m"),
                    "unit": f"{self.data.force_unit} s/{self.data.displacement_unit}",
                },
                "moving_mass_kg": {"value": lin["moving_mass_kg"],
                                   "std": lin_std.get("moving_mass_kg")},
                "preload": {"value": lin["preload_n"], "std": lin_std.get("preload_n"),
                            "unit": self.data.force_unit},
            },
            "findings": findings,
            "candidates": [
                {
                    "effects": list(c.effects),
                    "nrmse_validation": c.nrmse_validation,
                    "t": cmp.t,
                    "physical": c.physical,
                }
                for c, cmp in sel.ranking
            ],
            "validation": {"split_time_s": float(self.data.time_s[self.split_index])},
            "warnings": [],
        }

    def _region(self, cand: CandidateFit) -> dict | None:
        base = self.selection.baseline
        val = self.data.part(self.split_index, self.data.n)
        dmap = departure_map(
            val.displacement, val.velocity, base.residual_validation - cand.residual_validation
        )
        reg = dmap.region()
        return None if reg is None else {"displacement": reg["r_m"], "velocity": reg["rdot_mps"]}


def _rig_explanation(effect: str, p: dict[str, float], data: RigData) -> str:
    fu, du = data.force_unit, data.displacement_unit
    if effect == "coulomb_friction":
        return (
            f"dry friction of about {p['friction_force_n']:.3g} {fu}: a force step at every "
            "reversal of motion"
        )
    if effect == "cubic_stiffness":
        return (
            f"progressive spring: stiffness rises with deflection (cubic term "
            f"{p['cubic_stiffness_n_per_m3']:.3g} {fu}/{du}^3)"
        )
    if effect == "bump_stop":
        return (
            f"bump stop engaging {p['gap_m']:.3g} {du} into compression with "
            f"{p['stiffness_n_per_m']:.3g} {fu}/{du}"
        )
    if effect == "asymmetric_damping":
        return (
            f"damping differs by direction: {p['compression_damping_ns_per_m']:.4g} in "
            f"compression, {p['rebound_damping_ns_per_m']:.4g} in rebound ({fu} s/{du})"
        )
    return effect


def _unexplained_structure(
    base: CandidateFit, chosen: CandidateFit, fit: RigData, val: RigData
) -> dict | None:
    """Is there force left that depends on (r, rdot) but no candidate explains?

    A binned map of the chosen model's fit residual over (r, rdot) is applied to the
    held-out part; if it predicts the held-out residual significantly, structure is left.
    """
    model, z = chosen.extra["model"], chosen.extra["z"]
    res_fit, _ = _residual_and_jac(model, z, fit)
    dmap = departure_map(fit.displacement, fit.velocity, res_fit, bins=12)
    i = np.clip(np.searchsorted(dmap.r_edges_m, val.displacement) - 1, 0, dmap.mean.shape[0] - 1)
    j = np.clip(np.searchsorted(dmap.rdot_edges_mps, val.velocity) - 1, 0, dmap.mean.shape[1] - 1)
    pred = np.nan_to_num(dmap.mean[i, j])
    res_val = chosen.residual_validation
    from fielddiag.diagnose.selection import paired_block_t

    t = paired_block_t(res_val, res_val - pred)
    gain = 1.0 - np.mean((res_val - pred) ** 2) / np.mean(res_val**2)
    if t < 4.0 or gain < 0.1:
        return None
    reg = dmap.region()
    return {
        "effect": "unexplained",
        "confidence": float(min(1.0, gain)),
        "parameters": {},
        "where": {
            "region": None
            if reg is None
            else {"displacement": reg["r_m"], "velocity": reg["rdot_mps"]}
        },
        "explanation": (
            f"{100 * gain:.0f} % of the remaining force error depends on displacement and "
            "velocity in a way no effect in the library describes; look at the departure map"
        ),
    }


@single_threaded_blas
def diagnose_rig(
    data: RigData,
    *,
    effects: Sequence[str] = RIG_EFFECTS,
    holdout_fraction: float = 0.3,
    max_pair: bool = True,
) -> RigDiagnosis:
    """Fit the linear rig model and every candidate (single effects and pairs), and choose.

    Raises
    ------
    InsufficientDataError
        When the recording is too short or the motion too small to say anything.
    """
    if data.n < 500:
        raise InsufficientDataError(
            f"the rig recording has {data.n} samples; record at least 500 (several cycles)"
        )
    if np.std(data.velocity) <= 0 or np.std(data.force) <= 0:
        raise InsufficientDataError("the rig did not move or the force is constant")
    split = int(round(data.n * (1 - holdout_fraction)))
    fit, val = data.part(0, split), data.part(split, data.n)
    baseline = _candidate((), fit, val, {})
    linear = {k: v for k, v in baseline.values.items()}
    linear["f0"], linear["m"] = baseline.values["preload_n"], baseline.values["moving_mass_kg"]
    combos: list[tuple[str, ...]] = [(e,) for e in effects]
    if max_pair:
        combos += [c for c in itertools.combinations(effects, 2)]
    candidates = [_candidate(c, fit, val, linear) for c in combos]
    sel = select_model(baseline, candidates)
    unexplained = _unexplained_structure(baseline, sel.chosen, fit, val)
    return RigDiagnosis(sel, data, split, unexplained)


def rig_data_from_session(reader) -> RigData:
    """Rig samples from a session with a ``force`` channel and a ``displacement`` (or
    ``acceleration``) channel, on its time base.

    Raises
    ------
    ChannelNotFoundError
        Without a force channel, or with neither displacement nor acceleration.
    """
    from fielddiag.errors import ChannelNotFoundError

    force_spec = reader.channel_for_role("force")
    t = reader.time_s()
    force = reader.read(force_spec.name)
    fs = reader.sample_rate_hz
    if reader.channels_for_role("displacement"):
        spec = reader.channel_for_role("displacement")
        return rig_data_from_displacement(
            t,
            force,
            reader.read(spec.name),
            fs,
            force_unit=force_spec.unit or "N",
            displacement_unit=spec.unit or "m",
        )
    if reader.channels_for_role("acceleration"):
        spec = reader.channel_for_role("acceleration")
        return rig_data_from_acceleration(
            t, force, reader.read(spec.name), fs, force_unit=force_spec.unit or "N"
        )
    raise ChannelNotFoundError(
        f"{reader.path.name} has a force channel but no displacement or acceleration channel; "
        "import the rig's motion with --role displacement=COL (or --role acceleration=COL)"
    )
