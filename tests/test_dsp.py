"""fielddiag.dsp: offsets, zero-phase filters, integration, block spectra, noise floors."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from fielddiag import dsp

FS = 200.0


def _multisine(t: np.ndarray, comps: list[tuple[float, float, float]]):
    """Displacement, velocity, acceleration of sum(A sin(2 pi f t + phi))."""
    x = np.zeros_like(t)
    v = np.zeros_like(t)
    a = np.zeros_like(t)
    for amp, f, ph in comps:
        w = 2 * np.pi * f
        x += amp * np.sin(w * t + ph)
        v += amp * w * np.cos(w * t + ph)
        a -= amp * w * w * np.sin(w * t + ph)
    return x, v, a


COMPS = [(0.02, 0.9, 0.3), (0.005, 2.7, 1.0), (0.0004, 11.0, 2.0)]


def test_remove_offset_and_drift_takes_out_gravity_bias_and_drift():
    t = np.arange(0, 60, 1 / FS)
    _, _, a = _multisine(t, COMPS)
    reading = a + dsp.GRAVITY_MPS2 + 0.3 + 0.002 * t
    clean = dsp.remove_offset_and_drift(reading)
    assert abs(clean.mean()) < 1e-9
    assert abs(np.polyfit(t, clean, 1)[0]) < 1e-6
    # the dynamic part survives (the fitted line of a zero-mean multisine is tiny)
    assert np.std(clean - a) < 0.01 * np.std(a)


def test_zero_phase_filter_has_no_delay_in_its_passband():
    t = np.arange(0, 30, 1 / FS)
    x = np.sin(2 * np.pi * 3.0 * t)
    y = dsp.zero_phase_filter(x, FS, low_hz=0.5, high_hz=20.0)
    mid = slice(len(t) // 4, 3 * len(t) // 4)
    # amplitude within 1 % and no shift (a 1-sample lag at 3 Hz would be a 9 % error)
    assert np.max(np.abs(y[mid] - x[mid])) < 0.01
    with pytest.raises(ValueError):
        dsp.zero_phase_filter(x, FS, low_hz=150.0)


@pytest.mark.parametrize("method", ["frequency", "time"])
def test_integration_recovers_velocity_and_displacement_in_band(method):
    t = np.arange(0, 120, 1 / FS)
    x, v, a = _multisine(t, COMPS)
    # gravity, bias, drift and an out-of-band slow component (0.02 Hz) are removed
    slow = 0.5 * np.sin(2 * np.pi * 0.02 * t) * (2 * np.pi * 0.02) ** 2
    reading = a + slow + dsp.GRAVITY_MPS2 + 0.2 + 0.001 * t
    res = dsp.integrate_acceleration(reading, FS, (0.4, 20.0), method=method)
    assert res.band_hz == (0.4, 20.0)
    mid = slice(int(15 * FS), int(105 * FS))  # away from the record ends
    tol = 0.01 if method == "frequency" else 0.03
    assert np.std(res.displacement_m[mid] - x[mid]) < tol * np.std(x)
    assert np.std(res.velocity_mps[mid] - v[mid]) < tol * np.std(v)


def test_frequency_integration_resamples_to_output_rate():
    t = np.arange(0, 100, 1 / 1000.0)
    x, v, a = _multisine(t, COMPS)
    res = dsp.integrate_acceleration(a, 1000.0, (0.4, 20.0), output_rate_hz=100.0)
    assert res.sample_rate_hz == pytest.approx(100.0, rel=0.01)
    tt = res.time_s
    xt = np.interp(tt, t, x)
    mid = slice(int(10 * res.sample_rate_hz), int(90 * res.sample_rate_hz))
    assert np.std(res.displacement_m[mid] - xt[mid]) < 0.01 * np.std(x)


def test_integrate_rejects_band_above_nyquist():
    with pytest.raises(ValueError):
        dsp.integrate_acceleration(np.zeros(1000), 100.0, (1.0, 60.0))


def test_block_cross_spectra_equal_scipy_welch_and_jackknife_replicates(rng):
    n = int(200 * FS)
    x = rng.normal(size=n)
    y = signal.lfilter([0.5, 0.3], [1.0, -0.4], x) + 0.1 * rng.normal(size=n)
    bs = dsp.block_cross_spectra(x, y, FS, segment_s=4.0, n_blocks=8)
    tot = bs.total()
    f, pxx = signal.welch(x, FS, nperseg=800, detrend="linear")
    _, pyy = signal.welch(y, FS, nperseg=800, detrend="linear")
    _, pxy = signal.csd(x, y, FS, nperseg=800, detrend="linear")
    assert np.allclose(tot.freq_hz, f)
    assert np.allclose(tot.gxx, pxx, rtol=1e-10)
    assert np.allclose(tot.gyy, pyy, rtol=1e-10)
    assert np.allclose(tot.gxy, pxy, rtol=1e-10)
    assert tot.n_averages == bs.n_segments.sum() == (n - 800) // 400 + 1
    # leaving a block out = averaging the others
    lo = bs.leave_out(3)
    keep = [i for i in range(bs.n_blocks) if i != 3]
    assert np.allclose(lo.gxx, bs.sxx[keep].sum(0) / bs.n_segments[keep].sum())
    # the blocks tile the record in time
    assert bs.block_edges_s[0] == 0 and bs.block_edges_s[-1] == pytest.approx(n / FS)


def test_block_spectra_never_cross_a_gap(rng):
    x = rng.normal(size=10_000)
    bs = dsp.block_cross_spectra(x, x, 100.0, segment_s=10.0, n_blocks=4,
                                 pieces=[(0, 1500), (1500, 10_000)])
    # piece 1: segments at 0 and 500 (1000 long); piece 2: (8500 - 1000)//500 + 1 = 16;
    # one running over the gap would start at 1000 and is not there
    assert bs.n_segments.sum() == 2 + 16


def test_contiguous_pieces_splits_at_gaps():
    t = np.concatenate([np.arange(0, 10, 0.01), np.arange(12, 20, 0.01)])
    pieces = dsp.contiguous_pieces(t, t.size, 100.0)
    assert pieces == [(0, 1000), (1000, t.size)]
    assert dsp.contiguous_pieces(None, 50, 100.0) == [(0, 50)]


def _antialiased_signal_plus_noise(rng, fs, noise_std, n):
    """A broadband signal through a Butterworth at 0.4 fs, then white noise (like a DAQ)."""
    sos = signal.butter(8, 0.4 * fs, fs=fs, output="sos")
    sig = signal.sosfilt(sos, rng.normal(size=n) * 3.0)
    return sig + rng.normal(0, noise_std, n)


def test_plateau_noise_floor_finds_white_noise_above_anti_alias_filter(rng):
    fs = 500.0
    x = _antialiased_signal_plus_noise(rng, fs, 0.01, 300_000)
    f, p = dsp.welch_psd(x, fs, 4.0)
    nf = dsp.plateau_noise_floor(f, p, fs)
    true = 0.01**2 / (fs / 2)
    assert nf.found
    assert nf.psd_per_hz == pytest.approx(true, rel=0.15)
    assert nf.band_hz[0] >= 0.4 * fs / 2


def test_plateau_noise_floor_is_not_found_without_a_flat_top(rng):
    fs = 200.0
    # white only: flat everywhere -> not a floor below a signal
    f, p = dsp.welch_psd(rng.normal(size=100_000), fs, 4.0)
    assert not dsp.plateau_noise_floor(f, p, fs).found
    # a signal whose PSD still falls as 1/f^4 at Nyquist (1.8 dB over the top 10 %): no
    # flat top. (A 1/f^2 fall, 0.9 dB over the top 10 %, cannot be told from a floor by its
    # shape; the pipeline then relies on the coherence-based floor, the smaller of the two.)
    ff = np.fft.rfftfreq(200_000, 1 / fs)
    spec = (rng.normal(size=ff.size) + 1j * rng.normal(size=ff.size)) / np.maximum(ff, 0.5) ** 2
    x = np.fft.irfft(spec)
    f, p = dsp.welch_psd(x, fs, 4.0)
    nf = dsp.plateau_noise_floor(f, p, fs)
    assert not nf.found
    assert nf.psd_per_hz <= p[(f > 0.9 * fs / 2)].mean() * 1.5  # an upper bound from the top


def test_choose_integration_band_and_peaks():
    f = np.linspace(0, 50, 501)
    psd = 1e-4 + 1.0 / (1 + ((f - 5) / 2) ** 4)
    lo, hi = dsp.choose_integration_band(f, psd, 1e-4, snr_min=100.0, min_freq_hz=0.2)
    # psd >= 1e-2 (100 x noise) for |f - 5| <= 2 * 99**0.25 = 6.3
    assert lo == pytest.approx(0.2, abs=0.11)
    assert hi == pytest.approx(5 + 6.3, abs=0.3)
    mag = 1 / np.sqrt((1 - (f / 7.33) ** 2) ** 2 + (0.2 * f / 7.33) ** 2)
    pk = dsp.find_spectral_peaks(f, mag, max_peaks=1)
    # a resonance at 7.33 Hz with damping ratio 0.1: peak at 7.33 sqrt(1 - 2 * 0.1^2)
    assert pk[0][0] == pytest.approx(7.33 * np.sqrt(1 - 2 * 0.01), abs=0.02)


def test_spectrum_on_grid_is_exact_for_linear_spectra_and_nan_outside():
    f = np.linspace(0.0, 50.0, 401)  # 0.125 Hz lines
    g = np.array([-1.0, 0.0, 3.3, 17.06, 50.0, 50.1])
    real = 2.0 + 0.3 * f
    np.testing.assert_allclose(dsp.spectrum_on_grid(f, real, g)[1:5], 2.0 + 0.3 * g[1:5],
                               rtol=1e-12)
    comp = (1.0 - 0.1 * f) + 1j * (0.5 + 0.02 * f)
    out = dsp.spectrum_on_grid(f, comp, g)
    assert np.iscomplexobj(out) and not np.iscomplexobj(dsp.spectrum_on_grid(f, real, g))
    np.testing.assert_allclose(out[1:5], (1.0 - 0.1 * g[1:5]) + 1j * (0.5 + 0.02 * g[1:5]),
                               rtol=1e-12)
    # nothing is extrapolated
    assert np.isnan(out[0]) and np.isnan(out[-1])
    assert np.isnan(dsp.spectrum_on_grid(f, real, g)[[0, -1]]).all()


def test_spectrum_on_grid_between_two_sample_rates_within_the_interpolation_bound():
    """The transmissibility of a 1.3 Hz, 30 % damped body on the Welch lines of a 500 Hz
    drive, moved to those of a 500.001 Hz drive. Linear interpolation at a distance d from
    a line errs by at most d (h - d) / 2 max|T''| per part (h = 0.125 Hz): h^2/8 max|T''|
    half-way between lines, and here, where line k moves by only k x 2.5e-7 Hz, by far
    less."""
    def t_of(freq):
        s = 2j * np.pi * freq
        wn = 2 * np.pi * 1.3
        return (2 * 0.3 * wn * s + wn**2) / (s * s + 2 * 0.3 * wn * s + wn**2)

    f_a = np.fft.rfftfreq(4000, 1 / 500.0)  # 8 s segments at 500 Hz
    f_b = np.fft.rfftfreq(4000, 1 / 500.001)
    h = f_a[1] - f_a[0]
    fine = np.linspace(0, 250, 200001)
    d2max = np.abs(np.gradient(np.gradient(t_of(fine), fine), fine)).max()
    moved = dsp.spectrum_on_grid(f_a, t_of(f_a), f_b)
    ok = ~np.isnan(moved)
    assert ok.sum() == f_b.size - 1  # only the top line of b lies beyond a's last line
    d = f_b[ok] - f_a[ok]
    bound = d * (h - d) / 2 * d2max * np.sqrt(2)  # real and imaginary parts together
    assert np.all(np.abs(moved[ok] - t_of(f_b[ok])) <= bound + 1e-15)
    # half-way between lines the error is of the order of the bound h^2/8 max|T''|
    mid = f_a[:-1] + h / 2
    err_mid = np.abs(dsp.spectrum_on_grid(f_a, t_of(f_a), mid) - t_of(mid)).max()
    assert 0.25 * h**2 / 8 * d2max <= err_mid <= h**2 / 8 * d2max * np.sqrt(2)
    # on a spectrum sampled at the grid itself the result is the identity
    np.testing.assert_array_equal(dsp.spectrum_on_grid(f_a, t_of(f_a), f_a), t_of(f_a))
