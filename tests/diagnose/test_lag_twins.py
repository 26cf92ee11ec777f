"""A stiff top mount and a late body channel both delay the body's response: they compete.

A rubber top mount in series with the damper delays the damper's force by ``c / k_m``;
below its corner that is a late body channel to the transmissibility's phase. Where the
two predict alike the tool must say so (it reported a bare 0.46 ms "skew" on a car with a
0.45 ms mount in the randomized benchmark), and a real channel skew must still be
reported, not turned into a mount. Cases from the randomized generator's
linear car (seed 100 of benchmarks/random_cases.py, 244 Hz), 60 s drives.
"""

from __future__ import annotations

import math
import re
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

import random_cases as rc  # noqa: E402

from fielddiag.diagnose.engine import diagnose_drives  # noqa: E402

SEED_FAMILIES = ("asymmetric_damping", "bump_stop", "coulomb_friction", "cubic_stiffness",
                 "hysteretic_spring", "quadratic_damping")
LINEAR_SEED = 100


def _case(effects=(), nuisances=()):
    case = rc.draw_case(LINEAR_SEED, duration_s=60.0, families=SEED_FAMILIES)
    assert case.family == "linear" and not case.nuisances
    return replace(case, effects=tuple(effects), strengths=(1.0,) * len(effects),
                   nuisances=tuple(nuisances))


def _kinds(out):
    return [w["kind"] for w in out["warnings"]]


@pytest.mark.timeout(900)
def test_a_stiff_top_mount_is_not_taken_for_a_late_channel():
    # the mount's relaxation time c / k_m is 0.6 ms: to the data its lag is a pure delay
    # (the two predict held-out data within two standard errors; at 2 ms the mount wins)
    tau_s = 0.6e-3
    c = _case().params["suspension_damping_ns_per_m"]
    case = _case([("series_top_mount", {"suspension_damping_ns_per_m": c,
                                        "mount_stiffness_n_per_m": c / tau_s})])
    diag = diagnose_drives(rc.case_drives(case))
    out = diag.to_dict()
    # the two predict alike: the tool keeps the better and says both, never a bare skew
    assert "data_problem_or_physics" in _kinds(out)
    note = next(w["message"] for w in out["warnings"] if w["kind"] == "data_problem_or_physics")
    assert "cannot tell the two apart" in note and "series top mount" in note
    assert "time offset" in note
    # told once, as a tie: not also as a skew "that no suspension produces"
    assert "channel_time_offset" not in _kinds(out)
    named = [f["effect"] for f in out["findings"]]
    assert named in ([], ["series_top_mount"]), named
    if named:
        k_m = out["findings"][0]["parameters"]["mount_stiffness_n_per_m"]
        assert k_m == pytest.approx(c / tau_s, rel=0.1)
    else:
        offset = [w for w in diag.data_problems() if w.kind == "channel_time_offset"]
        assert offset[0].value == pytest.approx(tau_s, abs=0.2e-3)


@pytest.mark.timeout(900)
def test_a_late_channel_beats_the_top_mount_that_looks_like_it():
    case = _case(nuisances=[{"kind": "time_offset", "channel": "body", "session": "both",
                             "value": 1.5e-3}])
    lines = []
    diag = diagnose_drives(rc.case_drives(case), progress=lines.append)
    out = diag.to_dict()
    # the mount was fitted to compete with the delay, and lost
    assert any("series_top_mount: looks like a time offset" in s for s in lines)
    assert not out["findings"]
    offset = [w for w in diag.data_problems() if w.kind == "channel_time_offset"]
    assert offset and offset[0].value == pytest.approx(1.5e-3, abs=3e-4)
    # the warning says how the suspension's own lag fared, with the mount it would need
    c = out["augmented_model"]["suspension_damping_ns_per_m"]
    m = re.search(r"A series top mount \(this lag would be a mount of about ([\d.e+]+) N/m: "
                  r"the damping over the delay\) was fitted instead and predicted the "
                  r"held-out data worse \(t = ([\d.]+) for the late channel\)",
                  offset[0].message)
    assert m, offset[0].message
    assert float(m[1]) == pytest.approx(c / offset[0].value, rel=0.01) and float(m[2]) > 0


@pytest.mark.timeout(900)
def test_the_lag_of_dry_friction_is_not_told_as_a_late_channel():
    # 200 N of Dahl friction (pre-yield travel 0.1 mm): the library fits it as Coulomb
    # friction and a hysteretic spring, which leaves a lag the delay of a late channel
    # (+1.7 ms) predicts as well as a top mount does. Before session 34 the findings
    # assumed the late channel. Above the middle of the band, where a late channel shows
    # in full, the drives as recorded show 0.15 ms: the lag shrinks with frequency, as a
    # hysteresis's does (a constant phase), so it is the suspension's
    case = _case([("dahl_friction", {"friction_force_n": 200.0,
                                     "friction_gradient_n_per_m": 0.0,
                                     "yield_displacement_m": 1e-4})])
    diag = diagnose_drives(rc.case_drives(case))
    out = diag.to_dict()
    assert out["data_problems"] == []
    assert not any(w.kind == "channel_time_offset" for w in diag.data_problems())
    note = next(w["message"] for w in out["warnings"] if w["kind"] == "lag_of_the_suspension")
    m = re.search(r"\(\+([\d.]+) \+- [\d.]+ ms\) fits the residual's phase, but above "
                  r"([\d.]+) Hz, where a late channel shows in full, the recording's channels "
                  r"are ([+-][\d.]+) ms apart", note)
    if m:
        delay_ms, middle_hz, seen_ms = float(m[1]), float(m[2]), float(m[3])
        assert delay_ms > 1.0 and abs(seen_ms) < 0.5 * delay_ms
        band = out["band_hz"]
        assert middle_hz == pytest.approx((band[0] * band[1]) ** 0.5, abs=0.05)
    else:
        # since session 45 the delay beside friction + a mount is refined against the
        # friction to its own std (+0.24 +- 0.06 ms): then the quieter and livelier halves
        # tell it apart (0.74 and 0.15 ms): a lag that changes with amplitude
        m = re.search(r"([+-][\d.]+) \+- ([\d.]+) ms apart in its quieter half and "
                      r"([+-][\d.]+) \+- ([\d.]+) ms in its livelier half", note)
        assert m, note
        quiet, lively = float(m[1]), float(m[3])
        assert quiet - lively > 2 * math.hypot(float(m[2]), float(m[4]))
    # the tie with a top mount it was kept as is withdrawn, not left saying the findings
    # assume a late channel
    assert not any("time offset" in w["message"] for w in out["warnings"]
                   if w["kind"] == "data_problem_or_physics")
    assert "coulomb_friction" in [f["effect"] for f in out["findings"]]


@pytest.mark.timeout(900)
def test_a_late_channel_beside_dry_friction_is_still_reported():
    # the randomized generator's seed 1795817445 (60 s drives at 724 Hz): Dahl friction
    # and a body channel 2.15 ms late. Above the middle of the band the drives show the
    # delay in full (2.2 ms): reported
    case = rc.draw_case(1795817445, duration_s=60.0, families=rc.PINNED_FAMILIES)
    assert [e for e, _ in case.effects] == ["dahl_friction"]
    (late,) = [n for n in case.nuisances if n["kind"] == "time_offset"]
    out = diagnose_drives(rc.case_drives(case)).to_dict()
    (offset,) = [d for d in out["data_problems"] if d["kind"] == "channel_time_offset"]
    assert abs(offset["value"]) == pytest.approx(late["value"], rel=0.1)
    assert "lag_of_the_suspension" not in _kinds(out)


@pytest.mark.timeout(900)
def test_a_soft_top_mount_is_not_refitted_to_drives_its_delay_was_taken_from():
    # the speed benchmark's mount (c / k_m = 30 ms, corner 5.3 Hz) on its car, 60 s drives
    # at 500 Hz: tested against the late channel it looks like (about 12 ms), its signature
    # is gone from the drives corrected for that delay, and its refit there (stiff, at 32
    # substeps a sample) is skipped; the mount stays the finding
    from fielddiag import sim
    from fielddiag.diagnose.engine import Drive

    sensor = sim.SensorModel(output_rate_hz=500.0, snr_db=35.0)
    pair = sim.simulate_pair(
        sim.QuarterCarParams(), added_mass_kg=60.0, seed=17, duration_s=60.0,
        road_class="C", wheel_sensor=sensor, body_sensor=sensor,
        effects=[sim.make_effect("series_top_mount", suspension_damping_ns_per_m=1800.0,
                                 mount_stiffness_n_per_m=6e4)])
    drives = [Drive(wheel_accel_mps2=d.wheel_accel_mps2, body_accel_mps2=d.body_accel_mps2,
                    sample_rate_hz=d.sample_rate_hz, added_mass_kg=d.added_mass_kg,
                    label=label, name="mount", start_s=0.0)
              for label, d in zip(("before", "after"), pair, strict=True)]
    lines = []
    out = diagnose_drives(drives, progress=lines.append).to_dict()
    assert any(s.startswith("testing a time offset") for s in lines), lines
    assert any("series_top_mount: its signature does not improve held-out data once the "
               "drives are corrected" in s for s in lines), lines
    assert not any(s.startswith("fitting series_top_mount to drives corrected") for s in lines)
    assert [f["effect"] for f in out["findings"]] == ["series_top_mount"]
    params = out["findings"][0]["parameters"]
    assert params["mount_stiffness_n_per_m"] == pytest.approx(6e4, rel=0.1)
    assert params["suspension_damping_ns_per_m"] == pytest.approx(1800.0, rel=0.05)
    assert "channel_time_offset" not in _kinds(out)


@pytest.mark.timeout(900)
def test_a_late_channel_beside_a_top_mount_is_not_judged_by_the_mount():
    # the randomized generator's seed 1795847614 (60 s drives): Coulomb friction and
    # quadratic damping, the body channel 2.41 ms late. The chosen physics came with a top
    # mount, and the check above the middle of the band read the delay off the mount's fit
    # to the drives as recorded: the mount had taken it up there too (its lag is a delay
    # at every frequency), so the late channel was withdrawn as the suspension's lag
    case = rc.draw_case(1795847614, duration_s=60.0, families=rc.PINNED_FAMILIES)
    (late,) = [n for n in case.nuisances if n["kind"] == "time_offset"]
    assert late["channel"] == "body" and late["value"] == pytest.approx(2.41e-3, abs=0.01e-3)
    out = diagnose_drives(rc.case_drives(case)).to_dict()
    assert "lag_of_the_suspension" not in _kinds(out)
    (offset,) = [d for d in out["data_problems"] if d["kind"] == "channel_time_offset"]
    assert abs(offset["value"] - late["value"]) < 2 * offset["std"]


@pytest.mark.timeout(900)
def test_twins_are_compared_beside_the_same_gain_correction():
    # the randomized generator's seed 1795919219 (60 s drives): a linear car, its body
    # channel 1.48 ms late and its gain 3.8 % up in the 'after' drive. The top mount alone
    # beat the delay alone (NRMSE 0.0890 vs 0.0895), took the gain on top, and was
    # reported as a finding although the delay with the same gain predicted better
    # (0.0865 vs 0.0870): twins were matched only without a shared correction
    case = rc.draw_case(1795919219, duration_s=60.0, families=rc.PINNED_FAMILIES)
    assert case.family == "linear"
    assert case.nuisance("time_offset")["channel"] == "body"
    out = diagnose_drives(rc.case_drives(case)).to_dict()
    assert out["verdict"] == "adequate" and not out["findings"], out["findings"]
    twin = [w["message"] for w in out["warnings"] if w["kind"] == "data_problem_or_physics"]
    assert twin and "series top mount" in twin[0]
    delay = float(re.search(r"offset between the wheel and body channels \(\+([\d.]+)",
                            twin[0]).group(1))
    assert delay == pytest.approx(1e3 * case.nuisance("time_offset")["value"], abs=0.1)
    assert "sensor_gain_changed" in _kinds(out)


@pytest.mark.timeout(900)
def test_a_late_channel_bent_far_off_is_refined_from_the_recorded_drives():
    # the randomized generator's seed 1795928049 (60 s drives): 576 N of (Dahl) dry
    # friction, a 1.69 ms late wheel channel and a clipped body channel (0.6-0.8 %). The
    # transmissibility's phase and the linear model put the delay at -60 ms; refined
    # against the friction from there the steps swung between -43 and +13 ms and the delay
    # was dropped. Started where the friction on the recorded drives sees less delay left
    # (+1.26 ms), it settles at about 2 ms (the Dahl lag adds a little), and competes
    case = rc.draw_case(1795928049, duration_s=60.0, families=rc.PINNED_FAMILIES)
    offset = next(n for n in case.nuisances if n["kind"] == "time_offset")
    assert offset["value"] == pytest.approx(1.687e-3, abs=1e-5)
    diag = diagnose_drives(rc.case_drives(case))
    out = diag.to_dict()
    assert out["findings"][0]["effect"] == "coulomb_friction"
    assert diag.chosen.data is not None
    (delay,) = [h for h in diag.chosen.data.chain if h.kind == "channel_time_offset"]
    assert abs(delay.value) == pytest.approx(offset["value"], abs=0.5e-3)
    assert delay.std < 0.3e-3
    # told as the delay, or as tied with a top mount that would lag alike
    told = {w["kind"] for w in out["warnings"]}
    assert told & {"channel_time_offset", "data_problem_or_physics"}, told


def test_the_delay_in_windows_has_the_spread_of_its_estimates():
    # the std of a delay read off one-second windows whose misfit is correlated in time
    # (noise in the analysis band, 0.5 Hz up to a few Hz or to 30 Hz, as a model's misfit
    # is) matches the spread of the estimate over independent draws
    from scipy.signal import butter, sosfiltfilt

    from fielddiag.diagnose.engine import _delay_over_windows

    rate, tau = 500.0, 3e-4
    sos_motion = butter(2, 8.0, fs=rate, output="sos")
    rng = np.random.default_rng(7)
    for top_hz in (3.0, 30.0):
        sos_misfit = butter(2, (0.5, top_hz), btype="bandpass", fs=rate, output="sos")
        est, stds = [], []
        for _ in range(80):
            motion = sosfiltfilt(sos_motion, rng.standard_normal(30 * int(rate)))
            derivative = np.gradient(motion) * rate
            misfit = sosfiltfilt(sos_misfit, rng.standard_normal(motion.size))
            residual = -tau * derivative + 2e-4 * misfit / misfit.std() * derivative.std()
            t, s = _delay_over_windows(residual.reshape(30, -1), derivative.reshape(30, -1))
            est.append(t)
            stds.append(s)
        assert np.mean(est) == pytest.approx(tau, rel=0.05)
        assert np.median(stds) == pytest.approx(np.std(est), rel=0.25)


@pytest.mark.timeout(900)
def test_the_lag_of_dahl_friction_that_shrinks_with_amplitude_is_not_a_late_channel():
    # seed 1795938609 (Dahl friction at 2.8x the noise, no late channel): Coulomb friction +
    # a hysteretic spring leave a lag of 0.29 ms, held 0.35 ms in the quieter half of the
    # drives and 0.24 ms in the livelier. By the windows' own scatter (+-0.03 ms each) the
    # halves differ; by the fixed inflation (+-0.05) they did not and the lag was reported
    case = rc.draw_case(1795938609, duration_s=60.0, families=rc.PINNED_FAMILIES)
    assert [e for e, _ in case.effects] == ["dahl_friction"] and not case.nuisances
    out = diagnose_drives(rc.case_drives(case)).to_dict()
    assert out["data_problems"] == []
    assert "coulomb_friction" in [f["effect"] for f in out["findings"]]
    note = next(w["message"] for w in out["warnings"] if w["kind"] == "lag_of_the_suspension")
    m = re.search(r"([+-][\d.]+) \+- ([\d.]+) ms apart in its quieter half and "
                  r"([+-][\d.]+) \+- ([\d.]+) ms in its livelier", note)
    assert m, note
    quiet, quiet_std, lively, lively_std = (float(x) for x in m.groups())
    assert quiet - lively > 2 * np.hypot(quiet_std, lively_std)


@pytest.mark.timeout(900)
def test_a_late_channel_beside_friction_competes_with_a_mount_at_its_own_precision():
    # the randomized generator's seed 1795953005 (60 s drives): 280 N of Coulomb friction
    # and a body channel 1.33 ms late. Friction + a top mount was chosen; the delay beside
    # the friction was held at its first estimate, 1.66 +- 0.79 ms (a transmissibility's
    # phase), where it predicted worse than the mount, whose stiffness is fitted freely, and
    # the mount was named with no word of the delay. Refined against the friction to its
    # own least-squares std, the delay (1.15 ms) and the mount explain the held-out data
    # alike: told so, the findings assuming the delay
    case = rc.draw_case(1795953005, duration_s=60.0, families=rc.PINNED_FAMILIES)
    (late,) = [n for n in case.nuisances if n["kind"] == "time_offset"]
    out = diagnose_drives(rc.case_drives(case)).to_dict()
    named = [f["effect"] for f in out["findings"]]
    assert named[0] == "coulomb_friction" and "series_top_mount" not in named, named
    (tie,) = [w["message"] for w in out["warnings"] if w["kind"] == "data_problem_or_physics"]
    m = re.search(r"a time offset between the wheel and body channels \(\+([\d.]+) \+- "
                  r"([\d.]+) ms\) and a series top mount explain the held-out data", tie)
    assert m, tie
    assert float(m[1]) == pytest.approx(1e3 * late["value"], abs=0.3)
    assert float(m[2]) < 0.1


@pytest.mark.timeout(900)
def test_a_top_mount_and_a_late_channel_together_are_both_found():
    # the randomized generator's seed 1795955142 (60 s drives): a top mount 5.3x the noise
    # floor and the body channel 2.74 ms late. The delay estimated first took up both lags
    # (8.9 ms), and a hysteretic spring was found behind it: the mount was not named. A
    # mount fitted to the drives as recorded leaves 1.0 ms of the delay beside it (none
    # where no channel is late: it delays the damper's force only); refined from there
    # against the mount, the delay settles at the channel's and wins with it
    case = rc.draw_case(1795955142, duration_s=60.0, families=rc.PINNED_FAMILIES)
    assert case.family == "series_top_mount"
    (late,) = [n for n in case.nuisances if n["kind"] == "time_offset"]
    assert late["channel"] == "body" and late["value"] == pytest.approx(2.74e-3, abs=0.01e-3)
    out = diagnose_drives(rc.case_drives(case)).to_dict()
    assert [f["effect"] for f in out["findings"]][:1] == ["series_top_mount"], out["findings"]
    (offset,) = [d for d in out["data_problems"] if d["kind"] == "channel_time_offset"]
    assert offset["value"] == pytest.approx(late["value"], rel=0.1)
    (warned,) = [w for w in out["warnings"] if w["kind"] == "channel_time_offset"]
    assert warned["value"] == pytest.approx(offset["value"])


@pytest.mark.timeout(900)
def test_a_lag_parted_by_amplitude_beside_physics_without_memory_stays_a_late_channel():
    # seed 1795974827 (60 s drives): asymmetric damping and a progressive spring, 3.0x the
    # noise, and a wheel channel 1.80 ms late. The delay the chosen asymmetric damping holds
    # read 1.98 ms in the quieter half and 1.37 in the livelier (the spring it leaves out
    # acts there), and the late channel was withdrawn as the suspension's lag; physics
    # without memory cannot stand for such a lag
    case = rc.draw_case(1795974827, duration_s=60.0, families=rc.PINNED_FAMILIES)
    assert sorted(e for e, _ in case.effects) == ["asymmetric_damping", "cubic_stiffness"]
    (late,) = [n for n in case.nuisances if n["kind"] == "time_offset"]
    assert late["channel"] == "wheel" and late["value"] == pytest.approx(1.80e-3, abs=0.01e-3)
    out = diagnose_drives(rc.case_drives(case)).to_dict()
    assert "lag_of_the_suspension" not in _kinds(out)
    (told,) = [w for w in out["warnings"] if w["kind"] == "channel_time_offset"]
    assert -told["value"] == pytest.approx(late["value"], rel=0.25)
    assert out["findings"][0]["effect"] == "asymmetric_damping"


@pytest.mark.timeout(900)
def test_a_mount_and_a_late_body_channel_together_are_parted_by_the_fits_cost():
    # seed 1795986469 (60 s drives): a top mount whose lag is 2.2 ms (k = 2.54e6 N/m,
    # 13x the noise floor) and a body channel 1.51 ms late. The mount fitted to the drives
    # corrected for each step of the delay took up most of it, and the steps crawled
    # (0.10, 0.99 ... 1.08 ms, not settled): the delay alone, 3.61 ms, was reported and
    # the car called adequate. The profile of the fit's cost over the delay has its
    # minimum at the truth: both are reported, each at its size
    case = rc.draw_case(1795986469, duration_s=60.0)
    assert case.family == "series_top_mount"
    (late,) = [n for n in case.nuisances if n["kind"] == "time_offset"]
    assert late["channel"] == "body"
    out = diagnose_drives(rc.case_drives(case)).to_dict()
    assert [f["effect"] for f in out["findings"]] == ["series_top_mount"]
    k_true = case.effects[0][1]["mount_stiffness_n_per_m"]
    k = out["findings"][0]["parameters"]["mount_stiffness_n_per_m"]
    assert k == pytest.approx(k_true, rel=0.1)
    (delay,) = [p for p in out["data_problems"] if p["kind"] == "channel_time_offset"]
    assert delay["value"] == pytest.approx(late["value"], rel=0.1)
    assert not delay.get("undecided")
