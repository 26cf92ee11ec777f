"""The randomized validation generator (benchmarks/random_cases.py) and its scoring.

A small fixed sample: three seeds at 60 s per drive (determinism, truth, one linear case
diagnosed), plus draws only (no simulation) for the ranges and the strength spread.
"""

from __future__ import annotations

import json
import math
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import random_cases as rc  # noqa: E402
import random_scoring as rs  # noqa: E402

from fielddiag.effects import CubicStiffness, register_effect, unregister_effect  # noqa: E402
from fielddiag.units import GRAVITY_MPS2  # noqa: E402

#: The registry's families when the seeds below were chosen: drawing from them keeps each
#: seed's case fixed while the library grows.
SEED_FAMILIES = ("asymmetric_damping", "bump_stop", "coulomb_friction", "cubic_stiffness",
                 "hysteretic_spring", "quadratic_damping")
LINEAR_SEED = 100  # linear car, no nuisance, 244 Hz
NUISANCE_SEED = 115  # dry friction, self-levelling, gain change and clipping
BUMP_SEED = 112  # bump stop on a self-levelling car
SHORT_S = 60.0


def test_same_seed_same_case_and_json_round_trip() -> None:
    for seed in (LINEAR_SEED, NUISANCE_SEED, BUMP_SEED):
        a = rc.draw_case(seed, families=SEED_FAMILIES)
        b = rc.draw_case(seed, families=SEED_FAMILIES)
        assert a == b
        text = json.dumps(a.to_dict())
        assert rc.Case.from_dict(json.loads(text)) == a
        assert rc.draw_case(seed + 1, families=SEED_FAMILIES) != a
    # the truth is recorded, JSON-serialisable, in SI units
    c = rc.draw_case(NUISANCE_SEED, families=SEED_FAMILIES)
    truth = json.loads(json.dumps(c.truth()))
    assert truth["ride_height_restored"] is True
    assert truth["family"] == "coulomb_friction"
    assert truth["effects"][0]["parameters"]["friction_force_n"] > 0
    assert {n["kind"] for n in truth["nuisances"]} == {"gain_change", "clipping"}
    assert truth["sprung_mass_kg"] == c.params["body_mass_kg"]
    # a duration override changes nothing else
    short = rc.draw_case(NUISANCE_SEED, duration_s=SHORT_S, families=SEED_FAMILIES)
    assert short.duration_s == SHORT_S
    assert {**short.to_dict(), "duration_s": 0} == {**c.to_dict(), "duration_s": 0}


def test_same_seed_identical_signals_and_nuisances_applied(tmp_path) -> None:
    case = rc.draw_case(NUISANCE_SEED, duration_s=SHORT_S, families=SEED_FAMILIES)
    b1, a1 = rc.simulate_case(case)
    b2, a2 = rc.simulate_case(case)
    for x, y in ((b1, b2), (a1, a2)):
        np.testing.assert_array_equal(x.wheel_accel_mps2, y.wheel_accel_mps2)
        np.testing.assert_array_equal(x.body_accel_mps2, y.body_accel_mps2)
    assert b1.added_mass_kg == 0.0 and a1.added_mass_kg == pytest.approx(case.added_mass_kg)
    assert a1.ride_height_restored and a1.to_dict()["ride_height_restored"] is True
    assert b1.sample_rate_hz == case.rate_hz
    assert b1.wheel_accel_mps2.size == round(SHORT_S * case.rate_hz)
    # gain change: on the drawn channel of the 'after' drive only
    gain = case.nuisance("gain_change")
    sensor = f"{gain['channel']}_sensor"
    assert getattr(a1, sensor).gain == pytest.approx(1.0 + gain["value"])
    assert getattr(b1, sensor).gain == 1.0
    # clipping: the drawn share of both drives' samples sits at full scale
    clip = case.nuisance("clipping")
    x = np.concatenate([getattr(d, f"{clip['channel']}_accel_mps2") for d in (b1, a1)])
    level = getattr(a1, f"{clip['channel']}_sensor").clip_mps2
    assert level is not None and level == getattr(b1, f"{clip['channel']}_sensor").clip_mps2
    share = np.mean(np.abs(x) >= level)
    assert share == pytest.approx(clip["value"], rel=0.05, abs=2.0 / x.size)
    # the levelled drive moves about the unloaded deflection, not the sag
    sag = case.added_mass_kg * GRAVITY_MPS2 / case.car.suspension_stiffness_n_per_m
    assert abs(a1.suspension_extension_m.mean()) < 0.1 * sag
    # sessions and a separate truth file
    before, after, truth = rc.write_case(case, tmp_path)
    assert before.exists() and after.exists()
    assert json.loads(truth.read_text())["ride_height_restored"] is True


def test_draws_span_the_ranges() -> None:
    """Draws only (no simulation): ranges, probabilities and a log-uniform strength."""
    n = 3000
    cases = [rc.draw_case(50_000 + i) for i in range(n)]
    m2 = np.array([c.params["body_mass_kg"] for c in cases])
    assert m2.min() >= 250 and m2.max() <= 600
    f = np.array([c.car.body_natural_frequency_hz() for c in cases if
                  c.params["coupling_stiffness_n_per_m"] == 0.0])
    assert f.min() >= 1.0 - 1e-9 and f.max() <= 1.8 + 1e-9
    zeta = np.array([c.damping_ratio for c in cases])
    assert zeta.min() >= 0.2 and zeta.max() <= 0.45
    rate = np.array([c.rate_hz for c in cases])
    assert rate.min() >= 200 and rate.max() <= 1000 and np.ptp(rate) > 700
    frac = np.array([c.added_mass_kg / c.params["body_mass_kg"] for c in cases])
    assert frac.min() >= 0.05 and frac.max() <= 0.15
    dur = np.array([c.duration_s for c in cases])
    assert dur.min() >= 90 and dur.max() <= 300
    assert {c.road_class for c in cases} == {"B", "C", "D"}
    # physics: linear / single / pair about 25 / 55 / 20 % (binomial 3 sigma < 2.5 %)
    n_eff = np.array([len(c.effects) for c in cases])
    for k, p in enumerate((0.25, 0.55, 0.20)):
        assert np.mean(n_eff == k) == pytest.approx(p, abs=3 * math.sqrt(p * (1 - p) / n))
    # every family of the registry is drawn, alone and in pairs
    fams = {c.family for c in cases}
    for name in rc.effect_families():
        assert name in fams
        assert any(name in f and "+" in f for f in fams)
    # strength: log-uniform over 0.1-10, i.e. from below to far above the noise floor
    s = np.array([x for c in cases for x in c.strengths])
    assert s.min() >= 0.1 and s.max() <= 10.0
    assert s.min() < 0.11 and s.max() > 9.0
    below_1 = np.mean(s < 1.0)
    assert below_1 == pytest.approx(0.5, abs=3 * math.sqrt(0.25 / s.size))
    assert np.mean(s < math.sqrt(10) / 10) == pytest.approx(0.25, abs=0.04)
    # nuisances and self-levelling at their probabilities, sizes in range
    for kind, p in rc.NUISANCE_PROBABILITY.items():
        got = [c.nuisance(kind) for c in cases if c.nuisance(kind) is not None]
        assert len(got) / n == pytest.approx(p, abs=3 * math.sqrt(p * (1 - p) / n))
    g = np.array([abs(c.nuisance("gain_change")["value"]) for c in cases
                  if c.nuisance("gain_change")])
    assert g.min() >= 0.005 and g.max() <= 0.05
    t = np.array([c.nuisance("time_offset")["value"] for c in cases if c.nuisance("time_offset")])
    assert t.min() >= 0.5e-3 and t.max() <= 3e-3
    lev = np.mean([c.ride_height_restored for c in cases])
    assert lev == pytest.approx(0.25, abs=3 * math.sqrt(0.25 * 0.75 / n))


def test_a_family_registered_later_is_drawn() -> None:
    class StiffenerForTest(CubicStiffness):
        name = "test_only_stiffener"

    register_effect(StiffenerForTest)
    try:
        assert "test_only_stiffener" in rc.effect_families()
        found = [c for c in (rc.draw_case(70_000 + i) for i in range(400))
                 if "test_only_stiffener" in c.family]
        assert found
        params = dict(found[0].effects)["test_only_stiffener"]
        assert params["cubic_stiffness_n_per_m3"] > 0  # generic recipe: s x typical
    finally:
        unregister_effect("test_only_stiffener")
    assert "test_only_stiffener" not in rc.effect_families()


def test_linear_case_diagnosed_adequate() -> None:
    from fielddiag.diagnose.engine import diagnose_drives
    from fielddiag.effects import diagnosis_effects

    case = rc.draw_case(LINEAR_SEED, duration_s=SHORT_S, families=SEED_FAMILIES)
    assert case.family == "linear" and not case.nuisances
    out = diagnose_drives(rc.case_drives(case)).to_dict()
    row = rs.score_case(case, out, None, diagnosis_effects())
    assert out["verdict"] == "adequate"
    assert row["false_alarm"] is False and row["named"] == []
    assert row["reported_data_problems"] == []
    assert row["right_for_ride_height"] is True
    # the linear model finds the drawn car (pair mode: absolute values)
    lin = out["linear_model"]
    m = next(v for k, v in lin.items() if "mass" in k)
    assert m == pytest.approx(case.params["body_mass_kg"], rel=0.1)


def test_scoring_reads_warnings_findings_and_ride_height() -> None:
    case = rc.draw_case(BUMP_SEED, families=SEED_FAMILIES)
    assert case.family == "bump_stop" and case.ride_height_restored
    (name, params), = case.effects
    out = {
        "verdict": "missing_physics",
        "baseline": {"nrmse_validation": 0.3},
        "findings": [
            {"effect": "sensor_gain_change", "parameters": {"gain": 1.02}},
            {"effect": "bump_stop", "ride_height": {"supported": "restored"},
             "parameters": {k: v * 1.1 for k, v in params.items()}},
        ],
        "warnings": [{"kind": "channel_time_offset"}, {"kind": "findings_withheld"}],
    }
    row = rs.score_case(case, out, 0.1, ("bump_stop", "coulomb_friction"))
    assert row["named"] == ["bump_stop"] and row["top1"] is True
    assert row["reported_data_problems"] == ["gain_change", "time_offset"]
    assert row["strength_ratio"] == pytest.approx(3.0) and row["strength_bin"] == "2-4x"
    assert row["position_dependent"] == ["bump_stop"]
    assert row["ride_height_reported"] == "restored" and row["right_for_ride_height"] is True
    assert row["max_param_error"] == pytest.approx(0.1)
    assert not row["nuisances"]["gain_change"]["present"]
    # passive reported for a levelled car: wrong; not reported: judged on the effect only
    out["findings"][1]["ride_height"] = "passive sag"
    assert rs.score_case(case, out, 0.1, ("bump_stop",))["right_for_ride_height"] is False
    del out["findings"][1]["ride_height"]
    assert rs.score_case(case, out, 0.1, ("bump_stop",))["right_for_ride_height"] is True
    # a floor fit that failed (NaN) leaves the strength unknown, never a bin
    row = rs.score_case(case, out, float("nan"), ("bump_stop",))
    assert row["strength_ratio"] is None and row["strength_bin"] == "n/a"
    json.dumps(row, allow_nan=False)
    # an effect the diagnosis does not try is expected as "unexplained"
    assert rs.expected_names([("quadratic_damping", {})], ("bump_stop",)) == ["unexplained"]
    assert not rs.position_dependent("coulomb_friction", {"friction_force_n": 50.0})
    assert rs.position_dependent("cubic_stiffness", {"cubic_stiffness_n_per_m3": 1e6})


def test_tables_from_rows() -> None:
    """The benchmark's tables are computed from saved rows only (here: scored fake outputs)."""
    import bench_random

    lin = rc.draw_case(LINEAR_SEED, families=SEED_FAMILIES)
    bump = rc.draw_case(BUMP_SEED, families=SEED_FAMILIES)
    fric = rc.draw_case(NUISANCE_SEED, families=SEED_FAMILIES)
    quiet = {"verdict": "adequate", "baseline": {"nrmse_validation": 0.1}, "findings": [],
             "warnings": []}
    alarm = {**quiet, "verdict": "missing_physics",
             "findings": [{"effect": "coulomb_friction", "parameters": {}}]}
    found = {**quiet, "verdict": "missing_physics", "baseline": {"nrmse_validation": 0.5},
             "findings": [{"effect": "bump_stop", "parameters": dict(bump.effects[0][1])}],
             "warnings": [{"kind": "sensor_gain_changed"}]}
    lib = ("bump_stop", "coulomb_friction")
    rows = [rs.score_case(lin, quiet, None, lib), rs.score_case(lin, alarm, None, lib),
            rs.score_case(bump, found, 0.1, lib), rs.score_case(fric, quiet, None, lib)]
    rows = json.loads(json.dumps(rows))  # as saved
    text = "\n".join(bench_random.report(rows, [{"seed": 1, "family": "x", "error": "E: e"}]))
    assert "false alarms on linear cases (<= 5 %)            1/2 (50 %)" in text
    assert "top-1, library effects >= 2x floor (>= 95 %)     1/1 (100 %)" in text
    line = next(ln for ln in text.splitlines() if ln.startswith("bump_stop "))
    assert line.split()[1:6] == ["1", "-", "-", "-", "1/1"]  # ratio 5: the >4x bin
    # a gain change reported where none was drawn is counted as invented
    gain = next(ln for ln in text.splitlines() if ln.startswith("gain_change"))
    assert "1/3 (33 %)" in gain and gain.split()[-3:] == ["0", "/", "0"]  # no tie told
    assert "cases that raised: 1" in text and "seed 1 (x): E: e" in text


def test_a_subgroup_with_one_data_problem_is_drawn_from_consecutive_seeds() -> None:
    """``--with time_offset``: the first N consecutive seeds whose draw has a late channel,
    every one of them (and no seed skipped that has one)."""
    import bench_random

    seeds = bench_random._seeds(500, 6, None, "time_offset")
    assert len(seeds) == 6 and seeds == sorted(seeds) and seeds[0] >= 500
    has = [s for s in range(500, seeds[-1] + 1)
           if rc.draw_case(s).nuisance("time_offset") is not None]
    assert has == seeds
    assert bench_random._seeds(500, 3, None, None) == [500, 501, 502]


def test_same_physics_outside_the_library_is_named_or_unexplained() -> None:
    lib = ("coulomb_friction", "hysteretic_spring", "bouc_wen")
    dahl = [("dahl_friction", {"friction_force_n": 50.0})]
    travel = [("travel_dependent_damping", {"extra_damping_ns_per_m": 500.0})]
    # Dahl friction is dry friction with pre-sliding hysteresis: either names it
    assert rs.expected_names(dahl, lib) == ["dahl_friction"]
    assert rs.right_first(["hysteretic_spring"], dahl, lib)
    assert rs.right_first(["coulomb_friction", "hysteretic_spring"], dahl, lib)
    assert rs.right_first(["unexplained"], dahl, lib)  # its shape without a name: not wrong
    assert not rs.right_first(["cubic_stiffness"], dahl, lib)
    assert rs.all_named(["coulomb_friction"], dahl, lib)
    assert not rs.all_named(["cubic_stiffness"], dahl, lib)
    # without friction or hysteresis in the library, Dahl friction is 'unexplained'
    assert rs.expected_names(dahl, ("cubic_stiffness",)) == ["unexplained"]
    # a saved row is reprinted by the rule as it reads now
    row = {"case": {"effects": [{"effect": "dahl_friction", "parameters": {}}]},
           "named": ["coulomb_friction"], "top1": False, "all_named": False}
    assert rs.rescore(row, lib)["top1"] and rs.rescore(row, lib)["all_named"]
    # no form of a travel-dependent damper in the library: only 'unexplained' is right
    assert rs.expected_names(travel, lib) == ["unexplained"]
    assert rs.right_first(["unexplained"], travel, lib)
    assert not rs.right_first(["bouc_wen"], travel, lib)
    assert not rs.right_first([], travel, lib)
    # ... and it has no parameters to get right for its ride height: its top-1 decides
    travel_row = {"case": {"effects": [{"effect": "travel_dependent_damping", "parameters": {
        "extra_damping_ns_per_m": 500.0, "reference_travel_m": 0.03}}]},
        "named": ["unexplained"], "param_errors": [], "ride_height_reported": None,
        "ride_height_restored": True}
    again = rs.rescore(travel_row, lib)
    assert again["position_dependent"] == [] and again["right_for_ride_height"] is True


def test_a_tie_with_physics_is_told_neither_reported_nor_invented() -> None:
    case = rc.draw_case(LINEAR_SEED, families=SEED_FAMILIES)
    tied = {"verdict": "adequate", "baseline": {"nrmse_validation": 0.1}, "findings": [],
            "warnings": [{"kind": "data_problem_or_physics",
                          "message": "a time offset between the wheel and body channels "
                                     "(+0.34 +- 0.04 ms) and a series top mount explain ..."}]}
    row = rs.score_case(case, tied, None, ("series_top_mount",))
    assert row["nuisances"]["time_offset"] == {"present": False, "value": None,
                                               "must_report": False, "reported": False,
                                               "undecided": True,
                                               "value_reported": None, "size_right": False,
                                               "value_assumed": None,
                                               "assumed_size_right": False}
    assert not row["nuisances"]["gain_change"]["undecided"]
    # the findings assuming the delay tied with a mount: its size is scored apart
    late = replace(case, nuisances=({"kind": "time_offset", "channel": "body",
                                     "session": "both", "value": 2.22e-3},))
    assumed = {**tied, "data_problems": [{"kind": "channel_time_offset", "value": 2.25e-3,
                                          "std": 6e-5, "undecided": True}]}
    off = rs.score_case(late, assumed, None, ("series_top_mount",))["nuisances"]["time_offset"]
    assert not off["reported"] and off["undecided"]
    assert off["value_assumed"] == pytest.approx(2.25e-3) and off["assumed_size_right"]


def test_a_data_problem_is_reported_rightly_only_at_its_size_and_sign() -> None:
    late_body = {"kind": "time_offset", "channel": "body", "value": 2.74e-3}
    late_wheel = {"kind": "time_offset", "channel": "wheel", "value": 2.57e-3}
    # the warning carries the body channel's delay: negative where the wheel lags
    assert rs.size_right(late_body, 2.9e-3) and rs.size_right(late_wheel, -2.3e-3)
    assert not rs.size_right(late_wheel, +2.57e-3)  # the wrong channel
    assert not rs.size_right(late_body, 8.25e-3)  # a top mount's lag taken up beside it
    assert rs.size_right({"kind": "time_offset", "channel": "body", "value": 1.0e-3},
                         1.24e-3)  # within the 0.25 ms floor
    # a gain change of the 'after' drive, read as its body/wheel gain ratio less one
    wheel_gain = {"kind": "gain_change", "channel": "wheel", "value": 0.04}
    assert rs.expected_value(wheel_gain) == pytest.approx(1 / 1.04 - 1)
    assert rs.size_right(wheel_gain, -0.037) and not rs.size_right(wheel_gain, 0.04)
    out = {"warnings": [{"kind": "channel_time_offset", "message": "...", "value": 2.9e-3}]}
    assert rs.reported_value(out, "time_offset") == pytest.approx(2.9e-3)
    assert rs.reported_value(out, "gain_change") is None


def test_the_tests_pinned_families_are_the_registrys():
    # the tests of tests/diagnose draw their pinned seeds from rc.PINNED_FAMILIES, so that
    # a family added to the library re-draws none of their cases. Today the list is the
    # registry's: with it or without it a seed draws the same case
    assert set(rc.PINNED_FAMILIES) <= set(rc.effect_families())
    for seed in (1795922758, 1795928049, 1795919950):
        assert rc.draw_case(seed, duration_s=60.0) == rc.draw_case(
            seed, duration_s=60.0, families=rc.PINNED_FAMILIES)


def test_an_effects_strength_is_measured_without_the_nuisances() -> None:
    """A top mount whose lag is 0.19 ms beside a 2.4 ms late body channel (seed
    1795981352): on the drives as recorded the mount's true structure takes up the delay
    and the mount scored 2-4x the noise floor; on the same drives without the nuisance it
    is at the floor, and that is the strength the tables bin it by."""
    import bench_random as br

    case = rc.draw_case(1795981352, duration_s=SHORT_S)
    assert case.family == "series_top_mount"
    assert case.nuisance("time_offset")["value"] == pytest.approx(2.38e-3, abs=0.01e-3)
    lin, floor = br.clean_strength(case)
    assert lin / floor < 1.5
    recorded = rs.score_case(case, {"baseline": {"nrmse_validation": 3.0 * floor}}, floor,
                             ("series_top_mount",))
    assert recorded["strength_bin"] == "2-4x"
    row = rs.with_effect_strength(recorded, lin, floor)
    assert row["strength_bin"] == "1-2x" and row["strength_bin_recorded"] == "2-4x"
    assert row["strength_ratio_recorded"] == pytest.approx(3.0)
    # no floor: no strength, said so
    assert rs.with_effect_strength(recorded, lin, None)["strength_bin"] == "n/a"


def test_a_clipped_recordings_lost_peaks_count_against_an_effects_strength() -> None:
    """Coulomb friction beside 0.9 % clipped wheel readings (seed 1795989813): on drives
    without the clipping it is 6x the noise floor, on the drives recorded the true model
    predicts no better than the linear one. The clipping is kept where the strength is
    measured (what no model gives back), the corrected nuisances are not."""
    import bench_random as br

    case = rc.draw_case(1795989813, duration_s=SHORT_S)
    assert case.family == "coulomb_friction"
    assert [n["kind"] for n in case.nuisances] == ["clipping"]
    assert br.corrected_nuisances(case) == []
    lin, floor = br.clean_strength(case)
    assert lin / floor < 1.2
    lin0, floor0 = br.clean_strength(replace(case, nuisances=()))
    assert lin0 / floor0 > 4.0
    # a row re-measured keeps the strength first recorded, whatever was measured between
    row = {"strength_ratio": 6.0, "strength_bin": ">4x", "strength_ratio_recorded": 1.0,
           "strength_bin_recorded": "1-2x"}
    again = rs.with_effect_strength(row, lin, floor)
    assert again["strength_ratio_recorded"] == 1.0 and again["strength_bin"] in ("<1x", "1-2x")
