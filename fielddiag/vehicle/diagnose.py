"""Per-corner diagnosis of the full vehicle: which corner, which effect, where in time;
and the left/right mismatch of an axle (a worn damper, a sagged spring).

:func:`diagnose_vehicle` -> :class:`VehicleDiagnosis` (``to_dict()`` is the JSON of
``fielddiag diagnose BEFORE.h5 AFTER.h5 --added-mass KG --added-mass-at X_M,Y_M``).

Method (equation error, as the identification):

1. Both drives are prepared as for the identification
   (:func:`fielddiag.vehicle.identify.prepare_drive`: integrated, band-passed, decimated;
   suspension travel and rate per corner) and the three body equations written linear in
   the 18 parameters (:mod:`fielddiag.vehicle.regression`), the added mass fixing the scale.
   The identification's noise model (step 3 of :mod:`fielddiag.vehicle.identify`): the
   drives weighted in frequency by one over the noise's share of the equation errors
   (:func:`~fielddiag.vehicle.identify.weighted_drives`); the sensor-noise bias
   compensated, the body sensors' noise from their redundancy, the car signals' above
   fs/4, the hub sensors' (which holds what a gentle anti-alias filter folds into the
   band) estimated band by band from the equation errors of the model being fitted, with
   a covariance common to the left and right hub
   (:func:`~fielddiag.vehicle.regression.compensated_least_squares`), for the linear
   model and every candidate alike (a model that leaves a force out shows it as hub
   noise; the model with it does not).
2. A candidate effect of the library at a corner (or on both corners of an axle with one
   set of parameters) adds its force, evaluated on that corner's measured travel and rate,
   to the three equations with the corner's lever arms ``[1, x, y]``. Its force is linear in
   the parameters that scale with force (friction force, cubic stiffness, bump-stop
   stiffness, compression/rebound damping...) once its shape parameters (bump-stop gap,
   friction smoothing velocity) are fixed; those are searched on a short grid, chosen on
   the fitted part. An effect that replaces the linear damper or spring (asymmetric
   damping) takes that corner's column out. The force is evaluated at
   :data:`FORCE_RATE_HZ` or more on the interpolated motion, its harmonics above the
   recording's Nyquist frequency dropped, then weighted and filtered like the drive.
   Its columns are taken as noise-free: the noise of the measured travel and rate passes
   through the force into them, but measured on a simulated 200 Hz drive (a noise-free,
   alias-free reading of the same motion as reference; 500 Hz in brackets) it is 1e-4 of
   the column's energy for the damping effects (asymmetric, quadratic; 1e-5), 5e-4 to
   1.4e-3 for friction (4e-5 to 8e-5), 2.4e-2 for the cubic spring (3e-3) and 5e-2 for a
   bump stop 2 cm out (7e-3: the travel's low-frequency noise blurs the knee), against
   1e-4 (1e-5) for the linear travel column the compensation is for. Left
   uncompensated, such noise pulls the effect's own parameter towards zero by about that
   share (errors in variables): below 0.2 % for friction and the dampers, up to a few %
   for a bump stop's stiffness at 200 Hz.
3. Every model is fitted by weighted least squares on the first 70 % of each drive and
   predicts the body accelerations of the last 30 % (the four body sensors, from the
   measured suspension motion, weighted in frequency like the fit); the selection rule
   of the single-corner diagnosis (:func:`fielddiag.diagnose.selection.select_model`: a
   significant paired-block improvement worth its parameters, parameters physical)
   picks the simplest model, then greedily a further effect at another corner on top of
   it, up to ``max_effects``. The many candidates are screened first (no covariance, half
   the hub-noise rounds, the normal matrix's covariance), the most promising refitted
   with the full estimate.
4. The chosen model is fitted again on all the data for the reported parameters and their
   standard deviations (delete-a-block jackknife that repeats the whole estimate, the hub
   noise included). Where in time: the windows where the chosen model lowers the
   residual most.
5. Left/right mismatch: per axle, the two corners' damping and stiffness of the chosen
   model, their ratio with its delta-method standard deviation; a corner is reported when
   the ratio departs from 1 by more than ``mismatch_tolerance`` (manufacturing spread)
   significantly (one-sided z on the log ratio beyond the tolerance), with the z of the
   plain difference and its two-sided p value.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from scipy import fft as sp_fft
from scipy import signal, stats

from fielddiag.blas import single_threaded_blas
from fielddiag.channels import CORNERS
from fielddiag.diagnose.selection import CandidateFit, compare, confidence, select_model
from fielddiag.effects import EFFECTS, ForceModel, get_effect
from fielddiag.errors import FieldDiagError, InsufficientDataError, InvalidValueError
from fielddiag.sim._common import G_MPS2
from fielddiag.vehicle.identify import (
    VehicleIdentifyConfig,
    _derived,
    analysis_samples,
    band_edges_hz,
    body_noise_std_mps2,
    car_accel_noise_std_mps2,
    drive_noise,
    integrate_twice,
    noise_weighting,
    prepare_drive,
    weighted_drives,
)
from fielddiag.vehicle.recording import VehicleRecording, reading_notes
from fielddiag.vehicle.regression import (
    N_PARAMS,
    PARAM_NAMES,
    DriveNoise,
    DriveRegressors,
    WlsResult,
    band_split_signals,
    compensated_least_squares,
    equation_rows,
    mass_matrix,
)

__all__ = ["DEFAULT_EFFECTS", "VehicleDiagnoseConfig", "VehicleDiagnosis", "diagnose_vehicle",
           "format_vehicle_summary"]

#: Effects tried at every corner by default.
DEFAULT_EFFECTS = ("coulomb_friction", "cubic_stiffness", "bump_stop", "asymmetric_damping",
                   "quadratic_damping")
AXLES = {"front": ("fl", "fr"), "rear": ("rl", "rr")}
_K0, _C0 = 6, 10  # first stiffness / damping column in PARAM_NAMES


@dataclass(frozen=True)
class VehicleDiagnoseConfig:
    """Settings of the full-vehicle diagnosis.

    Parameters
    ----------
    identify : VehicleIdentifyConfig
        Preparation of the drives (band, rate, trims) and noise compensation.
    holdout_fraction : float
        Last fraction of every drive held out for the model choice.
    effects : tuple of str
        Library effects tried at each corner and on each axle.
    axle_candidates : bool
        Also try each effect on both corners of an axle with shared parameters.
    max_effects : int
        Most effects in the chosen model (greedy forward selection).
    exact_fits : int
        Candidates of each round screened by a fast fixed-weight fit; this many of the
        best that beat the current model are fitted again exactly for the choice.
    mismatch_tolerance : float
        Relative left/right difference tolerated without a finding (0.20: the ratio must
        leave 1/1.2..1.2; two parts each within a +-10 % production spread differ by up
        to ~20 %, and the random test cars' corners by up to 17 %).
    mismatch_z : float
        One-sided z the log ratio must exceed the tolerance by (1.645: 95 %).
    window_s : float
        Length of the time windows reported as where a finding acts [s].
    sag_passes : int
        Most searches with the static sag (the travel offset of the drive with the mass
        added, which the travel-dependent effects see) from the model the previous search
        chose.
    sag_tolerance_m : float
        Change of the static sag below which no further search is made [m].
    """

    identify: VehicleIdentifyConfig = VehicleIdentifyConfig(refine=False)
    holdout_fraction: float = 0.3
    effects: tuple[str, ...] = DEFAULT_EFFECTS
    axle_candidates: bool = True
    max_effects: int = 3
    exact_fits: int = 4
    mismatch_tolerance: float = 0.20
    mismatch_z: float = 1.645
    window_s: float = 5.0
    sag_passes: int = 3
    sag_tolerance_m: float = 0.001


# --------------------------------------------------------------------------- candidates
@dataclass(frozen=True)
class _Term:
    """One effect at one corner or on one axle, with its shape parameters fixed."""

    effect: str
    corners: tuple[str, ...]
    shape: tuple[tuple[str, float], ...] = ()

    @property
    def place(self) -> str:
        if len(self.corners) == 1:
            return self.corners[0]
        return "front" if self.corners[0][0] == "f" else "rear"

    @property
    def label(self) -> str:
        return f"{self.effect}@{self.place}"

    def linear_params(self) -> tuple[str, ...]:
        return tuple(p.name for p in get_effect(self.effect).params if p.scales_with_force)

    def replaced_columns(self) -> list[int]:
        cls = get_effect(self.effect)
        cols = []
        for c in self.corners:
            i = CORNERS.index(c)
            if "linear_damper" in cls.replaces:
                cols.append(_C0 + i)
            if "linear_spring" in cls.replaces:
                cols.append(_K0 + i)
        return cols

    def corner_columns(self, d: DriveRegressors) -> np.ndarray:
        """(corners, n, p) the effect's force per unit of each linear parameter at each of
        its corners (the force moved to the left of the body equations).

        The force is evaluated on the corner's travel and rate before the band-pass (only
        the drift removed; interpolated to at least :data:`FORCE_RATE_HZ`, its harmonics
        above the recording's Nyquist frequency dropped) and then weighted in frequency,
        filtered and decimated exactly like the other terms of the drive: the equation
        holds between band-passed quantities, and the band-pass of a nonlinear force is not
        the force of the band-passed motion (friction came out ~40 % low that way).
        """
        return np.stack([_Term(self.effect, (c,), self.shape)._one_corner(d)
                         for c in self.corners])

    def _one_corner(self, d: DriveRegressors) -> np.ndarray:
        """(n, p) :meth:`corner_columns` of a one-corner term (cached: the axle terms
        share them)."""
        key = (self, id(d), "corner")
        hit = _COLUMNS.get(key)
        if hit is not None and hit[0] is d:
            return hit[1]
        cls = get_effect(self.effect)
        if self.effect not in _MODELS:
            _MODELS[self.effect] = ForceModel([cls()])
        model = _MODELS[self.effect]
        values = {p.name: (p.typical if p.scales_with_force else
                           (p.default if p.default is not None else p.typical))
                  for p in cls.params}
        values.update(dict(self.shape))
        idx = [model.index(p) for p in self.linear_params()]
        _, raw, weight = _RAW[id(d)]
        i = CORNERS.index(self.corners[0])
        _, _, dp = model.force(raw.r[i], raw.rd[i], 0.0, model.vector(values))
        out = raw.filter(-dp[:, idx].T, weight).T
        _COLUMNS[key] = (d, out)
        return out

    def levers(self, d: DriveRegressors) -> np.ndarray:
        """(corners, 3) each corner's lever arms ``[1, x, y]`` in the three equations."""
        return np.array([[1.0, d.corner_x[CORNERS.index(c)], d.corner_y[CORNERS.index(c)]]
                         for c in self.corners])

    def columns(self, d: DriveRegressors) -> np.ndarray:
        """(3, n, p) columns of the body equations: :meth:`corner_columns` times the
        corners' lever arms, summed."""
        key = (self, id(d))
        hit = _COLUMNS.get(key)
        if hit is not None and hit[0] is d:
            return hit[1]
        out = np.einsum("ce,cnp->enp", self.levers(d), self.corner_columns(d))
        _COLUMNS[key] = (d, out)
        return out


#: Lowest rate [Hz] the effects' forces are evaluated at (the motion interpolated): a force
#: with sharp corners (friction's sign change, a bump stop's knee) has harmonics far above
#: the band, which samples of it at the recording rate fold into the band while the
#: sensors' anti-alias filter keeps most of them out of the body accelerations. Measured
#: on a 200 Hz pair without sensor noise or hub aliasing: 80 N of friction came out 86.3 N
#: evaluated at 200 Hz, 79.2 N at 600 Hz and at 1000 Hz (79.4 N at 500 Hz on the same pair
#: recorded at 500 Hz).
FORCE_RATE_HZ = 500.0


@dataclass
class _RawMotion:
    """A drive's suspension travel and rate (drift removed only) at ``upsample`` times the
    recording rate (interpolated), and the band-pass, trim and decimation of
    :func:`prepare_drive` to apply to a force evaluated on them."""

    r: np.ndarray
    rd: np.ndarray
    sos: np.ndarray
    passes: int
    keep: slice
    rate_hz: float  # the recording's
    n: int  # samples of the recording
    upsample: int = 1
    gains: dict[int, tuple[Callable, np.ndarray]] = field(default_factory=dict)  # weight(f)

    def filter(self, x: np.ndarray, weight: Callable[[np.ndarray], np.ndarray] | None = None
               ) -> np.ndarray:
        """Back to the recording rate through an ideal low-pass at its Nyquist frequency
        (if evaluated above it), the frequency weighting (as :func:`prepare_drive` applies
        it, over the whole drive), band-pass (zero phase, as often as the identification),
        trim, decimate."""
        n = self.n
        if weight is not None or self.upsample > 1:
            spec = sp_fft.rfft(x, axis=-1)[..., : n // 2 + 1] / self.upsample
            if weight is not None:
                gain = self.gains.get(id(weight))
                if gain is None or gain[0] is not weight:
                    gain = (weight, weight(sp_fft.rfftfreq(n, 1.0 / self.rate_hz)))
                    self.gains[id(weight)] = gain
                spec = spec * gain[1]
            x = sp_fft.irfft(spec, n, axis=-1)
        for _ in range(self.passes):
            x = signal.sosfiltfilt(self.sos, x, axis=-1)
        return x[..., self.keep]


def _static_sag_m(theta: np.ndarray, d: DriveRegressors) -> np.ndarray:
    """Static change of each corner's travel [m] from the added mass of drive ``d`` (tyres
    taken as rigid), from the linear model's corner and anti-roll stiffness."""
    if not d.added_mass_kg:
        return np.zeros(4)
    th = np.nan_to_num(theta)
    lever = np.array([np.ones(4), d.corner_x, d.corner_y])  # (3, 4)
    stiff = (lever * th[_K0:_K0 + 4]) @ lever.T
    tf, tr = d.corner_y[0] - d.corner_y[1], d.corner_y[2] - d.corner_y[3]
    stiff[2, 2] += th[14] * tf**2 + th[15] * tr**2
    xa, ya = d.added_mass_at_m
    load = -d.added_mass_kg * G_MPS2 * np.array([1.0, xa, ya])
    return lever.T @ np.linalg.solve(stiff, load)


#: Largest static sag [m] under the added mass taken from a linear fit; beyond it (or with
#: a corner stiffness <= 0) the fit is not a car's: a strongly nonlinear car (a damper
#: with rebound ~3 x its compression) can drive the linear model towards zero.
MAX_SAG_M = 0.15


def _plausible_sag_m(theta: np.ndarray, d: DriveRegressors) -> np.ndarray:
    """:func:`_static_sag_m`, or zeros (each drive's travel about its own rest, as before
    the sag was applied) when the linear model behind it is not plausible."""
    k = np.asarray(theta, float)[_K0:_K0 + 4]
    if not np.all(np.isfinite(k) & (k > 0)):
        return np.zeros(4)
    sag = _static_sag_m(theta, d)
    return sag if np.all(np.abs(sag) <= MAX_SAG_M) else np.zeros(4)


def _raw_motion(rec: VehicleRecording, cfg: VehicleIdentifyConfig) -> _RawMotion:
    fs = float(rec.sample_rate_hz)
    lo, hi = cfg.band_hz
    acc = np.vstack([rec.wheel_accel_mps2, rec.body_accel_mps2]).astype(float)
    _, v, x = integrate_twice(acc, fs, 0.5 * lo)
    g = rec.geometry
    proj = g.corner_matrix() @ np.linalg.pinv(g.sensor_matrix())
    r = proj @ x[4:] - x[:4]
    rd = proj @ v[4:] - v[:4]
    n = acc.shape[1]
    up = max(1, math.ceil(FORCE_RATE_HZ / fs - 1e-9))
    if up > 1:  # band-limited interpolation (the motion is periodic: integrated by FFT)
        r, rd = signal.resample(r, up * n, axis=-1), signal.resample(rd, up * n, axis=-1)
    sos = signal.butter(cfg.filter_order, [lo, hi], "bandpass", fs=fs, output="sos")
    return _RawMotion(r, rd, sos, cfg.passes, analysis_samples(n, fs, cfg), fs, n, up)


#: One compiled ForceModel per effect, and the columns of the terms of the running
#: diagnosis (cleared at its start and end); per prepared drive its raw motion and the
#: frequency weighting it was prepared with.
_MODELS: dict[str, ForceModel] = {}
_COLUMNS: dict[tuple, tuple[DriveRegressors, np.ndarray]] = {}
_RAW: dict[int, tuple[DriveRegressors, _RawMotion,
                      Callable[[np.ndarray], np.ndarray] | None]] = {}
_ROWS: dict[int, tuple[DriveRegressors, np.ndarray, np.ndarray]] = {}


@functools.cache
def _depends_on_travel(effect: str) -> bool:
    """Whether an effect's force changes with the suspension's travel (at typical values
    and a few travels and rates)."""
    cls = get_effect(effect)
    if effect not in _MODELS:
        _MODELS[effect] = ForceModel([cls()])
    model = _MODELS[effect]
    values = {p.name: (p.typical if p.scales_with_force or p.default is None else p.default)
              for p in cls.params}
    r = np.repeat([-0.08, -0.03, 0.0, 0.03, 0.08], 3)
    rd = np.tile([-0.2, 0.05, 0.3], 5)
    f = model.force(r, rd, 0.0, model.vector(values))[0].reshape(5, 3)
    return bool(np.any(np.abs(f - f[2]) > 1e-9 * (1.0 + np.abs(f[2]))))


def _forget_travel_columns() -> None:
    """Drop the cached columns of the effects that depend on the travel (it moved)."""
    for key in [k for k in _COLUMNS if _depends_on_travel(k[0].effect)]:
        del _COLUMNS[key]


def _equation_rows(d: DriveRegressors) -> tuple[np.ndarray, np.ndarray]:
    hit = _ROWS.get(id(d))
    if hit is not None and hit[0] is d:
        return hit[1], hit[2]
    a, b = equation_rows(d)
    _ROWS[id(d)] = (d, a, b)
    return a, b


def _shape_grid(effect: str, r: np.ndarray) -> list[tuple[tuple[str, float], ...]]:
    """Shape parameters to try: bump-stop gaps at quantiles of the compression, the
    friction smoothing at its default and around it."""
    if effect == "bump_stop":
        comp = np.abs(np.minimum(r, 0.0))
        qs = np.quantile(comp, [0.6, 0.75, 0.85, 0.9, 0.94, 0.97, 0.985, 0.995])
        return [(("gap_m", float(q)),) for q in qs if q > 0]
    if effect == "coulomb_friction":
        return [(("smoothing_velocity_mps", v),) for v in (0.003, 0.01, 0.03)]
    return [()]


# --------------------------------------------------------------------------- fitting
def _augment(lin: np.ndarray, cross: np.ndarray, extra: np.ndarray) -> np.ndarray:
    """Gram matrices of ``[A, E, b]`` from those of ``[A, b]`` (``lin``, (..., P0 + 1,
    P0 + 1)), ``E^T [A, b]`` (``cross``, (..., q, P0 + 1)) and ``E^T E`` (``extra``):
    the effects' columns ``E`` between the linear model's and the right-hand side, as
    :func:`compensated_least_squares` takes them (``b`` last)."""
    p0, q = N_PARAMS, extra.shape[-1]
    p = p0 + q
    out = np.zeros(lin.shape[:-2] + (p + 1, p + 1))
    idx = np.append(np.arange(p0), p)
    out[..., idx[:, None], idx] = lin
    out[..., p0:p, idx] = cross
    out[..., idx, p0:p] = np.swapaxes(cross, -1, -2)
    out[..., p0:p, p0:p] = extra
    return out


def _block_products(x: np.ndarray, y: np.ndarray, block: int) -> np.ndarray:
    """``x^T y`` over consecutive time blocks, the blocks of
    :func:`~fielddiag.vehicle.regression.block_grams` (from the first sample, the last one
    shorter): (..., n_blocks, p, q) from (..., n, p) and (..., n, q)."""
    n = x.shape[-2]
    bs = max(1, int(block))
    full = n // bs
    xb = x[..., : full * bs, :].reshape(x.shape[:-2] + (full, bs, x.shape[-1]))
    yb = y[..., : full * bs, :].reshape(y.shape[:-2] + (full, bs, y.shape[-1]))
    out = np.matmul(xb.swapaxes(-1, -2), yb)
    if n > full * bs:  # the last, shorter block
        last = np.matmul(x[..., full * bs:, :].swapaxes(-1, -2), y[..., full * bs:, :])
        out = np.concatenate([out, last[..., None, :, :]], axis=-3)
    return out


def _pieces(terms: Sequence[_Term], d: DriveRegressors) -> tuple[np.ndarray, np.ndarray]:
    """The effects' columns of ``terms`` as per-corner force columns ``U`` (n, m) and
    lever arms ``L`` (3, m, q): the equations' extra columns are ``E[e] = U L[e]``."""
    cols, rows = [], []
    q0 = 0
    q = sum(len(t.linear_params()) for t in terms)
    for t in terms:
        cc, lev = t.corner_columns(d), t.levers(d)
        for j in range(cc.shape[0]):
            for p in range(cc.shape[2]):
                cols.append(cc[j, :, p])
                row = np.zeros((3, q))
                row[:, q0 + p] = lev[j]
                rows.append(row)
        q0 += cc.shape[2]
    return np.stack(cols, axis=1), np.stack(rows, axis=1)


@dataclass
class _Data:
    """Both drives as fitted and scored (weighted in frequency), their noise, the held-out
    split, and the Gram matrices of the linear model's rows (cached per part and block)."""

    drives: list[DriveRegressors]
    noise: list[DriveNoise] | None  # per drive, for all its samples
    split: list[int]  # first held-out sample of each drive
    edges_hz: np.ndarray | None = None  # hub-noise bands; None: the hub noise not estimated
    hub_iterations: int = 0
    bias_correction: bool = False
    _cache: dict[Any, Any] = field(default_factory=dict)

    def _signals(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """The 13 signals the rows are made of, ``S`` (n, 13: heave/pitch/roll
        acceleration, travel and rate per corner, the car's accelerations), and the map
        ``M`` (3, 13, P0 + 1) with ``[A, b][e] = S M[e]`` (:func:`equation_rows` of unit
        signals)."""
        key = ("signals", k)
        if key not in self._cache:
            d = self.drives[k]
            unit = np.eye(13)
            basis = replace(d, qdd=unit[:3], r=unit[3:7], rd=unit[7:11], a_long=unit[11],
                            a_lat=unit[12])
            a, b = equation_rows(basis)
            sig = np.vstack([d.qdd, d.r, d.rd, d.a_long, d.a_lat]).T
            self._cache[key] = (np.ascontiguousarray(sig),
                                np.concatenate([a, b[..., None]], axis=2))
        return self._cache[key]

    def _band_signals(self, k: int, part: slice) -> np.ndarray:
        """:meth:`_signals` of each hub-noise band, the samples of ``part`` (bands, n, 13)."""
        key = ("band_signals", k, part.start, part.stop)
        if key not in self._cache:
            d = self.drives[k]
            sb = band_split_signals(self._signals(k)[0].T, d.rate_hz, self.edges_hz)
            self._cache[key] = np.ascontiguousarray(sb.swapaxes(1, 2)[:, part])
        return self._cache[key]

    def _linear(self, k: int, part: slice, block: int
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """Block Gram matrices of ``[A, b]`` over ``part`` (3, n_blocks, P0 + 1, P0 + 1),
        samples per block, and the same per band (3, n_blocks, n_bands, P0 + 1, P0 + 1):
        those of :func:`~fielddiag.vehicle.regression.block_grams` (of
        :func:`~fielddiag.vehicle.regression.band_split`), from :meth:`_signals`."""
        key = ("grams", k, part.start, part.stop, block)
        if key not in self._cache:
            sig, m = self._signals(k)
            sp = sig[part]
            g = np.einsum("esp,bst,etq->ebpq", m, _block_products(sp, sp, block), m)
            n = np.diff(np.append(np.arange(0, sp.shape[0], max(1, int(block))),
                                  sp.shape[0]))
            bg = None
            if self.edges_hz is not None:
                ss = _block_products(self._band_signals(k, part),
                                     self._band_signals(k, part), block)
                bg = np.einsum("esp,bjst,etq->ebjpq", m, ss.swapaxes(0, 1), m)
            self._cache[key] = (g, n, bg)
        return self._cache[key]

    def grams(self, terms: Sequence[_Term], parts: Sequence[slice], block: int
              ) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray] | None]:
        """Per drive, the block Gram matrices of ``[A, E, b]`` over ``part`` (3, n_blocks,
        P + 1, P + 1), the samples per block, and the same per hub-noise band (3, n_blocks,
        n_bands, P + 1, P + 1; None when the hub noise is not estimated).

        The effects' products are formed from their per-corner columns and the 13 signals
        the rows are made of (:meth:`_signals`, :func:`_pieces`): the same sums, a
        fraction of the memory traffic."""
        grams, samples, bands = [], [], []
        for k, (d, part) in enumerate(zip(self.drives, parts, strict=True)):
            g, n, bg = self._linear(k, part, block)
            if terms:
                u, lev = _pieces(terms, d)
                sig, m = self._signals(k)
                up = u[part]
                us = _block_products(up, sig[part], block)  # (blocks, m, 13)
                uu = _block_products(up, up, block)
                g = _augment(g, np.einsum("ekq,bks,esp->ebqp", lev, us, m),
                             np.einsum("ekq,bkl,elr->ebqr", lev, uu, lev))
                if bg is not None:
                    ub = band_split_signals(u.T, d.rate_hz, self.edges_hz)
                    ubp = np.ascontiguousarray(ub.swapaxes(1, 2)[:, part])  # (bands, n, m)
                    us = _block_products(ubp, self._band_signals(k, part), block)
                    uu = _block_products(ubp, ubp, block)  # (bands, blocks, m, m)
                    bg = _augment(bg, np.einsum("ekq,jbks,esp->ebjqp", lev, us, m),
                                  np.einsum("ekq,jbkl,elr->ebjqr", lev, uu, lev))
            grams.append(g)
            samples.append(n)
            bands.append(bg)
        return grams, samples, (bands if self.edges_hz is not None else None)

    def noise_for(self, parts: Sequence[slice], n_extra: int,
                  hub_s2: np.ndarray | None = None) -> list[DriveNoise] | None:
        """The noise's expected share in the Gram matrices of the samples of ``parts`` (a
        share of the drive's), with zeros for the effects' columns: they are taken as
        noise-free (see :func:`diagnose_vehicle`); the hub noise starting from ``hub_s2``
        (drives, components, bands) if given."""
        if self.noise is None:
            return None
        out = []
        for k, (d, part, nz) in enumerate(zip(self.drives, parts, self.noise, strict=True)):
            frac = len(range(*part.indices(d.n))) / d.n

            def pad(m: np.ndarray, frac: float = frac) -> np.ndarray:
                lead = m.shape[:-2]
                return frac * _augment(m, np.zeros(lead + (n_extra, N_PARAMS + 1)),
                                       np.zeros(lead + (n_extra, n_extra)))

            s2 = nz.hub_s2 if hub_s2 is None else hub_s2[k]
            out.append(DriveNoise(pad(nz.known), pad(nz.hub_unit), np.array(s2, float)))
        return out


@dataclass
class _Fitted:
    terms: tuple[_Term, ...]
    theta: np.ndarray
    cov: np.ndarray
    fitted: np.ndarray
    names: list[str]
    group_sigma: np.ndarray | None = None
    hub_noise_s2: np.ndarray | None = None  # (drives, components, bands)
    hub_fallback: bool = False  # the hub noise taken as the body sensors' (see _fit)


def _fit(data: _Data, terms: Sequence[_Term], parts: Sequence[slice], fitted_base: np.ndarray,
         block: int, screen: bool = False, hub_start: np.ndarray | None = None,
         hub_iterations: int | None = None) -> _Fitted | None:
    """Noise-compensated weighted least squares of the linear model plus ``terms`` on
    ``parts``, the hub noise estimated from this model's equation errors
    (:func:`~fielddiag.vehicle.regression.compensated_least_squares`); jackknife
    covariance over ``block``-sample blocks, or (``screen``) the normal matrix's."""
    grams, samples, bands = data.grams(terms, parts, block)
    q = grams[0].shape[-1] - 1 - N_PARAMS
    fitted = np.concatenate([fitted_base, np.ones(q, bool)])
    for term in terms:
        fitted[term.replaced_columns()] = False
    iters = data.hub_iterations if hub_iterations is None else hub_iterations

    def solve(rounds: int) -> WlsResult | None:
        try:
            return compensated_least_squares(
                grams, samples, fitted, data.noise_for(parts, q, hub_start), bands, rounds,
                jackknife=not screen, bias_correction=data.bias_correction and not screen,
                normal_covariance=screen)
        except np.linalg.LinAlgError:
            return None

    w = solve(iters if bands is not None else 0)
    fallback = False
    if bands is not None and iters > 0 and not _is_car(w):
        # a model that leaves a large force out shows it as hub noise; compensated, that
        # "noise" can take the signal with it (mass or a corner's stiffness to <= 0): such
        # a model is fitted with the hubs as noisy as the body sensors instead
        w, fallback = solve(0), True
    if w is None or not np.all(np.isfinite(w.theta[w.fitted])):
        if not terms:
            raise InsufficientDataError(
                "the linear full-vehicle model cannot be fitted to these drives (singular "
                "equations): drive longer, over a rough road")
        return None  # a candidate whose columns leave the equations singular: not a model
    return _Fitted(tuple(terms), w.theta, w.cov, w.fitted, _names(terms), w.group_sigma,
                   w.hub_noise_s2, fallback)


def _is_car(w: WlsResult | None) -> bool:
    """A fit with finite parameters, a positive mass and positive corner stiffness and
    damping (where fitted)."""
    if w is None or not np.all(np.isfinite(w.theta[w.fitted])):
        return False
    corners = np.arange(_K0, _C0 + 4)
    th = w.theta
    return bool(th[0] > 0 and np.all(th[corners][w.fitted[corners]] > 0))


def _names(terms: Sequence[_Term]) -> list[str]:
    return list(PARAM_NAMES) + [f"{t.label}.{p}" for t in terms for p in t.linear_params()]


def _predict(f: _Fitted, d: DriveRegressors) -> np.ndarray:
    """Body-sensor accelerations (4, n) from the measured suspension motion."""
    a, _ = _equation_rows(d)
    th = np.nan_to_num(f.theta)
    rest = th[:N_PARAMS].copy()
    rest[:6] = 0.0
    forces = -(a @ rest)
    p0 = N_PARAMS
    for t in f.terms:
        cols = t.columns(d)
        forces -= cols @ th[p0:p0 + cols.shape[2]]
        p0 += cols.shape[2]
    qdd = np.linalg.solve(mass_matrix(th, d.added_mass_kg, d.added_mass_at_m), forces)
    return d.sensor_matrix @ qdd


def _residual(f: _Fitted, drives: Sequence[DriveRegressors], parts: Sequence[slice],
              preds: Sequence[np.ndarray] | None = None) -> tuple[np.ndarray, float]:
    """Residuals of the body accelerations on ``parts`` (time-major, drives concatenated)
    and their NRMSE."""
    res, meas = [], []
    for k, (d, part) in enumerate(zip(drives, parts, strict=True)):
        p = (_predict(f, d) if preds is None else preds[k])[:, part]
        m = d.body_accel[:, part]
        res.append((m - p).T.ravel())
        meas.append(m.T.ravel())
    r, m = np.concatenate(res), np.concatenate(meas)
    return r, float(np.sqrt(np.mean(r**2) / np.mean(m**2)))


def _physical(f: _Fitted) -> tuple[str, ...]:
    """Effect parameters that leave their bounds (negative friction...) or are not
    distinguishable from zero (|value| < 2 std): such a candidate is not chosen."""
    bad = []
    for term in f.terms:
        cls = get_effect(term.effect)
        for p in cls.params:
            if not p.scales_with_force:
                continue
            i = f.names.index(f"{term.label}.{p.name}")
            v, s = f.theta[i], math.sqrt(max(f.cov[i, i], 0.0))
            if not (p.lower <= v <= p.upper) or abs(v) < 2.0 * s:
                bad.append(f"{term.label}.{p.name}")
    # the linear stiffness and damping of every corner must stay positive
    for i in range(_K0, _C0 + 4):
        if f.fitted[i] and f.theta[i] <= 0:
            bad.append(PARAM_NAMES[i])
    return tuple(bad)


def _candidate(f: _Fitted, data: _Data, fit_parts, hold_parts) -> CandidateFit:
    preds = [_predict(f, d) for d in data.drives]
    res, nrmse_v = _residual(f, data.drives, hold_parts, preds)
    _, nrmse_f = _residual(f, data.drives, fit_parts, preds)
    values = {n: float(v) for n, v in zip(f.names, f.theta, strict=True) if np.isfinite(v)}
    std = {n: float(math.sqrt(max(f.cov[i, i], 0.0))) for i, n in enumerate(f.names)
           if np.isfinite(f.theta[i])}
    return CandidateFit(effects=tuple(t.label for t in f.terms), values=values, std=std,
                        nrmse_fit=nrmse_f, nrmse_validation=nrmse_v, residual_validation=res,
                        n_params=int(np.sum(f.fitted)), at_bound=_physical(f),
                        extra={"fitted": f})


# --------------------------------------------------------------------------- result
@dataclass
class VehicleDiagnosis:
    """Everything the full-vehicle diagnosis reports; :meth:`to_dict` is its JSON."""

    findings: list[dict[str, Any]]
    baseline: CandidateFit
    chosen: CandidateFit
    candidates: list[dict[str, Any]]
    linear_model: dict[str, Any]
    augmented_model: dict[str, Any]
    sessions: list[dict[str, Any]]
    band_hz: tuple[float, float]
    method: str
    warnings: list[dict[str, Any]] = field(default_factory=list)
    cross_validation: list[dict[str, Any]] = field(default_factory=list)
    fit: list[dict[str, Any]] = field(default_factory=list)
    vehicle: dict[str, Any] = field(default_factory=dict)
    noise: dict[str, Any] = field(default_factory=dict)

    @property
    def verdict(self) -> str:
        """``missing_physics`` when an effect is found, ``left_right_mismatch`` when only a
        mismatch is, ``adequate`` otherwise."""
        kinds = {f["effect"] for f in self.findings}
        if kinds - {"left_right_mismatch"}:
            return "missing_physics"
        return "left_right_mismatch" if kinds else "adequate"

    def to_dict(self) -> dict[str, Any]:
        """The JSON of the full-vehicle ``fielddiag diagnose`` (SI units in key names)."""
        base, ch = self.baseline, self.chosen
        return {
            "mode": "full_vehicle",
            "verdict": self.verdict,
            "baseline": {"nrmse": base.nrmse_fit, "nrmse_validation": base.nrmse_validation},
            "augmented": {"nrmse": ch.nrmse_fit, "nrmse_validation": ch.nrmse_validation},
            "findings": self.findings,
            "warnings": self.warnings,
            "linear_model": self.linear_model,
            "augmented_model": self.augmented_model,
            "band_hz": list(self.band_hz),
            "candidates": self.candidates,
            "sessions": self.sessions,
            "holdout": "last 30 % of every drive",
            "cross_validation": self.cross_validation,
            "fit": self.fit,
            "linear_model_adequate": ch is base,
            "method": self.method,
            "vehicle": self.vehicle,
            "noise": self.noise,
        }


def _model_dict(f: _Fitted) -> dict[str, Any]:
    """Body and corners of a fitted model, each ``{"value", "std"}`` (the identification's
    keys)."""
    p = N_PARAMS
    w = WlsResult(f.theta[:p], f.cov[:p, :p], f.fitted[:p], np.ones(1), 1)
    est = _derived(w)
    out: dict[str, Any] = {k: est[k].to_dict() for k in (
        "sprung_mass_kg", "cog_behind_front_axle_m", "cog_left_of_centre_m",
        "pitch_inertia_kgm2", "roll_inertia_kgm2")}
    out["corners"] = {}
    for i, c in enumerate(CORNERS):
        corner = {}
        if f.fitted[_K0 + i]:
            corner["stiffness_n_per_m"] = est[f"k_{c}"].to_dict()
        if f.fitted[_C0 + i]:
            corner["damping_ns_per_m"] = est[f"c_{c}"].to_dict()
        out["corners"][c] = corner
    out["anti_roll_stiffness_front_n_per_m"] = est["arb_f"].to_dict()
    out["anti_roll_stiffness_rear_n_per_m"] = est["arb_r"].to_dict()
    return out


def _windows(base: _Fitted, chosen: _Fitted, drives: Sequence[DriveRegressors],
             names: Sequence[str], window_s: float, top: int = 3) -> list[dict[str, Any]]:
    """Windows where the chosen model lowers the body-acceleration residual most."""
    out = []
    for d, name in zip(drives, names, strict=True):
        rb = np.sum((d.body_accel - _predict(base, d)) ** 2, axis=0)
        rc = np.sum((d.body_accel - _predict(chosen, d)) ** 2, axis=0)
        step = max(1, int(round(window_s * d.rate_hz)))
        for i0 in range(0, d.n - step // 2, step):
            sl = slice(i0, min(d.n, i0 + step))
            mb, mc = rb[sl].mean(), rc[sl].mean()
            out.append({"session": name, "start_s": i0 / d.rate_hz + d.start_s,
                        "end_s": sl.stop / d.rate_hz + d.start_s,
                        "residual_reduction": float(1.0 - mc / mb) if mb > 0 else 0.0})
    out.sort(key=lambda w: -w["residual_reduction"])
    return [w for w in out[:top] if w["residual_reduction"] > 0]


def _effect_finding(term: _Term, f_all: _Fitted, base_cmp, base: CandidateFit,
                    chosen: CandidateFit, nrmse_before: float, nrmse_after: float,
                    where: list[dict[str, Any]]) -> dict[str, Any]:
    params, stds = {}, {}
    for p in term.linear_params():
        i = f_all.names.index(f"{term.label}.{p}")
        params[p] = float(f_all.theta[i])
        stds[p] = float(math.sqrt(max(f_all.cov[i, i], 0.0)))
    for k, v in term.shape:
        params[k] = float(v)
    cls = get_effect(term.effect)
    shape = {p.name: params.pop(p.name) for p in cls.params if p.shape and p.name in params}
    explained = 1.0 - chosen.mse_validation / base.mse_validation
    place = term.place
    where_words = f"at {place}" if len(term.corners) == 1 else f"on the {place} axle"
    finding = {
        "effect": term.effect,
        ("corner" if len(term.corners) == 1 else "axle"): place,
        "confidence": confidence(base_cmp, explained / max(explained, 0.25)),
        "parameters": params,
        "shape": shape,
        "std": stds,
        "where": {"time_windows_s": where, "corners": list(term.corners)},
        "explanation": f"{where_words}: " + cls().explain(params, ""),
        "nrmse_validation_before": nrmse_before,
        "nrmse_validation_after": nrmse_after,
    }
    return finding


def _mismatches(f: _Fitted, tol: float, z_min: float) -> list[dict[str, Any]]:
    out = []
    for axle, (left, right) in AXLES.items():
        for quantity, c0, unit in (("damping", _C0, "ns_per_m"), ("stiffness", _K0, "n_per_m")):
            i, j = c0 + CORNERS.index(left), c0 + CORNERS.index(right)
            if not (f.fitted[i] and f.fitted[j]):
                continue
            a, b = f.theta[i], f.theta[j]
            va, vb, cab = f.cov[i, i], f.cov[j, j], f.cov[i, j]
            if not (a > 0 and b > 0):
                continue
            sd_diff = math.sqrt(max(va + vb - 2 * cab, 1e-300))
            sd_log = math.sqrt(max(va / a**2 + vb / b**2 - 2 * cab / (a * b), 1e-300))
            lr = math.log(a / b)
            z_dep = (abs(lr) - math.log1p(tol)) / sd_log
            if z_dep < z_min:
                continue
            weak, strong = (left, right) if a < b else (right, left)
            vw, vs = (a, b) if a < b else (b, a)
            ratio = vw / vs
            z = (vw - vs) / sd_diff
            out.append({
                "effect": "left_right_mismatch",
                "corner": weak,
                "axle": axle,
                "confidence": float(stats.norm.cdf(z_dep)),
                "parameters": {"quantity": quantity, "ratio": ratio,
                               f"this_corner_{unit}": float(vw),
                               f"partner_{unit}": float(vs)},
                "std": {"ratio": ratio * sd_log, f"this_corner_{unit}":
                        math.sqrt(va if a < b else vb),
                        f"partner_{unit}": math.sqrt(vb if a < b else va)},
                "z": float(z),
                "p_value": float(2 * stats.norm.sf(abs(z))),
                "tolerance": tol,
                "where": {"corners": [weak, strong]},
                "explanation": (
                    f"the {quantity} at {weak} is {100 * (1 - ratio):.0f} % lower than at "
                    f"{strong} (ratio {ratio:.2f} +- {ratio * sd_log:.2f}, z = {z:.1f}): "
                    + ("check the damper at " + weak + " for wear or leaks"
                       if quantity == "damping" else
                       "check the spring at " + weak + " for sag or breakage, and the ride "
                       "height")),
            })
    return out


# --------------------------------------------------------------------------- main
@single_threaded_blas
def diagnose_vehicle(
    before: VehicleRecording,
    after: VehicleRecording,
    added_mass_kg: float | None = None,
    added_mass_at_m: tuple[float, float] | None = None,
    validate: Sequence[VehicleRecording] = (),
    config: VehicleDiagnoseConfig = VehicleDiagnoseConfig(),
    progress: Callable[[str], None] | None = None,
) -> VehicleDiagnosis:
    """Diagnose a full vehicle per corner from a drive before and one after adding a mass.

    Parameters
    ----------
    before, after : VehicleRecording
        The car as it is, and with a known mass added on the body.
    added_mass_kg : float or None
        Added mass [kg]; default ``after.added_mass_kg - before.added_mass_kg``.
    added_mass_at_m : (x_m, y_m) or None
        Where it sits [m]; default ``after.added_mass_at_m``.
    validate : sequence of VehicleRecording
        Other drives of the same car (another manoeuvre) on which the linear and the
        chosen model are also scored.
    config : VehicleDiagnoseConfig
    progress : callable or None
        Called with a short message at each stage.

    Returns
    -------
    VehicleDiagnosis

    Raises
    ------
    InvalidValueError
        No positive added mass, or no position for it, or a bad setting.
    FieldDiagError
        Drives of cars with different geometry.
    InsufficientDataError
        A drive too short.
    """
    say = progress or (lambda _m: None)
    if added_mass_kg is None:
        added_mass_kg = float(after.added_mass_kg) - float(before.added_mass_kg)
    if not (math.isfinite(added_mass_kg) and added_mass_kg > 0):
        raise InvalidValueError(
            f"added mass {added_mass_kg!r} kg: the second drive needs a known mass added on "
            "the body; give --added-mass KG (> 0)")
    at = added_mass_at_m if added_mass_at_m is not None else after.added_mass_at_m
    if at is None or len(at) != 2 or not all(math.isfinite(float(v)) for v in at):
        raise InvalidValueError("where the added mass sits is unknown; give --added-mass-at "
                                "X_M,Y_M (metres behind the front axle, metres left of centre)")
    at = (float(at[0]), float(at[1]))
    if not 0.05 <= config.holdout_fraction <= 0.6:
        raise InvalidValueError("holdout_fraction must lie in 0.05..0.6")
    unknown = [e for e in config.effects if e not in EFFECTS]
    if unknown:
        raise InvalidValueError(f"unknown effect(s) {unknown}; choose from "
                                f"{', '.join(DEFAULT_EFFECTS)}")
    for other in (after, *validate):
        if other.geometry != before.geometry:
            raise FieldDiagError(
                f"{other.name or other.label or 'a drive'} has another vehicle geometry than "
                f"{before.name or 'the before drive'}; all drives must be of the same car")
    _COLUMNS.clear()
    _ROWS.clear()
    _RAW.clear()
    try:
        return _diagnose(before, after, added_mass_kg, at, validate, config, say)
    finally:
        _COLUMNS.clear()
        _ROWS.clear()
        _RAW.clear()


def _diagnose(before: VehicleRecording, after: VehicleRecording, added_mass_kg: float,
              at: tuple[float, float], validate: Sequence[VehicleRecording],
              config: VehicleDiagnoseConfig, say: Callable[[str], None]) -> VehicleDiagnosis:
    icfg = config.identify
    say("preparing the drives (integration, band-pass)")
    recs = (before, after)
    drives = []  # prepared flat in frequency: for the traces shown
    raws = []
    for rec, dm, pos in ((before, 0.0, (0.0, 0.0)), (after, added_mass_kg, at)):
        d = prepare_drive(rec, icfg)
        d.added_mass_kg, d.added_mass_at_m = dm, pos
        d.start_s = _start_s(rec, icfg)
        raws.append(_raw_motion(rec, icfg))
        _RAW[id(d)] = (d, raws[-1], None)
        drives.append(d)
    base_fitted = np.ones(N_PARAMS, bool)
    for col, sig in ((16, "a_long"), (17, "a_lat")):
        rms = max(float(np.sqrt(np.mean(getattr(d, sig) ** 2))) for d in drives)
        base_fitted[col] = rms > 0.02
    block = max(1, int(round(icfg.block_s * drives[0].rate_hz)))
    # the identification's noise model: the frequency weighting, the body sensors' and car
    # signals' noise known, the hubs' estimated from each model's equation errors
    fit_drives, weights = list(drives), [None] * len(drives)
    noise, edges, body_sigma = None, None, None
    if icfg.noise_compensation:
        body_sigma = [body_noise_std_mps2(rec) for rec in recs]
        car_sigma = [car_accel_noise_std_mps2(rec) for rec in recs]
        if icfg.noise_weighting:
            say("weighting the band by the noise")
            weights, fit_drives = weighted_drives(recs, drives, base_fitted, block, icfg,
                                                  body_sigma, car_sigma)
        spectrum = icfg.hub_noise == "spectrum"
        all_edges = band_edges_hz(icfg.band_hz, icfg.hub_noise_bands)
        noise = [drive_noise(rec, d, icfg, wt, all_edges, bs, cs,
                             icfg.hub_noise_correlation if spectrum else ())
                 for rec, d, wt, bs, cs in zip(recs, fit_drives, weights, body_sigma,
                                               car_sigma, strict=True)]
        edges = all_edges if spectrum else None
    for d, d0, raw, wt in zip(fit_drives, drives, raws, weights, strict=True):
        d.start_s = d0.start_s
        _RAW[id(d)] = (d, raw, wt)
    data = _Data(fit_drives, noise, [int(round((1 - config.holdout_fraction) * d.n))
                                     for d in fit_drives], edges, icfg.hub_noise_iterations,
                 icfg.jackknife_bias)
    fit_parts = [slice(0, s) for s in data.split]
    hold_parts = [slice(s, None) for s in data.split]
    all_parts = [slice(None)] * len(drives)

    # fits of models whose effects do not depend on the travel: the same in every search
    kept: dict[tuple, _Fitted | None] = {}

    def remembered(key: tuple, terms: Sequence[_Term], make: Callable[[], _Fitted | None]
                   ) -> _Fitted | None:
        if any(_depends_on_travel(t.effect) for t in terms):
            return make()
        if key not in kept:
            kept[key] = make()
        return kept[key]

    def fit(terms: Sequence[_Term], parts=fit_parts) -> _Fitted | None:
        return remembered((tuple(terms), parts is fit_parts, False), terms,
                          lambda: _fit(data, terms, parts, base_fitted, block))

    def screen_fit(terms: Sequence[_Term]) -> _Fitted | None:
        # the hub noise's fixed point in half the rounds (as the jackknife replicates)
        return remembered((tuple(terms), True, True), terms, lambda: _fit(
            data, terms, fit_parts, base_fitted, block, screen=True,
            hub_iterations=max(1, icfg.hub_noise_iterations // 2)))

    def best_shape(prefix: tuple[_Term, ...], effect: str, corners: tuple[str, ...]
                   ) -> CandidateFit:
        r = np.concatenate([raw.r[CORNERS.index(c)] for raw in raws for c in corners])
        best = None
        for shape in _shape_grid(effect, r):
            f = screen_fit((*prefix, _Term(effect, corners, shape)))
            if f is None:
                continue
            cand = _candidate(f, data, fit_parts, hold_parts)
            if best is None or cand.nrmse_fit < best.nrmse_fit:
                best = cand
        return best

    say("fitting the linear model")
    base_fit = fit(())
    base = _candidate(base_fit, data, fit_parts, hold_parts)
    places = [(c,) for c in CORNERS]
    if config.axle_candidates:
        places += list(AXLES.values())
    travel = [raw.r for raw in raws]

    def search(sag_theta: np.ndarray) -> tuple[CandidateFit, tuple[_Term, ...],
                                               list[CandidateFit]]:
        """The greedy search with the travel shifted by the static sag ``sag_theta``'s
        stiffness gives: effects act on the travel from the unloaded car's rest, and the
        drive with the mass added rests lower."""
        for d, raw, r in zip(drives, raws, travel, strict=True):
            raw.r = r + _plausible_sag_m(sag_theta, d)[:, None]
        _forget_travel_columns()
        say(f"trying {len(config.effects)} effects at {len(places)} places")
        tried: list[CandidateFit] = []
        chosen = base
        prefix: tuple[_Term, ...] = ()
        for _round in range(config.max_effects):
            used = {c for t in prefix for c in t.corners}
            screened = []
            for e in config.effects:
                for pl in places:
                    if used & set(pl):
                        continue
                    cand = best_shape(prefix, e, pl)
                    if cand is not None:
                        screened.append(cand)
            # the most promising few fitted exactly (jackknife covariance)
            promising = sorted((c for c in screened
                                if compare(chosen, c).beats(c.n_params - chosen.n_params)),
                               key=lambda c: c.mse_validation)[:config.exact_fits]
            exact = [fit(c.extra["fitted"].terms) for c in promising]
            cands = [_candidate(f, data, fit_parts, hold_parts) for f in exact
                     if f is not None]
            tried.extend(cands)
            tried.extend(c for c in screened if c not in promising)
            if chosen is base:
                sel = select_model(base, cands)
                nxt = sel.chosen if sel.chosen is not base else None
            else:
                ok = [c for c in cands if c.physical
                      and compare(chosen, c).beats(c.n_params - chosen.n_params)
                      and compare(base, c).beats(c.n_params - base.n_params)]
                nxt = min(ok, key=lambda c: c.mse_validation) if ok else None
            if nxt is None:
                break
            chosen = nxt
            prefix = chosen.extra["fitted"].terms
            say("chosen so far: " + ", ".join(chosen.effects))
        return chosen, prefix, tried

    # the sag from the linear model first; a car with a strong effect biases the linear
    # model (or collapses it: no sag), so the search is repeated with the sag of the model
    # it chose until the two agree, when that model has an effect that depends on the
    # travel or there was no sag (else the sag moved only effects that lost anyway)
    sag_theta = base_fit.theta
    for _pass in range(config.sag_passes):
        chosen, prefix, tried = search(sag_theta)
        if not prefix:
            break
        theta = chosen.extra["fitted"].theta
        had_sag = bool(np.any(_plausible_sag_m(sag_theta, drives[1])))
        if had_sag and not any(_depends_on_travel(t.effect) for t in prefix):
            break
        shift = max(float(np.max(np.abs(_plausible_sag_m(theta, d)
                                        - _plausible_sag_m(sag_theta, d)))) for d in drives)
        if shift <= config.sag_tolerance_m:
            break
        say(f"the chosen model moves the static sag by {1000 * shift:.1f} mm: searching again")
        sag_theta = theta
    say("refitting on all the data")
    base_all = fit((), all_parts)
    chosen_all = (fit(prefix, all_parts) or chosen.extra["fitted"]) if prefix else base_all
    names = [rec.name or rec.label or ("before", "after")[k]
             for k, rec in enumerate((before, after))]
    findings = []
    nrmse_prev = base.nrmse_validation
    base_cmp = compare(base, chosen) if prefix else None
    for k, term in enumerate(prefix):
        upto = fit(prefix[:k + 1]) if k + 1 < len(prefix) else chosen.extra["fitted"]
        _, nrmse_after = _residual(upto, fit_drives, hold_parts)
        single = fit((term,), all_parts)
        where = ([] if single is None else
                 _windows(base_all, single, fit_drives, names, config.window_s))
        findings.append(_effect_finding(term, chosen_all, base_cmp, base, chosen, nrmse_prev,
                                        nrmse_after, where))
        nrmse_prev = nrmse_after
    findings.extend(_mismatches(chosen_all, config.mismatch_tolerance, config.mismatch_z))
    cv = []
    for k, rec in enumerate(validate):
        if rec.added_mass_kg and rec.added_mass_at_m is None:
            raise InvalidValueError(f"{rec.name or 'a validate drive'} carries an added "
                                    "mass but not where it sits; record added_mass_at_m")
        d = prepare_drive(rec, icfg)
        wt = None
        if icfg.noise_compensation and icfg.noise_weighting:  # weighted as the fit drives
            wt = noise_weighting(d, base_all.theta[:N_PARAMS], [body_noise_std_mps2(rec)] * 8,
                                 car_accel_noise_std_mps2(rec), icfg.band_hz)
            d = prepare_drive(rec, icfg, wt)
        raw = _raw_motion(rec, icfg)
        raw.r = raw.r + _plausible_sag_m(sag_theta, d)[:, None]
        _RAW[id(d)] = (d, raw, wt)
        _, nb = _residual(base_all, [d], [slice(None)])
        _, nc = _residual(chosen_all, [d], [slice(None)])
        cv.append({"session": rec.name or rec.label or f"validate_{k + 1}",
                   "nrmse_linear": nb, "nrmse_augmented": nc})
    lo, hi = icfg.band_hz
    method = (
        "full-vehicle equation-error diagnosis: drives prepared as for the identification "
        f"(band {lo:g}-{hi:g} Hz, {drives[0].rate_hz:g} Hz), the 3 body equations linear in "
        "18 parameters plus, per candidate, a library effect's force at one corner (or on "
        "both corners of an axle) with the corner's lever arms; weighted least squares "
        + ("with the identification's noise model (weighted in frequency by the noise's share "
           "of the equation errors, sensor-noise bias compensated: body sensors' noise from "
           "their redundancy, the hubs' band by band from each model's own equation errors; "
           "the effects' columns taken as noise-free) "
           if icfg.noise_compensation and icfg.noise_weighting and edges is not None else
           "(noise-bias compensated) " if icfg.noise_compensation else "")
        + f"on the first {100 * (1 - config.holdout_fraction):.0f} % "
        "of each drive, body accelerations (weighted like the fit) predicted on the last "
        f"{100 * config.holdout_fraction:.0f} %; the simplest model that predicts them "
        "significantly better (paired block t >= 3, gain >= 2 % per parameter, parameters "
        f"physical and > 2 std) chosen, greedily up to {config.max_effects} effects; "
        "parameters refitted on all the data; left/right mismatch when the ratio of an "
        f"axle's damping or stiffness departs from 1 by more than "
        f"{100 * config.mismatch_tolerance:.0f} % with one-sided z >= {config.mismatch_z:g}")
    cands_json = [{"effects": list(c.effects), "nrmse_validation": c.nrmse_validation,
                   "t_vs_linear": compare(base, c).t, "physical": c.physical,
                   "parameters": {k: v for k, v in c.values.items() if "@" in k}}
                  for c in tried]
    cands_json.sort(key=lambda c: c["nrmse_validation"])
    sessions = [{"label": rec.label or ("before", "after")[k], "name": names[k],
                 "added_mass_kg": float((0.0, added_mass_kg)[k]),
                 "added_mass_at_m": None if k == 0 else list(at),
                 "duration_s": rec.duration_s} for k, rec in enumerate((before, after))]
    return VehicleDiagnosis(
        findings=findings, baseline=base, chosen=chosen, candidates=cands_json[:40],
        warnings=[{"kind": "gaps", "message": n}
                  for n in reading_notes(before, after, *validate)],
        linear_model=_model_dict(base_all), augmented_model=_model_dict(chosen_all),
        sessions=sessions, band_hz=(lo, hi), method=method, cross_validation=cv,
        fit=_fit_traces(base_all, chosen_all, drives, names, hold_parts),
        vehicle=before.geometry.to_dict(),
        noise=_noise_dict(body_sigma, edges, base_all, chosen_all, weights,
                          0.5 * fit_drives[0].rate_hz))


def _noise_dict(body_sigma: Sequence[float] | None, edges: np.ndarray | None,
                base: _Fitted, chosen: _Fitted, weights: Sequence[Any], nyquist_hz: float
                ) -> dict[str, Any]:
    """The noise the compensation used: the body sensors' per drive; the hubs' per drive
    and band (white-equivalent, each hub's variance) as the linear and the chosen model's
    equation errors gave it, or the body sensors' where that fit collapsed (``..._fallback``);
    the bands' edges, the last one the analysis rate's Nyquist frequency."""
    if body_sigma is None:
        return {}
    out: dict[str, Any] = {"body_noise_std_mps2": [float(v) for v in body_sigma],
                           "frequency_weighting": weights[0] is not None}
    if edges is not None:
        out["band_edges_hz"] = [float(min(v, nyquist_hz)) for v in edges]
        for label, f in (("linear", base), ("chosen", chosen)):
            out[f"hub_noise_std_mps2_{label}"] = np.sqrt(f.hub_noise_s2[:, 0]).tolist()
            out[f"hub_noise_fallback_{label}"] = bool(f.hub_fallback)
    return out


def _start_s(rec: VehicleRecording, cfg: VehicleIdentifyConfig) -> float:
    """Time of the first prepared sample in the recording [s] (the trimmed filter ends of
    :func:`~fielddiag.vehicle.identify.prepare_drive`; a stretch read from later in the
    session counts from the session's first sample)."""
    fs = float(rec.sample_rate_hz)
    trim = int(round((4.5 / cfg.band_hz[0] if cfg.trim_s is None else cfg.trim_s) * fs))
    return float(getattr(rec, "start_s", 0.0)) + trim / fs


def _fit_traces(base: _Fitted, chosen: _Fitted, drives: Sequence[DriveRegressors],
                names: Sequence[str], hold_parts, max_points: int = 1500) -> list[dict]:
    """Held-out traces of the mean body acceleration: recorded, linear, augmented."""
    out = []
    for d, name, part in zip(drives, names, hold_parts, strict=True):
        t = d.start_s + np.arange(d.n) / d.rate_hz
        pb, pc = _predict(base, d), _predict(chosen, d)
        t, m, pb, pc = t[part], d.body_accel[:, part], pb[:, part], pc[:, part]
        step = max(1, t.size // max_points)
        out.append({"session": name, "time_s": t[::step].tolist(),
                    "recorded": m.mean(axis=0)[::step].tolist(),
                    "simulated_linear": pb.mean(axis=0)[::step].tolist(),
                    "simulated_augmented": pc.mean(axis=0)[::step].tolist()})
    return out


def is_full_vehicle_pair(paths: Sequence[Any]) -> bool:
    """True when every session holds all eight full-vehicle accelerometer roles."""
    from fielddiag.vehicle.recording import is_full_vehicle_session

    return bool(paths) and all(is_full_vehicle_session(p) for p in paths)



def format_vehicle_summary(out: dict[str, Any]) -> str:
    """Readable text of a full-vehicle diagnosis dict (:meth:`VehicleDiagnosis.to_dict`).

    Parameters
    ----------
    out : dict
        The JSON of the full-vehicle diagnosis.

    Returns
    -------
    str
    """
    lines = [f"full-vehicle diagnosis: {out['verdict']}"]
    lines.extend(f"  warning: {w.get('message', w) if isinstance(w, dict) else w}"
                 for w in out.get("warnings", []))
    b, a = out["baseline"], out["augmented"]
    lines.append(f"  held-out NRMSE of the body accelerations: linear "
                 f"{b['nrmse_validation']:.4f}, chosen model {a['nrmse_validation']:.4f}")
    if not out["findings"]:
        lines.append("  no finding: the linear full-vehicle model is adequate and the axles "
                     "are balanced")
    for f in out["findings"]:
        place = f.get("corner") or f"{f.get('axle')} axle"
        params = ", ".join(
            f"{k} = {v:.4g}" + (f" +- {f['std'][k]:.2g}" if k in f.get("std", {}) else "")
            if isinstance(v, (int, float)) else f"{k} = {v}"
            for k, v in f["parameters"].items())
        lines.append(f"  [{place}] {f['effect']}: {params}")
        lines.append(f"      {f['explanation']}")
        if "nrmse_validation_before" in f:
            lines.append(f"      held-out NRMSE {f['nrmse_validation_before']:.4f} -> "
                         f"{f['nrmse_validation_after']:.4f}")
        for w in f.get("where", {}).get("time_windows_s", [])[:3]:
            lines.append(f"      acts most in {w['session']} {w['start_s']:.0f}-"
                         f"{w['end_s']:.0f} s (residual -{100 * w['residual_reduction']:.0f} %)")
    m, lin = out["augmented_model"], out["linear_model"]
    fitted = "fitted with the findings" if out["findings"] else "the linear model"
    lines.append("  body, {}: mass {:.1f} +- {:.2g} kg, CoG {:.3f} m behind the front axle, "
                 "{:.3f} m left; pitch inertia {:.0f} kg m^2, roll inertia {:.0f} kg m^2".format(
                     fitted, m["sprung_mass_kg"]["value"], m["sprung_mass_kg"]["std"],
                     m["cog_behind_front_axle_m"]["value"], m["cog_left_of_centre_m"]["value"],
                     m["pitch_inertia_kgm2"]["value"], m["roll_inertia_kgm2"]["value"]))
    if out["findings"]:
        lines.append("      (the linear model alone, biased by what it leaves out: mass "
                     "{:.1f} +- {:.2g} kg)".format(lin["sprung_mass_kg"]["value"],
                                                   lin["sprung_mass_kg"]["std"]))
    for c, d in m["corners"].items():
        parts = [f"{k} {v['value']:.4g} +- {v['std']:.2g}" for k, v in d.items()]
        lines.append(f"  {c}: " + ", ".join(parts))
    for cv in out.get("cross_validation", []):
        lines.append(f"  {cv['session']}: NRMSE linear {cv['nrmse_linear']:.4f}, chosen "
                     f"{cv['nrmse_augmented']:.4f}")
    return "\n".join(lines)
