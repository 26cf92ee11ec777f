"""From two recordings (before / after adding a known mass) to an IdentificationResult.

:func:`identify_recordings` does the numerics on arrays plus a sample rate;
:func:`identify_sessions` reads the wheel and body channels of two session files by role
and calls it. Both check first what the data can answer and raise
:class:`~fielddiag.errors.InsufficientDataError` (or ``ChannelNotFoundError``) with what to
record instead, rather than return a confident wrong number:

* a drive shorter than ``min_duration_s``, or sampled too slowly;
* a wheel channel that hardly rises above its noise floor (no road excitation);
* too little body/wheel coherence around the body resonance;
* an added mass whose effect the noise cannot resolve (relative std of M2 above
  ``max_relative_std_mass``).

Steps: Welch spectra per time block -> noise floors -> band -> frequency-domain ML over
both sessions with and without K3 (jackknife std) -> time-domain route from the same
start -> cross-check -> transmissibility, restoring-force surfaces and loops for display.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from fielddiag.blas import single_threaded_blas
from fielddiag.drive import CornerDrive, read_corner_drive
from fielddiag.dsp import (
    BlockCrossSpectra,
    CrossSpectra,
    block_cross_spectra,
    spectrum_on_grid,
)
from fielddiag.errors import InsufficientDataError
from fielddiag.identify.boundary import (
    THETA_NAMES,
    RouteEstimate,
    frequency_route,
    model_transmissibility,
    pair_consistency,
    prepare_time_piece,
    prewhitened_signal_power,
    route_agreement,
    time_route,
)
from fielddiag.identify.restoring_force import (
    hysteresis_loops,
    motion_noise_covariance,
    restoring_force_surface,
    suspension_motion,
    travel_band,
)
from fielddiag.identify.results import (
    Band,
    ComplexSeries,
    Estimate,
    IdentificationResult,
    NoiseResult,
    Peak,
    RouteResult,
    SessionSummary,
    TransmissibilityResult,
)
from fielddiag.identify.transmissibility import (
    SessionNoise,
    choose_band,
    debiased_coherence,
    estimate_session_noise,
    hv_transmissibility,
    resonance_peaks,
)

METHOD = (
    "Welch spectra (Hann, 50 % overlap) per time block; white sensor-noise floors from the "
    "spectrum top and the body/wheel coherence; errors-in-variables maximum likelihood over "
    "the band lines of both drives (frequency route) and prewhitened output error over the "
    "whole record (time route); standard deviations by a delete-a-block jackknife."
)


#: One drive as identification takes it: the wheel and body readings in m/s^2 (gravity,
#: bias and drift allowed), built from arrays or read by :func:`read_recording`.
Recording = CornerDrive


@dataclass
class IdentifyConfig:
    """Settings of :func:`identify_recordings` (defaults suit 0.5-30 Hz quarter-car data).

    Attributes
    ----------
    segment_s : float or None
        Welch segment length; default ``clip(duration / 12, 4, 12)`` s. Longer segments
        leak less (Welch's resolution bias, which at the lowest lines shows up as a small
        negative K3), shorter ones give more averages.
    n_blocks : int or None
        Jackknife blocks per session; default ``clip(duration / (2.5 segment), 5, 20)``.
    coherence_min : float
        Bias-corrected coherence that both sessions must reach on every band line.
    max_band_hz : float
        Upper limit of the band (the quarter-car model is not meant beyond it).
    min_duration_s : float
        Shorter drives are refused.
    max_relative_std_mass : float
        Refuse when std(M2)/M2 is larger.
    target_relative_std_mass : float
        Warn when std(M2)/M2 is larger.
    k3 : {"auto", "fit", "zero"}
        Coupling stiffness K3: kept only when significant (auto), always fitted, or 0.
    k3_z_min : float
        |K3|/std needed for "auto" to keep it (4: the Welch resolution bias at the lowest
        lines is worth about half a std of K3, and the jackknife std has few degrees of
        freedom; K3 below ~1 % of K2 is immaterial anyway).
    time_route : bool
        Also run the time-domain route and cross-check.
    hysteresis_freqs_hz : tuple of float or None
        Loop frequencies; default 0.7, 1, 2 and 4 times the body natural frequency.
    display : bool
        Compute the restoring-force surfaces and loops (for plots and the dashboard);
        batch runs that need only the numbers can switch it off.
    max_plot_lines : int
        Frequency lines kept in the transmissibility arrays of the result.
    refuse : bool
        Refuse a pair whose drives do not behave like one corner, or whose mass is not
        resolved (the default: no number is better than a wrong one). False returns
        whatever the fit gives, with the warnings: the diagnosis uses the spectra of such
        a pair to estimate the data problems that may be the reason.
    """

    segment_s: float | None = None
    n_blocks: int | None = None
    coherence_min: float = 0.5
    max_band_hz: float = 40.0
    min_duration_s: float = 30.0
    max_relative_std_mass: float = 0.20
    target_relative_std_mass: float = 0.02
    k3: str = "auto"
    k3_z_min: float = 4.0
    time_route: bool = True
    hysteresis_freqs_hz: tuple[float, ...] | None = None
    display: bool = True
    max_plot_lines: int = 400
    refuse: bool = True


# ---------------------------------------------------------------------------------------
# Checks
# ---------------------------------------------------------------------------------------

#: Warn when the time route's prewhitened residual power exceeds the sensor noise by this
#: factor. Linear cars give 1.0-1.4 (100 random drive pairs of bench_identify: median
#: 1.06, max 1.35; a 60 s drive 1.41); the diagnosis catalogue's effects give 13-613, its
#: smallest (at 1.5-1.9x the noise floor of the diagnosis) 1.7-33.
LINEAR_MISFIT_WARN = 1.6
#: ... and when that excess over the noise is a material share of the body signal's power.
#: At high SNR (45 dB) linear cars leave 1.6-1.9 times the (tiny) noise, about 3e-5 of the
#: signal: not news. See :func:`~fielddiag.identify.boundary.prewhitened_signal_power`.
LINEAR_EXCESS_WARN = 1e-4

WHAT_TO_RECORD = (
    "record 2-5 min per drive at constant moderate speed on a rough road (ISO class B-C, "
    "cobbles or a worn country road), with a body-side and a wheel-side accelerometer, "
    "and add a mass of 10-30 % of the corner load for the second drive"
)


def _check_recording(rec: Recording, cfg: IdentifyConfig) -> None:
    name = rec.label or "a recording"
    where = f" ({rec.path})" if rec.path else ""
    if rec.sample_rate_hz < 20:
        raise InsufficientDataError(
            f"{name}{where} is sampled at {rec.sample_rate_hz:g} Hz; identification needs at "
            "least 50 Hz (200 Hz or more is better) so the band around the body resonance "
            "and the wheel hop is recorded")
    if rec.duration_s < cfg.min_duration_s:
        raise InsufficientDataError(
            f"{name}{where} lasts only {rec.duration_s:.1f} s; at least {cfg.min_duration_s:g}"
            f" s are needed and 120-300 s give a mass within 2 %: {WHAT_TO_RECORD}")
    for ch, arr in (("wheel", rec.wheel_accel_mps2), ("body", rec.body_accel_mps2)):
        a = np.asarray(arr)
        if not np.all(np.isfinite(a[: rec.n])):
            raise InsufficientDataError(
                f"the {ch} channel of {name}{where} holds NaN or infinite samples; cut the "
                "recording to the clean part or re-import it")


def _auto_segment(duration_s: float, cfg: IdentifyConfig) -> float:
    if cfg.segment_s is not None:
        return float(cfg.segment_s)
    return float(np.clip(duration_s / 12.0, 4.0, 12.0))


def _auto_blocks(duration_s: float, segment_s: float, cfg: IdentifyConfig) -> int:
    if cfg.n_blocks is not None:
        return int(cfg.n_blocks)
    return int(np.clip(duration_s / (2.5 * segment_s), 5, 20))


def _smooth(x: np.ndarray, n: int = 5) -> np.ndarray:
    return np.convolve(x, np.ones(n) / n, mode="same")


def _check_excitation(rec: Recording, sp: CrossSpectra, noise: SessionNoise) -> None:
    f = sp.freq_hz
    m = (f >= 0.5) & (f <= min(20.0, 0.4 * sp.sample_rate_hz))
    snr_x = _smooth(sp.gxx / noise.wheel_psd_per_hz)[m]
    snr_y = _smooth(sp.gyy / noise.body_psd_per_hz)[m]
    name = rec.label or "a recording"
    if snr_x.size == 0 or np.max(snr_x) < 10:
        raise InsufficientDataError(
            f"the wheel accelerometer of {name} hardly rises above its noise floor between "
            f"0.5 and 20 Hz (best signal/noise {np.max(snr_x, initial=0):.1f}): the road did "
            f"not excite the suspension (car standing, very smooth road, or a dead sensor). "
            f"Check the wheel sensor and {WHAT_TO_RECORD}")
    if np.max(snr_y) < 10:
        raise InsufficientDataError(
            f"the body accelerometer of {name} hardly rises above its noise floor between "
            f"0.5 and 20 Hz (best signal/noise {np.max(snr_y):.1f}); check the body sensor "
            f"(mounting, cable, range setting) and {WHAT_TO_RECORD}")


def _body_resonance_guess(sp: CrossSpectra, noise: SessionNoise) -> float:
    f = sp.freq_hz
    t = np.abs(hv_transmissibility(sp, noise.wheel_psd_per_hz, noise.body_psd_per_hz))
    coh = debiased_coherence(sp)
    m = (f >= 0.3) & (f <= 4.0) & (coh > 0.3)
    if not np.any(m):
        return float("nan")
    return float(f[m][np.argmax(_smooth(t)[m])])


# ---------------------------------------------------------------------------------------
# Main entry on arrays
# ---------------------------------------------------------------------------------------


def _route_result(route: RouteEstimate) -> RouteResult:
    est = [Estimate(float(v), float(s)) for v, s in zip(route.theta, route.std, strict=True)]
    fn, zeta = route.derived["body_natural_frequency_hz"], route.derived["damping_ratio"]
    return RouteResult(
        name=route.name, sprung_mass_kg=est[0], suspension_stiffness_n_per_m=est[1],
        suspension_damping_ns_per_m=est[2], coupling_stiffness_n_per_m=est[3],
        body_natural_frequency_hz=Estimate(*fn), damping_ratio=Estimate(*zeta),
        k3_included=route.include_k3, n_residuals=route.n_residuals, cost=route.cost,
        least_squares_std={n: float(s) for n, s in zip(THETA_NAMES, route.lsq_std, strict=True)},
        notes=list(route.notes))


def _plot_lines(f: np.ndarray, band: tuple[float, float], max_lines: int) -> np.ndarray:
    hi = min(1.5 * band[1], f[-1])
    idx = np.flatnonzero((f > 0) & (f <= hi))
    if idx.size > max_lines:
        pick = np.unique(np.round(np.geomspace(idx[0], idx[-1], max_lines)).astype(int))
        idx = pick
    return idx


def _noise_result(n: SessionNoise, fs: float) -> NoiseResult:
    return NoiseResult(
        wheel_psd_per_hz=n.wheel_psd_per_hz, body_psd_per_hz=n.body_psd_per_hz,
        wheel_rms_mps2=math.sqrt(n.wheel_psd_per_hz * fs / 2),
        body_rms_mps2=math.sqrt(n.body_psd_per_hz * fs / 2),
        wheel_plateau_found=n.wheel_plateau.found, body_plateau_found=n.body_plateau.found,
        notes=list(n.notes))


#: How the warning starts when the two drives do not behave like one corner with the mass
#: added (the diagnosis passes it on).
PAIR_INCONSISTENT = "the two drives do not behave like one corner"
#: The most mass a technician can add on one corner's body [kg] and the longest drive
#: [s] worth asking for: advice beyond these is not advice.
PRACTICAL_ADDED_MASS_KG = 150.0
PRACTICAL_DRIVE_S = 30 * 60.0


def _resolution_advice(dm: float, duration_s: float, rel: float, cfg: IdentifyConfig,
                       diagnose_hint: str) -> str:
    """What to record so that the mass std falls to the target, or where to look instead.

    The std of the mass falls about in proportion to the added mass and to the square root
    of the drive length; only advice a technician can follow is given.
    """
    target = cfg.target_relative_std_mass
    need_mass = dm * rel / target if math.isfinite(rel) else float("inf")
    need_time = duration_s * (rel / target) ** 2 if math.isfinite(rel) else float("inf")
    options = []
    if need_mass <= PRACTICAL_ADDED_MASS_KG:
        options.append(f"add about {need_mass:.0f} kg instead of {dm:g} kg")
    if need_time <= PRACTICAL_DRIVE_S:
        options.append(f"record about {need_time / 60:.0f} min per drive")
    if options:
        return (f"For a {100 * target:.0f} % std " + " or ".join(options)
                + f", or drive on a rougher road; if that does not help, {diagnose_hint}.")
    return ("No practical amount of added mass or drive length would fix this, so the linear "
            f"model probably does not describe these two drives: {diagnose_hint}, and check "
            "that both drives are of the same car corner.")


@single_threaded_blas
def identify_recordings(
    before: Recording,
    after: Recording,
    added_mass_kg: float | None = None,
    *,
    band_hz: tuple[float, float] | None = None,
    config: IdentifyConfig | None = None,
    progress: Callable[[float, str], None] | None = None,
) -> IdentificationResult:
    """Identify M2, K2, C2 (and K3) from a drive before and a drive after adding a mass.

    Parameters
    ----------
    before, after : Recording
        The two drives (same car, same sensors); ``after`` carries the added mass.
    added_mass_kg : float or None
        Mass added on the body for ``after`` [kg]; default ``after.added_mass_kg -
        before.added_mass_kg``.
    band_hz : (float, float) or None
        Frequency band [Hz]; default chosen from the coherence of both drives.
    config : IdentifyConfig or None
    progress : callable or None
        ``progress(fraction, message)`` is called between the steps (for a dashboard).

    Returns
    -------
    IdentificationResult

    Raises
    ------
    InsufficientDataError
        The drives cannot support an answer; the message says why and what to record.
    """
    cfg = config or IdentifyConfig()

    def step(fraction: float, message: str) -> None:
        if progress is not None:
            progress(fraction, message)

    warnings: list[str] = []
    if added_mass_kg is None:
        added_mass_kg = after.added_mass_kg - before.added_mass_kg
    dm = float(added_mass_kg)
    if not math.isfinite(dm) or dm <= 0:
        raise InsufficientDataError(
            f"the added mass must be a positive number of kg (got {added_mass_kg}); give it "
            "with --added-mass KG. Without a known added mass only ratios to the sprung mass "
            "can be identified")
    if after.added_mass_kg and abs(after.added_mass_kg - before.added_mass_kg - dm) > 1e-6:
        warnings.append(
            f"the sessions record an added mass of {after.added_mass_kg - before.added_mass_kg:g}"
            f" kg but {dm:g} kg was given; the given value is used")
    before.label = before.label or "before"
    after.label = after.label or "after"
    recs = [before, after]
    masses = [0.0, dm]
    for r in recs:
        _check_recording(r, cfg)
    fs_min = min(r.sample_rate_hz for r in recs)
    duration = min(r.duration_s for r in recs)
    seg = _auto_segment(duration, cfg)

    # spectra per time block, noise floors
    step(0.05, "spectra per time block")
    blocks: list[BlockCrossSpectra] = []
    for r in recs:
        nb = _auto_blocks(r.duration_s, seg, cfg)
        try:
            blocks.append(block_cross_spectra(
                np.asarray(r.wheel_accel_mps2)[: r.n], np.asarray(r.body_accel_mps2)[: r.n],
                r.sample_rate_hz, segment_s=seg, n_blocks=nb, pieces=r.piece_list()))
        except ValueError as exc:
            raise InsufficientDataError(
                f"{r.label}: {exc}; the recording has too many gaps. {WHAT_TO_RECORD}") from None
    totals = [b.total() for b in blocks]
    noise_band = (max(2.0 / seg, 0.1), min(0.3 * fs_min, 60.0))
    noises = [estimate_session_noise(sp, fit_band_hz=noise_band) for sp in totals]
    for r, sp, nz in zip(recs, totals, noises, strict=True):
        _check_excitation(r, sp, nz)
        for who, plat in (("wheel", nz.wheel_plateau), ("body", nz.body_plateau)):
            if not plat.found and nz.coherence_fit is None:
                warnings.append(f"{r.label}: no noise floor found for the {who} channel "
                                f"({plat.note}); the noise level used is an upper bound")

    # band
    step(0.2, "noise floors and band")
    f_anchor = _body_resonance_guess(totals[0], noises[0])
    hi_cap = min(cfg.max_band_hz, 0.35 * fs_min)
    for nz in noises:
        for plat in (nz.wheel_plateau, nz.body_plateau):
            if plat.found and plat.band_hz is not None:
                hi_cap = min(hi_cap, 0.9 * plat.band_hz[0])
    lo_min = 2.0 / seg
    if band_hz is None:
        try:
            band = choose_band(totals, coherence_min=cfg.coherence_min, min_freq_hz=lo_min,
                               max_freq_hz=hi_cap, anchor_hz=f_anchor)
        except ValueError:
            coh = [float(np.median(debiased_coherence(sp)[(sp.freq_hz > 0.5) &
                                                          (sp.freq_hz < 10)])) for sp in totals]
            raise InsufficientDataError(
                "the body and wheel accelerations are not coherent enough around the body "
                f"resonance (median coherence 0.5-10 Hz: before {coh[0]:.2f}, after "
                f"{coh[1]:.2f}; {cfg.coherence_min:g} needed): check that both sensors are "
                "vertical, firmly mounted on the same corner and recorded together, then "
                f"{WHAT_TO_RECORD}") from None
        band_src, band_note = "data", (
            f"both drives' coherence >= {cfg.coherence_min:g}, below {hi_cap:.1f} Hz")
        if not (band[0] <= f_anchor <= band[1]):
            warnings.append(f"the band {band[0]:.2f}-{band[1]:.2f} Hz does not contain the body "
                            f"resonance near {f_anchor:.2f} Hz")
    else:
        lo, hi = float(band_hz[0]), float(band_hz[1])
        if not (0 < lo < hi < 0.45 * fs_min):
            raise InsufficientDataError(
                f"--band {lo:g} {hi:g} is not a valid band for data sampled at {fs_min:g} Hz; "
                f"give 0 < LO < HI < {0.45 * fs_min:g}")
        if lo < lo_min:
            warnings.append(f"the given band starts at {lo:g} Hz, below the resolution of "
                            f"{seg:g} s segments ({lo_min:.2f} Hz)")
        band = (lo, hi)
        band_src, band_note = "user", "given with --band"
    n_lines = int(np.sum((totals[0].freq_hz >= band[0]) & (totals[0].freq_hz <= band[1])))
    if n_lines < 8:
        raise InsufficientDataError(
            f"the usable band {band[0]:.2f}-{band[1]:.2f} Hz holds only {n_lines} spectral "
            f"lines; {WHAT_TO_RECORD}")

    # noise per jackknife replicate (the same for both K3 choices)
    noise_total = [(n.wheel_psd_per_hz, n.body_psd_per_hz) for n in noises]
    noise_reps = []
    for blk in blocks:
        reps = []
        for b in range(blk.n_blocks):
            nz = estimate_session_noise(blk.leave_out(b), fit_band_hz=noise_band)
            reps.append((nz.wheel_psd_per_hz, nz.body_psd_per_hz))
        noise_reps.append(reps)

    # frequency route, with and without K3
    fits: dict[bool, RouteEstimate] = {}
    want = {"auto": (False, True), "fit": (True,), "zero": (False,)}.get(cfg.k3)
    if want is None:
        raise ValueError(f"config.k3 must be auto, fit or zero, not {cfg.k3!r}")
    for i, inc in enumerate(want):
        step(0.25 + 0.2 * i, f"frequency route {'with' if inc else 'without'} K3, jackknife")
        fits[inc] = frequency_route(blocks, masses, band, noise_total, noise_reps,
                                    include_k3=inc)
    k3_test: dict[str, float] = {}
    if True in fits:
        f4 = fits[True]
        z = abs(f4.theta[3]) / f4.std[3] if f4.std[3] > 0 else float("inf")
        k3_test = {"value": float(f4.theta[3]), "std": float(f4.std[3]), "z": float(z)}
        if False in fits:
            k3_test["cost_reduction"] = float(fits[False].cost - f4.cost)
    if cfg.k3 == "auto":
        keep_k3 = bool(k3_test["z"] > cfg.k3_z_min and k3_test["cost_reduction"] > 4.5)
    else:
        keep_k3 = cfg.k3 == "fit"
    main = fits[keep_k3]
    k3_std = float(k3_test.get("std", 0.0))

    m2, k2 = main.theta[0], main.theta[1]
    step(0.6, "do the two drives belong together")
    pair = pair_consistency(blocks, masses, band, noise_total, main.theta)
    diagnose_hint = ("run `fielddiag diagnose` on the same two drives to see what the linear "
                     "model leaves out")
    if pair.stiffness_drop_z < -3.0:
        # a competing hypothesis, not a gate: a spring that stiffens as the car sags under
        # the added mass raises the resonance too
        warnings.append(
            f"{PAIR_INCONSISTENT} with {dm:g} kg added: the body resonance rose (stiffness "
            f"per unit mass {pair.ratios_before[0]:.4g} before, {pair.ratios_after[0]:.4g} "
            "1/s2 after). Either the drives are swapped or not of the same car corner, or the "
            "spring stiffens as the car sags (a progressive spring or a bump stop), and these "
            f"values do not hold: {diagnose_hint}")
    mk, mc = pair.mass_from_stiffness_kg, pair.mass_from_damping_kg
    if (pair.stiffness_drop_z >= -3.0 and pair.disagreement_z > 4.0
            and not (mk > 0 and mc > 0 and 2 / 3 < mk / mc < 3 / 2)):
        warnings.append(
            f"{PAIR_INCONSISTENT} with {dm:g} kg added: their "
            f"stiffness implies a sprung mass of {mk:.4g} +- {pair.mass_from_stiffness_std_kg:.2g}"
            f" kg, their damping {mc:.4g} +- {pair.mass_from_damping_std_kg:.2g} kg. Either "
            "they are not of the same car corner, or the suspension is not linear (dry "
            "friction or a progressive spring change the equivalent damping and stiffness "
            f"with the load and the amplitude): {diagnose_hint}")
    mismatch = [w for w in warnings if w.startswith(PAIR_INCONSISTENT)]
    if not cfg.refuse:
        pass  # the caller wants the spectra and the fit whatever they say (the diagnosis)
    elif mismatch and not (m2 > 0 and k2 > 0 and main.std[0] < 0.2 * m2):
        # the best explanation of a hopeless fit: the drives do not behave as one corner
        raise InsufficientDataError(
            "no sprung mass can be given: " + mismatch[0].replace(
                "and these values do not hold: ", ""))
    elif not (m2 > 0 and k2 > 0 and np.all(np.isfinite(main.theta))):
        raise InsufficientDataError(
            f"the fit gives no physical answer (M2 {m2:.4g} kg, K2 {k2:.4g} N/m): the added mass"
            f" of {dm:g} kg does not shift the transmissibility measurably, or the linear model "
            f"does not describe these drives. Add more mass (10-30 % of the corner load), "
            f"record longer or on a rougher road, or {diagnose_hint}")
    rel = main.std[0] / m2 if m2 else math.inf
    if cfg.refuse and (not math.isfinite(rel) or rel > cfg.max_relative_std_mass):
        value = (f"{m2:.4g} +- {main.std[0]:.3g} kg ({100 * rel:.0f} % std, more than "
                 f"{100 * cfg.max_relative_std_mass:.0f} %)" if rel < 1.0
                 else "its standard deviation exceeds the value itself")
        raise InsufficientDataError(
            f"the sprung mass cannot be resolved: {value}. "
            + _resolution_advice(dm, duration, rel, cfg, diagnose_hint))
    if rel > cfg.target_relative_std_mass:
        warnings.append(
            f"the sprung mass is uncertain by {100 * rel:.1f} % (std). "
            + _resolution_advice(dm, duration, rel, cfg, diagnose_hint))
    warnings += main.notes

    # time route
    routes = {"frequency": _route_result(main)}
    agreement: dict[str, float] = {}
    if cfg.time_route:
        step(0.65, "time route")
        fs_out = min(fs_min, max(2.6 * band[1] * 1.3, 10.0))
        pieces = []
        for s, (r, blk, (nx, ny)) in enumerate(zip(recs, blocks, noise_total, strict=True)):
            for i0, i1 in r.piece_list():
                p = prepare_time_piece(
                    np.asarray(r.wheel_accel_mps2)[i0:i1], np.asarray(r.body_accel_mps2)[i0:i1],
                    r.sample_rate_hz, band, session=s, noise_x=nx, noise_y=ny,
                    added_mass_kg=masses[s], block_edges_s=blk.block_edges_s,
                    start_s=i0 / r.sample_rate_hz, output_rate_hz=fs_out)
                if p is not None:
                    pieces.append(p)
        if pieces:
            tr = time_route(pieces, main.theta, include_k3=keep_k3)
            routes["time"] = _route_result(tr)
            agreement = route_agreement(main, tr)
            bad = [n for n, z in agreement.items() if z > 3.0]
            if bad:
                warnings.append(
                    "the frequency and time routes disagree beyond their uncertainties on "
                    + ", ".join(f"{n} ({agreement[n]:.1f} std)" for n in bad)
                    + ": the linear model may not describe this suspension (friction, "
                    "progressive spring) or the noise is not white; see `fielddiag diagnose`")
            misfit = tr.cost / max(tr.n_residuals, 1)
            unexplained_share = (misfit - 1.0) / max(
                prewhitened_signal_power(tr.theta, pieces), 1e-300)
            if misfit > LINEAR_MISFIT_WARN and unexplained_share > LINEAR_EXCESS_WARN:
                warnings.append(
                    f"the linear model leaves {misfit:.1f} times the sensor noise unexplained "
                    "in the time domain (about 1 for a linear suspension): this one probably "
                    "is not linear (dry friction, a progressive spring, a bump stop, "
                    "asymmetric damping...), so these values may be off by more than their "
                    "std; `fielddiag diagnose` finds the missing physics and refits them")
            warnings += tr.notes

    # display data: transmissibility, restoring force, loops
    step(0.8, "transmissibility, restoring force and loops")
    theta = main.theta
    trans = []
    # One frequency grid for every drive (the first drive's plot lines): drives sampled at
    # slightly different rates have Welch lines at slightly different frequencies.
    grid = totals[0].freq_hz[_plot_lines(totals[0].freq_hz, band, cfg.max_plot_lines)]
    grid = grid[grid <= min(sp.freq_hz[-1] for sp in totals)]
    for r, sp, nz, dmass in zip(recs, totals, noises, masses, strict=True):
        f = grid
        hv = hv_transmissibility(sp, nz.wheel_psd_per_hz, nz.body_psd_per_hz)
        coh = sp.coherence
        inb = (sp.freq_hz >= band[0]) & (sp.freq_hz <= band[1])
        peaks = resonance_peaks(sp.freq_hz, hv, band)

        def on_grid(values: np.ndarray, sp: CrossSpectra = sp) -> np.ndarray:
            return spectrum_on_grid(sp.freq_hz, values, grid)

        trans.append(TransmissibilityResult(
            label=r.label, added_mass_kg=dmass, freq_hz=[float(v) for v in f],
            h1=ComplexSeries.of(on_grid(sp.h1)), h2=ComplexSeries.of(on_grid(sp.h2)),
            hv=ComplexSeries.of(on_grid(hv)), coherence=[float(v) for v in on_grid(coh)],
            model=ComplexSeries.of(model_transmissibility(theta, f, dmass)),
            peaks=[Peak(fp, mp) for fp, mp in peaks],
            mean_coherence_in_band=float(np.mean(coh[inb])), n_averages=sp.n_averages,
            segment_s=sp.segment_s, noise=_noise_result(nz, sp.sample_rate_hz)))
    fn = routes["frequency"].body_natural_frequency_hz.value
    freqs = cfg.hysteresis_freqs_hz or tuple(
        x * fn for x in (0.7, 1.0, 2.0, 4.0) if band[0] <= x * fn <= band[1])
    surfaces, loops = [], []
    for r, sp, nz, dmass in zip(recs, totals, noises, masses, strict=True):
        if not cfg.display:
            break
        tb = travel_band(sp, nz.wheel_psd_per_hz, nz.body_psd_per_hz, band)
        motion = suspension_motion(np.asarray(r.wheel_accel_mps2)[: r.n],
                                   np.asarray(r.body_accel_mps2)[: r.n], r.sample_rate_hz, tb)
        ncov = motion_noise_covariance(tb, nz.wheel_psd_per_hz, nz.body_psd_per_hz)
        mass = theta[0] + dmass
        k3pm = theta[3] / mass
        surfaces.append(restoring_force_surface(motion, label=r.label, noise_cov=ncov,
                                                coupling_per_mass=k3pm, mass_kg=mass))
        loops += hysteresis_loops(motion, freqs, label=r.label, coupling_per_mass=k3pm,
                                  mass_kg=mass)

    fr = routes["frequency"]
    coupling = fr.coupling_stiffness_n_per_m if keep_k3 else Estimate(0.0, k3_std)
    coherence = {t.label: t.mean_coherence_in_band for t in trans}
    coherence["min_in_band"] = float(min(
        np.min(sp.coherence[(sp.freq_hz >= band[0]) & (sp.freq_hz <= band[1])]) for sp in totals))
    from fielddiag import __version__

    step(1.0, "done")
    return IdentificationResult(
        sprung_mass_kg=fr.sprung_mass_kg,
        suspension_stiffness_n_per_m=fr.suspension_stiffness_n_per_m,
        suspension_damping_ns_per_m=fr.suspension_damping_ns_per_m,
        coupling_stiffness_n_per_m=coupling,
        body_natural_frequency_hz=fr.body_natural_frequency_hz,
        damping_ratio=fr.damping_ratio,
        added_mass_kg=dm,
        band_hz=Band(band[0], band[1], band_src, band_note),
        coherence=coherence,
        k3_included=keep_k3,
        k3_test=k3_test,
        routes=routes,
        route_agreement=agreement,
        transmissibility=trans,
        restoring_force=surfaces,
        hysteresis=loops,
        warnings=warnings,
        sessions=[SessionSummary(r.label, r.path, r.duration_s, r.sample_rate_hz, m)
                  for r, m in zip(recs, masses, strict=True)],
        method=METHOD,
        software_version=__version__,
    )


# ---------------------------------------------------------------------------------------
# Sessions
# ---------------------------------------------------------------------------------------


def read_recording(path: str | os.PathLike, label: str = "") -> Recording:
    """Read the wheel and body channels (by role) of a session, in m/s^2.

    :func:`fielddiag.drive.read_corner_drive` for identification: gaps are allowed (the
    analysis works on the contiguous pieces).

    Parameters
    ----------
    path : str or PathLike
        The session file.
    label : str
        ``before`` or ``after``, for the messages and the result.

    Returns
    -------
    Recording

    Raises
    ------
    ChannelNotFoundError
        The session has no wheel or no body channel (or several); the message names it
        and says what to record.
    SessionError
        The time stamps are too irregular to analyse as a uniformly sampled record.
    """
    return read_corner_drive(path, label=label, purpose="identify")


def identify_sessions(
    before_path: str | os.PathLike,
    after_path: str | os.PathLike,
    *,
    added_mass_kg: float | None = None,
    band_hz: tuple[float, float] | None = None,
    config: IdentifyConfig | None = None,
    progress: Callable[[float, str], None] | None = None,
) -> IdentificationResult:
    """:func:`identify_recordings` on two session files (channels found by role).

    The two files are first checked as a pair (:func:`fielddiag.pairs.check_pair`): the same
    file twice, swapped drives or different vehicles are refused, doubtful pairs warned.

    Parameters
    ----------
    before_path, after_path : str or PathLike
        Sessions without and with the added mass on the body.
    added_mass_kg : float or None
        Mass added for the second drive [kg]; None: the difference of the sessions' own
        ``added_mass_kg`` metadata.
    band_hz : (float, float) or None
        Analysis band [Hz]; None chooses it from the coherence.
    config : IdentifyConfig or None
        Options of the identification (None: defaults).
    progress : callable or None
        ``progress(fraction, message)`` as the work proceeds.

    Returns
    -------
    IdentificationResult
        Sprung mass [kg], stiffness [N/m], damping [N s/m] (and coupling [N/m]) with their
        standard deviations, and the pair's warnings.

    Raises
    ------
    ChannelNotFoundError, SessionError
        A session lacks its wheel or body channel, or cannot be read as a uniform record.
    PairError
        The two files are not a before/after pair of one vehicle.
    InsufficientDataError
        The drives are too short or too poorly excited.
    """
    from fielddiag.pairs import check_pair_files

    before = read_recording(before_path, "before")  # a missing channel is said first
    after = read_recording(after_path, "after")
    pair = check_pair_files(before_path, after_path, added_mass_kg)
    result = identify_recordings(before, after, pair.added_mass_kg, band_hz=band_hz,
                                 config=config, progress=progress)
    result.warnings = list(dict.fromkeys([*pair.warnings, *result.warnings]))
    return result
