"""Identify the full vehicle from a drive before and a drive after adding a known mass.

:func:`identify_vehicle` -> :class:`VehicleIdentification`. Method (seed 003, adapted to
output-only accelerometer data):

1. Each drive's eight accelerometers (gravity and offsets removed) are integrated twice
   in the frequency domain (:func:`integrate_twice`) and band-pass filtered without phase
   shift (Butterworth, ``scipy.signal.sosfiltfilt``), the same filters (and the frequency
   weighting of step 3) applied to every quantity, so that accelerations, velocities and
   displacements are the same linear filter of the true motion and the equations of
   motion hold between them exactly. The car's longitudinal and lateral accelerations
   get the same filter. The ends (filter transients) are dropped and the signals
   decimated to the analysis rate.
2. The four body sensors give heave, pitch and roll at the origin (least squares), hence
   the body motion above each hub and the suspension extension and its rate.
3. The body equations (:mod:`fielddiag.vehicle.regression`), linear in mass, first
   moments, inertias, corner stiffness and damping, anti-roll stiffness and the roll and
   pitch moment arms, are stacked over both drives; the known added mass at its known
   position is the only non-zero right-hand side and fixes the scale. Weighted least
   squares, the accelerometers' noise bias compensated (errors in variables), with a
   time-block jackknife that repeats the whole estimate gives every parameter a
   standard deviation, relative standard deviations and correlations. The noise:
   the body sensors' from their redundancy; the hub sensors' (which also carries the
   wheel's high-frequency acceleration a DAQ with a gentle anti-alias filter folds into
   the band) band by band from the equation errors, with a covariance common to the
   left and right hub (:func:`~fielddiag.vehicle.regression.compensated_least_squares`);
   the equations weighted in frequency by one over the noise's share of their errors
   (:func:`noise_weighting`, generalised least squares: double integration makes the
   noise grow as ``1 / f^2`` towards the band's low end, where the suspension hardly
   moves). The estimate with another structure of the hub noise (left-right and
   front-rear covariances) is carried as a systematic uncertainty.
4. Derived quantities (centre of gravity, inertias about it) get their standard
   deviations by the delta method.
5. Output-error refinement (:mod:`fielddiag.vehicle.output_error`): the body simulated
   from the measured hub motion, the parameters adjusted to its accelerations; tried when
   validate drives are given and kept only if it predicts them better (by
   ``refine_gain``).
6. Each ``validate`` drive (same car, another manoeuvre) is predicted: the body
   accelerations simulated from its measured hub motion and car accelerations, against
   the measured ones (NRMSE = RMS error / RMS of the measured, band-passed, after the
   first seconds of the simulation).

The JSON (:meth:`VehicleIdentification.to_dict`) has exactly the issue's contract keys.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import fft as sp_fft
from scipy import signal

from fielddiag.channels import CORNERS
from fielddiag.errors import FieldDiagError, InsufficientDataError, InvalidValueError
from fielddiag.vehicle.output_error import SETTLE_S, refine_output_error, simulate_body_accel
from fielddiag.vehicle.recording import VehicleRecording, reading_notes
from fielddiag.vehicle.regression import (
    N_PARAMS,
    PARAM_NAMES,
    DriveNoise,
    DriveRegressors,
    WlsResult,
    band_split,
    block_grams,
    compensated_least_squares,
    equation_error_transfer,
    noise_gram,
    regressors,
)

__all__ = ["VehicleIdentifyConfig", "VehicleIdentification", "identify_vehicle",
           "prepare_drive"]


@dataclass(frozen=True)
class VehicleIdentifyConfig:
    """Settings of the full-vehicle identification.

    Parameters
    ----------
    band_hz : (float, float)
        Zero-phase band-pass [Hz] (body modes ~1-2 Hz, wheel hop ~10-15 Hz).
    filter_order : int
        Butterworth order of each band-pass.
    analysis_rate_hz : float
        Rate after decimation [Hz] (at least 3 x the upper band edge).
    trim_s : float or None
        Dropped at each end of a drive after filtering [s]; None: 4.5 / low band edge (9 s
        at 0.5 Hz). The band-pass transients of the integrated signals last about that
        long (measured: with 0.4 Hz and 3 s the estimates collapse, with 15 s they are
        right).
    block_s : float
        Time block of the jackknife [s] (longer than the residuals' correlation).
    passes : int
        Times the zero-phase band-pass is applied (each pass squares the attenuation).
    jackknife_bias : bool
        Remove the jackknife's bias estimate from the least-squares estimate.
    compensation_doubt, scale_floor : float
        A systematic uncertainty of the common scale of all parameters (the added mass
        fixes the scale of mass, inertias, stiffness and damping together; ratios such as
        the centre of gravity do not carry it): ``compensation_doubt`` times the relative
        change of the mass the noise compensation made, and ``scale_floor`` (relative),
        added in quadrature to the covariance as ``s^2 theta theta^T``.
    min_duration_s : float
        Shortest drive accepted [s].
    noise_compensation : bool
        Remove the bias the accelerometer noise puts on least squares (errors in
        variables): the noise of the body sensors is measured from their redundancy
        (:func:`body_noise_std_mps2`), that of the car's acceleration signals above a
        quarter of the rate (:func:`car_accel_noise_std_mps2`), that of the hub sensors
        (see ``hub_noise``); its expected share of the normal equations follows from the
        processing's transfer functions (:func:`filter_response`,
        :func:`~fielddiag.vehicle.regression.noise_gram`) and is subtracted.
    refine : bool
        Try the output-error refinement (:mod:`fielddiag.vehicle.output_error`) when there
        are validate drives, and keep it only if it predicts their body accelerations
        better (on the identification drives it is better by construction, so they cannot
        judge it). Off by default: it costs 5-10 s on two 180 s drives, and on the
        simulated linear cars it was never kept (``fielddiag identify --refine``).
    refine_gain : float
        Relative NRMSE improvement the refinement must bring to be kept.
    noise_weighting : bool
        Weight the equations in frequency by one over the noise's share of their errors
        (:func:`noise_weighting`) instead of flat over the band.
    hub_noise : str
        ``"spectrum"``: the hub sensors' noise estimated band by band from the equation
        errors (it includes what aliasing folds into the band: on simulated 200 Hz drives
        with a 4th-order anti-alias filter at 0.4 fs, as much as 0.02-0.06 m/s^2 of
        white-equivalent noise, more than the sensors'); ``"body"``: taken as the body
        sensors' (the method before issue 18's 200 Hz fix).
    hub_noise_iterations : int
        Rounds of the fixed point between the parameters and the hub noise.
    hub_noise_bands : int
        Bands of the hub noise spectrum (geometric between the band's edges).
    hub_noise_correlation : tuple of str
        Covariances of the hub noise estimated besides each hub's variance:
        ``"left_right"`` (the two tracks of a road are alike; so is what they put into
        the hubs), ``"front_rear"`` (three equations cannot fit both: with both, the
        equations' cross products are used too, less stable).
    structure_doubt : float
        Times the difference between the estimate with ``hub_noise_correlation`` and
        with both covariances (fitted to the cross products as well), added to the
        covariance as a systematic uncertainty (0: off).
    """

    band_hz: tuple[float, float] = (0.5, 25.0)
    filter_order: int = 4
    analysis_rate_hz: float = 100.0
    trim_s: float | None = None
    block_s: float = 5.0
    passes: int = 1
    jackknife_bias: bool = False
    compensation_doubt: float = 0.0
    scale_floor: float = 0.001
    min_duration_s: float = 40.0
    noise_compensation: bool = True
    refine: bool = False
    refine_gain: float = 0.10
    noise_weighting: bool = True
    hub_noise: str = "spectrum"
    hub_noise_iterations: int = 4
    hub_noise_bands: int = 6
    hub_noise_correlation: tuple[str, ...] = ("left_right",)
    hub_noise_cross_products: bool = False
    structure_alternative: tuple[tuple[str, ...], bool] = (("left_right", "front_rear"), True)
    structure_doubt: float = 1.0


def _bp(x: np.ndarray, sos: np.ndarray, times: int = 1) -> np.ndarray:
    for _ in range(times):
        x = signal.sosfiltfilt(sos, x, axis=-1)
    return x


def integrate_twice(acc: np.ndarray, sample_rate_hz: float, low_hz: float,
                    weight: Callable[[np.ndarray], np.ndarray] | None = None
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Acceleration, velocity and displacement by exact integration in the frequency domain.

    The mean is removed and a zero-phase raised-cosine high-pass (0 below ``low_hz / 2``,
    1 above ``low_hz``) applied to all three alike, so they are the same linear filter of
    the true motion (``v = a / (j w)``, ``x = a / (j w)^2`` at every frequency line). The
    trapezoid rule would not be: its gain ``(w dt / 2) cot(w dt / 2)`` falls short of
    ``1 / (j w)`` by 1-3 % at the wheel hop at 200 Hz sampling, which biased every
    parameter by 5-9 % at that rate (measured).

    Parameters
    ----------
    acc : ndarray (channels, n)
        Accelerations [m/s^2] (gravity and offsets are removed with the mean).
    sample_rate_hz : float
    low_hz : float
        Edge of the high-pass [Hz].
    weight : callable or None
        A real zero-phase gain ``weight(f_hz)`` applied to all three alike (the frequency
        weighting of the least squares, :func:`noise_weighting`).

    Returns
    -------
    a, v, x : ndarray (channels, n)
        [m/s^2], [m/s], [m].
    """
    n = acc.shape[-1]
    spec = sp_fft.rfft(acc - acc.mean(axis=-1, keepdims=True), n, axis=-1)
    f = sp_fft.rfftfreq(n, 1.0 / sample_rate_hz)
    u = np.clip((f - 0.5 * low_hz) / (0.5 * low_hz), 0.0, 1.0)
    spec = spec * (0.5 - 0.5 * np.cos(np.pi * u))
    if weight is not None:
        spec = spec * weight(f)
    jw = 2j * np.pi * f
    jw[0] = 1.0
    vel = spec / jw
    return (sp_fft.irfft(spec, n, axis=-1), sp_fft.irfft(vel, n, axis=-1),
            sp_fft.irfft(vel / jw, n, axis=-1))


def prepare_drive(rec: VehicleRecording, cfg: VehicleIdentifyConfig = VehicleIdentifyConfig(),
                  weight: Callable[[np.ndarray], np.ndarray] | None = None) -> DriveRegressors:
    """Band-passed, integrated, decimated body and suspension motion of one drive.

    Parameters
    ----------
    rec : VehicleRecording
    cfg : VehicleIdentifyConfig
    weight : callable or None
        Frequency weighting applied to every signal (:func:`noise_weighting`).

    Returns
    -------
    DriveRegressors

    Raises
    ------
    InsufficientDataError
        The drive is shorter than ``cfg.min_duration_s``.
    InvalidValueError
        The band does not fit under the drive's Nyquist frequency.
    """
    fs = float(rec.sample_rate_hz)
    lo, hi = cfg.band_hz
    if not 0 < lo < hi < 0.45 * fs:
        raise InvalidValueError(f"band {lo:g}-{hi:g} Hz does not fit a {fs:g} Hz recording; "
                                f"give 0 < low < high < {0.45 * fs:g} Hz")
    if rec.duration_s < cfg.min_duration_s:
        kept = "".join(f" ({n})" for n in reading_notes(rec))
        raise InsufficientDataError(
            f"{rec.name or rec.label or 'a drive'} lasts {rec.duration_s:.1f} s{kept}; the "
            f"full vehicle needs at least {cfg.min_duration_s:g} s of driving on a rough road "
            "without a gap (record longer)")
    sos = signal.butter(cfg.filter_order, [lo, hi], "bandpass", fs=fs, output="sos")
    acc = np.vstack([rec.wheel_accel_mps2, rec.body_accel_mps2]).astype(float)
    car = np.vstack([rec.signal_or_zero("accel_long"), rec.signal_or_zero("accel_lat")])
    a0, v0, x0 = integrate_twice(acc, fs, 0.5 * lo, weight)
    c0 = integrate_twice(car, fs, 0.5 * lo, weight)[0]
    a3, v3, x1, car = (_bp(y, sos, cfg.passes) for y in (a0, v0, x0, c0))
    keep = analysis_samples(acc.shape[1], fs, cfg)
    step = keep.step
    a3, v3, x1, car = a3[:, keep], v3[:, keep], x1[:, keep], car[:, keep]
    g = rec.geometry
    pinv = np.linalg.pinv(g.sensor_matrix())
    cm = g.corner_matrix()
    qdd = pinv @ a3[4:]
    zb_v, zb_x = cm @ (pinv @ v3[4:]), cm @ (pinv @ x1[4:])
    at = rec.added_mass_at_m if rec.added_mass_at_m is not None else (0.0, 0.0)
    return DriveRegressors(
        qdd=qdd, r=zb_x - x1[:4], rd=zb_v - v3[:4], a_long=car[0], a_lat=car[1],
        body_accel=a3[4:], corner_x=g.corner_x_m, corner_y=g.corner_y_m,
        sensor_matrix=g.sensor_matrix(), added_mass_kg=float(rec.added_mass_kg),
        added_mass_at_m=(float(at[0]), float(at[1])), rate_hz=fs / step,
        wheel_disp=x1[:4], wheel_vel=v3[:4])


def analysis_samples(n_samples: int, sample_rate_hz: float, cfg: VehicleIdentifyConfig
                     ) -> slice:
    """The samples the equations use: the filter's settling time trimmed at both ends,
    every ``step``-th sample for about ``cfg.analysis_rate_hz``.

    The step is the whole number of samples per analysis sample, rounded when the rate is
    within 1 % of a multiple (a session's rate from its time stamps, 499.9998 Hz, is a
    500 Hz recording: step 5, not 4).

    Parameters
    ----------
    n_samples : int
        Samples of the drive.
    sample_rate_hz : float
        Its rate [Hz].
    cfg : VehicleIdentifyConfig
        Band (its low edge sets the trim), trim and analysis rate.

    Returns
    -------
    slice
    """
    ratio = float(sample_rate_hz) / cfg.analysis_rate_hz
    step = max(1, int(math.floor(ratio + 0.01 * ratio)))
    lo = cfg.band_hz[0]
    trim = int(round((4.5 / lo if cfg.trim_s is None else cfg.trim_s) * sample_rate_hz))
    return slice(trim, n_samples - trim, step)


# --------------------------------------------------------------------------- results
@dataclass
class Estimate:
    """A value with its standard deviation (SI)."""

    value: float
    std: float

    def to_dict(self) -> dict[str, float]:
        """``{"value", "std"}``."""
        return {"value": float(self.value), "std": float(self.std)}

    @property
    def relative_std(self) -> float:
        """std / |value| (inf for a zero value)."""
        return abs(self.std / self.value) if self.value else math.inf


@dataclass
class VehicleIdentification:
    """The identified full vehicle.

    Attributes
    ----------
    sprung_mass_kg, cog_behind_front_axle_m, cog_left_of_centre_m, pitch_inertia_kgm2,
    roll_inertia_kgm2, anti_roll_stiffness_front_n_per_m, anti_roll_stiffness_rear_n_per_m
        :class:`Estimate` each (inertias about axes through the centre of gravity).
    corners : dict corner -> {"stiffness_n_per_m": Estimate, "damping_ns_per_m": Estimate}
    cross_validation : list of {"session", "nrmse"}
        One entry per validate drive (empty without).
    wls : WlsResult
        The raw estimate of the linear-in-parameters model (:data:`PARAM_NAMES`).
    fit_nrmse : dict label -> float
        NRMSE of the simulated body accelerations on the identification drives.
    method : str
        How it was obtained.
    refinement : dict
        The output-error refinement: ``applied``, ``judged_on`` and the NRMSE of the
        least-squares and of the refined parameters it was judged by.
    noise : dict
        The noise the compensation used: ``body_noise_std_mps2`` and
        ``car_accel_noise_std_mps2`` per drive, ``hub_noise_std_mps2`` (drives, bands;
        white-equivalent at the recording's rate), ``hub_noise_ratio`` (per drive, over the
        body sensors', the bands weighted by their share of the equation errors),
        ``hub_noise_correlation``,
        ``band_edges_hz``, ``compensation_shift`` (relative change of the mass the
        compensation made), ``structure_shift``.
    warnings : list of str
        What limits the result, in words (also in :meth:`summary`).
    """

    sprung_mass_kg: Estimate
    cog_behind_front_axle_m: Estimate
    cog_left_of_centre_m: Estimate
    pitch_inertia_kgm2: Estimate
    roll_inertia_kgm2: Estimate
    corners: dict[str, dict[str, Estimate]]
    anti_roll_stiffness_front_n_per_m: Estimate
    anti_roll_stiffness_rear_n_per_m: Estimate
    wls: WlsResult
    cross_validation: list[dict[str, Any]] = field(default_factory=list)
    fit_nrmse: dict[str, float] = field(default_factory=dict)
    method: str = ""
    refinement: dict[str, Any] = field(default_factory=dict)
    noise: dict[str, Any] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        """The contract's JSON: each quantity ``{"value", "std"}`` in SI units."""
        out: dict[str, Any] = {
            "sprung_mass_kg": self.sprung_mass_kg.to_dict(),
            "cog_behind_front_axle_m": self.cog_behind_front_axle_m.to_dict(),
            "cog_left_of_centre_m": self.cog_left_of_centre_m.to_dict(),
            "pitch_inertia_kgm2": self.pitch_inertia_kgm2.to_dict(),
            "roll_inertia_kgm2": self.roll_inertia_kgm2.to_dict(),
            "corners": {c: {k: v.to_dict() for k, v in self.corners[c].items()}
                        for c in CORNERS},
            "anti_roll_stiffness_front_n_per_m": self.anti_roll_stiffness_front_n_per_m.to_dict(),
            "anti_roll_stiffness_rear_n_per_m": self.anti_roll_stiffness_rear_n_per_m.to_dict(),
        }
        if self.cross_validation:
            out["cross_validation"] = [dict(c) for c in self.cross_validation]
        return out

    def to_json(self) -> str:
        """:meth:`to_dict` as indented JSON."""
        return json.dumps(self.to_dict(), indent=2)

    def flat(self) -> dict[str, Estimate]:
        """Every reported quantity by a flat name (``corner_fl_stiffness_n_per_m``...)."""
        out = {k: getattr(self, k) for k in (
            "sprung_mass_kg", "cog_behind_front_axle_m", "cog_left_of_centre_m",
            "pitch_inertia_kgm2", "roll_inertia_kgm2", "anti_roll_stiffness_front_n_per_m",
            "anti_roll_stiffness_rear_n_per_m")}
        for c in CORNERS:
            for k, v in self.corners[c].items():
                out[f"corner_{c}_{k}"] = v
        return out

    def correlations(self, threshold: float = 0.9) -> list[tuple[str, str, float]]:
        """Pairs of model parameters correlated beyond ``threshold`` (|rho|)."""
        rho = self.wls.correlation()
        out = []
        for i in range(N_PARAMS):
            for j in range(i + 1, N_PARAMS):
                if np.isfinite(rho[i, j]) and abs(rho[i, j]) >= threshold:
                    out.append((PARAM_NAMES[i], PARAM_NAMES[j], float(rho[i, j])))
        return out

    def summary(self) -> str:
        """A table for people: value, std and relative std of every quantity."""
        lines = ["full vehicle (identified, +- 1 std):"]
        for name, e in self.flat().items():
            rel = f"{100 * e.relative_std:5.1f} %" if math.isfinite(e.relative_std) else "   -"
            lines.append(f"  {name:36s} {e.value:12.4g} +- {e.std:10.3g}  ({rel})")
        for label, v in self.fit_nrmse.items():
            lines.append(f"  fit NRMSE of body accelerations, {label}: {v:.3f}")
        for cv in self.cross_validation:
            lines.append(f"  cross-validation {cv['session']}: NRMSE {cv['nrmse']:.3f}")
        strong = self.correlations()
        if strong:
            lines.append("  strongly correlated: " + ", ".join(
                f"{a}/{b} {r:+.2f}" for a, b, r in strong[:6]))
        if "hub_noise_std_mps2" in self.noise:
            for k, label in enumerate(("before", "after")):
                hub = np.asarray(self.noise["hub_noise_std_mps2"])[k]
                lines.append(
                    f"  sensor noise, {label}: body {self.noise['body_noise_std_mps2'][k]:.3g}"
                    f" m/s^2, hubs {hub.min():.3g}-{hub.max():.3g} m/s^2 (white-equivalent, "
                    "by band)")
        lines.extend(f"  warning: {w}" for w in self.warnings)
        return "\n".join(lines)


def _derived(w: WlsResult) -> dict[str, Estimate]:
    """Physical quantities from the model parameters, with delta-method stds."""
    th = np.nan_to_num(w.theta)
    cov = w.cov
    m, sx, sy, jp, jr = th[:5]

    def est(value: float, grad: np.ndarray) -> Estimate:
        return Estimate(float(value), float(math.sqrt(max(grad @ cov @ grad, 0.0))))

    def unit(i: int) -> np.ndarray:
        g = np.zeros(N_PARAMS)
        g[i] = 1.0
        return g

    out = {"sprung_mass_kg": est(m, unit(0))}
    g = np.zeros(N_PARAMS)
    g[0], g[1] = -sx / m**2, 1 / m
    out["cog_behind_front_axle_m"] = est(sx / m, g)
    g = np.zeros(N_PARAMS)
    g[0], g[2] = -sy / m**2, 1 / m
    out["cog_left_of_centre_m"] = est(sy / m, g)
    g = np.zeros(N_PARAMS)
    g[0], g[1], g[3] = sx**2 / m**2, -2 * sx / m, 1.0
    out["pitch_inertia_kgm2"] = est(jp - sx**2 / m, g)
    g = np.zeros(N_PARAMS)
    g[0], g[2], g[4] = sy**2 / m**2, -2 * sy / m, 1.0
    out["roll_inertia_kgm2"] = est(jr - sy**2 / m, g)
    for i, c in enumerate(CORNERS):
        out[f"k_{c}"] = est(th[6 + i], unit(6 + i))
        out[f"c_{c}"] = est(th[10 + i], unit(10 + i))
    out["arb_f"] = est(th[14], unit(14))
    out["arb_r"] = est(th[15], unit(15))
    return out


def body_noise_std_mps2(rec: VehicleRecording) -> float:
    """Noise of the body accelerometers from the redundancy of four sensors on a rigid body.

    The part of the four readings no heave/pitch/roll explains, ``(I - G G^+) y``, holds
    only noise (plus body flexing and sensor-position errors, so the estimate errs on the
    high side); its summed variance is ``sigma^2 trace(I - G G^+) = sigma^2``. Offsets and
    drift are removed by a 0.5 Hz zero-phase high-pass first.

    Returns
    -------
    float
        Standard deviation of one body accelerometer's noise [m/s^2].
    """
    g = rec.geometry.sensor_matrix()
    proj = np.eye(4) - g @ np.linalg.pinv(g)
    sos = signal.butter(2, 0.5, "highpass", fs=rec.sample_rate_hz, output="sos")
    y = signal.sosfiltfilt(sos, rec.body_accel_mps2 - rec.body_accel_mps2.mean(axis=1,
                                                                               keepdims=True))
    res = proj @ y
    n0 = min(res.shape[1] // 10, int(5 * rec.sample_rate_hz))
    res = res[:, n0: res.shape[1] - n0] if n0 else res
    return float(np.sqrt(np.sum(np.mean(res**2, axis=1)) / np.trace(proj)))


def car_accel_noise_std_mps2(rec: VehicleRecording) -> tuple[float, float]:
    """Noise of the car's longitudinal and lateral acceleration signals [m/s^2].

    A car's own accelerations change slowly (well below a quarter of any DAQ rate), so
    what these signals hold above ``fs / 4`` is taken as white noise: its std there,
    times sqrt(2) for the half of the band below. 0 for a missing signal.

    Returns
    -------
    (float, float)
        Longitudinal, lateral.
    """
    fs = float(rec.sample_rate_hz)
    sos = signal.butter(4, 0.25 * fs, "highpass", fs=fs, output="sos")
    out = []
    for v in (rec.accel_long_mps2, rec.accel_lat_mps2):
        if v is None or len(v) < 100:
            out.append(0.0)
            continue
        hp = signal.sosfiltfilt(sos, np.asarray(v, float) - float(np.mean(v)))
        out.append(float(np.std(hp) * np.sqrt(2.0)))
    return out[0], out[1]


def filter_response(rec: VehicleRecording, cfg: VehicleIdentifyConfig,
                    weight: Callable[[np.ndarray], np.ndarray] | None = None,
                    band_edges_hz: Sequence[float] | None = None) -> np.ndarray:
    """Lag-0 cross-correlations of the acceleration, velocity and displacement filters of
    :func:`prepare_drive` (with the same ``weight``) for unit white noise:
    ``R[f, g] = (1/n) sum_k H_f H_g*``.

    With ``band_edges_hz`` (increasing, from 0, may end with inf), the same for each band
    ``[edge_j, edge_j+1)`` separately, (n_bands, 3, 3); they sum to the whole.

    Returns
    -------
    ndarray (3, 3) or (n_bands, 3, 3)
    """
    fs, n = float(rec.sample_rate_hz), rec.n
    lo, hi = cfg.band_hz
    sos = signal.butter(cfg.filter_order, [lo, hi], "bandpass", fs=fs, output="sos")
    f = sp_fft.rfftfreq(n, 1.0 / fs)
    u = np.clip((f - 0.25 * lo) / (0.25 * lo), 0.0, 1.0)
    _, bresp = signal.sosfreqz(sos, worN=f, fs=fs)
    gain = (0.5 - 0.5 * np.cos(np.pi * u)) * np.abs(bresp) ** (2 * cfg.passes)
    if weight is not None:
        gain = gain * weight(f)
    jw = 2j * np.pi * f
    jw[0] = 1.0
    h = np.array([gain, gain / jw, gain / jw**2])
    wts = np.full(f.size, 2.0)
    wts[0] = 1.0
    if n % 2 == 0:
        wts[-1] = 1.0
    if band_edges_hz is None:
        return np.real((h * wts) @ h.conj().T) / n
    idx = np.searchsorted(np.asarray(band_edges_hz, float), f, side="right") - 1
    out = np.zeros((len(band_edges_hz) - 1, 3, 3))
    for j in range(out.shape[0]):
        m = idx == j
        out[j] = np.real((h[:, m] * wts[m]) @ h[:, m].conj().T) / n
    return out


def _nrmse(pred: np.ndarray, meas: np.ndarray) -> float:
    return float(np.sqrt(np.mean((pred - meas) ** 2)) / np.sqrt(np.mean(meas**2)))


def sim_nrmse(theta: np.ndarray, d: DriveRegressors) -> float:
    """NRMSE of the body accelerations simulated from the hub motion (after the start)."""
    skip = int(round(SETTLE_S * d.rate_hz))
    return _nrmse(simulate_body_accel(theta, d)[:, skip:], d.body_accel[:, skip:])


def noise_weighting(d: DriveRegressors, theta: np.ndarray, sigma_mps2: Sequence[float],
                    car_sigma_mps2: tuple[float, float], band_hz: tuple[float, float]
                    ) -> Callable[[np.ndarray], np.ndarray]:
    """Frequency weighting of the least squares: one over the square root of the noise's
    share of the equation errors' spectrum (generalised least squares).

    White accelerometer noise enters the suspension extensions integrated twice, so the
    equation errors it makes grow as ``K / w^2`` towards low frequencies, where the
    suspension hardly moves; weighted flat, the band's low end holds most of the noise
    and little of the signal, and anything the noise compensation does not model there
    (aliasing, non-white noise) biases the result. The weight is the same zero-phase gain
    on every signal of the drive, so the equations still hold between them exactly.

    Parameters
    ----------
    d : DriveRegressors
    theta : ndarray
        A first estimate (its scale does not matter).
    sigma_mps2 : sequence of 8 float
        Noise std of the hub and body channels [m/s^2].
    car_sigma_mps2 : (float, float)
        Noise std of the longitudinal and lateral car accelerations [m/s^2].
    band_hz : (float, float)
        The analysis band (the weight's maximum there is 1).

    Returns
    -------
    callable
        ``weight(f_hz) -> gain`` (0 at 0 Hz).
    """
    c = equation_error_transfer(d, theta)  # (3, 8, 3)
    s2 = np.asarray(sigma_mps2, float) ** 2
    th = np.nan_to_num(np.asarray(theta, float))
    flat = np.array([0.0, (th[16] * car_sigma_mps2[0]) ** 2, (th[17] * car_sigma_mps2[1]) ** 2])

    def psd(f: np.ndarray) -> np.ndarray:
        jw = 2j * np.pi * f
        t = c[..., 0, None] + c[..., 1, None] / jw + c[..., 2, None] / jw**2
        return np.einsum("c,ecf->ef", s2, np.abs(t) ** 2) + flat[:, None]

    fb = np.linspace(band_hz[0], band_hz[1], 256)
    norm = np.maximum(psd(fb).mean(axis=1), 1e-300)
    wmax = float(np.max(1.0 / np.sqrt((psd(fb) / norm[:, None]).sum(axis=0))))

    def weight(f: np.ndarray) -> np.ndarray:
        f = np.asarray(f, float)
        out = np.zeros_like(f)
        pos = f > 0
        out[pos] = 1.0 / np.sqrt((psd(f[pos]) / norm[:, None]).sum(axis=0)) / wmax
        return out

    return weight


def band_edges_hz(band_hz: tuple[float, float], n_bands: int) -> np.ndarray:
    """Edges of the hub-noise bands: 0, ``n_bands - 1`` geometric steps between the band's
    edges, inf (the first and last take the band-pass skirts)."""
    lo, hi = band_hz
    inner = lo * (hi / lo) ** (np.arange(1, n_bands) / n_bands)
    return np.concatenate([[0.0], inner, [np.inf]])


def drive_noise(rec: VehicleRecording, d: DriveRegressors, cfg: VehicleIdentifyConfig,
                weight: Callable[[np.ndarray], np.ndarray] | None, edges_hz: np.ndarray,
                body_sigma_mps2: float, car_sigma_mps2: tuple[float, float],
                correlation: Sequence[str] = (), pairs: bool = False) -> DriveNoise:
    """The noise's expected share in the drive's Gram matrices, per band: body sensors and
    car signals known, hub sensors per unit of each component of their covariance
    (independent; ``correlation``: ``left_right``, ``front_rear``), starting as noisy as
    the body's and independent. ``pairs``: also the products of different equations.
    """
    resp = filter_response(rec, cfg, weight, edges_hz)
    body = [0.0] * 4 + [body_sigma_mps2] * 4
    known = np.stack([noise_gram(d, body, r, car_sigma_mps2, r, pairs=pairs) for r in resp],
                     axis=1)
    units = [np.diag([1.0] * 4 + [0.0] * 4)]
    channel_pairs = {"left_right": ((0, 1), (2, 3)), "front_rear": ((0, 2), (1, 3))}
    for name in correlation:
        u = np.zeros((8, 8))
        for i, k in channel_pairs[name]:
            u[i, k] = u[k, i] = 1.0
        units.append(u)
    hub = np.stack([np.stack([noise_gram(d, [], r, channel_cov=u, pairs=pairs) for r in resp],
                             axis=1) for u in units])
    s2 = np.zeros((len(units), len(resp)))
    s2[0] = body_sigma_mps2**2
    return DriveNoise(known, hub, s2)


def weighted_drives(recs: Sequence[VehicleRecording], drives: Sequence[DriveRegressors],
                    fitted: np.ndarray, block: int, cfg: VehicleIdentifyConfig,
                    body_sigma_mps2: Sequence[float],
                    car_sigma_mps2: Sequence[tuple[float, float]]
                    ) -> tuple[list[Callable[[np.ndarray], np.ndarray]], list[DriveRegressors]]:
    """The frequency weighting of step 3 and the drives prepared with it: a first fit flat
    in frequency, the hubs taken as noisy as the body sensors, gives the equations' noise
    transfer, whose inverse square root is the weight (:func:`noise_weighting`).

    Parameters
    ----------
    recs : sequence of VehicleRecording
        The drives as recorded.
    drives : sequence of DriveRegressors
        The same, prepared flat (:func:`prepare_drive`), with their added mass.
    fitted : ndarray of bool
        Parameters fitted.
    block : int
        Jackknife block [samples] (the Gram matrices' blocks).
    cfg : VehicleIdentifyConfig
    body_sigma_mps2 : sequence of float
        Per drive, the body sensors' noise (:func:`body_noise_std_mps2`).
    car_sigma_mps2 : sequence of (float, float)
        Per drive, the car acceleration signals' noise (:func:`car_accel_noise_std_mps2`).

    Returns
    -------
    weights : list of callable
        Per drive, ``weight(f_hz) -> gain``.
    weighted : list of DriveRegressors
        Per drive, prepared again with its weight (added mass as in ``drives``).
    """
    edges = band_edges_hz(cfg.band_hz, cfg.hub_noise_bands)
    g = [block_grams(d, block) for d in drives]
    noise = [drive_noise(rec, d, cfg, None, edges, bs, cs)
             for rec, d, bs, cs in zip(recs, drives, body_sigma_mps2, car_sigma_mps2,
                                       strict=True)]
    first = compensated_least_squares([x for x, _ in g], [n for _, n in g], fitted, noise,
                                      jackknife=False)
    weights = [noise_weighting(d, first.theta, [bs] * 8, cs, cfg.band_hz)
               for d, bs, cs in zip(drives, body_sigma_mps2, car_sigma_mps2, strict=True)]
    weighted = []
    for rec, d, wt in zip(recs, drives, weights, strict=True):
        dw = prepare_drive(rec, cfg, wt)
        dw.added_mass_kg, dw.added_mass_at_m = d.added_mass_kg, d.added_mass_at_m
        weighted.append(dw)
    return weights, weighted


def _compensated_fit(recs: Sequence[VehicleRecording], drives: Sequence[DriveRegressors],
                     fitted: np.ndarray, block: int, cfg: VehicleIdentifyConfig
                     ) -> tuple[WlsResult, WlsResult, dict[str, Any]]:
    """Steps 3-4 of the method with the noise compensation: first fit (flat in frequency,
    the hubs as noisy as the body), frequency weighting from it, the weighted fit with the
    hub noise spectrum estimated; and the weighted fit without compensation."""
    body_sigma = [body_noise_std_mps2(rec) for rec in recs]
    car_sigma = [car_accel_noise_std_mps2(rec) for rec in recs]
    edges = band_edges_hz(cfg.band_hz, cfg.hub_noise_bands)

    def setup(ds: Sequence[DriveRegressors], wts: Sequence[Callable | None],
              correlation: Sequence[str] = (), pairs: bool = False) -> list[DriveNoise]:
        return [drive_noise(rec, d, cfg, wt, edges, bs, cs, correlation, pairs)
                for rec, d, wt, bs, cs in zip(recs, ds, wts, body_sigma, car_sigma,
                                                  strict=True)]

    def grams_of(ds: Sequence[DriveRegressors]) -> tuple[list, list]:
        g = [block_grams(d, block) for d in ds]
        return [x for x, _ in g], [n for _, n in g]

    weights: list[Callable[[np.ndarray], np.ndarray] | None] = [None] * len(recs)
    fit_drives = list(drives)
    if cfg.noise_weighting:
        weights, fit_drives = weighted_drives(recs, drives, fitted, block, cfg, body_sigma,
                                              car_sigma)
    grams, samples = grams_of(fit_drives)
    info: dict[str, Any] = {"body_noise_std_mps2": body_sigma,
                            "car_accel_noise_std_mps2": car_sigma, "band_edges_hz": edges,
                            "weights": weights}
    if cfg.hub_noise != "spectrum":
        w = compensated_least_squares(grams, samples, fitted, setup(fit_drives, weights),
                                      bias_correction=cfg.jackknife_bias)
    else:
        # the hub noise spectrum estimated from the equation errors, band by band
        band_grams = [np.stack([block_grams(part, block, True)[0]
                                for part in band_split(d, edges)], axis=2)
                      for d in fit_drives]
        noise = setup(fit_drives, weights, cfg.hub_noise_correlation,
                      cfg.hub_noise_cross_products)
        w = compensated_least_squares(
            grams, samples, fitted, noise,
            [g if cfg.hub_noise_cross_products else g[:3] for g in band_grams],
            cfg.hub_noise_iterations, bias_correction=cfg.jackknife_bias)
        info["hub_noise_std_mps2"] = np.sqrt(w.hub_noise_s2[:, 0])
        # the hub noise over the body sensors' as the equation errors see it: the bands
        # weighted by what a unit of hub noise there puts into the errors
        z = np.append(np.nan_to_num(w.theta), -1.0)
        ratio = []
        for k, nz in enumerate(noise):
            q = np.einsum("p,ejpq,q->j", z, nz.hub_unit[0, :3], z)
            ratio.append(float(np.sqrt(np.sum(w.hub_noise_s2[k, 0] * q) / max(
                np.sum(body_sigma[k] ** 2 * q), 1e-300))))
        info["hub_noise_ratio"] = ratio
        if cfg.hub_noise_correlation:
            info["hub_noise_correlation"] = w.hub_noise_s2[:, 1:] / np.maximum(
                w.hub_noise_s2[:, :1], 1e-300)
        if cfg.structure_doubt:
            # the hub noise's structure (which hubs share it) is not fully identifiable from
            # the three equations: the estimate with another structure (left-right and
            # front-rear covariances, fitted to the equations' cross products too) is
            # carried as a systematic uncertainty
            alt_corr, alt_pairs = cfg.structure_alternative
            alt = compensated_least_squares(
                grams, samples, fitted, setup(fit_drives, weights, alt_corr, alt_pairs),
                [g if alt_pairs else g[:3] for g in band_grams], cfg.hub_noise_iterations,
                jackknife=False)
            delta = cfg.structure_doubt * np.nan_to_num(alt.theta - w.theta)
            w.cov = w.cov + np.outer(delta, delta)
            info["structure_shift"] = float(alt.theta[0] / w.theta[0] - 1.0)
    raw = compensated_least_squares(grams, samples, fitted, None, jackknife=False)
    return w, raw, info


def noise_warnings(info: dict[str, Any], w: WlsResult, hub_ratio: float = 1.5,
                   dominance: float = 0.5) -> list[str]:
    """What the noise says about the result, in words.

    Parameters
    ----------
    info : dict
        The noise information of :func:`_compensated_fit`.
    w : WlsResult
    hub_ratio : float
        Hub noise over the body sensors' noise (``hub_noise_ratio``: rms, the bands
        weighted by their share of the equation errors) beyond which it is reported.
    dominance : float
        Relative change of the mass by the compensation beyond which the result is said
        to rest on it.
    """
    out = []
    ratio = info.get("hub_noise_ratio")
    if ratio is not None and max(ratio) > hub_ratio:
        out.append(
            f"the hub channels carry {max(ratio):.1f} x the body sensors' noise (as the "
            "equations see it; up to "
            f"{np.max(info['hub_noise_std_mps2']):.3g} m/s^2 white-equivalent in a band): "
            "aliasing of the wheel's high-frequency acceleration (a DAQ with a gentle "
            "anti-alias filter: record at 500 Hz or more, or with a steep filter), noisier "
            "hub sensors, or a model that does not fit (check with fielddiag diagnose). It "
            "is compensated as noise and its uncertainty is in the standard deviations; "
            "if it is a model error, the result is biased")
    shift = info.get("compensation_shift")
    if shift is not None and abs(shift) > dominance:
        out.append(
            f"the sensor noise dominates the equations: its compensation changed the mass "
            f"by {100 * shift:+.0f} %, so the result rests on the noise model; drive longer, "
            "on a rougher road, or with a larger added mass")
    rel = w.std[0] / abs(w.theta[0]) if w.theta[0] else math.inf
    if rel > 0.03:
        out.append(f"the sprung mass is uncertain by {100 * rel:.1f} % (1 std), more than "
                   "the 3 % the method aims at; drive longer, on a rougher road, or with a "
                   "larger added mass")
    return out


def identify_vehicle(
    before: VehicleRecording,
    after: VehicleRecording,
    added_mass_kg: float | None = None,
    added_mass_at_m: tuple[float, float] | None = None,
    validate: Sequence[VehicleRecording] = (),
    config: VehicleIdentifyConfig = VehicleIdentifyConfig(),
) -> VehicleIdentification:
    """Identify the body and the four corners from two full-vehicle drives.

    Parameters
    ----------
    before, after : VehicleRecording (or VehicleDrive)
        The car as it is, and with a known mass added on the body.
    added_mass_kg : float or None
        The added mass [kg]; default: ``after.added_mass_kg - before.added_mass_kg``.
    added_mass_at_m : (x_m, y_m) or None
        Where it sits [m]; default: from ``after.added_mass_at_m``.
    validate : sequence of VehicleRecording
        Drives of the same car (any manoeuvre, their own added mass as recorded) to
        cross-validate on.
    config : VehicleIdentifyConfig

    Returns
    -------
    VehicleIdentification

    Raises
    ------
    InvalidValueError
        No positive added mass, or no position for it.
    FieldDiagError
        The drives are of cars with different geometry.
    InsufficientDataError
        A drive too short, or no excitation of the parameters.
    """
    if added_mass_kg is None:
        added_mass_kg = float(after.added_mass_kg) - float(before.added_mass_kg)
    if not (math.isfinite(added_mass_kg) and added_mass_kg > 0):
        raise InvalidValueError(
            f"added mass {added_mass_kg!r} kg: the second drive needs a known mass added on the "
            "body; give --added-mass KG (> 0)")
    at = added_mass_at_m if added_mass_at_m is not None else after.added_mass_at_m
    if at is None or len(at) != 2 or not all(math.isfinite(float(v)) for v in at):
        raise InvalidValueError("where the added mass sits is unknown; give --added-mass-at "
                                "X_M,Y_M (metres behind the front axle, metres left of centre)")
    at = (float(at[0]), float(at[1]))
    for other in (after, *validate):
        if other.geometry != before.geometry:
            raise FieldDiagError(
                f"{other.name or other.label or 'a drive'} has another vehicle geometry than "
                f"{before.name or 'the before drive'}; all drives must be of the same car "
                "(import them with the same --vehicle file)")
    d0 = prepare_drive(before, config)
    d0.added_mass_kg, d0.added_mass_at_m = 0.0, (0.0, 0.0)
    d1 = prepare_drive(after, config)
    d1.added_mass_kg, d1.added_mass_at_m = added_mass_kg, at
    drives = [d0, d1]
    a, _, _, _ = regressors(drives)
    fitted = np.ones(N_PARAMS, bool)
    # moment arms: only where the car accelerated (else the column is noise or zero)
    for col, sig in ((16, "a_long"), (17, "a_lat")):
        rms = max(float(np.sqrt(np.mean(getattr(d, sig) ** 2))) for d in drives)
        fitted[col] = rms > 0.02
    col_norm = np.linalg.norm(a, axis=0)
    if np.any(col_norm[fitted] == 0):
        raise InsufficientDataError("the drives do not move the body or the suspensions; drive "
                                    "over a rough road")
    recs = (before, after)
    block = max(1, int(round(config.block_s * d0.rate_hz)))
    if config.noise_compensation:
        w, raw, noise_info = _compensated_fit(recs, drives, fitted, block, config)
        # a floor for the processing (bias without noise: 0.04-0.13 %, measured), and
        # optionally compensation_doubt x the scale change the compensation made, as a
        # fully correlated scale uncertainty
        shift = w.theta[0] / raw.theta[0] - 1.0
        w.scale_std = float(np.hypot(config.compensation_doubt * shift, config.scale_floor))
        noise_info["compensation_shift"] = float(shift)
    else:
        grams = [block_grams(d, block) for d in drives]
        w = compensated_least_squares([g for g, _ in grams], [n for _, n in grams], fitted,
                                      bias_correction=config.jackknife_bias)
        w.scale_std = float(config.scale_floor)
        noise_info = {}
    th = np.nan_to_num(w.theta)
    w.cov = w.cov + w.scale_std**2 * np.outer(th, th)
    dvs = []
    for k, rec in enumerate(validate):
        if rec.added_mass_kg and rec.added_mass_at_m is None:
            raise InvalidValueError(f"{rec.name or 'a validate drive'} carries an added mass "
                                    "but not where it sits; record added_mass_at_m")
        dvs.append((rec.name or rec.label or f"validate_{k + 1}", prepare_drive(rec, config)))
    refinement: dict[str, Any] = {"applied": False}
    if config.refine and dvs:
        oe = refine_output_error(w, drives, config.block_s)
        ls_score = float(np.mean([sim_nrmse(w.theta, d) for _, d in dvs]))
        oe_score = float(np.mean([sim_nrmse(oe.wls.theta, d) for _, d in dvs]))
        better = oe.success and oe_score < (1.0 - config.refine_gain) * ls_score
        refinement = {"applied": bool(better), "judged_on": "validate",
                      "nrmse_least_squares": ls_score, "nrmse_output_error": oe_score,
                      "nrmse_identification": [oe.nrmse_start, oe.nrmse]}
        if better:
            scale_std = w.scale_std
            w = oe.wls
            w.scale_std = scale_std
            th = np.nan_to_num(w.theta)
            w.cov = w.cov + scale_std**2 * np.outer(th, th)
    est = _derived(w)
    fit = {"before": sim_nrmse(w.theta, d0), "after": sim_nrmse(w.theta, d1)}
    cv = [{"session": name, "nrmse": sim_nrmse(w.theta, d)} for name, d in dvs]
    lo, hi = config.band_hz
    refined = ""
    if config.refine:
        refined = "; output-error refinement " + (
            ("applied" if refinement["applied"] else "tried, not better on the validate drives")
            if dvs else "not tried (no validate drive to judge it on)")
    method = (
        f"output-only full-vehicle identification: 8 accelerometers integrated twice in the "
        f"frequency domain and band-passed {lo:g}-{hi:g} Hz (zero-phase Butterworth order "
        f"{config.filter_order}, sosfiltfilt), heave/pitch/roll from the 4 body sensors "
        "(least squares), 3 body equations linear in 18 parameters stacked over the drive "
        f"before and after adding {added_mass_kg:g} kg at ({at[0]:g}, {at[1]:g}) m, "
        "weighted least squares (per-equation weights"
        + (", weighted in frequency by the noise's share of the equation errors"
           if config.noise_weighting and config.noise_compensation else "")
        + (", sensor-noise bias compensated: body sensors' noise from their redundancy, "
           + ("the hubs' band by band from the equation errors"
              if config.hub_noise == "spectrum" else "the hubs' taken as the body's")
           if config.noise_compensation else "") + "), "
        f"a {100 * w.scale_std:.2f} % systematic scale uncertainty added"
        + (", and the difference to the estimate with another structure of the hub noise "
           "(left-right and front-rear covariances)"
           if "structure_shift" in noise_info else "") + ", "
        f"delete-a-block jackknife over {w.n_blocks} blocks of {config.block_s:g} s "
        "(the whole estimate repeated) for the covariance, "
        f"delta method for derived quantities{refined}; NRMSE = RMS error / RMS of the "
        "body accelerations simulated from the hub motion, after the first "
        f"{SETTLE_S:g} s")
    return VehicleIdentification(
        sprung_mass_kg=est["sprung_mass_kg"],
        cog_behind_front_axle_m=est["cog_behind_front_axle_m"],
        cog_left_of_centre_m=est["cog_left_of_centre_m"],
        pitch_inertia_kgm2=est["pitch_inertia_kgm2"],
        roll_inertia_kgm2=est["roll_inertia_kgm2"],
        corners={c: {"stiffness_n_per_m": est[f"k_{c}"], "damping_ns_per_m": est[f"c_{c}"]}
                 for c in CORNERS},
        anti_roll_stiffness_front_n_per_m=est["arb_f"],
        anti_roll_stiffness_rear_n_per_m=est["arb_r"],
        wls=w, cross_validation=cv, fit_nrmse=fit, method=method, refinement=refinement,
        noise={k: v for k, v in noise_info.items() if k != "weights"},
        warnings=[*reading_notes(before, after, *validate), *noise_warnings(noise_info, w)])
