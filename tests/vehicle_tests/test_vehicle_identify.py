"""Full-vehicle identification on simulated cars, and the command line round trip."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from fielddiag.cli import main
from fielddiag.errors import FieldDiagError, InsufficientDataError, InvalidValueError
from fielddiag.vehicle import random_vehicle, simulate_vehicle
from fielddiag.vehicle.identify import body_noise_std_mps2, identify_vehicle
from fielddiag.vehicle.writer import csv_role_args

CONTRACT_KEYS = {"sprung_mass_kg", "cog_behind_front_axle_m", "cog_left_of_centre_m",
                 "pitch_inertia_kgm2", "roll_inertia_kgm2", "corners",
                 "anti_roll_stiffness_front_n_per_m", "anti_roll_stiffness_rear_n_per_m"}


@pytest.fixture(scope="module")
def pair():
    """A random car (seed 11), 60 s rough-road drives before/after 160 kg, and a 60 s
    braking drive to validate on."""
    car = random_vehicle(11)
    at = (0.65 * car.geometry.wheelbase_m, -0.25)
    before = simulate_vehicle(car, duration_s=60.0, seed=1, accel_noise_std_mps2=0.03)
    after = simulate_vehicle(car, duration_s=60.0, seed=2, accel_noise_std_mps2=0.03,
                             added_mass_kg=160.0, added_mass_at_m=at)
    val = simulate_vehicle(car, duration_s=60.0, seed=3, manoeuvre="braking",
                           accel_noise_std_mps2=0.03)
    val.name = "braking"
    return car, before, after, val, at


def test_identifies_a_random_car_within_the_issue_budget(pair):
    car, before, after, val, at = pair
    res = identify_vehicle(before, after, 160.0, at, validate=[val])
    t = car.truth()
    # the issue's figures: mass 3 %, CoG 2 cm, inertias 10 %, K 5 %, C 15 %, ARB 20 %
    assert res.sprung_mass_kg.value == pytest.approx(t["sprung_mass_kg"], rel=0.03)
    assert abs(res.cog_behind_front_axle_m.value - t["cog_behind_front_axle_m"]) < 0.02
    assert abs(res.cog_left_of_centre_m.value - t["cog_left_of_centre_m"]) < 0.02
    assert res.pitch_inertia_kgm2.value == pytest.approx(t["pitch_inertia_kgm2"], rel=0.10)
    assert res.roll_inertia_kgm2.value == pytest.approx(t["roll_inertia_kgm2"], rel=0.10)
    for c, d in t["corners"].items():
        assert res.corners[c]["stiffness_n_per_m"].value == pytest.approx(
            d["stiffness_n_per_m"], rel=0.05)
        assert res.corners[c]["damping_ns_per_m"].value == pytest.approx(
            d["damping_ns_per_m"], rel=0.15)
    for axle in ("front", "rear"):
        key = f"anti_roll_stiffness_{axle}_n_per_m"
        assert getattr(res, key).value == pytest.approx(t[key], rel=0.20)
    # standard deviations: positive, and the mass error within 4 of them
    assert 0 < res.sprung_mass_kg.std < 0.02 * t["sprung_mass_kg"]
    assert abs(res.sprung_mass_kg.value - t["sprung_mass_kg"]) < 4 * res.sprung_mass_kg.std
    # a linear car is predicted on another manoeuvre to a few % of the body acceleration
    assert res.cross_validation[0]["session"] == "braking"
    assert res.cross_validation[0]["nrmse"] < 0.1
    d = res.to_dict()
    assert set(d) == CONTRACT_KEYS | {"cross_validation"}
    assert set(d["corners"]) == {"fl", "fr", "rl", "rr"}
    assert all(set(v) == {"stiffness_n_per_m", "damping_ns_per_m"} for v in d["corners"].values())
    assert set(d["sprung_mass_kg"]) == {"value", "std"}
    rho = res.wls.correlation()
    assert np.allclose(np.diag(rho)[np.isfinite(np.diag(rho))], 1.0)


def test_noise_estimate_from_the_redundant_body_sensor(pair):
    _, before, *_ = pair
    assert body_noise_std_mps2(before) == pytest.approx(0.03, rel=0.15)


def test_bad_inputs(pair):
    car, before, after, _, at = pair
    with pytest.raises(InvalidValueError, match="added mass"):
        identify_vehicle(before, after, 0.0, at)
    after.added_mass_at_m, keep = None, after.added_mass_at_m
    try:
        with pytest.raises(InvalidValueError, match="--added-mass-at"):
            identify_vehicle(before, after, 160.0, None)
    finally:
        after.added_mass_at_m = keep
    short = simulate_vehicle(car, duration_s=20.0, seed=5)
    with pytest.raises(InsufficientDataError, match="at least"):
        identify_vehicle(short, after, 160.0, at)
    with pytest.raises(FieldDiagError, match="same car"):
        identify_vehicle(simulate_vehicle(duration_s=41.0, seed=6), after, 160.0, at)


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "fielddiag.cli", *args], capture_output=True,
                          text=True)


def test_cli_csv_import_identify_round_trip(tmp_path, capsys):
    out = tmp_path / "sim"
    assert main(["vehicle-sim", str(out), "--duration", "50", "--added-mass", "150",
                 "--added-mass-at", "1.9,0.3", "--seed", "4"]) == 0
    roles = [a for r in csv_role_args() for a in ("--role", r)]
    for name in ("before", "after", "validate"):
        assert main(["import", str(out / f"{name}.csv"), "-o", str(tmp_path / f"{name}.h5"),
                     "--time", "time_s", "--vehicle", str(out / "vehicle.json"), *roles]) == 0
    capsys.readouterr()
    js = tmp_path / "id.json"
    assert main(["identify", str(tmp_path / "before.h5"), str(tmp_path / "after.h5"),
                 "--added-mass", "150", "--added-mass-at", "1.9,0.3", "--validate",
                 str(tmp_path / "validate.h5"), "--json", str(js)]) == 0
    d = json.loads(js.read_text())
    assert set(d) == CONTRACT_KEYS | {"cross_validation"}
    assert d["cross_validation"][0]["session"] == "validate.h5"
    truth = json.loads((out / "truth.json").read_text())
    assert d["sprung_mass_kg"]["value"] == pytest.approx(truth["sprung_mass_kg"], rel=0.03)
    assert d["corners"]["rl"]["damping_ns_per_m"]["value"] == pytest.approx(
        truth["corners"]["rl"]["damping_ns_per_m"], rel=0.15)
    # bad input: one line, exit 1
    bad_vehicle = tmp_path / "bad.json"
    bad_vehicle.write_text('{"wheelbase_m": 2.7}')
    cases = [
        (("identify", str(tmp_path / "before.h5"), str(tmp_path / "after.h5"),
          "--added-mass", "150", "--added-mass-at", "1.9"), "X_M,Y_M"),
        (("import", str(out / "before.csv"), "-o", str(tmp_path / "x.h5"), "--time", "time_s",
          "--vehicle", str(out / "vehicle.json"), "--role", "wheel_fl=wheel_fl"), "missing"),
        (("import", str(out / "before.csv"), "-o", str(tmp_path / "x.h5"), "--time", "time_s",
          "--vehicle", str(bad_vehicle), *roles), "track_front_m"),
    ]
    for args, words in cases:
        proc = _cli(*args)
        assert proc.returncode == 1, proc.stderr
        assert "Traceback" not in proc.stderr and words in proc.stderr
        assert len(proc.stderr.strip().splitlines()) == 1


def test_body_simulated_from_the_hubs_matches_with_the_true_parameters(pair):
    """The output-error model (body driven by the measured hub motion) with the simulated
    car's own parameters reproduces the measured body accelerations; the refinement
    started from the least squares does not make the fit worse."""
    from fielddiag.vehicle import body_mass_matrix
    from fielddiag.vehicle.identify import prepare_drive, sim_nrmse
    from fielddiag.vehicle.output_error import refine_output_error
    from fielddiag.vehicle.regression import N_PARAMS

    car, before, after, val, at = pair
    mq = body_mass_matrix(car)
    theta = np.zeros(N_PARAMS)
    theta[:6] = [mq[0, 0], mq[0, 1], mq[0, 2], mq[1, 1], mq[2, 2], mq[1, 2]]
    for i, c in enumerate(("fl", "fr", "rl", "rr")):
        theta[6 + i] = car.corner(c).stiffness_n_per_m
        theta[10 + i] = car.corner(c).damping_ns_per_m
    theta[14:16] = car.anti_roll_stiffness_front_n_per_m, car.anti_roll_stiffness_rear_n_per_m
    theta[16:18] = car.sprung_mass_kg * car.cog_height_m
    d0, dv = prepare_drive(before), prepare_drive(val)
    # noise 0.03 m/s2 on ~1.5 m/s2 of body acceleration: a few % at most
    assert sim_nrmse(theta, d0) < 0.05
    assert sim_nrmse(theta, dv) < 0.05
    res = identify_vehicle(before, after, 160.0, at)
    d1 = prepare_drive(after)
    d1.added_mass_kg, d1.added_mass_at_m = 160.0, at
    oe = refine_output_error(res.wls, [d0, d1])
    assert oe.nrmse <= oe.nrmse_start * 1.001
    assert oe.wls.theta[0] == pytest.approx(car.sprung_mass_kg, rel=0.03)


@pytest.fixture(scope="module")
def drives_200hz():
    """A random car (seed 22) on road B, 90 s before/after 120 kg, recorded at 200 Hz with
    0.02 m/s^2 of sensor noise through the simulator's 4th-order Butterworth anti-alias
    filter at 0.4 fs (gentle: the hubs' broadband acceleration folds into the band) and at
    0.2 fs (steeper at the folding frequencies)."""
    from fielddiag.sim.sensors import SensorModel

    car = random_vehicle(22)
    at = (0.6 * car.geometry.wheelbase_m, 0.2)
    out = {}
    for ratio in (0.4, 0.2):
        kw = dict(duration_s=90.0, sample_rate_hz=200.0, road_class="B",
                  sensor=SensorModel(output_rate_hz=200.0, noise_std_mps2=0.02,
                                     anti_alias_cutoff_ratio=ratio))
        out[ratio] = (simulate_vehicle(car, seed=45, **kw),
                      simulate_vehicle(car, seed=46, added_mass_kg=120.0, added_mass_at_m=at,
                                       **kw))
    return car, at, out


def test_200hz_recording_with_aliased_hub_acceleration(drives_200hz):
    """Issue 18, 200 Hz: what the gentle anti-alias filter folds into the hub channels acts as
    hub noise in the errors-in-variables compensation; taken equal to the body sensors' noise
    it biased every parameter low (here -8.9 %, up to -21 % on the benchmark). Estimated
    band by band from the equation errors, the result is within the issue's budget and its
    standard deviations cover the error."""
    from fielddiag.vehicle.identify import VehicleIdentifyConfig

    car, at, runs = drives_200hz
    t = car.truth()
    before, after = runs[0.4]
    old = identify_vehicle(before, after, 120.0, at, config=VehicleIdentifyConfig(
        noise_weighting=False, hub_noise="body", hub_noise_correlation=(),
        structure_doubt=0.0))
    # the hubs taken as noisy as the body: attenuation bias, larger than 3 of its stds
    assert old.sprung_mass_kg.value < 0.95 * t["sprung_mass_kg"]
    res = identify_vehicle(before, after, 120.0, at)
    # the aliased content: about twice the sensors' noise (white-equivalent, median of bands)
    body = np.asarray(res.noise["body_noise_std_mps2"])
    assert body == pytest.approx(0.02, rel=0.05)
    assert np.median(res.noise["hub_noise_std_mps2"]) > 1.5 * 0.02
    assert min(res.noise["hub_noise_ratio"]) > 1.6  # as the equations see it (2.0, 2.2)
    assert any("record at 500 Hz" in w for w in res.warnings)
    # the issue's budget; every error within 3 of its standard deviations
    budget = {"sprung_mass_kg": 0.03, "pitch_inertia_kgm2": 0.10, "roll_inertia_kgm2": 0.10,
              "anti_roll_stiffness_front_n_per_m": 0.20,
              "anti_roll_stiffness_rear_n_per_m": 0.20}
    for key, rel in budget.items():
        est = getattr(res, key)
        assert est.value == pytest.approx(t[key], rel=rel), key
        assert abs(est.value - t[key]) < 3 * est.std, key
    for key in ("cog_behind_front_axle_m", "cog_left_of_centre_m"):
        est = getattr(res, key)
        assert abs(est.value - t[key]) < min(0.02, 3 * est.std), key
    for c, d in t["corners"].items():
        for key, rel in (("stiffness_n_per_m", 0.05), ("damping_ns_per_m", 0.15)):
            est = res.corners[c][key]
            assert est.value == pytest.approx(d[key], rel=rel), (c, key)
            assert abs(est.value - d[key]) < 3 * est.std, (c, key)
    # a steeper filter folds less: the hub noise found is then close to the sensors' own
    before, after = runs[0.2]
    steep = identify_vehicle(before, after, 120.0, at)
    assert np.median(steep.noise["hub_noise_std_mps2"]) < 1.3 * 0.02
    assert steep.sprung_mass_kg.value == pytest.approx(t["sprung_mass_kg"], rel=0.03)
    assert abs(steep.sprung_mass_kg.value - t["sprung_mass_kg"]) < 3 * steep.sprung_mass_kg.std


def test_analysis_step_rounds_a_rate_read_off_time_stamps():
    from fielddiag.vehicle.identify import VehicleIdentifyConfig, analysis_samples

    cfg = VehicleIdentifyConfig()  # 100 Hz analysis rate, band from 0.5 Hz
    # a 500 Hz session whose rate from time stamps is a hair low: still every 5th sample
    assert analysis_samples(90_000, 499.9998, cfg).step == 5
    assert analysis_samples(90_000, 500.0, cfg).step == 5
    # a rate between multiples keeps the floor (at least the analysis rate)
    assert analysis_samples(90_000, 480.0, cfg).step == 4
    assert analysis_samples(90_000, 150.0, cfg).step == 1
    # the band-pass settles for 4.5 / 0.5 Hz = 9 s at each end
    keep = analysis_samples(90_000, 500.0, cfg)
    assert (keep.start, keep.stop) == (4500, 85_500)
