"""Data problems as hypotheses: estimates, corrections and the units of their residuals."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from fielddiag.diagnose import data_checks
from fielddiag.diagnose.data_hypotheses import (
    GAIN_CHANGE,
    TIME_OFFSET,
    DataHypothesis,
    correct_drives,
    from_transmissibility,
    moved_text,
    residual_scale,
    shift_signal,
)


@dataclass
class _Drive:
    body_accel_mps2: np.ndarray
    sample_rate_hz: float


def _linear_t(f_hz, m, k, c):
    w = 2 * np.pi * f_hz
    return (k + 1j * w * c) / (k - w * w * m + 1j * w * c)


def _transmissibilities(gain=1.0, delay_s=0.0, seed=0, m=380.0, dm=50.0, k=2.4e4, c=1.8e3):
    """Two drives' measured T (a linear car, 1 % complex noise), the second with a gain,
    both with the body channel delayed; the model is the true linear car."""
    rng = np.random.default_rng(seed)
    f = np.linspace(0.5, 25.0, 300)
    out = []
    for i, mass in enumerate((m, m + dm)):
        t = _linear_t(f, mass, k, c)
        meas = t * np.exp(-2j * np.pi * f * delay_s) * (gain if i == 1 else 1.0)
        meas = meas * (1 + 0.01 * (rng.standard_normal(f.size) + 1j * rng.standard_normal(f.size)))
        out.append({"freq_hz": f, "measured": meas, "model": t, "coherence": np.full(f.size, 0.97),
                    "label": ("before", "after")[i]})
    return out, {"sprung_mass_kg": m, "suspension_stiffness_n_per_m": k,
                 "suspension_damping_ns_per_m": c, "coupling_stiffness_n_per_m": 0.0}


def test_a_gain_change_is_estimated_with_its_std():
    trs, start = _transmissibilities(gain=1.03)
    g = data_checks.fit_gain_change(trs, (0.5, 25.0), added_mass_kg=50.0, start=start)
    assert g.change == pytest.approx(0.03, abs=3 * g.std)
    assert 0 < g.std < 0.005
    assert g.explained > 0.9  # a flat gain removes the drives' inconsistency
    (hyp,) = [h for h in from_transmissibility(trs, (0.5, 25.0), 50.0, start)
              if h.kind == GAIN_CHANGE]
    assert hyp.value == pytest.approx(g.change) and hyp.z > 5


def test_a_time_offset_is_estimated_with_its_std():
    trs, start = _transmissibilities(delay_s=0.002)
    tau, std = data_checks.fit_time_offset(trs, (0.5, 25.0))
    assert tau == pytest.approx(0.002, abs=5e-5)
    assert 0 < std < 5e-5


def test_no_hypothesis_without_a_problem():
    """Over fresh noise draws, a clean pair rarely offers a hypothesis (pre-selection at 2
    std: about 5 % per hypothesis for Gaussian estimates, less with the doubled std)."""
    offered = 0
    for seed in range(20):
        trs, start = _transmissibilities(seed=1000 + seed)
        offered += len(from_transmissibility(trs, (0.5, 25.0), 50.0, start))
    assert offered <= 2


def test_shift_signal_moves_a_sine_by_a_fraction_of_a_sample():
    fs = 500.0
    t = np.arange(5000) / fs
    x = np.sin(2 * np.pi * 7.3 * t) + 9.81
    y = shift_signal(x, 0.37)  # y[n] = x[n + 0.37]
    want = np.sin(2 * np.pi * 7.3 * (t + 0.37 / fs)) + 9.81
    inner = slice(200, -200)  # the ends of a finite record leak a little
    assert np.max(np.abs(y[inner] - want[inner])) < 2e-3


def test_correcting_undoes_the_problem():
    fs = 400.0
    t = np.arange(4000) / fs
    true = np.sin(2 * np.pi * 3.0 * t) + 9.81
    gain = correct_drives([_Drive(true.copy(), fs), _Drive(1.05 * true, fs)],
                          DataHypothesis(GAIN_CHANGE, 0.05, 0.001))
    np.testing.assert_allclose(gain[1].body_accel_mps2, true, rtol=1e-12)
    np.testing.assert_array_equal(gain[0].body_accel_mps2, true)
    late = np.sin(2 * np.pi * 3.0 * (t - 0.004)) + 9.81  # the body channel 4 ms late
    fixed = correct_drives([_Drive(late, fs)], DataHypothesis(TIME_OFFSET, 0.004, 1e-5))
    assert np.max(np.abs(fixed[0].body_accel_mps2 - true)[100:-100]) < 2e-3


def test_residuals_return_to_the_recording_units():
    gain = DataHypothesis(GAIN_CHANGE, 0.04, 0.002)
    assert residual_scale(gain, 0, 2) == 1.0 and residual_scale(gain, 1, 2) == pytest.approx(1.04)
    assert residual_scale(DataHypothesis(TIME_OFFSET, 0.001, 1e-5), 1, 2) == 1.0


def test_moved_text_names_every_parameter_with_its_change():
    txt = moved_text({"sprung_mass_kg": 400.0, "suspension_stiffness_n_per_m": 2.5e4},
                     {"sprung_mass_kg": 380.0, "suspension_stiffness_n_per_m": 2.4e4})
    assert "sprung mass from 400 to 380 kg (-5.0 %)" in txt
    assert "stiffness from 2.5e+04 to 2.4e+04 N/m (-4.0 %)" in txt


def test_clipped_mask_finds_runs_at_full_scale_only():
    rng = np.random.default_rng(3)
    x = rng.standard_normal(20000)
    assert not data_checks.clipped_mask(x).any()  # a noisy maximum is reached once
    t = np.arange(20000) / 500.0
    s = 3.0 * np.sin(2 * np.pi * 1.0 * t) + 0.01 * x  # a sensor driven past its range
    y = np.clip(s, -2.0, 2.0)
    mask = data_checks.clipped_mask(y)
    assert np.all(np.abs(y[mask]) == 2.0)
    assert mask.sum() == pytest.approx(np.sum(np.abs(s) >= 2.0), rel=0.01)


def test_a_gain_on_top_of_a_delay_is_undone_in_order():
    """A body channel 3 ms late in both drives and 4 % high in the second: the chain
    corrects the delay, then the gain; residuals return to the recording's units by the
    gain alone."""
    fs = 400.0
    t = np.arange(4000) / fs
    true = np.sin(2 * np.pi * 2.0 * t) + 9.81
    late = np.sin(2 * np.pi * 2.0 * (t - 0.003)) + 9.81
    delay = DataHypothesis(TIME_OFFSET, 0.003, 1e-5)
    both = DataHypothesis(GAIN_CHANGE, 0.04, 0.002, prior=delay)
    assert [h.kind for h in both.chain] == [TIME_OFFSET, GAIN_CHANGE]
    fixed = correct_drives([_Drive(late, fs), _Drive(1.04 * late, fs)], both)
    for d in fixed:
        assert np.max(np.abs(d.body_accel_mps2 - true)[100:-100]) < 3e-3
    assert residual_scale(both, 1, 2) == pytest.approx(1.04)
    assert residual_scale(both, 0, 2) == 1.0


def _fake_fits(seed: int):
    """A maker of fits (engine ``_Fit``) whose held-out residuals are one noise, scaled,
    plus a little of their own: ``fit(effects, scale, data=None)``."""
    from fielddiag.diagnose.engine import _Fit
    from fielddiag.diagnose.selection import CandidateFit

    rng = np.random.default_rng(seed)
    noise = rng.normal(0.0, 1.0, 3000)

    def fit(effects, scale, data=None):
        own = rng.normal(0.0, 0.05, noise.size)
        cand = CandidateFit(effects, {}, {}, 0.1, 0.1, scale * noise + own, len(effects) + 3)
        return _Fit(effects + ((data.kind,) if data else ()), None, cand, [], (), data)

    return fit


def test_a_decisive_gain_is_carried_to_physics_chosen_after_it_was_tested():
    """The gain was tested on the physics first chosen (friction); the selection then took
    friction + a top mount, never fitted to the corrected drives: the gain is handed on,
    unless its correction made the first physics predict worse, or it is not decisive."""
    from fielddiag.diagnose.engine import _decisive_gain_elsewhere

    fit = _fake_fits(seed=0)

    gain = DataHypothesis(GAIN_CHANGE, -0.037, 0.002)
    friction = fit(("coulomb_friction",), 1.0)
    corrected = fit(("coulomb_friction",), 0.99, gain)
    chosen = fit(("coulomb_friction", "series_top_mount"), 0.9)
    assert _decisive_gain_elsewhere(chosen, friction, [friction, corrected, chosen]) is gain
    # the physics it was tested on is the chosen one: the usual rule decides
    assert _decisive_gain_elsewhere(friction, friction, [friction, corrected]) is None
    worse = fit(("coulomb_friction",), 1.2, gain)
    assert _decisive_gain_elsewhere(chosen, friction, [friction, worse, chosen]) is None
    weak = fit(("coulomb_friction",), 0.99, DataHypothesis(GAIN_CHANGE, -0.005, 0.002))
    assert _decisive_gain_elsewhere(chosen, friction, [friction, weak, chosen]) is None
    # on top of a late channel: hysteresis + damping was chosen first, the damping alone
    # with the delay corrected was chosen at last; the gain tested on top of the delay (on
    # hysteresis + damping) is handed on to the damping with the delay corrected
    late = DataHypothesis(TIME_OFFSET, 2.5e-3, 2e-4)
    both = fit(("hysteretic_spring", "quadratic_damping"), 1.0)
    both_late = fit(("hysteretic_spring", "quadratic_damping"), 0.95, late)
    on_top = DataHypothesis(GAIN_CHANGE, 0.011, 0.0024, prior=late)
    both_gain = fit(("hysteretic_spring", "quadratic_damping"), 0.95, on_top)
    damping_late = fit(("quadratic_damping",), 0.95, late)
    fits = [both, both_late, both_gain, damping_late]
    assert _decisive_gain_elsewhere(damping_late, both, fits) is on_top
    # ... once: not when the damping has been fitted with it already
    done = fit(("quadratic_damping",), 0.95, on_top)
    assert _decisive_gain_elsewhere(damping_late, both, [*fits, done]) is None


def test_a_late_channel_that_physics_predicts_as_well_is_not_decisive():
    """A delay's estimate rests on the residual's phase, which a lag left out of the model
    (hysteresis, a top mount) moves alike: a decisive late channel is chosen over the
    linear model only where it also predicts better than the best physics added to it;
    else neither is reported and the user is told why. A gain change keeps its rule."""
    from fielddiag.diagnose.engine import _decisive_data_problem

    fit = _fake_fits(seed=1)

    late = DataHypothesis(TIME_OFFSET, 4.9e-4, 4e-5)
    linear = fit((), 1.0)
    delayed = fit((), 0.99, late)
    hysteresis = fit(("bouc_wen",), 0.99)
    chosen, note = _decisive_data_problem(linear, [linear, delayed, hysteresis])
    assert chosen is linear
    assert "0.49 +- 0.04 ms" in note and "bouc wen" in note and "neither is reported" in note
    # a delay that predicts better than the physics too stays decisive
    sharper = fit((), 0.95, late)
    chosen, note = _decisive_data_problem(linear, [linear, sharper, hysteresis])
    assert chosen is sharper and note is None
    # without physics that improves on the linear model, as before
    chosen, note = _decisive_data_problem(linear, [linear, delayed, fit(("bouc_wen",), 1.01)])
    assert chosen is delayed and note is None


def test_a_data_problem_warning_carries_its_size_in_the_json():
    # a program reading the diagnosis's JSON needs the number, not only the sentence
    late = data_checks.time_offset_warning(-2.5e-3, 0.1e-3).to_dict()
    assert late["kind"] == "channel_time_offset" and late["value"] == pytest.approx(-2.5e-3)
    assert "wheel channel lags the other by 2.50 +- 0.10 ms" in late["message"]
    gain = data_checks.gain_warning("before", "after", 0.031, 0.004).to_dict()
    assert gain["value"] == pytest.approx(0.031) and gain["session"] == "after"
    assert set(data_checks.DataWarning("clipping", "clips").to_dict()) == {"kind", "message"}


def test_a_refined_estimate_below_the_size_worth_correcting_does_not_compete():
    # seed 1795966240: a delay refined against the linear model to 0.16 +- 0.02 ms (z 8)
    # was reported, under the 0.2 ms a first estimate must reach
    from fielddiag.diagnose.data_hypotheses import (
        GAIN_CHANGE,
        MIN_GAIN_CHANGE,
        MIN_TIME_OFFSET_S,
        TIME_OFFSET,
        DataHypothesis,
    )
    from fielddiag.diagnose.engine import _competes

    small = DataHypothesis(TIME_OFFSET, 1.6e-4, 2e-5)
    assert small.z == pytest.approx(8.0) and not small.worth_correcting
    assert DataHypothesis(TIME_OFFSET, -MIN_TIME_OFFSET_S, 2e-5).worth_correcting
    assert not DataHypothesis(GAIN_CHANGE, 0.5 * MIN_GAIN_CHANGE, 1e-4).worth_correcting
    assert DataHypothesis(GAIN_CHANGE, -0.01, 1e-3).worth_correcting

    class _Fit:  # the two attributes _competes reads
        def __init__(self, data, physics=()):
            self.data, self.physics = data, physics

    assert not _competes(_Fit(small))
    assert not _competes(_Fit(DataHypothesis(GAIN_CHANGE, 0.01, 1e-3, prior=small)))
    assert _competes(_Fit(DataHypothesis(TIME_OFFSET, 1.0e-3, 1e-4)))
    assert _competes(_Fit(None))
