"""fielddiag.identify.transmissibility on signals through a known linear filter.

White noise x (the wheel) is passed through the bilinear discretisation of the body's
base-excitation transmissibility ``T(s) = (c s + k) / (m s^2 + c s + k)`` (3 Hz, 30 %
damping) to give y (the body); the analytic T is ``scipy.signal.freqz`` of that filter.
White sensor noise of known one-sided density ``2 sigma^2 / fs`` is added where a test
needs it.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import signal

from fielddiag.dsp import CrossSpectra, block_cross_spectra
from fielddiag.identify.transmissibility import (
    WELCH_EFFICIENCY,
    choose_band,
    coherence_noise_fit,
    debiased_coherence,
    hv_transmissibility,
    resonance_peaks,
)

FS = 100.0
FN, ZETA = 3.0, 0.3
W_N = 2 * np.pi * FN
B, A = signal.bilinear([2 * ZETA * W_N, W_N**2], [1.0, 2 * ZETA * W_N, W_N**2], FS)
BAND = (0.5, 20.0)
SEG = 8.0


def _drive(seed: int, seconds: float = 400.0, sx: float = 0.0, sy: float = 0.0):
    rng = np.random.default_rng(seed)
    n = int(seconds * FS)
    x = rng.standard_normal(n)
    y = signal.lfilter(B, A, x)
    xn = x + sx * rng.standard_normal(n)
    yn = y + sy * rng.standard_normal(n)
    sp = block_cross_spectra(xn, yn, FS, segment_s=SEG, n_blocks=4).total()
    _, h = signal.freqz(B, A, worN=sp.freq_hz, fs=FS)
    band = (sp.freq_hz >= BAND[0]) & (sp.freq_hz <= BAND[1])
    return sp, h, band


def _density(sigma: float) -> float:
    return 2 * sigma**2 / FS  # one-sided density of white noise of sd sigma


def test_noise_free_h1_is_the_filter_and_coherence_is_one():
    """Without noise the only error is Hann leakage across the resonance (half-power width
    2 zeta fn = 1.8 Hz over 0.125 Hz lines): well under 2 %, coherence above 0.99."""
    sp, h, band = _drive(1)
    err = np.abs(sp.h1[band] / h[band] - 1)
    assert np.median(err) < 2e-3
    assert err.max() < 0.02
    assert sp.coherence[band].min() > 0.99
    # with zero noise every estimator agrees: H-v with noise_x = 0 is H1 by definition
    np.testing.assert_array_equal(hv_transmissibility(sp, 0.0, 1.0), sp.h1)


def test_h1_error_matches_its_statistical_error():
    """Noise only on the body: H1 is unbiased with complex variance
    |H|^2 (1 - coh) / (coh n_eff) per line (Bendat & Piersol), n_eff = n / 1.06 for Hann
    windows with 50 % overlap. The mean normalised squared error over the 156 band lines
    is 1 (sd ~0.1 with adjacent lines correlated)."""
    sy = 0.3
    sp, h, band = _drive(2, sy=sy)
    gxx = _density(1.0)
    coh = np.abs(h) ** 2 * gxx / (np.abs(h) ** 2 * gxx + _density(sy))
    n_eff = sp.n_averages * WELCH_EFFICIENCY
    var = np.abs(h) ** 2 * (1 - coh) / (coh * n_eff)
    z = np.abs(sp.h1 - h) ** 2 / var
    assert z[band].mean() == pytest.approx(1.0, abs=0.3)
    assert np.max(z[band]) < 20  # exponential tail: P(z > 20) = 2e-9 per line


def test_hv_removes_the_input_noise_bias_of_h1():
    """Wheel noise sd 0.5 on a unit white input: H1 = H / (1 + Nx/Gxx) = 0.8 H; H-v with the
    true densities is unbiased. Compared on the lines where |H| > 0.3 (coherence > 0.6,
    0.5-8 Hz): per line the ratio is known to ~5 %, its median over ~60 correlated lines to
    ~1 %, and the sample variances of 40 000 samples differ from nominal by ~0.7 %; the
    real part of the complex ratio is used (the modulus of a noisy ratio is biased up)."""
    sx, sy = 0.5, 0.3
    sp, h, band = _drive(3, sx=sx, sy=sy)
    sel = band & (np.abs(h) > 0.3)
    ratio_h1 = np.median((sp.h1[sel] / h[sel]).real)
    assert ratio_h1 == pytest.approx(1 / (1 + sx**2), abs=0.025)
    hv = hv_transmissibility(sp, _density(sx), _density(sy))
    ratio_hv = hv[sel] / h[sel]
    assert np.median(ratio_hv.real) == pytest.approx(1.0, abs=0.025)
    assert abs(np.median(ratio_hv.imag)) < 0.025  # no phase bias either


def test_coherence_noise_fit_recovers_both_densities():
    """coh = (1 - Nx/Gxx)(1 - Ny/Gyy) over 156 lines of ~94 averages: each density is
    fixed to a few per cent; 15 % is more than 4 sigma of the fit here."""
    sx, sy = 0.5, 0.3
    sp, _, _ = _drive(4, sx=sx, sy=sy)
    nx, ny = coherence_noise_fit(sp, BAND)
    assert nx == pytest.approx(_density(sx), rel=0.15)
    assert ny == pytest.approx(_density(sy), rel=0.15)
    assert coherence_noise_fit(sp, (5.0, 5.5)) is None  # 5 lines < min_lines


def test_debiased_coherence_inverts_the_bias_formula_exactly():
    """coh_hat = c + (1 - c)^2 / n_eff is mapped back to c for every c in [0, 1]."""
    n_avg = 10
    n_eff = n_avg * WELCH_EFFICIENCY
    c = np.linspace(0.0, 1.0, 101)
    c_hat = c + (1 - c) ** 2 / n_eff
    f = np.arange(c.size, dtype=float)
    sp = CrossSpectra(f, np.ones_like(f), np.ones_like(f), np.sqrt(c_hat).astype(complex),
                      n_avg, FS, SEG)
    np.testing.assert_allclose(debiased_coherence(sp), c, atol=1e-9)


def test_debiasing_on_short_records():
    """True coherence 0.5 (y = 0.7 x + noise of variance 0.49) from 4 Welch segments: the
    raw estimate is biased up by ~(1 - c)^2 / n_eff = 0.066 (the first-order formula; the
    exact bias at n = 4 is a little larger); the debiased one is not. Mean over 400 lines
    of 10 records: sd ~0.017 / sqrt(10) = 0.005."""
    rng = np.random.default_rng(5)
    n_seg = 4
    n = int((n_seg + 1) * SEG / 2 * FS)
    raw, deb = [], []
    for _ in range(10):
        x = rng.standard_normal(n)
        y = 0.7 * x + 0.7 * rng.standard_normal(n)
        sp = block_cross_spectra(x, y, FS, segment_s=SEG, n_blocks=1).total()
        assert sp.n_averages == n_seg
        raw.append(sp.coherence[1:-1].mean())
        deb.append(debiased_coherence(sp)[1:-1].mean())
    first_order = 0.25 / (n_seg * WELCH_EFFICIENCY)
    assert first_order <= np.mean(raw) - 0.5 <= first_order + 0.035  # 0.074-0.088 measured
    assert np.mean(deb) == pytest.approx(0.5, abs=0.02)


def _flat_spectra(coh: np.ndarray, df: float = 0.1, n_avg: int = 1000) -> CrossSpectra:
    f = np.arange(coh.size) * df
    ones = np.ones_like(f)
    return CrossSpectra(f, ones, ones, np.sqrt(coh).astype(complex), n_avg, FS, SEG)


def _coh_runs(n: int, runs: list[tuple[float, float]], df: float = 0.1) -> np.ndarray:
    f = np.arange(n) * df
    c = np.full(n, 0.1)
    for lo, hi in runs:
        c[(f >= lo - 1e-9) & (f <= hi + 1e-9)] = 0.9
    return c


def test_choose_band_finds_the_coherent_run_to_the_line():
    """Steps 0.1 -> 0.9 smoothed over 5 lines: the first 0.9 line averages to 0.58 >= 0.5,
    the line before to 0.42: the band is exactly the coherent run."""
    sp = _flat_spectra(_coh_runs(400, [(3.0, 12.0)]))
    assert choose_band([sp]) == (pytest.approx(3.0), pytest.approx(12.0))
    # every session must be coherent: the intersection of [3, 12] and [5, 15]
    sp2 = _flat_spectra(_coh_runs(400, [(5.0, 15.0)]))
    assert choose_band([sp, sp2]) == (pytest.approx(5.0), pytest.approx(12.0))
    assert choose_band([sp], max_freq_hz=10.0) == (pytest.approx(3.0), pytest.approx(10.0))


def test_choose_band_prefers_the_run_holding_the_anchor():
    sp = _flat_spectra(_coh_runs(400, [(1.0, 3.0), (6.0, 15.0)]))
    assert choose_band([sp]) == (pytest.approx(6.0), pytest.approx(15.0))  # longest
    assert choose_band([sp], anchor_hz=2.0) == (pytest.approx(1.0), pytest.approx(3.0))
    with pytest.raises(ValueError, match="no band"):
        choose_band([_flat_spectra(np.full(400, 0.2))])


def test_resonance_peak_of_the_analytic_transmissibility():
    """|T| of base excitation peaks at r = sqrt(sqrt(1 + 8 zeta^2) - 1) / (2 zeta) with
    |T|^2 = (1 + (2 zeta r)^2) / ((1 - r^2)^2 + (2 zeta r)^2); on 0.05 Hz lines with the
    parabolic refinement the frequency is found to a fraction of a line."""
    f = np.arange(0.0, 20.0, 0.05)
    s = 2j * np.pi * f
    t = (2 * ZETA * W_N * s + W_N**2) / (s * s + 2 * ZETA * W_N * s + W_N**2)
    r = math.sqrt(math.sqrt(1 + 8 * ZETA**2) - 1) / (2 * ZETA)
    peak = math.sqrt((1 + (2 * ZETA * r) ** 2) / ((1 - r * r) ** 2 + (2 * ZETA * r) ** 2))
    peaks = resonance_peaks(f, t, (0.5, 15.0))
    assert len(peaks) == 1
    assert peaks[0][0] == pytest.approx(r * FN, abs=0.01)
    assert peaks[0][1] == pytest.approx(peak, rel=1e-3)
    # a second, sharper resonance near 11 Hz (a band-pass term of 5 % damping, peak 0.5,
    # < 0.005 below 2 Hz) is found too, where |T2| is largest on a 1e-4 Hz grid, and
    # leaves the body's peak where it was
    s11 = 2 * np.pi * 11.0

    def t2_of(freq):
        sf = 2j * np.pi * freq
        body = (2 * ZETA * W_N * sf + W_N**2) / (sf * sf + 2 * ZETA * W_N * sf + W_N**2)
        return body + 0.5 * (2 * 0.05 * s11 * sf) / (sf * sf + 2 * 0.05 * s11 * sf + s11**2)

    fine = np.arange(9.0, 13.0, 1e-4)
    f_true = fine[np.argmax(np.abs(t2_of(fine)))]
    found = sorted(resonance_peaks(f, t2_of(f), (0.5, 15.0)))
    assert len(found) == 2
    assert found[0][0] == pytest.approx(r * FN, abs=0.03)
    assert found[1][0] == pytest.approx(f_true, abs=0.01)
    assert found[1][1] == pytest.approx(np.abs(t2_of(f_true)), rel=0.01)
    assert resonance_peaks(f, t, (20.0, 30.0)) == []
