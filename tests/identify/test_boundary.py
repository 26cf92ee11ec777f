"""fielddiag.identify.boundary: the frequency route and the pair-consistency check.

* Exact spectra of the model (gxy = T gxx, gyy = |T|^2 gxx, per block, with any gxx):
  the errors-in-variables cost is zero at the model's parameters, so the frequency route
  must return them (to the optimiser's tolerance), with and without K3.
* Simulated drives (white wheel acceleration through the bilinear discretisation of T at
  200 Hz, whose frequency warping at 1.3 Hz is 1e-4, plus white sensor noise): two drives
  of one car imply the same sprung mass from stiffness and from damping; a drive of another
  car does not, and the pipeline's thresholds (disagreement_z > 4, stiffness_drop_z < -3)
  flag it.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import signal

from fielddiag.dsp import BlockCrossSpectra, block_cross_spectra
from fielddiag.identify.boundary import (
    THETA_NAMES,
    damping_ratio,
    frequency_route,
    model_transmissibility,
    natural_frequency_hz,
    pair_consistency,
)

THETA = np.array([380.0, 24000.0, 1800.0, 0.0])
DM = 60.0
BAND = (0.5, 15.0)
NOISE = (1e-5, 2e-5)


def _exact_blocks(theta: np.ndarray, dm: float, seed: int, n_blocks: int = 4
                  ) -> BlockCrossSpectra:
    rng = np.random.default_rng(seed)
    f = np.arange(0.0, 25.0, 0.125)
    t = model_transmissibility(theta, f, dm)
    n_seg = np.full(n_blocks, 10)
    # each block its own (coloured) wheel spectrum: every partial sum stays exact
    gxx = (1.0 + rng.random((n_blocks, f.size))) * n_seg[:, None]
    return BlockCrossSpectra(f, 100.0, 8.0, np.linspace(0, 320, n_blocks + 1), gxx,
                             np.abs(t) ** 2 * gxx, t * gxx, n_seg)


def test_derived_quantities():
    assert natural_frequency_hz(THETA) == pytest.approx(math.sqrt(24000 / 380) / (2 * math.pi))
    assert damping_ratio(THETA) == pytest.approx(1800 / (2 * math.sqrt(24000 * 380)))
    assert math.isnan(damping_ratio([0.0, 1.0, 1.0, 0.0]))
    assert natural_frequency_hz([380.0, -5.0, 1.0, 0.0]) == 0.0
    # T -> 1 at low frequency (the body follows the wheel), peak near fn
    f = np.array([1e-3])
    assert model_transmissibility(THETA, f)[0] == pytest.approx(1.0, abs=1e-6)


@pytest.mark.parametrize("include_k3, theta", [
    (False, THETA),
    (True, np.array([380.0, 24000.0, 1800.0, 3000.0])),
])
def test_frequency_route_on_exact_spectra_returns_the_model(include_k3, theta):
    blocks = [_exact_blocks(theta, 0.0, 1), _exact_blocks(theta, DM, 2)]
    est = frequency_route(blocks, [0.0, DM], BAND, [NOISE, NOISE],
                          [[NOISE] * 4, [NOISE] * 4], include_k3=include_k3,
                          theta0=np.array([300.0, 20000.0, 1500.0, 0.0]))
    assert est.name == "frequency" and est.notes == []
    np.testing.assert_allclose(est.theta, theta, rtol=1e-6, atol=1e-6 * theta[1])
    # a fit to noisy spectra has a cost ~ n_residuals (chi^2); exact ones leave rounding
    assert est.cost < 1e-9 * est.n_residuals
    # every delete-a-block replicate is exact too
    np.testing.assert_allclose(est.replicates, np.tile(theta, (8, 1)), rtol=1e-5,
                               atol=1e-5 * theta[1])
    fn, _ = est.derived["body_natural_frequency_hz"]
    assert fn == pytest.approx(natural_frequency_hz(theta), rel=1e-6)
    assert len(THETA_NAMES) == est.theta.size


def test_frequency_route_from_the_linear_start():
    """Without theta0 the route starts from the stacked linear equations (exact here)."""
    blocks = [_exact_blocks(THETA, 0.0, 3), _exact_blocks(THETA, DM, 4)]
    est = frequency_route(blocks, [0.0, DM], BAND, [NOISE, NOISE],
                          [[NOISE] * 4, [NOISE] * 4], include_k3=False)
    np.testing.assert_allclose(est.theta[:3], THETA[:3], rtol=1e-6)


FS = 200.0
SENSOR_SD = 0.02


def _drive(theta: np.ndarray, dm: float, seed: int, seconds: float = 300.0
           ) -> BlockCrossSpectra:
    m, k, c, k3 = theta
    b, a = signal.bilinear([c, k], [m + dm, c, k + k3], FS)
    rng = np.random.default_rng(seed)
    n = int(seconds * FS)
    x = rng.standard_normal(n)
    y = signal.lfilter(b, a, x)
    return block_cross_spectra(x + SENSOR_SD * rng.standard_normal(n),
                               y + SENSOR_SD * rng.standard_normal(n), FS, segment_s=8.0,
                               n_blocks=8, max_freq_hz=30.0)


def test_pair_consistency_passes_two_drives_of_one_car():
    nz = 2 * SENSOR_SD**2 / FS
    pc = pair_consistency([_drive(THETA, 0.0, 1), _drive(THETA, DM, 2)], [0.0, DM], BAND,
                          [(nz, nz), (nz, nz)], THETA)
    # each drive's own ratios are the car's, to their statistical error (~0.5 %)
    assert pc.ratios_before[0] == pytest.approx(24000 / 380, rel=0.02)
    assert pc.ratios_after[0] == pytest.approx(24000 / 440, rel=0.02)
    assert pc.ratios_before[1] == pytest.approx(1800 / 380, rel=0.03)
    # both routes to the mass agree with the truth and with each other; the std is a
    # jackknife over 8 blocks (7 dof), so the error over it is Student t7: 4 std
    # (P = 0.5 %) rather than 3 (P = 2 %)
    assert abs(pc.mass_from_stiffness_kg - 380.0) < 4 * pc.mass_from_stiffness_std_kg
    assert abs(pc.mass_from_damping_kg - 380.0) < 4 * pc.mass_from_damping_std_kg
    assert pc.mass_from_stiffness_std_kg < 0.03 * 380  # the check has teeth
    assert pc.disagreement_z < 4.0  # the pipeline's threshold
    assert pc.stiffness_drop_z > 10.0  # the mass was added: k/M2 fell by 14 %


def test_pair_consistency_flags_drives_of_different_cars():
    """After-drive of another car (300 kg, 30 kN/m, 1.2 kNs/m with the 60 kg on it): its
    k/M is higher than the first car's, so the 'mass from stiffness' is negative, and the
    damping says ~145 kg."""
    nz = 2 * SENSOR_SD**2 / FS
    other = np.array([300.0, 30000.0, 1200.0, 0.0])
    pc = pair_consistency([_drive(THETA, 0.0, 1), _drive(other, DM, 3)], [0.0, DM], BAND,
                          [(nz, nz), (nz, nz)], THETA)
    k_b, k_a = 24000 / 380, 30000 / 360
    c_b, c_a = 1800 / 380, 1200 / 360
    assert pc.mass_from_stiffness_kg == pytest.approx(DM * k_a / (k_b - k_a), rel=0.05)
    assert pc.mass_from_damping_kg == pytest.approx(DM * c_a / (c_b - c_a), rel=0.1)
    assert pc.stiffness_drop_z < -3.0
    assert pc.disagreement_z > 4.0
