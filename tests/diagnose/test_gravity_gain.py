"""A sensor's gain change read off its gravity level, and how it joins the dynamic estimate."""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np
import pytest

from fielddiag.diagnose.data_hypotheses import GAIN_CHANGE, combine_gain
from fielddiag.diagnose.gravity_gain import (
    BIAS_CHANGE_STD_MPS2,
    clipped_excess_mps2,
    gain_from_gravity,
    gravity_level,
)
from fielddiag.units import GRAVITY_MPS2

FS_HZ = 200.0


@dataclass
class _Drive:
    time_s: np.ndarray
    wheel_accel_mps2: np.ndarray
    body_accel_mps2: np.ndarray


def _motion(seed: int, duration_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Time and a wheel/body vertical acceleration whose velocity returns to zero: the
    second derivative of band-limited random displacements (0.5-20 Hz)."""
    from scipy import signal

    rng = np.random.default_rng(seed)
    n = int(duration_s * FS_HZ)
    t = np.arange(n) / FS_HZ
    sos = signal.butter(2, (0.5, 20.0), "bandpass", fs=FS_HZ, output="sos")
    out = []
    for accel_rms_mps2 in (5.0, 1.5):  # a hub and a body on a rough road
        x = signal.sosfiltfilt(sos, rng.standard_normal(n))
        a = np.gradient(np.gradient(x, 1 / FS_HZ), 1 / FS_HZ)
        out.append(a * accel_rms_mps2 / a.std())
    return t, out[0], out[1]


def _drive(seed, duration_s=120.0, wheel_gain=1.0, body_gain=1.0, drift_mps2_per_s=0.0,
           noise_mps2=0.3, bias_mps2=(0.03, -0.02)):
    rng = np.random.default_rng(seed + 1000)
    t, aw, ab = _motion(seed, duration_s)
    w = wheel_gain * (aw + GRAVITY_MPS2) + bias_mps2[0] + rng.normal(0, noise_mps2, t.size)
    b = (body_gain * (ab + GRAVITY_MPS2) + bias_mps2[1] + drift_mps2_per_s * t
         + rng.normal(0, noise_mps2, t.size))
    return _Drive(t, w, b)


def test_a_level_is_g_plus_bias_within_its_std():
    d = _drive(1)
    lev = gravity_level(d.time_s, d.wheel_accel_mps2)
    assert lev.level_mps2 == pytest.approx(GRAVITY_MPS2 + 0.03, abs=max(4 * lev.std_mps2, 1e-4))
    # 12 windows of a band-limited random motion: the level is known to a few mm/s^2
    assert lev.std_mps2 < 0.01


def test_no_level_without_gravity_or_too_short():
    d = _drive(2)
    assert gravity_level(d.time_s, d.wheel_accel_mps2 - GRAVITY_MPS2) is None  # AC-coupled
    assert gravity_level(d.time_s[:4000], d.wheel_accel_mps2[:4000]) is None  # 20 s: 2 windows


@pytest.mark.parametrize(("wheel_gain", "body_gain"), [(1.0, 1.012), (0.985, 1.0), (1.0, 1.0)])
def test_each_channels_gain_change_is_found(wheel_gain, body_gain):
    g = gain_from_gravity([_drive(3), _drive(4, wheel_gain=wheel_gain, body_gain=body_gain)])
    assert g.wheel.change == pytest.approx(wheel_gain - 1, abs=3 * g.wheel.std)
    assert g.body.change == pytest.approx(body_gain - 1, abs=3 * g.body.std)
    # the std is the sensor's possible bias change between drives (2 mg -> 0.2 %), not less
    assert g.body.std == pytest.approx(BIAS_CHANGE_STD_MPS2 / GRAVITY_MPS2, rel=0.2)
    assert g.ratio_change == pytest.approx(body_gain / wheel_gain - 1, abs=3 * g.ratio_std)
    if wheel_gain != body_gain:
        culprit = "body" if body_gain != 1.0 else "wheel"
        assert g.culprit().channel == culprit
        assert f"the {culprit} accelerometer's gravity reading" in g.describe()


def test_a_drifting_bias_widens_the_std():
    steady = gain_from_gravity([_drive(5), _drive(6)])
    drifting = gain_from_gravity([_drive(5), _drive(6, drift_mps2_per_s=2e-3)])
    # 0.24 m/s^2 of drift over 120 s: the level of the drive is uncertain by ~0.07 m/s^2
    assert drifting.body.std > 3 * steady.body.std
    assert abs(drifting.body.change) < 3 * drifting.body.std


def test_one_sensors_change_is_not_blurred_by_the_other_channels_noisy_level():
    # the wheel's level drifts (its std ~1 %), the body's gain moved 1.5 %: a gain change is
    # one sensor's fault, so the ratio is the body's change with the body's std
    assert gain_from_gravity([_drive(11), _drive(12, body_gain=1.015)]).single_channel
    drifting = _drive(12, body_gain=1.015)
    drifting.wheel_accel_mps2 = drifting.wheel_accel_mps2 + 4e-3 * drifting.time_s
    g = gain_from_gravity([_drive(11), drifting])
    assert g.wheel.std > 3 * g.body.std and abs(g.wheel.change) < 2 * g.wheel.std
    assert g.single_channel
    assert g.ratio_change == pytest.approx(0.015, abs=3 * g.ratio_std)
    assert g.ratio_std == pytest.approx(g.body.std)
    assert abs(g.ratio_change) / g.ratio_std > 5  # the wheel's noise would hide it
    assert "taken as unchanged" in g.describe()
    # nothing moved: the full ratio, with both channels' stds
    same = gain_from_gravity([_drive(11), _drive(12)])
    assert not same.single_channel
    assert same.ratio_std == pytest.approx(np.hypot(same.body.std, same.wheel.std), rel=0.05)


def test_gravity_needs_both_channels_of_both_drives():
    a, b = _drive(7), _drive(8)
    b.wheel_accel_mps2 = b.wheel_accel_mps2 - GRAVITY_MPS2
    assert gain_from_gravity([a, b]) is None
    assert gain_from_gravity([a]) is None


def test_combining_agreeing_and_disagreeing_estimates():
    grav = gain_from_gravity([_drive(9), _drive(10, body_gain=1.02)])
    # agreeing: inverse-variance mean, smaller std than either
    both = combine_gain((0.019, 0.004), grav)
    assert both.kind == GAIN_CHANGE
    assert both.std < min(0.004, grav.ratio_std)
    assert both.value == pytest.approx(0.02, abs=3 * both.std)
    assert "agrees" in both.evidence
    assert both.confirmed  # two independent measurements, each significant, one result
    # the gravity levels moved (a bias drift could do that) but the transmissibility's
    # level did not, significantly: agreeing, not confirmed
    flat = combine_gain((0.010, 0.006), grav)
    assert "agrees" in flat.evidence and not flat.confirmed
    # the transmissibility's level moved 8 % but gravity says 2 %: physics moved the level
    odd = combine_gain((0.08, 0.004), grav)
    assert odd.value == pytest.approx(grav.ratio_change) and odd.std == grav.ratio_std
    assert "do not confirm" in odd.evidence and not odd.confirmed
    # a level fit that did not settle (seed 1795817438: +880 +- 560 %) agrees with
    # anything: the gravity levels alone, and the words say it cannot tell
    lost = combine_gain((8.8, 5.6), grav)
    assert (lost.value, lost.std) == (grav.ratio_change, grav.ratio_std)
    assert "cannot tell (+- 560 %)" in lost.evidence and "agrees" not in lost.evidence
    # no gravity: the dynamic estimate alone; neither: nothing
    alone = combine_gain((0.03, 0.005), None)
    assert (alone.value, alone.std, alone.evidence, alone.confirmed) == (0.03, 0.005, "", False)
    assert combine_gain(None, None) is None


@pytest.mark.parametrize("seed", [3, 4, 5])
def test_what_clipping_took_from_the_mean_is_added_back(seed):
    """A hub's acceleration with heavy tails (road impacts), clipped at a full scale that
    1 % of the readings exceed, mostly on the upper side: the mean's loss is estimated from
    the readings just inside full scale, within its std, and the clipped channel's level
    comes back to the unclipped one."""
    from scipy import signal

    rng = np.random.default_rng(seed)
    t = np.arange(int(120 * FS_HZ)) / FS_HZ
    sos = signal.butter(2, 20.0, fs=FS_HZ, output="sos")
    motion = signal.sosfiltfilt(sos, rng.laplace(0.0, 1.0, t.size))
    true = GRAVITY_MPS2 + 8.0 * motion / motion.std()
    full_scale = float(np.quantile(np.abs(true), 0.99))
    clipped = np.clip(true, -full_scale, full_scale)
    lost = true.mean() - clipped.mean()
    shift, std = clipped_excess_mps2(clipped)
    assert lost > 0.02  # 0.2 % of g: a fifth of the smallest gain change to report
    assert shift == pytest.approx(lost, rel=0.3)
    assert abs(shift - lost) < 2 * std
    lev = gravity_level(t, clipped)
    assert abs(lev.level_mps2 - true.mean()) < 0.3 * lost + 3 * np.std(true) / np.sqrt(t.size)
    assert clipped_excess_mps2(true) == (0.0, 0.0)


@pytest.mark.timeout(900)
def test_a_gain_change_that_confounds_the_added_mass_is_identified_again():
    # the randomized generator's seed 1795941194 (60 s drives at 307 Hz): a linear car of
    # 431 kg, 23 kg added, the wheel accelerometer's gain 4.9 % down in the second drive.
    # The frequency-domain identification read 5216 kg and bounded the mass from 1304 kg;
    # the fit to the corrected drives stayed at that bound, the linear model was called
    # hopeless and the car `unexplained`. Drives corrected for a gain change are
    # identified again for their own range
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
    import random_cases as rc

    from fielddiag.diagnose.engine import diagnose_drives

    case = rc.draw_case(1795941194, duration_s=60.0, families=rc.PINNED_FAMILIES)
    assert case.family == "linear"
    out = diagnose_drives(rc.case_drives(case)).to_dict()
    assert out["verdict"] == "adequate" and not out["findings"], out["findings"]
    assert "linear_model_inadequate" not in [w["kind"] for w in out["warnings"]]
    (gain,) = [w["message"] for w in out["warnings"] if w["kind"] == "sensor_gain_changed"]
    m = re.search(r"moves the sprung mass from [\d.]+ to ([\d.]+) kg", gain)
    assert m, gain
    assert float(m[1]) == pytest.approx(case.params["body_mass_kg"], rel=0.05)
