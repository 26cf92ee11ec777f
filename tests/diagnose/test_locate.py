"""fielddiag.diagnose.locate: where a residual lives in time, frequency and (r, rdot).

Expectations are constructed: a noise burst at a known time and level, a PSD bump between
known frequencies, a sine on a Welch line (Hann window: peak = power / (1.5 df)), and a
departure confined to a known corner of the (r, rdot) plane.
"""

from __future__ import annotations

import numpy as np
import pytest

from fielddiag.diagnose.locate import (
    departure_map,
    excess_band,
    residual_psd,
    residual_windows,
    rolling_rms,
)

FS = 100.0


def test_rolling_rms_of_a_constant_and_of_a_sine():
    x = np.full(1000, 3.0)
    rms = rolling_rms(x, FS, 1.0)
    assert np.allclose(rms[100:-100], 3.0, rtol=1e-12)
    t = np.arange(2000) / FS
    s = 2.0 * np.sin(2 * np.pi * 5.0 * t)  # 1 s window = 5 whole periods: rms = A/sqrt(2)
    assert np.allclose(rolling_rms(s, FS, 1.0)[100:-100], 2.0 / np.sqrt(2), rtol=1e-9)


def test_a_burst_is_found_at_its_time_with_its_rms_ratio():
    """Unit white noise for 60 s, sd 5 between 30 and 32 s.

    With a 1 s window a fraction p of which covers the burst, the mean square is
    25 p + (1 - p), above 4 (threshold 2 on the rms) for p > 1/8: the marked stretch is
    [29.625, 32.375] s, padded by half a window: [29.125, 32.875] s. Inside the burst the
    1 s rms is 5 (sd 5/sqrt(200) = 0.35 per window); the median rms is ~1.
    """
    rng = np.random.default_rng(1)
    t = np.arange(int(60 * FS)) / FS
    x = rng.standard_normal(t.size)
    burst = (t >= 30.0) & (t < 32.0)
    x[burst] *= 5.0
    wins = residual_windows(t, x, FS, window_s=1.0, threshold=2.0)
    assert len(wins) == 1
    w = wins[0]
    assert w.start_s == pytest.approx(29.125, abs=0.2)
    assert w.end_s == pytest.approx(32.875, abs=0.2)
    assert 4.5 <= w.rms_ratio <= 6.5


def test_windows_are_sorted_strongest_first_and_capped():
    rng = np.random.default_rng(2)
    t = np.arange(int(80 * FS)) / FS
    x = rng.standard_normal(t.size)
    for start, gain in ((10.0, 3.0), (30.0, 8.0), (50.0, 5.0)):
        x[(t >= start) & (t < start + 2)] *= gain
    wins = residual_windows(t, x, FS)
    assert [round(w.start_s) for w in wins] == [29, 49, 9]
    ratios = [w.rms_ratio for w in wins]
    assert ratios == sorted(ratios, reverse=True)
    assert ratios[0] == pytest.approx(8.0, rel=0.2)
    assert len(residual_windows(t, x, FS, max_windows=2)) == 2


def test_evenly_spread_residual_gives_no_window_unless_a_reference_says_so():
    rng = np.random.default_rng(3)
    t = np.arange(int(60 * FS)) / FS
    x = 3.0 * rng.standard_normal(t.size)
    assert residual_windows(t, x, FS) == []
    # against a noise-only reference 3x smaller, the whole record stands out, ratio ~3
    ref = rng.standard_normal(t.size)
    wins = residual_windows(t, x, FS, reference=ref)
    assert len(wins) == 1
    assert wins[0].start_s == pytest.approx(0.0)
    assert wins[0].end_s == pytest.approx(t[-1])
    assert 3.0 <= wins[0].rms_ratio <= 4.5  # max over 6000 windows of rms with sd 0.15
    assert residual_windows(t, np.zeros(t.size), FS) == []


def test_excess_band_of_a_flat_bump():
    """Excess 10 (units^2/Hz) uniform on 5..15 Hz over a floor of 1: the 10-90 % quantiles
    of its power are at 6 and 14 Hz (exactly on the 0.1 Hz lines)."""
    f = np.arange(0, 50.0001, 0.1)
    psd = np.ones_like(f)
    psd[(f >= 5 - 1e-9) & (f <= 15 + 1e-9)] += 10.0
    lo, hi = excess_band(f, psd, 1.0)
    assert lo == pytest.approx(6.0, abs=0.1)
    assert hi == pytest.approx(14.0, abs=0.1)
    lo, hi = excess_band(f, psd, 1.0, fraction=1.0)
    assert (lo, hi) == (pytest.approx(5.0, abs=1e-9), pytest.approx(15.0, abs=1e-9))
    # a second bump outside band_hz is ignored
    psd2 = psd.copy()
    psd2[(f >= 30) & (f <= 32)] += 100.0
    assert excess_band(f, psd2, 1.0, band_hz=(0.0, 20.0)) == (lo_hi := excess_band(f, psd, 1.0))
    assert lo_hi[0] == pytest.approx(6.0, abs=0.1)
    # an array floor works as a scalar one
    assert excess_band(f, psd, np.ones_like(f)) == lo_hi


def test_excess_band_none_when_below_the_floor():
    f = np.linspace(0, 50, 501)
    assert excess_band(f, np.full(f.size, 0.5), 1.0) is None


def test_residual_psd_parseval_and_a_sine_on_its_line():
    """Sine A = 0.3 at 12.5 Hz (a line of the 8 s Welch grid, df = 0.125 Hz) plus white
    noise sd 0.1 at 200 Hz.

    * Parseval: the PSD integrates to the variance A^2/2 + sigma^2 (Hann-windowed Welch is
      unbiased for power; 1 % sampling error with 14 segments of 1600 samples).
    * The Hann window spreads a line-centred sine over 1.5 df (its noise bandwidth): the
      peak is (A^2/2) / (1.5 df).
    * The floor is the one-sided white density 2 sigma^2 / fs.
    """
    fs, amp, sigma, f0 = 200.0, 0.3, 0.1, 12.5
    rng = np.random.default_rng(4)
    t = np.arange(int(60 * fs)) / fs
    x = amp * np.sin(2 * np.pi * f0 * t) + sigma * rng.standard_normal(t.size)
    f, p = residual_psd(x, fs, segment_s=8.0)
    df = f[1] - f[0]
    assert df == pytest.approx(0.125)
    assert np.sum(p) * df == pytest.approx(amp**2 / 2 + sigma**2, rel=0.03)
    k = int(np.argmax(p))
    assert f[k] == pytest.approx(f0)
    assert p[k] == pytest.approx(amp**2 / 2 / (1.5 * df) + 2 * sigma**2 / fs, rel=0.03)
    floor = np.median(p[(f > 30) & (f < 90)])
    # median of a chi^2 spectrum with ~2x14 dof is ~0.98 of its mean
    assert floor == pytest.approx(2 * sigma**2 / fs, rel=0.1)


def test_residual_psd_short_record_uses_the_whole_record():
    x = np.random.default_rng(5).standard_normal(100)
    f, p = residual_psd(x, FS, segment_s=8.0)
    assert f.size == 51  # nperseg = len(x) = 100 -> 51 one-sided lines


def _plane(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return rng.uniform(-1, 1, n), rng.uniform(-1, 1, n)


def test_departure_map_bins_a_constant_departure_in_one_corner():
    r, v = _plane(40000, 6)
    d = np.where((r > 0.5) & (v > 0.5), 5.0, 0.0)
    dmap = departure_map(r, v, d, bins=10)
    assert dmap.mean.shape == (10, 10) and dmap.count.shape == (10, 10)
    # the grid spans the 0.5-99.5 % quantiles of a uniform on [-1, 1]: +-0.99
    assert dmap.r_edges_m[0] == pytest.approx(-0.99, abs=0.01)
    assert dmap.rdot_edges_mps[-1] == pytest.approx(0.99, abs=0.01)
    # every sample inside the grid is counted once; ~1 % fall outside on either axis
    inside = ((r >= dmap.r_edges_m[0]) & (r <= dmap.r_edges_m[-1])
              & (v >= dmap.rdot_edges_mps[0]) & (v <= dmap.rdot_edges_mps[-1]))
    assert dmap.count.sum() == inside.sum()
    # bins wholly inside the corner have mean exactly 5, bins wholly outside exactly 0
    rc = 0.5 * (dmap.r_edges_m[1:] + dmap.r_edges_m[:-1])
    vc = 0.5 * (dmap.rdot_edges_mps[1:] + dmap.rdot_edges_mps[:-1])
    width = dmap.r_edges_m[1] - dmap.r_edges_m[0]
    full = (rc[:, None] - width / 2 > 0.5) & (vc[None, :] - width / 2 > 0.5)
    empty = (rc[:, None] + width / 2 < 0.5) | (vc[None, :] + width / 2 < 0.5)
    assert np.all(dmap.mean[full] == 5.0)
    assert np.all(dmap.mean[empty] == 0.0)
    # the region holding (nearly) all of the departure is the corner, to one bin
    reg = dmap.region(share=0.999)
    assert 0.5 - width <= reg["r_m"][0] <= 0.5
    assert reg["r_m"][1] == pytest.approx(dmap.r_edges_m[-1])
    assert 0.5 - width <= reg["rdot_mps"][0] <= 0.5
    assert reg["rdot_mps"][1] == pytest.approx(dmap.rdot_edges_mps[-1])


def test_region_favours_populated_bins_and_is_none_without_departure():
    r, v = _plane(20000, 7)
    dmap = departure_map(r, v, np.zeros(r.size), bins=8)
    assert dmap.region() is None
    # the departure lives in the band |r| < 0.2; the corner r > 0.6, rdot < -0.6 is empty
    # but for 5 samples with a huge departure: their bin has < min_count samples
    keep = ~((r > 0.6) & (v < -0.6))
    r2 = np.append(r[keep], np.full(5, 0.9))
    v2 = np.append(v[keep], np.full(5, -0.9))
    d2 = np.append(np.where(np.abs(r[keep]) < 0.2, 1.0, 0.0), np.full(5, 1e3))
    dmap2 = departure_map(r2, v2, d2, bins=8)
    assert dmap2.count[-1, 0] == 5
    reg = dmap2.region(share=0.999, min_count=20)
    w = dmap2.r_edges_m[1] - dmap2.r_edges_m[0]
    assert -0.2 - w <= reg["r_m"][0] <= -0.2 and 0.2 <= reg["r_m"][1] <= 0.2 + w
    assert reg["rdot_mps"] == [pytest.approx(dmap2.rdot_edges_mps[0]),
                               pytest.approx(dmap2.rdot_edges_mps[-1])]
    # counting sparse bins, the 5 outliers (weight 1e3 sqrt(5)) dominate the box
    reg_all = dmap2.region(share=0.5, min_count=1)
    assert reg_all["r_m"][1] == pytest.approx(dmap2.r_edges_m[-1])
    assert reg_all["rdot_mps"][0] == pytest.approx(dmap2.rdot_edges_mps[0])


def test_empty_bins_are_nan():
    r = np.concatenate([np.full(100, -1.0), np.full(100, 1.0)])
    v = np.concatenate([np.full(100, -1.0), np.full(100, 1.0)])
    dmap = departure_map(r, v, np.ones(200), bins=4, quantile=0.0)
    assert dmap.count[0, 0] == 100 and dmap.count[-1, -1] == 100
    assert dmap.mean[0, 0] == 1.0
    assert np.isnan(dmap.mean[0, -1]) and np.isnan(dmap.mean[1, 1])
