"""Tests of the quarter-car simulator (fielddiag.sim) against the physics."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy import integrate, signal

from fielddiag.errors import FieldDiagError
from fielddiag.sim import (
    EFFECTS,
    G_MPS2,
    AsymmetricDamping,
    BumpStop,
    CoulombFriction,
    CubicStiffness,
    HystereticSpring,
    InitialOffset,
    Pothole,
    QuadraticDamping,
    QuarterCarParams,
    SensorModel,
    SpeedBump,
    SpeedProfile,
    analytic_transmissibility,
    internal_rate_factor,
    iso8608_profile,
    iso8608_variance_m2,
    make_effect,
    simulate,
    simulate_from_dict,
    simulate_pair,
    static_state,
    suspension_force_n,
)

P = QuarterCarParams()


def h1(x: np.ndarray, y: np.ndarray, fs: float, nperseg: int) -> tuple[np.ndarray, np.ndarray]:
    kw = dict(fs=fs, nperseg=nperseg, noverlap=7 * nperseg // 8, window="hann")
    f, pxy = signal.csd(x, y, **kw)
    _, pxx = signal.welch(x, **kw)
    return f, pxy / pxx


def energy_j(params: QuarterCarParams, added_mass_kg: float, x1, v1, x2, v2) -> np.ndarray:
    """Mechanical energy about the unloaded equilibrium (flat road), incl. added-mass weight."""
    return (
        0.5 * params.wheel_mass_kg * v1**2
        + 0.5 * (params.body_mass_kg + added_mass_kg) * v2**2
        + 0.5 * params.tire_stiffness_n_per_m * x1**2
        + 0.5 * params.suspension_stiffness_n_per_m * (x2 - x1) ** 2
        + 0.5 * params.coupling_stiffness_n_per_m * x2**2
        + added_mass_kg * G_MPS2 * x2
    )


def drive_energy_j(d) -> np.ndarray:
    return energy_j(
        d.params, d.added_mass_kg, d.wheel_disp_m, d.wheel_vel_mps, d.body_disp_m, d.body_vel_mps
    )


# --------------------------------------------------------------------------- 1. linear model


@pytest.mark.parametrize(
    ("k3", "added_mass_kg"), [(0.0, 0.0), (8000.0, 0.0), (-6000.0, 0.0), (8000.0, 60.0)]
)
def test_transmissibility_matches_analytic(k3: float, added_mass_kg: float) -> None:
    # Stationary input (constant speed): Welch H1 then only carries its leakage noise
    # (~0.4 % at the body resonance for 300 s and 33 s segments).
    params = QuarterCarParams(coupling_stiffness_n_per_m=k3)
    d = simulate(
        params,
        duration_s=300.0,
        road_class="C",
        seed=11,
        added_mass_kg=added_mass_kg,
        speed=SpeedProfile.constant(20.0, 300.0),
    )
    assert d.sample_rate_hz == 500.0 and d.internal_rate_hz == 4000.0
    f, h = h1(d.wheel_accel_mps2, d.body_accel_mps2, 500.0, 2**14)
    band = (f >= 0.5) & (f <= 20.0)
    t = analytic_transmissibility(params, f[band], added_mass_kg)
    mag_err = np.abs(np.abs(h[band]) / np.abs(t) - 1.0)
    phase_err_deg = np.abs(np.degrees(np.angle(h[band] / t)))
    assert mag_err.max() < 0.01, f"max |H1|/|T| - 1 = {mag_err.max():.4f}"
    assert phase_err_deg.max() < 2.0


def test_body_natural_frequency() -> None:
    p = QuarterCarParams(coupling_stiffness_n_per_m=4000.0)
    assert p.body_natural_frequency_hz() == pytest.approx(math.sqrt(28e3 / 380) / (2 * math.pi))
    # undamped, wheel fixed: |T| peaks at the body frequency
    p0 = QuarterCarParams(suspension_damping_ns_per_m=1.0)
    f = np.linspace(0.5, 3.0, 25001)
    fpk = f[np.argmax(np.abs(analytic_transmissibility(p0, f)))]
    assert fpk == pytest.approx(p0.body_natural_frequency_hz(), rel=1e-3)


# --------------------------------------------------------------------------- 2. energy


def test_energy_conserved_without_damping() -> None:
    params = QuarterCarParams(
        tire_damping_ns_per_m=0.0,
        suspension_damping_ns_per_m=0.0,
        coupling_stiffness_n_per_m=5000.0,
    )
    dm = 50.0
    d = simulate(
        params,
        duration_s=10.0,
        road_class=None,
        seed=1,
        added_mass_kg=dm,
        speed=SpeedProfile.constant(10.0, 10.0),
        initial_offset=InitialOffset(
            wheel_disp_m=-0.01, body_disp_m=0.03, wheel_vel_mps=0.2, body_vel_mps=-0.1
        ),
    )
    x1, _, x2, _, _ = static_state(params, (), dm)
    e = drive_energy_j(d) - energy_j(params, dm, x1, 0.0, x2, 0.0)  # energy of the oscillation
    assert np.abs(d.body_vel_mps).max() > 0.1  # it does oscillate
    assert np.abs(e / e[0] - 1.0).max() < 1e-6


def test_energy_decrease_equals_damper_dissipation() -> None:
    params = QuarterCarParams(coupling_stiffness_n_per_m=3000.0)
    d = simulate(
        params,
        duration_s=10.0,
        road_class=None,
        seed=1,
        speed=SpeedProfile.constant(10.0, 10.0),
        sensor=SensorModel(output_rate_hz=4000),
        initial_offset=InitialOffset(wheel_disp_m=0.01, body_disp_m=0.05),
    )
    e = drive_energy_j(d)
    assert np.all(np.diff(e) <= 1e-12 * e[0])
    rdot = d.body_vel_mps - d.wheel_vel_mps
    power = (
        params.tire_damping_ns_per_m * d.wheel_vel_mps**2
        + params.suspension_damping_ns_per_m * rdot**2
    )
    dissipated = integrate.cumulative_simpson(power, x=d.time_s, initial=0.0)
    lost = e[0] - e
    assert lost[-1] > 0.99 * e[0]  # the motion has died out
    assert np.abs(lost[1:] - dissipated[1:]).max() < 1e-4 * lost[-1]


# --------------------------------------------------------------------------- 3. equilibrium


@pytest.mark.parametrize("k3", [0.0, 6000.0, -5000.0])
def test_static_equilibrium_with_added_mass(k3: float) -> None:
    params = QuarterCarParams(coupling_stiffness_n_per_m=k3)
    dm = 120.0
    d = simulate(
        params,
        duration_s=5.0,
        road_class=None,
        added_mass_kg=dm,
        seed=2,
        wheel_sensor=SensorModel(bias_mps2=0.3),
        body_sensor=SensorModel(),
    )
    k1, k2 = params.tire_stiffness_n_per_m, params.suspension_stiffness_n_per_m
    x2 = -dm * G_MPS2 * (k1 + k2) / (k1 * k2 + k1 * k3 + k2 * k3)
    if k3 == 0.0:
        assert x2 == pytest.approx(-dm * G_MPS2 * (1 / k2 + 1 / k1), rel=1e-12)
    x1 = -(k3 * x2 + dm * G_MPS2) / k1
    assert np.allclose(d.body_disp_m, x2, rtol=1e-10, atol=0)
    assert np.allclose(d.wheel_disp_m, x1, rtol=1e-10, atol=0)
    assert np.abs(d.body_vel_mps).max() < 1e-12 and np.abs(d.wheel_vel_mps).max() < 1e-12
    assert np.abs(d.body_accel_mps2 - G_MPS2).max() < 1e-12
    assert np.abs(d.wheel_accel_mps2 - (G_MPS2 + 0.3)).max() < 1e-12
    assert d.suspension_force_n == pytest.approx(k3 * x2 + dm * G_MPS2, rel=1e-9)


def test_static_equilibrium_on_bump_stop_and_cubic_spring() -> None:
    dm, gap, kb = 300.0, 0.02, 2e5
    d = simulate(
        P,
        duration_s=2.0,
        road_class=None,
        added_mass_kg=dm,
        seed=3,
        effects=[BumpStop(gap_m=gap, stiffness_n_per_m=kb)],
    )
    r = d.body_disp_m - d.wheel_disp_m
    k2 = P.suspension_stiffness_n_per_m
    assert dm * G_MPS2 / k2 > gap  # the linear spring alone would go through the gap
    assert np.allclose(-r, (dm * G_MPS2 + kb * gap) / (k2 + kb), rtol=1e-10, atol=0)
    assert np.abs(d.body_accel_mps2 - G_MPS2).max() < 1e-10
    k3c = 4e6
    s = static_state(P, [CubicStiffness(cubic_stiffness_n_per_m3=k3c)], added_mass_kg=dm)
    r = s[2] - s[0]
    assert k2 * r + k3c * r**3 == pytest.approx(-dm * G_MPS2, rel=1e-12)
    assert s[0] == pytest.approx(-dm * G_MPS2 / P.tire_stiffness_n_per_m, rel=1e-12)


def test_unstable_or_overloaded_corner_raises() -> None:
    with pytest.raises(FieldDiagError, match="coupling_stiffness"):
        simulate(
            QuarterCarParams(coupling_stiffness_n_per_m=-30e3),
            duration_s=1.0,
            road_class=None,
            seed=0,
        )
    with pytest.raises(FieldDiagError, match="wheel_mass_kg"):
        QuarterCarParams(wheel_mass_kg=-1.0)


# --------------------------------------------------------------------------- 4. ISO 8608


def test_iso8608_variance_matches_psd_integral() -> None:
    gd0, n0, lo, hi = 256e-6, 0.1, 0.01, 10.0
    expected = gd0 * n0**2 * (1 / lo - 1 / hi)
    assert iso8608_variance_m2("C") == pytest.approx(expected, rel=1e-12)
    variances = []
    for seed in range(5):
        x, h = iso8608_profile("C", 2000.0, seed=seed)
        assert x[1] - x[0] == pytest.approx(0.02) and x[-1] >= 2000.0
        variances.append(np.var(h))
    assert np.mean(variances) == pytest.approx(expected, rel=0.10)
    assert np.allclose(variances, expected, rtol=0.02)  # equal line powers: each realisation


def test_iso8608_class_ordering() -> None:
    stds = [np.std(iso8608_profile(c, 500.0, seed=4)[1]) for c in "ABCDEFGH"]
    assert np.all(np.diff(stds) > 0)
    assert np.allclose(np.array(stds[1:]) / stds[:-1], 2.0, rtol=1e-9)  # x4 PSD per class
    assert np.std(iso8608_profile("c", 500.0, seed=4)[1]) == stds[2]
    with pytest.raises(FieldDiagError, match="road class"):
        iso8608_profile("Z", 100.0)


@pytest.mark.parametrize("waviness", [2.0, 2.5])
def test_iso8608_psd_slope_and_level(waviness: float) -> None:
    x, h = iso8608_profile("D", 6000.0, seed=5, waviness=waviness)
    n, g = signal.welch(h, fs=1 / 0.02, nperseg=2**15)
    band = (n > 0.05) & (n < 5.0)
    slope = np.polyfit(np.log(n[band]), np.log(g[band]), 1)[0]
    assert slope == pytest.approx(-waviness, abs=0.05)
    level = np.exp(np.interp(np.log(0.1), np.log(n[band]), np.log(g[band])))
    assert level == pytest.approx(1024e-6, rel=0.2)


# --------------------------------------------------------------------------- 5. effects


def delta_force(effects, r, rdot, params=P):
    return suspension_force_n(r, rdot, params, effects) - suspension_force_n(r, rdot, params)


def test_effect_forces_as_specified() -> None:
    rd = np.array([-0.5, -0.01, 0.0, 0.01, 0.5])
    df = delta_force([CoulombFriction(friction_force_n=80.0)], 0.01, rd)
    assert np.allclose(df, -80.0 * np.tanh(rd / 0.01), rtol=1e-12, atol=1e-12)
    assert abs(df[-1]) == pytest.approx(80.0, rel=1e-12) and df[-1] < 0 < df[0]

    r = np.array([-0.08, -0.03, 0.0, 0.05])
    df = delta_force([CubicStiffness(cubic_stiffness_n_per_m3=3e6)], r, 0.2)
    assert np.allclose(df, -3e6 * r**3, rtol=1e-12)

    df = delta_force([BumpStop(gap_m=0.04, stiffness_n_per_m=1e5)], r, 0.0)
    assert np.allclose(df, [1e5 * 0.04, 0.0, 0.0, 0.0], rtol=1e-12, atol=1e-9)

    asym = [AsymmetricDamping(compression_damping_ns_per_m=1000.0, rebound_damping_ns_per_m=3000.0)]
    f = suspension_force_n(0.0, np.array([-0.3, 0.3]), P, asym)
    assert np.allclose(f, [300.0, -900.0], rtol=1e-12)  # C2 is replaced, not added
    assert f[1] / f[0] == pytest.approx(-3.0)

    df = delta_force([QuadraticDamping(damping_ns2_per_m2=2000.0)], 0.0, rd)
    assert np.allclose(df, -2000.0 * rd * np.abs(rd), rtol=1e-12)


def test_effects_compose() -> None:
    fr, asym = CoulombFriction(friction_force_n=60.0), AsymmetricDamping(800.0, 2400.0)
    r, rd = np.linspace(-0.1, 0.1, 7), np.linspace(-0.4, 0.4, 7)
    both = suspension_force_n(r, rd, P, [fr, asym])
    expect = suspension_force_n(r, rd, P, [asym]) + delta_force([fr], r, rd)
    assert np.allclose(both, expect, rtol=1e-12)
    cub, bump = CubicStiffness(2e6), BumpStop(0.03, 2e5)
    both = suspension_force_n(r, rd, P, [cub, bump])
    expect = suspension_force_n(r, rd, P) + delta_force([cub], r, rd) + delta_force([bump], r, rd)
    assert np.allclose(both, expect, rtol=1e-12)


def test_hysteretic_spring_loop() -> None:
    k_h, z_y = 20e3, 0.002
    hs = HystereticSpring(hysteretic_stiffness_n_per_m=k_h, yield_displacement_m=z_y)
    d = simulate(
        P,
        duration_s=30.0,
        road_class="D",
        seed=6,
        effects=[hs],
        speed=SpeedProfile.constant(15.0, 30.0),
    )
    z = d.hysteretic_state_m
    assert np.abs(z).max() <= z_y * (1 + 1e-6)
    assert np.abs(z).max() > 0.9 * z_y  # the loop saturates on a rough road
    r = d.suspension_extension_m
    rd = d.body_vel_mps - d.wheel_vel_mps
    f = suspension_force_n(r, rd, P, [hs], z)
    assert np.allclose(d.suspension_force_n, f, rtol=1e-12, atol=1e-9)
    # dissipation: the hysteretic force does net negative work on the suspension motion
    work = integrate.trapezoid(-k_h * z * rd, d.time_s)
    assert work < 0


def test_simulated_force_obeys_equations_with_effects() -> None:
    effects = [
        CoulombFriction(80.0, 0.02),
        AsymmetricDamping(1200.0, 2600.0),
        CubicStiffness(1e6),
        BumpStop(0.03, 3e5),
        QuadraticDamping(500.0),
    ]
    dm, params = 40.0, QuarterCarParams(coupling_stiffness_n_per_m=2000.0)
    d = simulate(
        params,
        duration_s=20.0,
        road_class="D",
        seed=7,
        effects=effects,
        added_mass_kg=dm,
        road_events=[Pothole(60.0, depth_m=0.06)],
        speed=SpeedProfile.constant(12.0, 20.0),
    )
    r, rd = d.suspension_extension_m, d.body_vel_mps - d.wheel_vel_mps
    assert (-r).max() > 0.03  # the bump stop was hit
    fs = suspension_force_n(r, rd, params, effects)
    assert np.allclose(d.suspension_force_n, fs, rtol=1e-12, atol=1e-9)
    m2 = params.body_mass_kg + dm
    lhs = m2 * d.body_acc_true_mps2
    rhs = fs - params.coupling_stiffness_n_per_m * d.body_disp_m - dm * G_MPS2
    assert np.abs(lhs - rhs).max() < 1e-9 * np.abs(fs).max()
    lin = simulate(
        params,
        duration_s=20.0,
        road_class="D",
        seed=7,
        added_mass_kg=dm,
        road_events=[Pothole(60.0, depth_m=0.06)],
        speed=SpeedProfile.constant(12.0, 20.0),
    )
    assert np.array_equal(lin.road_m, d.road_m)
    assert np.abs(lin.suspension_force_n - d.suspension_force_n).max() > 50.0


def test_make_effect_and_errors() -> None:
    assert set(EFFECTS) >= {
        "coulomb_friction",
        "cubic_stiffness",
        "bump_stop",
        "asymmetric_damping",
        "quadratic_damping",
        "hysteretic_spring",
        "bouc_wen",
        "digressive_damping",
        "series_top_mount",
        "travel_dependent_damping",
    }
    e = make_effect("coulomb_friction", friction_force_n="80")
    assert e == CoulombFriction(friction_force_n=80.0, smoothing_velocity_mps=0.01)
    assert make_effect(**{"name": e.name, **e.to_dict()["params"]}) == e
    json.dumps(e.to_dict())
    with pytest.raises(FieldDiagError, match="valid effects.*bump_stop"):
        make_effect("magic_damper", x=1)
    with pytest.raises(FieldDiagError, match="gap_m"):
        make_effect("bump_stop", gap=0.02, stiffness_n_per_m=1e5)
    with pytest.raises(FieldDiagError, match="missing"):
        make_effect("bump_stop", gap_m=0.02)
    with pytest.raises(FieldDiagError, match="not a number"):
        make_effect("cubic_stiffness", cubic_stiffness_n_per_m3="lots")
    with pytest.raises(FieldDiagError, match="friction_force_n"):
        make_effect("coulomb_friction", friction_force_n=-5)
    with pytest.raises(FieldDiagError, match="twice"):
        simulate(duration_s=1.0, effects=[CubicStiffness(1e6), CubicStiffness(2e6)])


def test_step_is_refined_for_stiff_effects() -> None:
    stiff = [CoulombFriction(80.0, smoothing_velocity_mps=1e-4)]
    k = internal_rate_factor(500.0, P, stiff)
    assert k * 500.0 * 0.5 >= 80.0 / 1e-4 / P.wheel_mass_kg
    assert internal_rate_factor(500.0, P) == 8 and internal_rate_factor(333.0, P) == 13
    d = simulate(
        P,
        duration_s=10.0,
        road_class="C",
        seed=8,
        effects=stiff,
        road_events=[SpeedBump(40.0, height_m=0.1)],
        speed=SpeedProfile.constant(8.0, 10.0),
    )
    assert d.internal_rate_hz == k * 500.0
    assert np.all(np.isfinite(d.body_accel_mps2)) and np.abs(d.suspension_extension_m).max() < 0.2


# --------------------------------------------------------------------------- 6. sensors


def drive(**kw):
    base = dict(duration_s=40.0, road_class="D", seed=9, speed=SpeedProfile.constant(15.0, 40.0))
    return simulate(P, **{**base, **kw})


def test_sensor_bias_and_drift() -> None:
    s = SensorModel(bias_mps2=0.25, bias_drift_mps2_per_s=0.01)
    d = simulate(P, duration_s=20.0, road_class=None, seed=0, sensor=s)
    slope, icpt = np.polyfit(d.time_s[50:], d.body_accel_mps2[50:], 1)
    assert slope == pytest.approx(0.01, rel=1e-6)
    # the causal anti-alias filter delays the ramp by its DC group delay (~2 ms)
    assert icpt == pytest.approx(G_MPS2 + 0.25, abs=0.01 * 5e-3)
    assert d.wheel_accel_mps2[0] == pytest.approx(G_MPS2 + 0.25, abs=1e-12)


def test_sensor_gain_clip_quantisation() -> None:
    ref = drive()
    g = drive(sensor=SensorModel(gain=1.05))
    assert np.allclose(
        g.body_accel_mps2 - 1.05 * G_MPS2, 1.05 * (ref.body_accel_mps2 - G_MPS2), rtol=0, atol=1e-9
    )
    clip = 25.0
    c = drive(sensor=SensorModel(clip_mps2=clip))
    w = ref.wheel_accel_mps2
    outside = np.abs(w) > clip
    assert outside.mean() > 0.002
    assert np.abs(c.wheel_accel_mps2).max() == pytest.approx(clip)
    assert np.array_equal(c.wheel_accel_mps2[~outside], w[~outside])
    assert np.array_equal(c.wheel_accel_mps2[outside], np.sign(w[outside]) * clip)
    step = 0.05
    q = drive(sensor=SensorModel(quantization_step_mps2=step))
    k = q.body_accel_mps2 / step
    assert np.abs(k - np.round(k)).max() < 1e-6
    assert np.abs(q.body_accel_mps2 - ref.body_accel_mps2).max() <= step / 2 + 1e-12
    assert np.unique(q.body_accel_mps2).size > 20


def test_sensor_time_offset() -> None:
    ref = drive()
    d = drive(body_sensor=SensorModel(time_offset_s=0.004))  # 2 output samples
    assert np.array_equal(d.wheel_accel_mps2, ref.wheel_accel_mps2)
    assert np.allclose(d.body_accel_mps2[2:], ref.body_accel_mps2[:-2], rtol=0, atol=1e-12)
    tau = 0.0013
    d = drive(body_sensor=SensorModel(time_offset_s=tau))
    f, h = h1(ref.body_accel_mps2, d.body_accel_mps2, 500.0, 4096)
    band = (f > 0.5) & (f < 30.0)
    phase = np.unwrap(np.angle(h[band]))
    est = -np.polyfit(2 * np.pi * f[band], phase, 1)[0]
    assert est == pytest.approx(tau, rel=0.02)
    assert np.abs(np.abs(h[band]) - 1).max() < 0.01


def test_sensor_noise_levels_and_antialias_filter() -> None:
    ref = drive()
    d = drive(sensor=SensorModel(snr_db=20.0))
    for read, base, true in (
        (d.body_accel_mps2, ref.body_accel_mps2, d.body_acc_true_mps2),
        (d.wheel_accel_mps2, ref.wheel_accel_mps2, d.wheel_acc_true_mps2),
    ):
        noise = read - base
        assert np.std(noise) == pytest.approx(np.std(true) / 10.0, rel=0.02)
    n = drive(sensor=SensorModel(noise_std_mps2=0.05))
    noise = n.body_accel_mps2 - ref.body_accel_mps2
    assert np.std(noise) == pytest.approx(0.05, rel=0.02)
    # noise is white up to Nyquist, added after the filter; the signal is cut above 200 Hz
    f, pn = signal.welch(noise, fs=500.0, nperseg=1024)
    assert np.mean(pn[(f > 225) & (f < 245)]) / np.mean(pn[(f > 10) & (f < 50)]) == (
        pytest.approx(1.0, rel=0.2)
    )
    # anti-alias filter response: true wheel acceleration -> reading
    s = SensorModel(anti_alias_cutoff_ratio=0.1)  # 50 Hz cutoff
    a = drive(sensor=s)
    f, h = h1(a.wheel_acc_true_mps2, a.wheel_accel_mps2, 500.0, 2048)
    band = (f > 2) & (f < 100)
    sos = signal.butter(4, 50.0, fs=a.internal_rate_hz, output="sos")
    _, expect = signal.sosfreqz(sos, worN=f[band], fs=a.internal_rate_hz)
    assert np.abs(np.abs(h[band]) / np.abs(expect) - 1).max() < 0.02
    assert np.abs(np.angle(h[band] / expect)).max() < np.radians(2.0)


def test_sensor_validation() -> None:
    with pytest.raises(FieldDiagError, match="not both"):
        SensorModel(noise_std_mps2=0.1, snr_db=30.0)
    with pytest.raises(FieldDiagError, match="anti_alias_cutoff_ratio"):
        SensorModel(anti_alias_cutoff_ratio=0.6)
    with pytest.raises(FieldDiagError, match="output_rate_hz"):
        simulate(duration_s=1.0, wheel_sensor=SensorModel(output_rate_hz=1000.0))


# --------------------------------------------------------------------------- speed, events


def test_speed_profile() -> None:
    sp = SpeedProfile([0.0, 10.0, 15.0, 30.0], [10.0, 10.0, 20.0, 5.0])
    t = np.linspace(0, 40, 400001)
    d_num = integrate.cumulative_trapezoid(sp.speed_mps(t), t, initial=0.0)
    assert np.abs(sp.distance_m(t) - d_num).max() < 1e-6
    assert sp.speed_mps(35.0) == 5.0 and sp.distance_m(40.0) == pytest.approx(100 + 75 + 187.5 + 50)
    for dist in (5.0, 120.0, 300.0, 400.0):
        assert sp.distance_m(sp.time_at_distance_s(dist)) == pytest.approx(dist, rel=1e-12)
    rd = SpeedProfile.random_drive(
        600.0, seed=3, min_speed_mps=5, max_speed_mps=25, max_accel_mps2=2.0
    )
    v = rd.knot_speed_mps
    assert rd.knot_time_s[-1] == 600.0 and v.min() >= 5.0 and v.max() <= 25.0
    assert np.abs(np.diff(v) / np.diff(rd.knot_time_s)).max() <= 2.0 + 1e-9
    assert np.sum(np.diff(v) == 0) >= 5  # cruise segments
    with pytest.raises(FieldDiagError):
        SpeedProfile([0.0, 1.0, 1.0], [1.0, 2.0, 3.0])


def test_events_and_can_speed() -> None:
    bump, hole = SpeedBump(50.0), Pothole(120.0, depth_m=0.05)
    d = simulate(
        P,
        duration_s=20.0,
        road_class=None,
        seed=1,
        speed=SpeedProfile.constant(10.0, 20.0),
        road_events=[bump, hole, SpeedBump(1e4)],
    )
    times = [e.time_s for e in d.events]
    assert times[0] == pytest.approx(5.0) and times[1] == pytest.approx(12.0)
    assert times[2] is None
    assert d.road_m.max() == pytest.approx(0.07, rel=1e-6)
    assert d.road_m.min() == pytest.approx(-0.05, rel=1e-6)
    assert d.time_s[np.argmax(d.road_m)] == pytest.approx(5.0, abs=1e-9)
    x = np.linspace(49.0, 51.0, 2001)
    prof = bump.height_profile_m(x)
    assert prof[np.abs(x - 50) > 0.25].max() == 0.0 and prof.max() == pytest.approx(0.07)
    rd = simulate(P, duration_s=30.0, road_class=None, seed=4, can_speed_rate_hz=50.0)
    assert rd.vehicle_speed_time_s[1] == pytest.approx(0.02)
    kmh = rd.vehicle_speed_mps * 3.6
    assert np.abs(kmh / 0.01 - np.round(kmh / 0.01)).max() < 1e-6
    assert np.abs(rd.vehicle_speed_mps - rd.speed.speed_mps(rd.vehicle_speed_time_s)).max() <= (
        0.005 / 3.6 + 1e-12
    )


def test_road_rate_is_derivative_of_road_height() -> None:
    # udot enters only the tyre damper: recover it from the wheel equation and integrate it
    d = simulate(
        P,
        duration_s=10.0,
        road_class="C",
        seed=3,
        sensor=SensorModel(output_rate_hz=4000),
        speed=SpeedProfile([0.0, 5.0, 10.0], [8.0, 12.0, 12.0]),
    )
    udot = (
        P.wheel_mass_kg * d.wheel_acc_true_mps2
        + d.suspension_force_n
        - P.tire_stiffness_n_per_m * (d.road_m - d.wheel_disp_m)
    ) / P.tire_damping_ns_per_m
    udot += d.wheel_vel_mps
    u = d.road_m[0] + integrate.cumulative_simpson(udot, x=d.time_s, initial=0.0)
    assert np.abs(u - d.road_m).max() < 0.005 * np.std(d.road_m)


def test_simulate_argument_errors() -> None:
    with pytest.raises(FieldDiagError, match="two samples"):
        simulate(duration_s=0.001)
    with pytest.raises(FieldDiagError, match="seed"):
        simulate(duration_s=1.0, seed=-3)
    with pytest.raises(FieldDiagError, match="SpeedProfile"):
        simulate(duration_s=1.0, speed=12.0)
    with pytest.raises(FieldDiagError, match="road class"):
        simulate(duration_s=1.0, road_class="Q")


# --------------------------------------------------------------------------- 7. determinism


def test_determinism_metadata_and_pair() -> None:
    kw = dict(
        duration_s=20.0,
        road_class="C",
        sensor=SensorModel(snr_db=30.0),
        effects=[CoulombFriction(50.0)],
        road_events=[SpeedBump(100.0)],
    )
    a, b, c = simulate(seed=5, **kw), simulate(seed=5, **kw), simulate(seed=6, **kw)
    for name in (
        "wheel_accel_mps2",
        "body_accel_mps2",
        "road_m",
        "body_disp_m",
        "vehicle_speed_mps",
    ):
        assert np.array_equal(getattr(a, name), getattr(b, name))
        assert not np.array_equal(getattr(a, name), getattr(c, name))
    meta = json.loads(json.dumps(a.to_dict()))
    assert meta["seed"] == 5 and meta["effects"][0]["name"] == "coulomb_friction"
    assert meta["road_events"][0]["time_s"] == pytest.approx(a.events[0].time_s)
    again = simulate_from_dict(meta)
    assert np.array_equal(again.body_accel_mps2, a.body_accel_mps2)
    unseeded = simulate(duration_s=1.0)
    assert np.array_equal(simulate(duration_s=1.0, seed=unseeded.seed).road_m, unseeded.road_m)

    before, after = simulate_pair(P, added_mass_kg=80.0, seed=42, duration_s=10.0)
    assert before.added_mass_kg == 0.0 and after.added_mass_kg == 80.0
    assert before.seed != after.seed and before.params == after.params
    assert not np.array_equal(before.road_m, after.road_m)
    b2, a2 = simulate_pair(P, added_mass_kg=80.0, seed=42, duration_s=10.0)
    assert np.array_equal(a2.body_accel_mps2, after.body_accel_mps2)
