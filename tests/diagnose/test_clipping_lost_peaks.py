"""What a clipped wheel peak lost: its shape in the model's residual, fitted alongside."""

from __future__ import annotations

import numpy as np
import pytest

from fielddiag import dsp
from fielddiag.diagnose.clipping import (
    ClippedPeaks,
    _body_response,
    at_rails,
    clipped_runs_s,
)
from fielddiag.errors import FieldDiagError
from fielddiag.identify.greybox import GreyBoxData

FS_HZ, RATE_HZ, BAND_HZ = 400.0, 125.0, (0.5, 30.0)
K_PER_KG, C_PER_KG = (2 * np.pi * 1.4) ** 2, 2 * 0.3 * 2 * np.pi * 1.4


def _wheel(seed: int = 3, duration_s: float = 40.0) -> np.ndarray:
    """A rough-road wheel reading with sharp bumps far above the rest (m/s^2)."""
    rng = np.random.default_rng(seed)
    n = int(duration_s * FS_HZ)
    t = np.arange(n) / FS_HZ
    x = 8.0 * np.sin(2 * np.pi * 12.0 * t) + rng.normal(0.0, 6.0, n)
    for t0 in rng.uniform(1.0, duration_s - 1.0, 25):
        x += 300.0 * np.exp(-0.5 * ((t - t0) / 0.006) ** 2) * np.sin(2 * np.pi * 40 * (t - t0))
    return x


def test_the_rails_and_their_runs_are_found():
    x = _wheel()
    rail = 30.0
    clipped = np.clip(x, -rail, rail)
    at = at_rails(clipped)
    assert np.array_equal(at, np.abs(x) >= rail)
    runs = clipped_runs_s(clipped, FS_HZ, start_s=5.0)
    assert runs.shape[1] == 2 and np.all(runs[:, 1] >= runs[:, 0])
    assert runs.shape[0] == np.count_nonzero(np.diff(np.concatenate([[0], at.astype(int)])) == 1)
    assert runs[0, 0] == pytest.approx(5.0 + np.flatnonzero(at)[0] / FS_HZ)
    assert not at_rails(x).any()  # nothing sits at a rail: nothing is clipped


def test_the_lost_peaks_shapes_span_what_the_clipping_did_to_the_prediction():
    # the truth: the body's predicted acceleration from the true and from the clipped
    # wheel reading differ by the response to what the rails took; the shapes of the lost
    # peaks, fitted by least squares, must take (nearly) all of it, anywhere in the drive
    x = _wheel()
    clipped = np.clip(x, -30.0, 30.0)
    w, _ = dsp.integrate_pair(x - clipped, np.zeros_like(x), FS_HZ, BAND_HZ,
                              output_rate_hz=RATE_HZ)
    error = _body_response(w.displacement_m, w.velocity_mps, w.sample_rate_hz,
                           K_PER_KG, C_PER_KG)
    peaks = ClippedPeaks.of(clipped, np.zeros_like(x), FS_HZ, BAND_HZ, RATE_HZ)
    assert peaks is not None
    t = np.arange(error.size) / w.sample_rate_hz
    for part in (slice(0, error.size // 4), slice(error.size // 2, 3 * error.size // 4)):
        basis = peaks.basis(t[part], K_PER_KG, C_PER_KG)
        coef, *_ = np.linalg.lstsq(basis, error[part], rcond=None)
        left = error[part] - basis @ coef
        assert np.std(error[part]) > 0.05
        assert np.std(left) < 0.03 * np.std(error[part])
        # not a basis that takes anything: a random signal keeps most of itself
        noise = np.random.default_rng(1).normal(size=basis.shape[0])
        coef, *_ = np.linalg.lstsq(basis, noise, rcond=None)
        assert np.std(noise - basis @ coef) > 0.6 * np.std(noise)
    assert ClippedPeaks.of(x, x, FS_HZ, BAND_HZ, RATE_HZ) is None


def test_a_disturbance_basis_is_cut_with_its_data_and_checked():
    n = 1000
    x = np.sin(np.arange(n) / 50.0)
    basis = np.column_stack([np.arange(n), np.ones(n)]).astype(float)
    d = GreyBoxData(sample_rate_hz=100.0, wheel_disp_m=x, wheel_vel_mps=x,
                    body_accel_mps2=x, disturbance_basis=basis)
    part = d.segment(2.0, 5.0)
    assert part.disturbance_basis.shape == (300, 2)
    assert part.disturbance_basis[0, 0] == 200.0
    with pytest.raises(FieldDiagError, match="disturbance_basis"):
        GreyBoxData(sample_rate_hz=100.0, wheel_disp_m=x, wheel_vel_mps=x,
                    body_accel_mps2=x, disturbance_basis=basis[:10])


def test_a_clipped_body_channel_s_lost_peaks_are_what_the_band_leaves_of_them():
    # the body channel is what the prediction is compared with: its lost area enters the
    # residual as the band leaves it, through no body
    x = _wheel(seed=5)
    clipped = np.clip(x, -30.0, 30.0)
    _, b = dsp.integrate_pair(np.zeros_like(x), x - clipped, FS_HZ, BAND_HZ,
                              output_rate_hz=RATE_HZ)
    error = b.acceleration_mps2
    peaks = ClippedPeaks.of(np.zeros_like(x), clipped, FS_HZ, BAND_HZ, RATE_HZ)
    assert peaks is not None and peaks.wheel_runs_s.size == 0
    t = np.arange(error.size) / b.sample_rate_hz
    part = slice(error.size // 3, 2 * error.size // 3)
    basis = peaks.basis(t[part], K_PER_KG, C_PER_KG)
    coef, *_ = np.linalg.lstsq(basis, error[part], rcond=None)
    assert np.std(error[part]) > 0.5
    assert np.std(error[part] - basis @ coef) < 0.03 * np.std(error[part])
