"""Mismatch diagnosis on before/after pairs with known, concealed physics.

Each case comes from fielddiag.scenarios (the same catalogue as the benchmark and
sample_data/concealed). The catalogue holds the acceptance list: the library's first four
effects at three sizes or more, one of them small (the linear model's held-out NRMSE only
1.3-2x the noise floor), both pairs of effects, an effect outside the library, linear cars
(plain, noisy 200 Hz, short, bias drifting) and every sensor problem; all of it is scored
by benchmarks/bench_diagnose.py, the randomized benchmark draws every family at every
strength. The suite diagnoses a fixed sample: one case per effect, a small one, a pair,
issue 17's quadratic damping, the effect outside the library, three linear cars and the
sensor problems but clipping (test_clipping_away.py), once, two at a time in worker
processes, by a module fixture; the tests assert on the stored results against the
scenarios' truth.
"""

from __future__ import annotations

import json
import multiprocessing
import os
import re
from collections.abc import Iterator
from concurrent.futures import Future, ProcessPoolExecutor

import pytest
from _summary_text import values_without_std
from threadpoolctl import threadpool_limits

from fielddiag.cli import main
from fielddiag.diagnose.report import format_summary
from fielddiag.scenarios import SCENARIOS, diagnose_scenario, write_scenario

#: The catalogue's cases of the library's first four effects (three sizes and a small one
#: each); the whole catalogue is scored by benchmarks/bench_diagnose.py (about 20 min), the
#: suite diagnoses a fixed sample of it (about 3 min on two idle cores): one mid-size or
#: strong case per effect but friction (a friction fit is the dearest, 60-80 s a case: a
#: small friction and friction beside asymmetric damping here, the demo's and
#: tests/diagnose/test_rig.py's friction besides), a small one, each kind of case below.
EFFECT_CASES = {
    "coulomb_friction": ["friction_1", "friction_2", "friction_3", "small_friction"],
    "cubic_stiffness": ["cubic_1", "cubic_2", "cubic_3", "small_cubic"],
    "bump_stop": ["bump_stop_1", "bump_stop_2", "bump_stop_3", "small_bump_stop"],
    "asymmetric_damping": ["asymmetric_1", "asymmetric_2", "asymmetric_3", "small_asymmetric"],
}
#: Families added by issue 17: one catalogue case each where it is cheap (the randomized
#: benchmark draws every family at every strength).
NEW_FAMILIES = ["quadratic_damping"]
#: The sample diagnosed here (cubic_3: a spring strong enough to leave the linear model
#: without one sprung mass); asymmetric_3 is diagnosed through the CLI, by
#: test_cli_pair_with_plots, which checks it as the others are checked.
SINGLE = ["cubic_3", "bump_stop_2", "small_friction"] + NEW_FAMILIES
THROUGH_THE_CLI = "asymmetric_3"
PAIRS = ["friction_and_asymmetric"]
OUTSIDE = ["travel_dependent_damping"]
LINEAR = ["linear_plain", "linear_noisy_200hz", "linear_bias_drift"]
#: (clipping: tests/diagnose/test_clipping_away.py diagnoses two clipped drives instead)
SENSOR = ["sensor_gain_changed", "channel_time_offset"]
ALL_CASES = SINGLE + PAIRS + OUTSIDE + LINEAR + SENSOR

#: The module diagnoses its sample in two workers; the first test that needs the results
#: waits for all of them (a few minutes, longer on loaded cores), longer than the suite's
#: default per-test limit.
pytestmark = pytest.mark.timeout(2400)

#: Parameter tolerance: one effect alone / each of two effects acting together.
REL_SINGLE = 0.20
REL_PAIR = 0.25
#: Held-out NRMSE of the augmented model at most this fraction of the linear model's
#: (where the effect is not small).
NRMSE_RATIO = 0.7


_BLAS_THREADS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


@pytest.fixture(scope="module")
def pending() -> Iterator[dict[str, Future]]:
    """Every case submitted for diagnosis, in two worker processes with single-threaded
    BLAS (the fits' tall least-squares problems gain nothing from BLAS threads on shared
    cores, and lose a lot to oversubscription)."""
    saved = {k: os.environ.get(k) for k in _BLAS_THREADS}
    pool = ProcessPoolExecutor(max_workers=2, mp_context=multiprocessing.get_context("spawn"))
    try:
        os.environ.update({k: "1" for k in _BLAS_THREADS})  # the workers start on submit
        # sensor cases (no effect fits) last, so that the two workers finish together
        order = sorted(ALL_CASES, key=lambda n: n in SENSOR)
        futures = {name: pool.submit(diagnose_scenario, name) for name in order}
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    try:
        yield futures
    finally:
        pool.shutdown(cancel_futures=True)


@pytest.fixture(scope="module")
def results(pending) -> dict[str, dict]:
    """The diagnosis of every case (waits for the workers)."""
    return {name: fut.result() for name, fut in pending.items()}


def test_cli_pair_with_plots(pending, tmp_path, capsys):
    # runs in this process while the workers diagnose the catalogue
    assert pending
    before, after, _ = write_scenario(SCENARIOS[THROUGH_THE_CLI], tmp_path)
    out_json = tmp_path / "d.json"
    args = ["diagnose", str(before), str(after), "--added-mass", "60", "--json",
            str(out_json), "--plots", str(tmp_path / "plots")]
    limit = threadpool_limits(1)
    with limit:
        assert main(args) == 0
    out = json.loads(out_json.read_text())
    _ranked_first_with_its_size(THROUGH_THE_CLI, out)
    f = out["findings"][0]
    assert set(f["where"]) >= {"band_hz", "time_windows_s", "region"}
    for w in f["where"]["time_windows_s"]:
        assert w["session"] in ("before", "after") and w["end_s"] > w["start_s"]
    pngs = sorted(p.name for p in (tmp_path / "plots").iterdir())
    assert pngs == [
        "diagnosis_departure_map.png",
        "diagnosis_residual_spectrum.png",
        "diagnosis_windows.png",
    ]
    text = capsys.readouterr().out
    assert "asymmetric" in text and "MISSING PHYSICS" in text
    # no mass, stiffness or damping of a model or a finding printed without its standard
    # deviation (a finding's description in words may round them: "1499 N s/m in
    # compression, 2096 in rebound")
    results = "\n".join(ln for ln in text.splitlines() if ln.lstrip().startswith(
        ("* ", "suspension", "(the linear model")))
    assert "sprung mass" in results and values_without_std(results) == [], text
    # the finding's parameters are printed with their standard deviations
    assert re.search(r"\* asymmetric_damping.*= [\d.]+ \+- [\d.]+", text), text
    # the linear part refitted with the finding, in SI units, beside the linear model alone
    m2 = out["augmented_model"]["sprung_mass_kg"]
    s2 = out["augmented_model_std"]["sprung_mass_kg"]
    # the headline is the model with the findings, the linear model alone beneath it
    lines = text.splitlines()
    head = next(i for i, ln in enumerate(lines) if "suspension, fitted with the findings: " in ln)
    assert f"sprung mass {m2:.4g} +- {s2:.2g} kg" in lines[head]
    assert "(the linear model alone, biased by what it leaves out: " in lines[head + 1]
    assert 0 < s2 < 0.05 * m2


def _true_params(name: str, effect: str) -> dict[str, float]:
    return dict(next(p for n, p in SCENARIOS[name].effects if n == effect))


def _finding(out: dict, effect: str) -> dict:
    return next(f for f in out["findings"] if f["effect"] == effect)


def test_single_drive_names_friction_per_kg_and_nothing_else(pending, tmp_path, capsys):
    """One drive, no added mass: parameters per kg of sprung mass. The friction fit leaves
    a little shape error near zero speed; that is not reported as unexplained physics."""
    from fielddiag import sim
    from fielddiag.simio import drive_to_session

    assert pending
    car = sim.QuarterCarParams()
    drive = sim.simulate(car, duration_s=40.0, seed=21, effects=(
        sim.make_effect("coulomb_friction", friction_force_n=150.0),),
        sensor=sim.SensorModel(output_rate_hz=200.0, snr_db=40.0))
    path = drive_to_session(drive, tmp_path / "one.h5")
    with threadpool_limits(1):
        assert main(["diagnose", str(path), "--json", str(tmp_path / "one.json")]) == 0
    out = json.loads((tmp_path / "one.json").read_text())
    assert [f["effect"] for f in out["findings"]] == ["coulomb_friction"]
    per_kg = out["findings"][0]["parameters"]["friction_force_n_per_kg"]
    assert per_kg == pytest.approx(150.0 / car.body_mass_kg, rel=REL_SINGLE)
    assert out["augmented"]["nrmse_validation"] < NRMSE_RATIO * out["baseline"][
        "nrmse_validation"]
    text = capsys.readouterr().out
    assert "suspension, fitted with the findings: " in text and "N/m per kg" in text


def test_catalogue_covers_the_acceptance_list():
    assert all(SCENARIOS[n].expected_effects == (n,) for n in NEW_FAMILIES)
    for effect, names in EFFECT_CASES.items():
        assert len(names) >= 3
        assert all(SCENARIOS[n].expected_effects == (effect,) for n in names)
        assert any(SCENARIOS[n].small for n in names), effect
    pairs = ["friction_and_asymmetric", "cubic_and_bump_stop"]  # the catalogue's pairs
    assert {e for n in pairs for e in SCENARIOS[n].expected_effects} == set(EFFECT_CASES)
    assert len(LINEAR) >= 3 and all(not SCENARIOS[n].effects for n in LINEAR)
    # varied drives: roads, rates, noise, added masses, speeds
    catalogue = [n for names in EFFECT_CASES.values() for n in names] + NEW_FAMILIES
    cases = [SCENARIOS[n] for n in catalogue + LINEAR + ["linear_short"]]
    assert len({c.road_class for c in cases}) >= 2
    assert len({c.rate_hz for c in cases}) >= 2
    assert len({c.snr_db for c in cases}) >= 3
    assert len({c.added_mass_kg for c in cases}) >= 3
    assert len({c.speed_range_mps for c in cases}) >= 3


@pytest.mark.parametrize("name", SINGLE)
def test_single_effect_is_ranked_first_with_its_size(results, name):
    _ranked_first_with_its_size(name, results[name]["out"])


def _ranked_first_with_its_size(name: str, out: dict) -> None:
    sc = SCENARIOS[name]
    effect = sc.expected_effects[0]
    assert out["verdict"] == "missing_physics"
    assert out["findings"][0]["effect"] == effect, [f["effect"] for f in out["findings"]]
    for key, true in _true_params(name, effect).items():
        got = out["findings"][0]["parameters"][key]
        assert got == pytest.approx(true, rel=REL_SINGLE), key
    base = out["baseline"]["nrmse_validation"]
    aug = out["augmented"]["nrmse_validation"]
    if sc.small:
        # near the noise floor the augmented model cannot gain much; it reaches the floor
        # (the true model's held-out NRMSE, benchmarks/bench_diagnose.py), so the linear
        # model's error over it is the effect's size in units of the noise: 1.3-2
        assert 1.25 < base / aug < 2.1
    else:
        assert aug < NRMSE_RATIO * base
    kinds = [w["kind"] for w in out["warnings"]]
    # a strong progressive spring leaves the linear model without one sprung mass (it
    # runs to its bound): said in words, and the model with the finding has the car's
    assert set(kinds) <= {"linear_model_inadequate"}, kinds
    if kinds:
        assert out["linear_model_adequate"] is False
        assert out["augmented_model"]["sprung_mass_kg"] == pytest.approx(
            sc.car.body_mass_kg, rel=0.05)
    json.dumps(out)


@pytest.mark.parametrize("name", ["friction_and_asymmetric"])
def test_dry_friction_force_is_not_biased_by_the_band(results, name):
    # With the smoothing velocity held at the simulator's 10 mm/s these came out 7.5-11 %
    # low: the vibration above the band dithers the friction (engine fits an effective
    # smoothing velocity instead, 15-35 mm/s on class B-C roads)
    f = _finding(results[name]["out"], "coulomb_friction")
    true = _true_params(name, "coulomb_friction")["friction_force_n"]
    assert f["parameters"]["friction_force_n"] == pytest.approx(true, rel=0.06)
    # the smoothing velocity is a parameter of the fitted form: reported apart, so that
    # "parameters" holds only the physics a technician acts on
    assert set(f["parameters"]) == {"friction_force_n"}
    assert 0.01 < f["shape"]["smoothing_velocity_mps"] < 0.06


@pytest.mark.parametrize("name", PAIRS)
def test_two_effects_are_both_named_with_their_sizes(results, name):
    sc = SCENARIOS[name]
    out = results[name]["out"]
    assert out["verdict"] == "missing_physics"
    named = [f["effect"] for f in out["findings"]]
    assert set(named[:2]) == set(sc.expected_effects), named
    for effect in sc.expected_effects:
        f = _finding(out, effect)
        for key, true in _true_params(name, effect).items():
            assert f["parameters"][key] == pytest.approx(true, rel=REL_PAIR), (effect, key)
    assert out["augmented"]["nrmse_validation"] < NRMSE_RATIO * out["baseline"][
        "nrmse_validation"]


def test_effect_outside_the_library_is_unexplained_where_it_acts(results):
    """Damping that grows with travel is in no library effect: a smooth force surface in
    travel and speed (which names nothing) predicts held-out data better than every named
    effect, so it is reported as ``unexplained``, first, with the surface attached, words
    that say the damping grows with travel and by how much, and a region away from the
    ride height. The truth: 1800 N s/m at 30 mm, growing with the square of the travel,
    so 800 N s/m at the 20 mm where the words give it."""
    out = results["travel_dependent_damping"]["out"]
    assert out["verdict"] == "missing_physics"
    last = out["findings"][0]
    assert last["effect"] == "unexplained"
    assert last["held_out_gain"] >= 0.30
    assert last["model"]["coefficients_n"] and last["shape_description"]
    words = " ".join(last["shape_description"])
    assert "damping grows with travel" in words and "mm of travel" in words, words
    surface = last["force_surface"]
    assert surface["held_out_gain_over_linear"] >= 0.30 and surface["t_vs_named"] > 4.0
    extra_at_20mm = surface["coefficients_n"]["surface_travel2_speed_n"] / 0.2
    assert extra_at_20mm == pytest.approx(1800.0 * (20 / 30) ** 2, rel=0.15)
    # the fit improves with it, and the car fitted beside the surface is the true one
    assert out["augmented"]["nrmse_validation"] < 0.3 * out["baseline"]["nrmse_validation"]
    car = SCENARIOS["travel_dependent_damping"].car
    assert out["augmented_model"]["sprung_mass_kg"] == pytest.approx(car.body_mass_kg,
                                                                      rel=0.05)
    fit = out["fit"][0]
    assert fit["simulated_augmented"] != fit["simulated_linear"]
    region = last["where"]["region"]
    assert region is not None
    # it acts where the travel is large: the region reaches the outer quarters of r
    edges = out["departure_map"]["r_edges_m"]
    lo, hi = region["r_m"]
    quarter = 0.25 * (edges[-1] - edges[0])
    assert lo <= edges[0] + quarter or hi >= edges[-1] - quarter, (region, edges[0], edges[-1])


@pytest.mark.parametrize("name", LINEAR)
def test_linear_car_is_adequate(results, name):
    sc = SCENARIOS[name]
    out = results[name]["out"]
    assert out["verdict"] == "adequate" and out["findings"] == []
    assert out["augmented"] == out["baseline"]
    lin = out["linear_model"]
    car = sc.car
    # noise on the wheel channel (the model's input) biases the linear fit low (errors in
    # variables): 9-14 % at 25 dB SNR, a few per cent at 35 dB
    rel = 0.05 if sc.snr_db >= 35.0 else 0.20
    assert lin["sprung_mass_kg"] == pytest.approx(car.body_mass_kg, rel=rel)
    assert lin["suspension_stiffness_n_per_m"] == pytest.approx(
        car.suspension_stiffness_n_per_m, rel=rel)
    assert lin["suspension_damping_ns_per_m"] == pytest.approx(
        car.suspension_damping_ns_per_m, rel=2 * rel)
    kinds = [w["kind"] for w in results[name]["warnings"]]
    assert set(kinds) == set(sc.expected_warnings), kinds


@pytest.mark.parametrize(
    "name, kind, value, tol",
    [
        ("sensor_gain_changed", "sensor_gain_changed", 0.08, 0.01),
        ("channel_time_offset", "channel_time_offset", 0.004, 0.0005),
        ("linear_bias_drift", "bias_drift", None, None),
    ],
)
def test_each_sensor_problem_is_a_data_warning_not_physics(results, name, kind, value, tol):
    out = results[name]["out"]
    kinds = [w["kind"] for w in out["warnings"]]
    assert kind in kinds, kinds
    if value is not None:
        # a gain or a delay wins the held-out comparison as a data hypothesis, with its
        # size (refined on the corrected drives) and its standard deviation
        (found,) = [p for p in out["data_problems"] if p["kind"] == kind]
        assert found["value"] == pytest.approx(value, abs=tol)
        assert 0 < found["std"] < tol
        # corrected, the linear model describes the car: the held-out error drops
        assert out["augmented"]["nrmse_validation"] < 0.8 * out["baseline"]["nrmse_validation"]
        # ... and its values, not those of the drives as recorded, are the headline
        car = SCENARIOS[name].car
        assert out["augmented_model"]["sprung_mass_kg"] == pytest.approx(car.body_mass_kg,
                                                                        rel=0.03)
        text = format_summary(out)
        assert "suspension, linear model with the " in text and " corrected: " in text
        assert "(fitted to the drives as recorded: " in text
    # no physics blamed
    assert out["verdict"] == "adequate" and out["findings"] == []
