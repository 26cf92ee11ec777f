"""The effect library: each effect's force law, derivatives and static contribution, and the
promise that a new effect is one class that the simulator, the grey-box fit and the
diagnosis all take up."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numba import njit

from fielddiag import effects as fx
from fielddiag.effects import (
    EFFECTS,
    AsymmetricDamping,
    BoucWen,
    BumpStop,
    CoulombFriction,
    CouplingSpring,
    CubicStiffness,
    DigressiveDamping,
    Effect,
    HystereticSpring,
    LinearDamper,
    LinearSpring,
    ParamSpec,
    QuadraticDamping,
    SeriesTopMount,
    TravelDependentDamping,
    diagnosis_effects,
    make_effect,
    register_effect,
    unregister_effect,
)
from fielddiag.effects.buildup_hysteresis import BuildupHysteresis
from fielddiag.errors import FieldDiagError

# ------------------------------------------------------------------ force laws by hand

#: (effect with values, r [m], rdot [m/s], x2 [m], expected force on the body [N])
HAND = [
    (LinearSpring(24e3), 0.01, 0.3, 0.0, -240.0),
    (LinearDamper(1800.0), 0.01, 0.2, 0.0, -360.0),
    (CouplingSpring(2000.0), 0.5, 0.5, 0.01, -20.0),
    (CoulombFriction(80.0), 0.0, 0.01, 0.0, -80.0 * math.tanh(1.0)),  # v_s 10 mm/s default
    (CoulombFriction(80.0, 0.02), 0.0, -0.04, 0.0, 80.0 * math.tanh(2.0)),
    (CubicStiffness(2e6), 0.05, 0.0, 0.0, -250.0),
    (CubicStiffness(2e6), -0.05, 0.0, 0.0, 250.0),
    (BumpStop(0.04, 1e5), -0.06, 0.0, 0.0, 2000.0),  # simulated: the sharp hinge
    (BumpStop(0.04, 1e5), -0.03, 0.0, 0.0, 0.0),
    (BumpStop(0.04, 1e5, width_m=1e-3), -0.04, 0.0, 0.0, 1e5 * 1e-3 * math.log(2.0)),
    (AsymmetricDamping(1000.0, 3000.0), 0.0, -0.3, 0.0, 300.0),
    (AsymmetricDamping(1000.0, 3000.0), 0.0, 0.3, 0.0, -900.0),
    (QuadraticDamping(2000.0), 0.0, -0.5, 0.0, 500.0),
    # blow-off above the knee: the damper's slope loses `drop` (sharp knee when simulated)
    (DigressiveDamping(0.1, 600.0, 0.2, 1200.0), 0.0, -0.3, 0.0, -600.0 * 0.2),
    (DigressiveDamping(0.1, 600.0, 0.2, 1200.0), 0.0, 0.5, 0.0, 1200.0 * 0.3),
    (DigressiveDamping(0.1, 600.0, 0.2, 1200.0), 0.0, 0.15, 0.0, 0.0),
    (TravelDependentDamping(1800.0, 0.03), 0.03, 0.2, 0.0, -360.0),
    (TravelDependentDamping(1800.0, 0.03), -0.015, -0.2, 0.0, 90.0),
]


@pytest.mark.parametrize("effect,r,rd,x2,expected", HAND, ids=lambda v: getattr(v, "name", ""))
def test_force_law_against_hand_computed_numbers(effect, r, rd, x2, expected) -> None:
    f = effect.force(np.array([r]), np.array([rd]), np.array([x2]))[0]
    assert f[0] == pytest.approx(expected, rel=1e-12, abs=1e-12)


def test_hysteretic_force_and_state_rate_by_hand() -> None:
    hs = HystereticSpring(2e4, 2e-3)
    model = fx.ForceModel([hs])
    f, _, _, dz = model.force_and_state_rates(np.array([0.0]), np.array([0.1]), 0.0,
                                              model.values_of(), np.array([[1e-3]]))
    assert f[0] == pytest.approx(-20.0, rel=1e-12)  # -k z
    assert dz[0, 0] == pytest.approx(0.1 - 0.1 * 0.5, rel=1e-12)  # rdot - |rdot| z / z_y


def test_stateful_force_and_state_rates_by_hand() -> None:
    # Bouc-Wen, n = 2: loading (rdot w > 0) slows as |w|^n; unloading runs at rdot / x_y
    bw = fx.ForceModel([BoucWen(hysteretic_force_n=200.0, yield_displacement_m=1e-3,
                                yield_exponent=2.0)])
    f, _, _, dz = bw.force_and_state_rates(np.array([0.0, 0.0]), np.array([0.1, -0.1]), 0.0,
                                           bw.values_of(), np.array([[0.5], [0.5]]))
    np.testing.assert_allclose(f, [-100.0, -100.0], rtol=1e-12)
    np.testing.assert_allclose(dz[:, 0], [0.1 / 1e-3 * (1 - 0.25), -0.1 / 1e-3], rtol=1e-12)
    # a damper through a top mount: the mount carries k_m u = c (rdot - du/dt)
    tm = fx.ForceModel([SeriesTopMount(suspension_damping_ns_per_m=1800.0,
                                       mount_stiffness_n_per_m=1.5e5)])
    f, _, _, dz = tm.force_and_state_rates(np.array([0.0]), np.array([0.1]), 0.0,
                                           tm.values_of(), np.array([[1e-3]]))
    assert f[0] == pytest.approx(-150.0, rel=1e-12)
    assert dz[0, 0] == pytest.approx(0.1 - 1.5e5 / 1800.0 * 1e-3, rel=1e-12)


def test_buildup_hysteresis_force_state_rates_and_rest_by_hand() -> None:
    # F_f 50 N, x_y 0.1 mm, x_r 0.2 mm, k_c 3000 N/m, k_e 1000 N/m, h_y 20 mm
    bh = BuildupHysteresis(50.0, 1e-4, 2e-4, 3000.0, 1000.0, 0.02)
    model = fx.ForceModel([bh])
    z = np.array([[0.5, 0.004, 0.002], [0.5, 0.004, 0.002]])
    f, _, dp, dz = model.force_and_state_rates(np.zeros(2), np.array([-0.1, 0.1]), 0.0,
                                               model.values_of(), z)
    # F = -F_f w + k_c a - k_e b = -25 + 12 - 2
    np.testing.assert_allclose(f, [-15.0, -15.0], rtol=1e-12)
    np.testing.assert_allclose(dp[0], [-0.5, 0.0, 0.0, 0.004, -0.002, 0.0], rtol=1e-12)
    # compressing: w towards -1 at |rdot| / x_y, a builds up as |rdot| (1 - a / h_y), b is
    # released as |rdot| b / x_r
    np.testing.assert_allclose(dz[0], [(-0.1 - 0.05) / 1e-4, 0.1 * (1 - 0.2), -1.0],
                               rtol=1e-12)
    # extending: the mirror image
    np.testing.assert_allclose(dz[1], [(0.1 - 0.05) / 1e-4, -2.0, 0.1 * (1 - 0.1)],
                               rtol=1e-12)
    # at rest after a slow compression to r = -10 mm: full friction up, the build-up of
    # 10 mm of travel, h_y (1 - exp(-0.5))
    a = 0.02 * (1 - math.exp(-0.5))
    assert bh.static_force_n(-0.01)[()] == pytest.approx(50.0 * (1 - math.exp(-100.0))
                                                         + 3000.0 * a, rel=1e-12)
    assert bh.static_force_n(0.01)[()] == pytest.approx(-50.0 * (1 - math.exp(-100.0))
                                                        - 1000.0 * a, rel=1e-12)


def test_states_integrated_along_a_path() -> None:
    """force_along_path: the states follow the path (a fine-step run agrees to 1e-6 of
    the loop once started), the top mount's force tends to the damper's at low frequency, and the
    parameter derivatives through the states match central differences."""
    fs = 200.0
    t = np.arange(0.0, 10.0, 1 / fs)
    r = 0.01 * np.sin(2 * np.pi * 0.2 * t)
    rd = 0.01 * 2 * np.pi * 0.2 * np.cos(2 * np.pi * 0.2 * t)
    tm = fx.ForceModel([SeriesTopMount(1800.0, 1.5e5)])
    th = tm.values_of()
    f, _, dp, z = tm.force_along_path(r, rd, 0.0, th, fs)
    lag = 2 * np.pi * 0.2 * 1800.0 / 1.5e5  # the mount's first-order share at 0.2 Hz: 1.5 %
    assert np.max(np.abs(f[200:] + 1800.0 * rd[200:])) < 1.5 * lag * np.max(np.abs(1800 * rd))
    fine = np.arange(0.0, 10.0, 1 / (10 * fs))
    f10 = tm.force_along_path(np.interp(fine, t, r), np.interp(fine, t, rd), 0.0, th,
                              10 * fs)[0]
    # RK4 at a step of 0.42 / (k_m / c): 1e-4 in the start-up transient, 1e-6 after it
    err = np.abs(f - f10[::10]) / np.max(np.abs(f))
    assert err.max() < 1e-3 and err[200:].max() < 1e-6
    bw = fx.ForceModel([BoucWen(200.0, 1e-3, 2.0)])
    thb = bw.values_of()
    _, _, dpb, _ = bw.force_along_path(r, rd, 0.0, thb, fs)
    for j, h in ((1, 1e-8), (2, 1e-5)):
        tp, tm_ = thb.copy(), thb.copy()
        tp[j] += h
        tm_[j] -= h
        cd = (bw.force_along_path(r, rd, 0.0, tp, fs)[0]
              - bw.force_along_path(r, rd, 0.0, tm_, fs)[0]) / (2 * h)
        assert np.max(np.abs(cd - dpb[:, j])) < 1e-3 * np.max(np.abs(cd)), j


def test_substeps_follow_the_paths_rate_and_the_resolution_bounds() -> None:
    """path_substeps: few RK4 steps where the suspension is slow, as many as
    state_substeps where it is fastest, and the force agrees with a fine run (200 steps
    per sample) to 0.5 % of its range after the start-up, 0.1 % rms; resolved_bounds
    keeps a yield travel at half the travel per sample and a top mount's c / k_m at 1/16
    of a sample, and turns SI bounds of force-scaled parameters into per-unit-mass bounds
    over a mass range."""
    fs = 100.0
    t = np.arange(0.0, 20.0, 1 / fs)
    amp = np.where(t < 10.0, 0.002, 0.02)  # a slow half, a fast half
    r = amp * np.sin(2 * np.pi * 1.5 * t)
    rd = amp * 2 * np.pi * 1.5 * np.cos(2 * np.pi * 1.5 * t)
    bw = fx.ForceModel([BoucWen(200.0, 2e-4, 2.0)])
    th = bw.values_of()
    ns = bw.path_substeps(th, rd, 1 / fs)
    assert ns.shape == r.shape and ns.dtype == np.int64
    assert ns.max() == bw.state_substeps(th, float(np.max(np.abs(rd))), 1 / fs) >= 4
    assert ns[t < 9.9].max() <= ns.max() // 4
    f = bw.force_along_path(r, rd, 0.0, th, fs, follow_rate=True)[0]
    kernel = bw.compile(fx.model.__name__, "_force_path_z", error_model="numpy")._force_path_z
    fine = kernel(r, rd, np.zeros_like(r), bw.static_states(float(r[0]), th), th,
                  bw.constant_values(), 1 / fs, np.full(r.size, 200, dtype=np.int64))[0]
    # RK4 at state rate x step <= 1 in every interval (measured: 0.27 % after the start,
    # 0.06 % rms; with the fastest interval's count everywhere 1e-5, at 2.5x the steps)
    err = np.abs(f - fine) / np.ptp(fine)
    assert err[200:].max() < 5e-3 and np.sqrt(np.mean(err**2)) < 1e-3
    assert ns.mean() < 0.5 * ns.max()
    travel, step = 1e-3, 0.01
    lo, _ = bw.resolved_bounds(travel, step)
    assert lo[bw.index("bouc_wen.yield_displacement_m")] == pytest.approx(0.5e-3)
    tm = fx.ForceModel([SeriesTopMount(1800.0, 1.5e5)])
    _, hi = tm.resolved_bounds(travel, step, tm.values_of())
    assert hi[tm.index("series_top_mount.mount_stiffness_n_per_m")] == pytest.approx(
        1800.0 / (step / fx.model.MAX_RELAXATION_STEPS))
    assert tm.resolved_bounds(travel, step)[1][1] == math.inf  # no start: no limit
    lo_u, _ = tm.resolved_bounds(travel, step, per_unit_mass_kg=(100.0, 1000.0))
    assert lo_u[tm.index("series_top_mount.mount_stiffness_n_per_m")] == pytest.approx(1.0)


def test_a_top_mount_starts_where_it_lags_like_a_late_channel() -> None:
    # c / k_m = the delay: below the mount's corner its lag is the late channel's
    start = {"linear_damper.suspension_damping_ns_per_m": 2000.0}
    got = SeriesTopMount().twin_start("channel_time_offset", -0.8e-3, start)
    assert got == {"suspension_damping_ns_per_m": 2000.0,
                   "mount_stiffness_n_per_m": pytest.approx(2000.0 / 0.8e-3)}
    assert SeriesTopMount().twin_start("sensor_gain_changed", 0.02, start) == {}
    assert SeriesTopMount().twin_start("channel_time_offset", 1e-3, {}) == {}
    assert fx.CoulombFriction().twin_start("channel_time_offset", 1e-3, start) == {}


def test_a_top_mount_looks_like_a_late_body_channel_only() -> None:
    # it lags the body's response behind the wheel's; a late wheel channel makes the body
    # seem to lead, which no mount does
    assert SeriesTopMount.looks_like_data("channel_time_offset", 1.2e-3)
    assert not SeriesTopMount.looks_like_data("channel_time_offset", -1.2e-3)
    assert not SeriesTopMount.looks_like_data("sensor_gain_changed", 0.03)
    assert not fx.CoulombFriction.looks_like_data("channel_time_offset", 1.2e-3)


# ------------------------------------------------------------------ derivatives

MEMORYLESS = [c for c in EFFECTS.values() if c.n_states == 0]


@pytest.mark.parametrize("cls", MEMORYLESS, ids=lambda c: c.name)
def test_derivatives_match_central_differences(cls, rng: np.random.Generator) -> None:
    e = cls()  # a term of a fit: the bump stop is rounded, so it has derivatives
    theta = e.value_vector()
    n = 300
    r, rd, x2 = rng.uniform(-0.08, 0.08, n), rng.uniform(-0.8, 0.8, n), rng.uniform(-0.05,
                                                                                    0.05, n)
    rd = np.where(np.abs(rd) < 1e-3, 1e-3, rd)  # away from the asymmetric damper's kink
    f, ds, dp = e.force(r, rd, x2, theta)
    for k in range(3):
        h = 1e-7
        args_p, args_m = [r, rd, x2], [r, rd, x2]
        args_p[k] = args_p[k] + h
        args_m[k] = args_m[k] - h
        fd = (e.force(*args_p, theta)[0] - e.force(*args_m, theta)[0]) / (2 * h)
        scale = np.abs(ds[:, k]) + 1e-3 * np.max(np.abs(ds[:, k])) + 1e-9
        assert np.all(np.abs(fd - ds[:, k]) / scale < 1e-4), (cls.name, k)
    for j in range(theta.size):
        h = 1e-6 * max(abs(theta[j]), 1e-3)
        tp, tm = theta.copy(), theta.copy()
        tp[j] += h
        tm[j] -= h
        fd = (e.force(r, rd, x2, tp)[0] - e.force(r, rd, x2, tm)[0]) / (2 * h)
        roundoff = 1e4 * np.finfo(float).eps * (np.abs(f) + 1.0) / h
        scale = np.abs(dp[:, j]) + 1e-6 * np.max(np.abs(dp[:, j])) + 1e-12 + roundoff
        assert np.all(np.abs(fd - dp[:, j]) / scale < 1e-4), (cls.name, e.params[j].name)


# ------------------------------------------------------------------ static contribution


def test_static_contributions() -> None:
    r = np.array([-0.06, -0.02, 0.0, 0.03])
    np.testing.assert_allclose(LinearSpring(24e3).static_force_n(r), -24e3 * r, rtol=1e-14)
    np.testing.assert_allclose(CouplingSpring(3e3).static_force_n(r, x2=0.01), -30.0)
    for moving_only in (LinearDamper(1800.0), CoulombFriction(80.0),
                        AsymmetricDamping(1e3, 3e3), QuadraticDamping(500.0)):
        np.testing.assert_array_equal(moving_only.static_force_n(r), 0.0)
    np.testing.assert_allclose(CubicStiffness(2e6).static_force_n(r), -2e6 * r**3, rtol=1e-14)
    np.testing.assert_allclose(BumpStop(0.04, 1e5).static_force_n(r), [2000.0, 0, 0, 0],
                               atol=1e-9)
    # hysteresis loaded slowly from 0: z = z_y (1 - exp(-|r| / z_y)) sign(r)
    hs = HystereticSpring(2e4, 2e-3)
    z = np.sign(r) * 2e-3 * (1 - np.exp(-np.abs(r) / 2e-3))
    np.testing.assert_allclose(hs.static_force_n(r), -2e4 * z, rtol=1e-12, atol=1e-12)


def test_parameters_carry_si_units_and_bounds() -> None:
    for cls in EFFECTS.values():
        assert cls.description, cls.name
        for p in cls.params:
            assert p.unit and p.lower <= p.typical <= p.upper, (cls.name, p.name)
            si = ("_n", "_m", "_mps", "_n_per_m", "_ns_per_m", "_n_per_m3", "_ns2_per_m2")
            dimensionless = p.unit == "1" and p.name.endswith("_exponent")
            assert p.name.endswith(si) or dimensionless, p.name
    assert diagnosis_effects() == ("coulomb_friction", "cubic_stiffness", "bump_stop",
                                   "asymmetric_damping", "quadratic_damping",
                                   "digressive_damping", "hysteretic_spring", "bouc_wen",
                                   "series_top_mount")


def test_values_are_checked_and_round_trip() -> None:
    e = make_effect("bump_stop", gap_m="0.03", stiffness_n_per_m=2e5)
    assert e == BumpStop(0.03, 2e5) and e.settings == {"width_m": 0.0}
    assert make_effect(e.name, **e.to_dict()["params"]) == e
    assert BumpStop().settings == {"width_m": 1e-3}  # a term of a fit: rounded hinge
    with pytest.raises(FieldDiagError, match="stiffness_n_per_m"):
        BumpStop(0.03, 0.0)
    with pytest.raises(FieldDiagError, match="missing"):
        make_effect("coulomb_friction")
    with pytest.raises(FieldDiagError, match="linear_spring|valid effects"):
        make_effect("linear_spring", suspension_stiffness_n_per_m=1.0)


# ------------------------------------------------------------------ a new effect, one class


@njit(cache=True)
def _cubic_damper(r, rd, x2, p, c, dp):  # pragma: no cover - compiled
    dp[0] = -rd * rd * rd
    return -p[0] * rd * rd * rd, 0.0, -3.0 * p[0] * rd * rd, 0.0


class CubicDamper(Effect):
    """A throw-away effect: damping that grows with the cube of the rate."""

    name = "throwaway_cubic_damper"
    description = "cubic damper"
    diagnosable = True
    params = (ParamSpec("cubic_damping_ns3_per_m3", "N s^3/m^3", 0.0, math.inf, 1e4, True,
                        "cubic damping", "drive over sharp bumps", significant=True),)
    kernel = _cubic_damper

    def speed_bounds(self, values):
        return 0.0, 3.0 * values[0] * fx.RATE_BOUND_MPS**2, 0.0


@pytest.fixture
def cubic_damper():
    register_effect(CubicDamper)
    try:
        yield CubicDamper
    finally:
        unregister_effect(CubicDamper.name)


def test_a_new_effect_is_simulated_fitted_and_diagnosed(cubic_damper) -> None:
    from fielddiag import sim
    from fielddiag.diagnose.engine import Drive, diagnose_drives
    from fielddiag.identify.greybox import GreyBoxData, fit_greybox

    c3 = 3e4
    car = sim.QuarterCarParams()
    effect = sim.make_effect(CubicDamper.name, cubic_damping_ns3_per_m3=c3)
    # simulated: the suspension force is the law
    d = sim.simulate(car, duration_s=40.0, seed=31, road_class="C", effects=(effect,),
                     sensor=sim.SensorModel(output_rate_hz=200.0, snr_db=40.0))
    r, rd = d.suspension_extension_m, d.body_vel_mps - d.wheel_vel_mps
    expect = (-car.suspension_stiffness_n_per_m * r - car.suspension_damping_ns_per_m * rd
              - c3 * rd**3)
    np.testing.assert_allclose(d.suspension_force_n, expect, rtol=1e-12, atol=1e-9)
    assert np.max(np.abs(c3 * rd**3)) > 100.0  # the effect acts (> 100 N at times)
    # fitted: the grey-box recovers it from the true motion
    model, truth = fx.model_from_sim(car, [effect])
    res = fit_greybox(GreyBoxData.from_drive(d, truth=True), model)
    c3_per_kg = res.per_unit_mass[f"{CubicDamper.name}.cubic_damping_ns3_per_m3"]
    assert c3_per_kg == pytest.approx(c3 / car.body_mass_kg, rel=1e-3)
    # diagnosed: named first among every diagnosable effect (the new one included)
    drive = Drive(d.wheel_accel_mps2, d.body_accel_mps2, d.sample_rate_hz, label="drive",
                  name="sim")
    out = diagnose_drives([drive]).to_dict()
    assert CubicDamper.name in [c["effects"][0] for c in out["candidates"]]
    assert out["findings"][0]["effect"] == CubicDamper.name
    per_kg = out["findings"][0]["parameters"]["cubic_damping_ns3_per_m3_per_kg"]
    assert per_kg == pytest.approx(c3 / car.body_mass_kg, rel=0.25)
    assert "cubic damper" in out["findings"][0]["explanation"]


def test_an_effect_with_internal_state_is_fitted_through_its_state() -> None:
    """Dahl hysteresis (a hidden deflection state): the grey-box fit integrates the state
    along the simulated body motion and recovers every parameter and the sprung mass from
    noise-free data started 50 % off (derivatives by forward differences)."""
    from fielddiag.identify.greybox import GreyBoxData, fit_greybox
    from fielddiag.sim import QuarterCarParams, simulate_pair

    car = QuarterCarParams()
    eff = [HystereticSpring(hysteretic_stiffness_n_per_m=3e4, yield_displacement_m=3e-3)]
    drives = simulate_pair(car, added_mass_kg=60.0, seed=4, duration_s=20.0, effects=eff)
    model, truth = fx.model_from_sim(car, eff)
    truth["body_mass_kg"] = car.body_mass_kg
    res = fit_greybox([GreyBoxData.from_drive(d, truth=True) for d in drives], model,
                      initial={k: 1.5 * v for k, v in truth.items()})
    got = {p.key: p.value for p in res.parameters}
    for key, value in truth.items():
        # the fit's RK4 steps at the sample rate (with the substeps the state's rate
        # needs), the simulator's at >= 4 kHz: their discretisations agree to 1e-4
        assert got[key] == pytest.approx(value, rel=1e-4), key
    assert max(s.nrmse for s in res.sessions) < 1e-4


def test_a_knee_no_drive_reached_is_unphysical():
    """A drop that is there at a knee at the top of its range (seed 1795997625: 1.9986
    m/s, a rise of 2e8 N s/m carried by a few peak samples) is no damper's knee; a side
    without a drop may sit there (one direction's knee only)."""
    eff = DigressiveDamping()
    std = {"compression_knee_mps": 0.01, "compression_drop_ns_per_m": 20.0,
           "rebound_knee_mps": 2e-13, "rebound_drop_ns_per_m": 4e6}
    vals = {"compression_knee_mps": 0.26, "compression_drop_ns_per_m": 176.0,
            "rebound_knee_mps": 1.9986, "rebound_drop_ns_per_m": -2.03e8}
    assert eff.unphysical(vals, std)
    # the same rebound knee with no drop there: a one-sided knee, physical
    assert not eff.unphysical({**vals, "rebound_drop_ns_per_m": 1.0e6}, std)
    # a knee within the speeds with its drop: physical
    assert not eff.unphysical({**vals, "rebound_knee_mps": 0.3,
                               "rebound_drop_ns_per_m": 216.0},
                              {**std, "rebound_drop_ns_per_m": 30.0})
    # no drop on either side: no knee
    assert eff.unphysical({**vals, "compression_drop_ns_per_m": 10.0,
                           "rebound_drop_ns_per_m": 1.0e6}, std)
