"""Modelling clipping: the stretches of a drive away from its clipped readings."""

from __future__ import annotations

import re

import numpy as np
import pytest

from fielddiag.diagnose.engine import (
    CLEAN_STRETCH_MIN_S,
    CLIP_REACH_S,
    _clean_stretches,
    _near_clipping,
)
from fielddiag.identify.greybox import GreyBoxData


def _part(duration_s: float = 60.0, fs: float = 125.0, start_s: float = 10.0) -> GreyBoxData:
    n = int(duration_s * fs)
    x = np.sin(np.arange(n) / fs)
    return GreyBoxData(sample_rate_hz=fs, wheel_disp_m=x, wheel_vel_mps=x,
                       body_accel_mps2=x, body_disp_m=x, body_vel_mps=x,
                       band_hz=(0.5, 30.0), start_s=start_s, name="before")


def test_the_stretches_leave_out_the_clipped_readings_and_the_short_gaps():
    part = _part()
    # clipped at 20 s and 22 s (a gap too short to keep) and at 50 s, in recording time
    clipped = np.array([20.0, 22.0, 50.0])
    stretches, share = _clean_stretches(part, clipped)
    spans = [(s.start_s, s.start_s + s.duration_s) for s in stretches]
    assert spans == [pytest.approx((10.0, 20.0 - CLIP_REACH_S), abs=0.02),
                     pytest.approx((22.0 + CLIP_REACH_S, 50.0 - CLIP_REACH_S), abs=0.02),
                     pytest.approx((50.0 + CLIP_REACH_S, 70.0), abs=0.02)]
    # the share counts what is left once each stretch's band-filter edges (2 / 0.5 Hz)
    # are cut
    kept = sum(b - a - 4.0 for a, b in spans)
    assert share == pytest.approx(kept / 60.0, abs=1e-3)
    assert all(s.duration_s >= CLEAN_STRETCH_MIN_S + 4.0 for s in stretches)


def test_a_drive_clipped_throughout_leaves_nothing():
    part = _part()
    stretches, share = _clean_stretches(part, np.arange(10.0, 70.0, 3.0))
    assert stretches == [] and share == 0.0


def test_without_clipping_the_whole_part_is_one_stretch():
    stretches, share = _clean_stretches(_part(), np.empty(0))
    assert len(stretches) == 1 and stretches[0].n_samples == _part().n_samples
    assert share == pytest.approx(56.0 / 60.0, abs=1e-3)


def test_held_out_readings_near_clipping_are_a_mask_even_where_none_is_near():
    # a clipped peak far from the held-out data still acts on it (its lost speed): the
    # comparison goes on with no reading left out, so the mask is never None
    t_before, t_after = np.arange(45.0, 60.0, 0.01), np.arange(45.0, 60.0, 0.01)
    runs = [(None, None, None, t_before), (None, None, None, t_after)]
    near = _near_clipping(runs, {"before": np.array([10.0]), "after": np.empty(0)})
    assert near.dtype == bool and near.shape == (2 * t_before.size,) and not near.any()
    near = _near_clipping(runs, {"before": np.array([50.0]), "after": np.empty(0)})
    assert near.sum() == np.count_nonzero(np.abs(t_before - 50.0) <= CLIP_REACH_S)


def _linear_case_diagnosed(seed: int, family: str = "linear"):
    """The randomized generator's case ``seed`` (60 s drives, a linear car) and its
    diagnosis."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
    import random_cases as rc

    from fielddiag.diagnose.engine import diagnose_drives

    case = rc.draw_case(seed, duration_s=60.0, families=rc.PINNED_FAMILIES)
    assert case.family == family
    return case, diagnose_drives(rc.case_drives(case))


@pytest.mark.timeout(900)
def test_a_late_channel_beside_clipping_is_measured_away_from_it():
    # the randomized generator's seed 1795764045 (60 s drives, 280 Hz): a linear car whose
    # wheel channel is 2.71 ms late, with 0.4 % of the wheel readings clipped. The clipped
    # peaks hold 81 % of the linear model's held-out misfit: measured on the whole drives
    # the delay refined to -0.48 ms, and asymmetric damping absorbed the peaks, then fell
    # to the clipping and took the delay with it ("adequate", nothing reported)
    case, diag = _linear_case_diagnosed(1795764045)
    truth = {n["kind"]: n for n in case.nuisances}
    assert truth["time_offset"]["channel"] == "wheel" and "clipping" in truth
    out = diag.to_dict()
    assert not out["findings"]
    kinds = [w["kind"] for w in out["warnings"]]
    assert "clipping_explains" in kinds
    offset = [w for w in diag.data_problems() if w.kind == "channel_time_offset"]
    assert offset, kinds
    # the body channel leads: a negative offset of the body against the wheel
    assert offset[0].value == pytest.approx(-truth["time_offset"]["value"], abs=0.6e-3)
    assert "wheel channel lags" in offset[0].message


@pytest.mark.timeout(900)
def test_structure_beside_clipping_is_judged_with_the_model_fitted_away_from_it():
    # the randomized generator's seed 1795802919 (60 s drives): a linear car, self-levelled,
    # whose body channel is 1.27 ms late, with 0.07 % of the wheel readings clipped. Fitted
    # to the clipped readings too, the linear model's values carry what the clipping took,
    # a misfit that follows travel and speed away from the clipped readings as well: it was
    # told as `unexplained` (10-14 % of the residual, t = 4.2-4.8), a false alarm
    case, diag = _linear_case_diagnosed(1795802919)
    truth = {n["kind"]: n for n in case.nuisances}
    assert truth["time_offset"]["channel"] == "body" and "clipping" in truth
    out = diag.to_dict()
    assert out["verdict"] == "adequate" and not out["findings"], out["findings"]
    offset = [w for w in diag.data_problems() if w.kind == "channel_time_offset"]
    assert offset and offset[0].value == pytest.approx(truth["time_offset"]["value"],
                                                       abs=0.3e-3)


@pytest.mark.timeout(900)
def test_a_wheel_clipped_far_below_its_peaks_does_not_fake_a_damper():
    # the randomized generator's seed 1795886491 (60 s drives, 224 Hz): a linear car whose
    # wheel readings clip at +-37.7 m/s2 on 0.8-1.1 % of the samples, the true peaks up to
    # 13 times the rail. Each lost peak is a step in the wheel's integrated speed whose
    # error reaches seconds away (half the wheel's displacement 4 s on): left out only
    # within 0.25 s of the clipped readings, digressive damping with negative drops took
    # it (27-40 % better there) and was reported. With what each peak lost fitted
    # alongside both models, the damper predicts no better than the linear car
    case, diag = _linear_case_diagnosed(1795886491)
    assert case.nuisance("clipping")["channel"] == "wheel"
    out = diag.to_dict()
    assert out["verdict"] == "adequate" and not out["findings"], out["findings"]
    explains = [w["message"] for w in out["warnings"] if w["kind"] == "clipping_explains"]
    assert explains and "fitted alongside both models" in explains[0]
    assert "the clipping explains the mismatch" in explains[0]


@pytest.mark.timeout(900)
def test_structure_a_lost_wheel_peak_leaves_in_the_travel_is_the_clipping():
    # the randomized generator's seed 1795913879 (60 s drives): a linear car whose wheel
    # readings clip on 0.06 % of the samples. The departure map reads the force on the
    # measured travel, in which each lost wheel peak is a speed step and a displacement
    # ramp for seconds: 30-33 % "structure" (t = 9), told `unexplained` even away from the
    # clipped readings. With what each peak lost (its shapes through the linear spring
    # and damper) fitted and taken out, none is left
    case, diag = _linear_case_diagnosed(1795913879)
    assert case.nuisance("clipping")["channel"] == "wheel"
    out = diag.to_dict()
    assert out["verdict"] == "adequate" and not out["findings"], out["findings"]
    explains = [w["message"] for w in out["warnings"] if w["kind"] == "clipping_explains"]
    assert explains and "with what each clipped peak lost taken out" in explains[0]


@pytest.mark.timeout(900)
def test_a_recording_the_clipping_corrupts_is_inconclusive_not_adequate():
    # the randomized generator's seed 1795919194 (60 s drives): friction and a cubic
    # spring, the wheel clipped on 1.2 % of its samples, 55 % of the held-out data within
    # 0.25 s of a clipped reading. The physics cannot be told from the clipping there and
    # is withdrawn; the car was then called "adequate". It is not known to be
    case, diag = _linear_case_diagnosed(1795919194, "coulomb_friction + cubic_stiffness")
    out = diag.to_dict()
    assert out["verdict"] == "inconclusive" and not out["findings"], out["findings"]
    assert out["inconclusive"].startswith("55 % of the held-out data")
    from fielddiag.diagnose.report import format_summary

    assert "INCONCLUSIVE" in format_summary(out).splitlines()[0]


@pytest.mark.timeout(900)
def test_too_many_clipped_peaks_to_take_out_of_the_travel_is_inconclusive():
    # the randomized generator's seed 1795920028 (60 s drives): a linear car, self-levelled,
    # its wheel clipped on 1.6 % of the samples (11 % of the held-out data near a clipped
    # reading). The structure test found 17-20 % "structure" away from the clipped
    # readings: what the peaks lost could not be taken out of the travel (280-680 shapes
    # a part, under 20 samples a shape). Told `unexplained` before; now it is not known
    case, diag = _linear_case_diagnosed(1795920028)
    out = diag.to_dict()
    assert out["verdict"] == "inconclusive" and not out["findings"], out["findings"]
    assert "too many to tell it from what they lost" in out["inconclusive"]
    explains = [w["message"] for w in out["warnings"] if w["kind"] == "clipping_explains"]
    assert explains and "the clipping may explain it" in explains[0]


@pytest.mark.timeout(900)
def test_a_late_channel_is_told_away_from_a_clipping_that_corrupts_most_of_the_recording():
    # the randomized generator's seed 1795941144 (60 s drives at 817 Hz): a linear car, its
    # wheel channel 2.95 ms late and clipped on 0.5-0.6 % of the samples, 58 % of the
    # held-out data near a clipped reading. No physics can be told from the clipping there,
    # but a late channel acts at every sample: away from the clipped readings its
    # correction predicts far better, and it was withheld as the clipping's before
    case, diag = _linear_case_diagnosed(1795941144)
    (late,) = [n for n in case.nuisances if n["kind"] == "time_offset"]
    out = diag.to_dict()
    assert out["verdict"] == "inconclusive" and not out["findings"], out["findings"]
    (offset,) = [d for d in out["data_problems"] if d["kind"] == "channel_time_offset"]
    assert abs(offset["value"]) == pytest.approx(late["value"], rel=0.1)
    explains = [w["message"] for w in out["warnings"] if w["kind"] == "clipping_explains"]
    assert explains and "so it is not the clipping's" in explains[0]


@pytest.mark.timeout(900)
def test_a_tie_by_a_gain_too_small_to_earn_a_parameter_says_so():
    # the randomized generator's seed 1795941185 (60 s drives): a digressive damper, a body
    # channel 1.19 ms late, the wheel clipped (61 % of the held-out data near a clipped
    # reading). The late channel and a top mount tie: the delay predicts 0.4 % better at
    # t = 6.5, under what a parameter must earn. It was worded "within two standard
    # errors (t = 6.5)"
    case, diag = _linear_case_diagnosed(1795941185, "digressive_damping")
    out = diag.to_dict()
    (tie,) = [w["message"] for w in out["warnings"] if w["kind"] == "data_problem_or_physics"]
    m = re.search(r"explain the held-out data alike: the data problem predicts them only "
                  r"([\d.]+) % better \(t = ([\d.]+)\), under the 2 % a parameter must earn: "
                  r"by what they predict, these data cannot tell the two apart",
                  tie)
    assert m, tie
    assert float(m[1]) < 2.0 and float(m[2]) >= 2.0
    assert "within two standard errors" not in tie


@pytest.mark.timeout(300)
def test_a_fit_whose_sensitivities_overflow_is_dropped_not_run_for_ever():
    # the randomized generator's seed 1795948194 (60 s drives at 242 Hz): a linear car, its
    # wheel clipped on 0.7-0.9 % of the samples. The bump stop's fit ended where its
    # sensitivities overflow, and the SVD of its covariance looped on them: the case ran
    # for over 20 minutes. The fit is dropped with a message; the rest is diagnosed
    messages: list[str] = []
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
    import random_cases as rc

    from fielddiag.diagnose.engine import diagnose_drives

    case = rc.draw_case(1795948194, duration_s=60.0, families=rc.PINNED_FAMILIES)
    assert case.family == "linear"
    out = diagnose_drives(rc.case_drives(case), progress=messages.append).to_dict()
    assert not out["findings"], out["findings"]
    dropped = [m for m in messages if "bump_stop could not be fitted" in m]
    assert dropped and "sensitivities overflow" in dropped[0], messages


def test_a_late_channel_beside_clipping_is_judged_by_the_typical_block():
    # seed 1795976905 (60 s drives): a linear car, its wheel channel 1.16 ms late and
    # 0.12-0.25 % of its readings clipped. Away from the clipped readings the delay's
    # correction predicts the typical block 37 % better (t = 7.7), the mean square 7 %
    # worse (a few events the corrected model still misfits): judged by the mean square,
    # as physics is, it was withheld as the clipping's (session 46)
    case, diag = _linear_case_diagnosed(1795976905)
    kinds = {n["kind"]: n for n in case.nuisances}
    late = kinds["time_offset"]
    assert late["channel"] == "wheel" and late["value"] == pytest.approx(1.16e-3, abs=0.01e-3)
    assert kinds["clipping"]["channel"] == "wheel"
    out = diag.to_dict()
    assert out["verdict"] == "adequate" and out["findings"] == []
    (told,) = [w for w in out["warnings"] if w["kind"] == "channel_time_offset"]
    assert -told["value"] == pytest.approx(late["value"], rel=0.1)
    note = next(w["message"] for w in out["warnings"] if w["kind"] == "clipping_explains")
    assert "so it is not the clipping's" in note
