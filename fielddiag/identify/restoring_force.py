"""Restoring force of the suspension from one drive: surface over (r, rdot), slopes, loops.

From the body equation ``M2 a2 = -K2 r - C2 rdot - K3 x2 + N(r, rdot)`` the restoring
force per unit sprung mass is ``f/M2 = -a2`` (``- (K3/M2) x2`` once K3 is known). Plotted
over suspension travel ``r = x2 - x1`` and rate ``rdot`` it is a plane for a linear
suspension (slope in r: stiffness, slope in rdot: damping, per unit mass) and bends or
steps where the suspension is not linear. One session gives it up to the mass; the
absolute force follows once M2 is identified.

The motion comes from integrating both accelerometers in the same band
(:func:`fielddiag.dsp.integrate_pair`); the band's lower edge is raised until the
suspension travel is clear of the sensor noise (integrated noise grows as 1/w^2). The
plane is fitted by bias-compensated least squares: the noise covariance of the
regressors, known from the noise floors and the integration filter, is removed from the
normal equations, so the slopes are not biased by noise in r and rdot.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from fielddiag.dsp import (
    CrossSpectra,
    band_window,
    choose_integration_band,
    integrate_pair,
    zero_phase_filter,
)
from fielddiag.identify.results import Estimate, HysteresisLoop, RestoringForceSurface

TAPER = 0.3


@dataclass
class SuspensionMotion:
    """Band-limited body acceleration, suspension travel and rate, and body displacement.

    Parameters
    ----------
    sample_rate_hz : float
        Sample rate of the arrays [Hz].
    band_hz : (float, float)
        Integration band [Hz].
    body_acc_mps2 : ndarray
        Body acceleration a2 [m/s^2] (gravity, bias and drift removed).
    r_m : ndarray
        Suspension extension r = x2 - x1 [m], positive in rebound.
    rdot_mps : ndarray
        Its rate [m/s].
    body_disp_m : ndarray
        Body displacement x2 [m].
    """

    sample_rate_hz: float
    band_hz: tuple[float, float]
    body_acc_mps2: np.ndarray
    r_m: np.ndarray
    rdot_mps: np.ndarray
    body_disp_m: np.ndarray

    @property
    def n(self) -> int:
        """Number of samples."""
        return int(self.r_m.size)


def suspension_motion(wheel_mps2: np.ndarray, body_mps2: np.ndarray, sample_rate_hz: float,
                      band_hz: tuple[float, float], *, output_rate_hz: float | None = None
                      ) -> SuspensionMotion:
    """Integrate both channels in ``band_hz`` and form r, rdot (ends trimmed by 3 periods).

    Parameters
    ----------
    wheel_mps2, body_mps2 : ndarray
        Accelerometer readings (g, bias, drift are removed).
    sample_rate_hz : float
        Sample rate [Hz].
    band_hz : (float, float)
        Integration band [Hz].
    output_rate_hz : float or None
        Resample to about this rate (default: 6 x the upper band edge with its taper, at
        most the input rate).

    Returns
    -------
    SuspensionMotion
        Band-limited body acceleration [m/s^2], extension r = x2 - x1 [m] (positive in
        rebound), its rate [m/s] and body displacement [m].
    """
    lo, hi = band_hz
    if output_rate_hz is None:
        output_rate_hz = min(sample_rate_hz, max(6.0 * hi * (1 + TAPER), 20.0))
    wm, bm = integrate_pair(wheel_mps2, body_mps2, sample_rate_hz, band_hz,
                            output_rate_hz=output_rate_hz, taper=TAPER)
    fs = wm.sample_rate_hz
    trim = min(int(math.ceil(3.0 / lo * fs)), wm.acceleration_mps2.size // 4)
    sl = slice(trim, wm.acceleration_mps2.size - trim)
    return SuspensionMotion(
        fs, (float(lo), float(hi)), bm.acceleration_mps2[sl],
        (bm.displacement_m - wm.displacement_m)[sl], (bm.velocity_mps - wm.velocity_mps)[sl],
        bm.displacement_m[sl])


def motion_noise_covariance(band_hz: tuple[float, float], noise_x: float, noise_y: float,
                            *, n_grid: int = 20000) -> np.ndarray:
    """Per-sample noise covariance of [a2, r, rdot, x2] from white sensor noise.

    ``noise_x``, ``noise_y``: one-sided densities of the wheel and body noise
    [(m/s^2)^2/Hz]. Each quantity is a filter (band window W, ``1/(jw)``, ``-1/w^2``) of
    ``n2`` or ``n2 - n1``; the covariance is ``int Re(g_i conj(g_j)) N df``.

    Parameters
    ----------
    band_hz : (float, float)
        Integration band [Hz] (tapered as in :func:`suspension_motion`).
    noise_x, noise_y : float
        Wheel and body noise densities [(m/s^2)^2/Hz].
    n_grid : int
        Frequency points of the integral.

    Returns
    -------
    numpy.ndarray
        ``(4, 4)`` covariance in the units of [m/s^2, m, m/s, m].
    """
    lo, hi = band_hz
    f = np.linspace(lo * (1 - TAPER), hi * (1 + TAPER), n_grid)
    f = f[f > 0]
    w = 2 * np.pi * f
    win = band_window(f, band_hz, TAPER)
    g = [win, -win / w**2, win / (1j * w), -win / w**2]
    c = [(0.0, 1.0), (-1.0, 1.0), (-1.0, 1.0), (0.0, 1.0)]
    cov = np.zeros((4, 4))
    for i in range(4):
        for j in range(i, 4):
            dens = c[i][0] * c[j][0] * noise_x + c[i][1] * c[j][1] * noise_y
            cov[i, j] = cov[j, i] = float(np.trapezoid(np.real(g[i] * np.conj(g[j])) * dens, f))
    return cov


def travel_band(spectra: CrossSpectra, noise_x: float, noise_y: float,
                band_hz: tuple[float, float], *, snr_min: float = 10.0) -> tuple[float, float]:
    """Raise the lower edge of ``band_hz`` until the suspension travel is ``snr_min`` above
    noise (``|A2 - A1|^2`` against ``Nx + Ny``, smoothed over lines).

    Parameters
    ----------
    spectra : CrossSpectra
        Wheel (x) and body (y) acceleration spectra.
    noise_x, noise_y : float
        Wheel and body noise densities [(m/s^2)^2/Hz].
    band_hz : (float, float)
        The analysis band [Hz].
    snr_min : float
        Power ratio of travel over noise required at the lower edge.

    Returns
    -------
    (float, float)
        ``(low_hz, band_hz[1])`` with ``low_hz`` at most half the upper edge; ``band_hz``
        unchanged when no line qualifies.
    """
    g_rr = np.maximum(spectra.gxx + spectra.gyy - 2 * spectra.gxy.real, 0.0)
    try:
        lo, _ = choose_integration_band(spectra.freq_hz, g_rr, noise_x + noise_y,
                                        snr_min=snr_min, min_freq_hz=band_hz[0],
                                        max_freq_hz=band_hz[1])
    except ValueError:
        return band_hz
    lo = min(max(lo, band_hz[0]), 0.5 * band_hz[1])
    return float(lo), float(band_hz[1])


def fit_restoring_force(motion: SuspensionMotion, noise_cov: np.ndarray | None = None, *,
                        include_k3: bool = False, n_blocks: int = 10
                        ) -> tuple[np.ndarray, np.ndarray]:
    """Plane ``-a2 = k r + c rdot (+ k3 x2)`` per unit mass, noise-compensated.

    Parameters
    ----------
    motion : SuspensionMotion
    noise_cov : ndarray (4, 4) or None
        From :func:`motion_noise_covariance`; None fits ordinary least squares.
    include_k3 : bool
        Include the body displacement term.
    n_blocks : int
        Time blocks for the jackknife standard deviation.

    Returns
    -------
    (values, stds) : ndarray
        [k/M2 (1/s^2), c/M2 (1/s), k3/M2 (1/s^2)] and their jackknife standard deviations.
    """
    cols = [1, 2, 3] if include_k3 else [1, 2]
    z = np.column_stack([motion.body_acc_mps2, motion.r_m, motion.rdot_mps, motion.body_disp_m])
    n = z.shape[0]
    edges = np.linspace(0, n, n_blocks + 1).astype(int)
    moments = np.array([z[a:b].T @ z[a:b] for a, b in zip(edges[:-1], edges[1:], strict=True)])
    counts = np.diff(edges)
    nc = np.zeros((4, 4)) if noise_cov is None else noise_cov

    def solve(m: np.ndarray, cnt: int) -> np.ndarray:
        r = m - cnt * nc
        a = r[np.ix_(cols, cols)]
        b = -r[cols, 0]
        sol = np.linalg.solve(a, b)
        out = np.zeros(3)
        out[: len(cols)] = sol
        return out

    full = solve(moments.sum(0), n)
    reps = np.array([solve(moments.sum(0) - moments[i], n - counts[i]) for i in range(n_blocks)])
    var = (n_blocks - 1) / n_blocks * np.sum((reps - reps.mean(0)) ** 2, axis=0)
    return full, np.sqrt(var)


def restoring_force_surface(
    motion: SuspensionMotion,
    *,
    label: str,
    noise_cov: np.ndarray | None = None,
    coupling_per_mass: float = 0.0,
    mass_kg: float | None = None,
    n_bins: int = 15,
    min_count: int = 10,
) -> RestoringForceSurface:
    """Mean restoring force per unit mass on an (r, rdot) grid, with the fitted slopes.

    Parameters
    ----------
    motion : SuspensionMotion
        r [m], rdot [m/s], body acceleration [m/s^2] and displacement [m] of one session.
    label : str
        Which session (``before``, ``after``).
    noise_cov : ndarray or None
        Noise covariance for the slope fit (:func:`motion_noise_covariance`).
    coupling_per_mass : float
        K3/(M2 + dM) [1/s^2], subtracted as ``- k3 x2`` from the force when known.
    mass_kg : float or None
        Body mass in this session (M2 + dM) to give absolute stiffness and damping.
    n_bins : int
        Bins per axis over the 1st-99th percentile of r and rdot.
    min_count : int
        Bins with fewer samples are left empty (None).

    Returns
    -------
    RestoringForceSurface
        Mean ``-a2 - k3 x2`` per bin [m/s^2 = N/kg], the plane's slopes per unit mass
        [1/s^2, 1/s] and, with ``mass_kg``, stiffness [N/m] and damping [N s/m].
    """
    force = -motion.body_acc_mps2 - coupling_per_mass * motion.body_disp_m
    r, rd = motion.r_m, motion.rdot_mps
    r_edges = np.linspace(*np.percentile(r, [1, 99]), n_bins + 1)
    v_edges = np.linspace(*np.percentile(rd, [1, 99]), n_bins + 1)
    ir = np.digitize(r, r_edges) - 1
    iv = np.digitize(rd, v_edges) - 1
    ok = (ir >= 0) & (ir < n_bins) & (iv >= 0) & (iv < n_bins)
    flat = ir[ok] * n_bins + iv[ok]
    counts = np.bincount(flat, minlength=n_bins * n_bins)
    sums = np.bincount(flat, weights=force[ok], minlength=n_bins * n_bins)
    mean = np.where(counts >= min_count, sums / np.maximum(counts, 1), np.nan)
    grid = [[None if not np.isfinite(v) else float(v) for v in row]
            for row in mean.reshape(n_bins, n_bins)]
    vals, stds = fit_restoring_force(motion, noise_cov)
    k = Estimate(float(vals[0]), float(stds[0]))
    c = Estimate(float(vals[1]), float(stds[1]))
    surf = RestoringForceSurface(
        label=label, band_hz=[motion.band_hz[0], motion.band_hz[1]],
        r_centers_m=[float(v) for v in 0.5 * (r_edges[1:] + r_edges[:-1])],
        rdot_centers_mps=[float(v) for v in 0.5 * (v_edges[1:] + v_edges[:-1])],
        force_per_mass_mps2=grid,
        counts=[[int(v) for v in row] for row in counts.reshape(n_bins, n_bins)],
        stiffness_per_mass=k, damping_per_mass=c)
    if mass_kg is not None:
        surf.mass_kg = float(mass_kg)
        surf.stiffness_n_per_m = Estimate(k.value * mass_kg, k.std * mass_kg)
        surf.damping_ns_per_m = Estimate(c.value * mass_kg, c.std * mass_kg)
    return surf


def hysteresis_loops(
    motion: SuspensionMotion,
    freqs_hz: Sequence[float],
    *,
    label: str,
    coupling_per_mass: float = 0.0,
    mass_kg: float | None = None,
    rel_bandwidth: float = 0.3,
    n_cycles: float = 4.0,
    max_points: int = 300,
) -> list[HysteresisLoop]:
    """Narrow-band loops of restoring force against r and rdot at each frequency.

    Each signal is band-passed (zero phase) to ``f (1 +- rel_bandwidth/2)`` and the
    stretch of ``n_cycles`` periods with the largest travel is kept. For a linear
    suspension, force against r is an ellipse whose area shows the damping, force against
    rdot one whose area shows the stiffness.

    Parameters
    ----------
    motion : SuspensionMotion
        One session's motion.
    freqs_hz : sequence of float
        Centre frequencies [Hz]; those whose band reaches 0 or 0.45 x the sample rate, or
        whose window does not fit the record, are skipped.
    label : str
        Which session (``before``, ``after``).
    coupling_per_mass : float
        K3/(M2 + dM) [1/s^2], subtracted as ``- k3 x2`` from the force.
    mass_kg : float or None
        Body mass in this session [kg], stored with each loop.
    rel_bandwidth : float
        Relative width of the band-pass.
    n_cycles : float
        Periods per loop.
    max_points : int
        Points per loop at most (decimated).

    Returns
    -------
    list of HysteresisLoop
        r [m], rdot [m/s] and force per unit mass [m/s^2] per loop.
    """
    fs = motion.sample_rate_hz
    force = -motion.body_acc_mps2 - coupling_per_mass * motion.body_disp_m
    out = []
    for f0 in freqs_hz:
        lo = f0 * (1 - rel_bandwidth / 2)
        hi = f0 * (1 + rel_bandwidth / 2)
        if lo <= 0 or hi >= 0.45 * fs:
            continue
        filt = [zero_phase_filter(s, fs, low_hz=lo, high_hz=hi, order=2)
                for s in (motion.r_m, motion.rdot_mps, force)]
        n_win = int(round(n_cycles / f0 * fs))
        if n_win < 8 or n_win >= motion.n:
            continue
        c = np.concatenate(([0.0], np.cumsum(filt[0] ** 2)))
        r2 = c[n_win:] - c[:-n_win]  # moving sum of r^2 over n_win samples
        # keep clear of the band-pass's edge transients: its envelope decays with a time
        # constant of 1/(pi bw), so 2/bw leaves exp(-2 pi) = 0.2 % (n_win alone left ~5 %)
        ring = int(math.ceil(2.0 / (hi - lo) * fs))
        margin = min(max(n_win, ring), r2.size // 4)
        i0 = margin + int(np.argmax(r2[margin:r2.size - margin])) if r2.size > 2 * margin else 0
        sl = slice(i0, i0 + n_win)
        step = max(1, -(-n_win // max_points))  # ceil: at most max_points points
        out.append(HysteresisLoop(
            label=label, freq_hz=float(f0), band_hz=[float(lo), float(hi)],
            r_m=[float(v) for v in filt[0][sl][::step]],
            rdot_mps=[float(v) for v in filt[1][sl][::step]],
            force_per_mass_mps2=[float(v) for v in filt[2][sl][::step]],
            mass_kg=None if mass_kg is None else float(mass_kg)))
    return out
