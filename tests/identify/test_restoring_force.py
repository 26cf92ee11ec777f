"""fielddiag.identify.restoring_force: noise covariance, travel band, hysteresis loops.

* The noise covariance of [a2, r, rdot, x2] is checked against its closed form (which
  channel enters which entry, the 1/w, 1/w^2 weights, the zero cross terms of a signal and
  its quadrature) and against the sample covariance of white noise run through
  :func:`suspension_motion`.
* A linear damper driven at r = X sin(w t) has the elliptic loop whose area (energy per
  cycle per unit mass) is pi c w X^2 against r and pi k w X^2 against rdot.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import integrate

from fielddiag.dsp import CrossSpectra, band_window
from fielddiag.identify.restoring_force import (
    TAPER,
    SuspensionMotion,
    hysteresis_loops,
    motion_noise_covariance,
    suspension_motion,
    travel_band,
)

BAND = (1.0, 8.0)


def _integral(weight) -> float:
    lo, hi = BAND[0] * (1 - TAPER), BAND[1] * (1 + TAPER)
    pts = [BAND[0], BAND[1]]
    return integrate.quad(lambda f: band_window(np.array([f]), BAND, TAPER)[0] ** 2
                          * weight(2 * np.pi * f), lo, hi, points=pts, limit=200)[0]


def test_noise_covariance_closed_form():
    """a2 = W n2, r = -W (n2 - n1)/w^2, rdot = W (n2 - n1)/(j w), x2 = -W n2/w^2."""
    nx, ny = 3e-4, 1e-4
    cov = motion_noise_covariance(BAND, nx, ny)
    i0 = _integral(lambda w: 1.0)
    i2 = _integral(lambda w: w**-2)
    i4 = _integral(lambda w: w**-4)
    expected = np.array([
        [ny * i0, -ny * i2, 0.0, -ny * i2],
        [-ny * i2, (nx + ny) * i4, 0.0, ny * i4],
        [0.0, 0.0, (nx + ny) * i2, 0.0],
        [-ny * i2, ny * i4, 0.0, ny * i4],
    ])
    # the trapezoid on 20 000 points is exact to ~1e-7 relative on these smooth integrands
    scale = np.sqrt(np.outer(np.diag(expected), np.diag(expected)))
    np.testing.assert_allclose(cov / scale, expected / scale, atol=1e-6)
    np.testing.assert_allclose(cov, cov.T)
    assert np.all(np.linalg.eigvalsh(cov) >= -1e-12 * cov.max())
    # linear in the densities
    np.testing.assert_allclose(motion_noise_covariance(BAND, 2 * nx, 2 * ny), 2 * cov)


def test_noise_covariance_matches_white_noise_through_suspension_motion():
    """Pure sensor noise in both channels: the sample variances of a2, r, rdot after
    suspension_motion equal the diagonal of the predicted covariance. r is narrow-band
    (1/w^4 weights the ~1 Hz edge): ~2 x 1.3 Hz x 600 s = 1600 dof, a 4 % sd."""
    fs, seconds = 50.0, 600.0
    sx, sy = 0.03, 0.02
    nx, ny = 2 * sx**2 / fs, 2 * sy**2 / fs
    rng = np.random.default_rng(1)
    n = int(fs * seconds)
    mot = suspension_motion(sx * rng.standard_normal(n), sy * rng.standard_normal(n), fs, BAND)
    cov = motion_noise_covariance(BAND, nx, ny)
    assert np.var(mot.body_acc_mps2) == pytest.approx(cov[0, 0], rel=0.06)
    assert np.var(mot.r_m) == pytest.approx(cov[1, 1], rel=0.15)
    assert np.var(mot.rdot_mps) == pytest.approx(cov[2, 2], rel=0.1)
    assert np.var(mot.body_disp_m) == pytest.approx(cov[3, 3], rel=0.15)


def _travel_spectra(g_rr: np.ndarray, df: float = 0.1) -> CrossSpectra:
    f = np.arange(g_rr.size) * df
    zero = np.zeros_like(f)
    # gxx = gxy = 0: |A2 - A1|^2 = gyy
    return CrossSpectra(f, zero, g_rr, zero.astype(complex), 100, 100.0, 10.0)


def test_travel_band_raises_the_low_edge_to_the_snr():
    """Travel 100 N above 2 Hz, 1 N below (N = Nx + Ny), peak at 5 Hz; smoothed over 5
    lines the SNR of 10 is first reached 2 lines (0.2 Hz) below the step: 1.8 Hz."""
    f = np.arange(400) * 0.1
    noise = 1e-6
    g = np.where(f >= 2.0 - 1e-9, 100.0, 1.0) * noise
    g[50] *= 1.5  # the peak
    sp = _travel_spectra(g)
    lo, hi = travel_band(sp, 0.4 * noise, 0.6 * noise, (0.5, 20.0))
    assert lo == pytest.approx(1.8)
    assert hi == 20.0
    # never above half the upper edge
    assert travel_band(sp, 0.4 * noise, 0.6 * noise, (0.5, 3.0)) == (pytest.approx(1.5), 3.0)
    # nothing above the noise: the band is left as it was
    flat = _travel_spectra(np.full(400, noise))
    assert travel_band(flat, 0.5 * noise, 0.5 * noise, (0.5, 20.0)) == (0.5, 20.0)


def _motion(fs: float, seconds: float, comps: list[tuple[float, float]], k: float, c: float,
            x2_amp: float = 0.0) -> SuspensionMotion:
    t = np.arange(int(fs * seconds)) / fs
    r = np.zeros_like(t)
    rd = np.zeros_like(t)
    for amp, f0 in comps:
        w = 2 * np.pi * f0
        r += amp * np.sin(w * t)
        rd += amp * w * np.cos(w * t)
    x2 = x2_amp * np.sin(2 * np.pi * comps[0][1] * t + 0.7)
    # linear suspension per unit mass: -a2 = k r + c rdot (+ k3 x2 when coupled)
    return SuspensionMotion(fs, (0.3, 10.0), -(k * r + c * rd), r, rd, x2)


def _area(u: list[float], v: list[float]) -> float:
    u, v = np.asarray(u), np.asarray(v)
    return 0.5 * abs(np.sum(u * np.roll(v, -1) - np.roll(u, -1) * v))


def test_hysteresis_loop_area_is_the_damper_energy_per_cycle():
    """Two tones (1 Hz, 4 Hz) in one record; each loop holds 4 cycles, so its area is
    4 pi c w X^2 (force against r) and 4 pi k w X^2 (force against rdot). The loop is a
    polygon of N points a cycle equally spaced in phase, whose area is that of the ellipse
    times sin(2 pi/N)/(2 pi/N) (N = 50 at 1 Hz, 25 at 4 Hz: 0.3 %, 1 %). The band-pass
    passes each tone with a gain within 0.2 % of 1 and the other tone leaks < 0.1 %:
    0.5 % tolerance."""
    k, c = 400.0, 6.0  # per unit mass [1/s^2], [1/s]
    comps = [(0.02, 1.0), (0.004, 4.0)]
    mot = _motion(100.0, 40.0, comps, k, c)
    loops = hysteresis_loops(mot, [1.0, 4.0, 60.0], label="before", mass_kg=350.0)
    assert [lp.freq_hz for lp in loops] == [1.0, 4.0]  # 60 Hz is above 0.45 fs: skipped
    for lp, (amp, f0) in zip(loops, comps, strict=True):
        w = 2 * np.pi * f0
        assert lp.label == "before" and lp.mass_kg == 350.0
        assert lp.band_hz == [pytest.approx(0.85 * f0), pytest.approx(1.15 * f0)]
        assert max(np.abs(lp.r_m)) == pytest.approx(amp, rel=0.01)
        n_cycle = len(lp.r_m) / 4
        assert n_cycle == pytest.approx(100.0 / f0 / math.ceil(4 * 100.0 / f0 / 300))
        poly = math.sin(2 * math.pi / n_cycle) / (2 * math.pi / n_cycle)
        assert _area(lp.r_m, lp.force_per_mass_mps2) == pytest.approx(
            4 * math.pi * c * w * amp**2 * poly, rel=0.005)
        assert _area(lp.rdot_mps, lp.force_per_mass_mps2) == pytest.approx(
            4 * math.pi * k * w * amp**2 * poly, rel=0.005)
        assert len(lp.r_m) <= 300  # max_points


def test_hysteresis_loop_of_a_pure_spring_has_no_area_and_coupling_is_removed():
    """c = 0: force against r is a line (area 0). A body displacement term k3 x2 in the
    acceleration is removed exactly when coupling_per_mass = k3."""
    k, k3 = 400.0, 50.0
    mot = _motion(100.0, 30.0, [(0.02, 1.5)], k, 0.0, x2_amp=0.01)
    coupled = SuspensionMotion(mot.sample_rate_hz, mot.band_hz,
                               mot.body_acc_mps2 - k3 * mot.body_disp_m, mot.r_m,
                               mot.rdot_mps, mot.body_disp_m)
    (lp,) = hysteresis_loops(coupled, [1.5], label="after", coupling_per_mass=k3)
    full = 4 * math.pi * k * (2 * math.pi * 1.5) * 0.02**2  # the stiffness loop's area
    assert _area(lp.r_m, lp.force_per_mass_mps2) < 1e-3 * full
    assert _area(lp.rdot_mps, lp.force_per_mass_mps2) == pytest.approx(full, rel=0.01)
    # force = k r on the loop
    np.testing.assert_allclose(lp.force_per_mass_mps2, k * np.asarray(lp.r_m),
                               atol=2e-3 * k * 0.02)


def test_hysteresis_window_is_where_the_travel_is_largest():
    """Amplitude 0.01 m for the first half, 0.03 m for the second: the loop is cut from
    the second half (the band-pass rings ~2 % over at the amplitude step: 5 %)."""
    fs = 100.0
    t = np.arange(int(fs * 40)) / fs
    amp = np.where(t < 20, 0.01, 0.03)
    w = 2 * np.pi * 2.0
    r = amp * np.sin(w * t)
    rd = amp * w * np.cos(w * t)
    mot = SuspensionMotion(fs, (0.3, 10.0), -(300 * r + 5 * rd), r, rd, np.zeros_like(t))
    (lp,) = hysteresis_loops(mot, [2.0], label="before")
    assert max(np.abs(lp.r_m)) == pytest.approx(0.03, rel=0.05)
