"""Output-only identification on simulated drives: accuracy, honest std, refusals, CLI.

Tolerances come from the issue (M2 2 %, K2 3 %, C2 10 %) and from the reported standard
deviations (truth within 3 std). Drives are simulated with fielddiag.sim (quarter car,
ISO 8608 road, sensors with anti-alias filter, white noise, bias and drift).
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from PIL import Image

from fielddiag import dsp
from fielddiag.cli import main as cli_main
from fielddiag.errors import ChannelNotFoundError, InsufficientDataError
from fielddiag.identify import (
    IdentificationResult,
    IdentifyConfig,
    Recording,
    identify_recordings,
    identify_sessions,
)
from fielddiag.sim import QuarterCarParams, SensorModel, analytic_transmissibility, simulate_pair
from fielddiag.simio import drive_to_session

TRUTH = QuarterCarParams()
BUDGET = {"sprung_mass_kg": ("body_mass_kg", 0.02),
          "suspension_stiffness_n_per_m": ("suspension_stiffness_n_per_m", 0.03),
          "suspension_damping_ns_per_m": ("suspension_damping_ns_per_m", 0.10)}
QUICK = IdentifyConfig(time_route=False, display=False)


def _pair(params=TRUTH, *, dm, seed, duration=120.0, rate=500.0, snr=30.0, road="C",
          bias=0.3, **kw):
    sensor = SensorModel(output_rate_hz=rate, snr_db=snr, bias_mps2=bias,
                         bias_drift_mps2_per_s=2e-4)
    return simulate_pair(params, added_mass_kg=dm, seed=seed, duration_s=duration,
                         road_class=road, sensor=sensor, **kw)


def _recs(before, after):
    fs = before.sample_rate_hz
    return (Recording(before.wheel_accel_mps2, before.body_accel_mps2, fs),
            Recording(after.wheel_accel_mps2, after.body_accel_mps2, fs))


def _check_within_budget_and_std(res: IdentificationResult, params: QuarterCarParams):
    truth = params.to_dict()
    for key, (tkey, budget) in BUDGET.items():
        est = getattr(res, key)
        err = est.value / truth[tkey] - 1
        assert abs(err) <= budget, f"{key}: {est} vs {truth[tkey]} ({100 * err:.2f} %)"
        assert abs(est.value - truth[tkey]) <= 3 * est.std, f"{key}: {est} vs {truth[tkey]}"


# ---------------------------------------------------------------------------------------
# accuracy and the errors-in-variables trap
# ---------------------------------------------------------------------------------------

CASES = [
    # (params, added mass fraction, rate, snr, road, duration, seed)
    (TRUTH, 0.10, 200.0, 25.0, "C", 240.0, 1),
    (TRUTH, 0.30, 500.0, 30.0, "B", 120.0, 2),
    (QuarterCarParams(body_mass_kg=520, suspension_stiffness_n_per_m=35e3,
                      suspension_damping_ns_per_m=2500, wheel_mass_kg=50), 0.08, 1000.0, 40.0,
     "C", 150.0, 3),
    (QuarterCarParams(body_mass_kg=260, suspension_stiffness_n_per_m=16e3,
                      suspension_damping_ns_per_m=900), 0.20, 500.0, 25.0, "B", 180.0, 4),
]


@pytest.mark.parametrize("params,frac,rate,snr,road,duration,seed", CASES)
def test_identifies_mass_stiffness_damping_within_budget(params, frac, rate, snr, road,
                                                         duration, seed):
    dm = frac * params.body_mass_kg
    b, a = _pair(params, dm=dm, seed=seed, duration=duration, rate=rate, snr=snr, road=road)
    res = identify_recordings(*_recs(b, a), dm, config=IdentifyConfig(display=False))
    _check_within_budget_and_std(res, params)
    assert not res.k3_included  # K3 = 0 in truth
    assert not [w for w in res.warnings if "not linear" in w]  # no false alarm
    # the two routes agree within their uncertainties
    assert max(res.route_agreement[k] for k in BUDGET) < 3.0
    fn = params.body_natural_frequency_hz()
    assert abs(res.body_natural_frequency_hz.value - fn) <= max(
        3 * res.body_natural_frequency_hz.std, 0.005 * fn)


def _ols_stacked_h1(before, after, dm, band):
    """The naive route: T = H1 per line, stack the linear equations, ordinary LS."""
    rows, rhs = [], []
    for d, m in ((before, 0.0), (after, dm)):
        sp = dsp.block_cross_spectra(d.wheel_accel_mps2, d.body_accel_mps2, d.sample_rate_hz,
                                     segment_s=10.0, n_blocks=1).total()
        sel = (sp.freq_hz >= band[0]) & (sp.freq_hz <= band[1])
        t, w = sp.h1[sel], 2 * np.pi * sp.freq_hz[sel]
        a = np.column_stack([-w * w * t, t - 1, 1j * w * (t - 1)]) / np.abs(w * w * t)[:, None]
        rows.append(a)
        rhs.append(w * w * m * t / np.abs(w * w * t))
    a, b = np.concatenate(rows), np.concatenate(rhs)
    return np.linalg.lstsq(np.vstack([a.real, a.imag]), np.concatenate([b.real, b.imag]),
                           rcond=None)[0]


def _ols_time_domain(before, after, dm, band):
    """The naive time route: M2 a2 + K2 r + C2 rdot = -dM a2 by ordinary LS."""
    mom = np.zeros((3, 3))
    rhs = np.zeros(3)
    for d, m in ((before, 0.0), (after, dm)):
        w, bd = dsp.integrate_pair(d.wheel_accel_mps2, d.body_accel_mps2, d.sample_rate_hz, band)
        z = np.column_stack([bd.acceleration_mps2, bd.displacement_m - w.displacement_m,
                             bd.velocity_mps - w.velocity_mps])[500:-500]
        mom += z.T @ z
        rhs += -m * (z.T @ z[:, 0])
    return np.linalg.solve(mom, rhs)


def test_wheel_noise_biases_ols_and_h1_but_not_the_estimator_at_200_hz():
    """The errors-in-variables trap: at 200 Hz, 25 dB, 10 % added mass, noise on the wheel
    (the model's input) drives ordinary least squares and H1 far below the true mass; the
    errors-in-variables estimator stays within the budget and within 3 std."""
    dm = 38.0
    b, a = _pair(dm=dm, seed=11, duration=300.0, rate=200.0, snr=25.0)
    res = identify_recordings(*_recs(b, a), dm, config=IdentifyConfig(display=False))
    _check_within_budget_and_std(res, TRUTH)
    band = (res.band_hz.low_hz, res.band_hz.high_hz)
    m2_h1 = _ols_stacked_h1(b, a, dm, band)[0]
    m2_td = _ols_time_domain(b, a, dm, band)[0]
    assert m2_h1 < 0.9 * TRUTH.body_mass_kg  # more than 5x the 2 % budget, low
    assert m2_td < 0.9 * TRUTH.body_mass_kg
    # per line: H1 is biased low where the wheel is weak (below ~1 Hz); H-v is not
    tr = res.transmissibility[0]
    f = np.asarray(tr.freq_hz)
    t_true = analytic_transmissibility(TRUTH, f)
    low = (f >= band[0]) & (f <= 0.8)
    ratio_h1 = np.abs(tr.h1.array()[low]) / np.abs(t_true[low])
    ratio_hv = np.abs(tr.hv.array()[low]) / np.abs(t_true[low])
    assert np.median(ratio_h1) < 0.95
    assert abs(np.median(ratio_hv) - 1) < 0.02


def test_std_is_calibrated_quick_monte_carlo():
    """20 short drives (random cars, 200/500 Hz, 25-40 dB, roads B/C, 8-30 % mass): for
    each of M2, K2 and C2 the truth lies within 3 std in at least 18 (the 100-drive run is
    in benchmarks/), and the
    std is not inflated to get there (median relative std of M2 below 1.5 %)."""
    rng = np.random.default_rng(77)
    inside, rel_std, n = dict.fromkeys(BUDGET, 0), [], 20
    for _ in range(n):
        m2, k2, zeta = rng.uniform(250, 550), rng.uniform(15e3, 40e3), rng.uniform(0.2, 0.4)
        p = QuarterCarParams(body_mass_kg=m2, suspension_stiffness_n_per_m=k2,
                             suspension_damping_ns_per_m=2 * zeta * math.sqrt(k2 * m2))
        dm = m2 * rng.uniform(0.08, 0.3)
        b, a = _pair(p, dm=dm, seed=int(rng.integers(1e9)), duration=120.0,
                     rate=float(rng.choice([200.0, 500.0])), snr=rng.uniform(25, 40),
                     road=str(rng.choice(["B", "C"])))
        res = identify_recordings(*_recs(b, a), dm, config=QUICK)
        truth = p.to_dict()
        for key, (tkey, _) in BUDGET.items():
            est = getattr(res, key)
            inside[key] += abs(est.value - truth[tkey]) <= 3 * est.std
        rel_std.append(res.sprung_mass_kg.relative_std)
    assert min(inside.values()) >= 18, inside
    assert np.median(rel_std) < 0.015


def test_std_grows_with_a_small_added_mass_instead_of_a_confident_wrong_answer():
    b, a = _pair(dm=11.4, seed=21, duration=200.0, rate=200.0, snr=25.0)
    small = identify_recordings(*_recs(b, a), 11.4, config=QUICK)  # 3 % of M2
    b2, a2 = _pair(dm=57.0, seed=21, duration=200.0, rate=200.0, snr=25.0)
    large = identify_recordings(*_recs(b2, a2), 57.0, config=QUICK)  # 15 % of M2
    # the mass information scales with dM/M2: 5x less mass -> std several times larger
    assert small.sprung_mass_kg.std > 3 * large.sprung_mass_kg.std
    assert small.sprung_mass_kg.relative_std > 0.01
    assert abs(small.sprung_mass_kg.value - 380) <= 3 * small.sprung_mass_kg.std
    assert any("uncertain" in w for w in small.warnings) or small.sprung_mass_kg.relative_std < 0.02


def test_std_grows_for_a_noisy_200_hz_recording():
    """The same car, road and seed recorded at 1000 Hz / 40 dB and at 200 Hz / 20 dB: the
    noisy recording's std is clearly larger and a warning says what to record instead, and
    the truth stays within 3 std in both (less certain, not confidently wrong)."""
    res = {}
    for rate, snr in ((1000.0, 40.0), (200.0, 20.0)):
        b, a = _pair(dm=40.0, seed=41, duration=150.0, rate=rate, snr=snr)
        res[rate] = identify_recordings(*_recs(b, a), 40.0, config=QUICK)
    truth = TRUTH.to_dict()
    for key, (tkey, _) in BUDGET.items():
        clean, noisy = getattr(res[1000.0], key), getattr(res[200.0], key)
        assert noisy.std > 5 * clean.std, f"{key}: {noisy} vs {clean}"  # ~25x measured
        for est in (clean, noisy):
            assert abs(est.value - truth[tkey]) <= 3 * est.std, f"{key}: {est}"
    assert not res[1000.0].warnings
    assert any("sprung mass is uncertain" in w for w in res[200.0].warnings)


def test_transmissibility_peaks_and_estimators():
    """Each session's transmissibility peaks at the analytic body resonance (within one
    frequency line), the peak moves down with the added mass, and where coherence is
    below 1 the estimators bracket the truth as theory says: H1 (noise on the wheel
    input) low, H2 and H-v not."""
    dm = 57.0
    b, a = _pair(dm=dm, seed=31, duration=120.0, rate=500.0, snr=25.0)
    res = identify_recordings(*_recs(b, a), dm, config=QUICK)
    fine = np.linspace(0.3, 5.0, 20001)
    peaks = []
    for tr, mass in zip(res.transmissibility, (0.0, dm), strict=True):
        p = QuarterCarParams(body_mass_kg=TRUTH.body_mass_kg + mass)
        f_true = fine[np.argmax(np.abs(analytic_transmissibility(p, fine)))]
        f_peak = tr.peaks[0].freq_hz
        assert abs(f_peak - f_true) <= 1.0 / tr.segment_s, (tr.label, f_peak, f_true)
        peaks.append(f_peak)
        f = np.asarray(tr.freq_hz)
        low = (f >= res.band_hz.low_hz) & (f <= 3.0)
        t_true = np.abs(analytic_transmissibility(p, f[low]))
        assert np.median(np.asarray(tr.coherence)[low]) < 0.99
        assert np.median(np.abs(tr.h1.array()[low]) / t_true) < 0.99
        assert abs(np.median(np.abs(tr.hv.array()[low]) / t_true) - 1) < 0.02
        # |H1| = coherence * |H2| line by line (Welch estimates)
        np.testing.assert_allclose(np.abs(tr.h1.array()),
                                   np.asarray(tr.coherence) * np.abs(tr.h2.array()),
                                   rtol=1e-6)
    assert peaks[1] < peaks[0]


@pytest.mark.parametrize("name", ["cubic_1", "small_cubic"])
def test_a_nonlinear_suspension_is_flagged_not_reported_as_linear(name):
    """A progressive spring biases the linear answer far beyond its std (cubic_1: M2
    about 420 +- 2 kg against 380); the time route's residual, many times the sensor
    noise, gives it away and the warning sends the user to the diagnosis."""
    from fielddiag.scenarios import SCENARIOS, simulate_scenario

    sc = SCENARIOS[name]
    b, a = simulate_scenario(sc)
    res = identify_recordings(*_recs(b, a), sc.added_mass_kg,
                              config=IdentifyConfig(display=False))
    flagged = [w for w in res.warnings if "times the sensor noise" in w]
    assert len(flagged) == 1 and "fielddiag diagnose" in flagged[0]
    assert "not linear" in flagged[0]


@pytest.mark.parametrize("seed", [11, 12])
def test_a_clean_linear_car_at_high_snr_is_not_flagged(seed):
    """At 45 dB the sensor noise is tiny and a linear car leaves 1.5-1.9 times it (model
    details far below the signal: ~1e-5 of its power); the warning needs the excess to be
    a material share (1e-4) of the signal as well, which every catalogue effect reaches
    (small_cubic, the weakest, 1.9e-4)."""
    b, a = _pair(dm=60.0, seed=seed, duration=150.0, rate=800.0, snr=45.0, road="D")
    res = identify_recordings(*_recs(b, a), 60.0, config=IdentifyConfig(display=False))
    assert not [w for w in res.warnings if "times the sensor noise" in w]
    assert res.sprung_mass_kg.value == pytest.approx(TRUTH.body_mass_kg, rel=0.01)


def test_coupling_stiffness_is_kept_only_when_the_data_call_for_it():
    p = QuarterCarParams(coupling_stiffness_n_per_m=-0.3 * 24e3)
    b, a = _pair(p, dm=60.0, seed=5, duration=150.0)
    res = identify_recordings(*_recs(b, a), 60.0, config=QUICK)
    assert res.k3_included
    k3 = res.coupling_stiffness_n_per_m
    assert abs(k3.value - p.coupling_stiffness_n_per_m) <= max(3 * k3.std, 0.05 * 7200)
    _check_within_budget_and_std(res, p)
    fn = p.body_natural_frequency_hz()
    assert res.body_natural_frequency_hz.value == pytest.approx(fn, rel=0.01)


# ---------------------------------------------------------------------------------------
# refusals
# ---------------------------------------------------------------------------------------


def test_refuses_a_drive_that_is_too_short():
    b, a = _pair(dm=60.0, seed=1, duration=20.0)
    with pytest.raises(InsufficientDataError, match="lasts only 20.0 s"):
        identify_recordings(*_recs(b, a), 60.0)


def test_refuses_without_road_excitation():
    sensor = SensorModel(output_rate_hz=500.0, noise_std_mps2=0.05)
    b, a = simulate_pair(TRUTH, added_mass_kg=60.0, seed=2, duration_s=60.0, road_class=None,
                         sensor=sensor)
    with pytest.raises(InsufficientDataError, match="hardly rises above its noise floor"):
        identify_recordings(*_recs(b, a), 60.0)


def test_refuses_when_body_and_wheel_are_not_coherent():
    b, a = _pair(dm=60.0, seed=3, duration=60.0)
    b2, a2 = _pair(dm=60.0, seed=4, duration=60.0)
    fs = b.sample_rate_hz
    # body channels from other drives: strong signals, no relation to these wheels
    before = Recording(b.wheel_accel_mps2, b2.body_accel_mps2, fs)
    after = Recording(a.wheel_accel_mps2, a2.body_accel_mps2, fs)
    with pytest.raises(InsufficientDataError, match="not coherent enough"):
        identify_recordings(before, after, 60.0)


def test_refuses_an_added_mass_too_small_for_the_noise():
    b, a = _pair(dm=1.0, seed=6, duration=60.0, rate=200.0, snr=20.0)
    with pytest.raises(InsufficientDataError, match="cannot be resolved") as exc:
        identify_recordings(*_recs(b, a), 1.0, config=QUICK)
    assert "add about" in str(exc.value)


def test_refuses_a_missing_or_zero_added_mass():
    b, a = _pair(dm=60.0, seed=1, duration=40.0)
    with pytest.raises(InsufficientDataError, match="positive number of kg"):
        identify_recordings(*_recs(b, a), 0.0)


# ---------------------------------------------------------------------------------------
# sessions, command line, JSON, plots, restoring force
# ---------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def session_pair(tmp_path_factory):
    d = tmp_path_factory.mktemp("identify")
    b, a = _pair(dm=60.0, seed=8, duration=150.0, rate=500.0, snr=30.0)
    return (drive_to_session(b, d / "before.h5"), drive_to_session(a, d / "after.h5"), d)


def test_cli_identify_writes_json_and_plots(session_pair, capsys):
    before, after, d = session_pair
    out, plots = d / "out.json", d / "plots"
    rc = cli_main(["identify", str(before), str(after), "--added-mass", "60", "--json", str(out),
                   "--plots", str(plots)])
    assert rc == 0
    text = capsys.readouterr().out
    assert "sprung mass M2" in text and "Band" in text
    data = json.loads(out.read_text())
    for key in ("sprung_mass_kg", "suspension_stiffness_n_per_m", "suspension_damping_ns_per_m",
                "coupling_stiffness_n_per_m", "body_natural_frequency_hz"):
        assert set(data[key]) == {"value", "std"}
        assert isinstance(data[key]["value"], float) and data[key]["std"] >= 0
    assert data["sprung_mass_kg"]["value"] == pytest.approx(380, rel=0.02)
    assert data["band_hz"]["source"] == "data"
    assert 0 < data["band_hz"]["low_hz"] < 1.0 < data["band_hz"]["high_hz"]
    assert data["coherence"]["before"] > 0.9
    for name in ("transmissibility.png", "restoring_force.png", "hysteresis.png"):
        img = Image.open(plots / name)
        assert img.size[0] >= 600 and img.size[1] >= 400
        # not a blank canvas: many distinct colours
        assert len(img.convert("RGB").getcolors(maxcolors=1_000_000)) > 200


def test_cli_band_override_and_metadata_mass(session_pair, capsys):
    before, after, d = session_pair
    out = d / "band.json"
    # --added-mass omitted: taken from the sessions' added_mass_kg (0 and 60)
    rc = cli_main(["identify", str(before), str(after), "--band", "0.5", "20", "--json",
                   str(out)])
    assert rc == 0
    data = json.loads(out.read_text())
    assert data["band_hz"]["low_hz"] == 0.5 and data["band_hz"]["high_hz"] == 20.0
    assert data["band_hz"]["source"] == "user"
    assert data["added_mass_kg"] == 60.0
    assert data["sprung_mass_kg"]["value"] == pytest.approx(380, rel=0.02)


def test_cli_refusal_is_one_line_and_exit_1(session_pair, tmp_path, capsys):
    before, after, _ = session_pair
    rc = cli_main(["identify", str(before), str(after), "--added-mass", "60", "--band", "5",
                   "400"])
    assert rc == 1
    err = capsys.readouterr().err
    assert "error:" in err and "--band" in err and "Traceback" not in err


def test_result_json_round_trip(session_pair):
    before, after, _ = session_pair
    res = identify_sessions(before, after, added_mass_kg=60.0)
    back = IdentificationResult.from_json(res.to_json())
    assert back.to_dict() == res.to_dict()
    assert back.sprung_mass_kg.value == res.sprung_mass_kg.value
    assert np.allclose(back.transmissibility[1].hv.array(), res.transmissibility[1].hv.array())
    # restoring force: slopes per unit mass = K2/(M2 + dM), C2/(M2 + dM), noise-compensated
    for surf, mass in zip(res.restoring_force, (380.0, 440.0), strict=True):
        assert surf.stiffness_per_mass.value == pytest.approx(24e3 / mass, rel=0.03)
        assert surf.damping_per_mass.value == pytest.approx(1800 / mass, rel=0.05)
        assert surf.stiffness_n_per_m.value == pytest.approx(24e3, rel=0.03)
        filled = [v for row in surf.force_per_mass_mps2 for v in row if v is not None]
        assert len(filled) > 100
    # loops: force/travel amplitude ratio = |K2 + j w C2| / mass at the loop frequency
    for lp in res.hysteresis:
        mass = 380.0 if lp.label == "before" else 440.0
        w = 2 * np.pi * lp.freq_hz
        expect = abs(24e3 + 1j * w * 1800) / mass
        got = np.std(lp.force_per_mass_mps2) / np.std(lp.r_m)
        assert got == pytest.approx(expect, rel=0.15)


def test_session_without_wheel_channel_is_refused_naming_it(tmp_path):
    from fielddiag.channels import ChannelSpec, SessionMetadata
    from fielddiag.session import write_session

    b, _ = _pair(dm=60.0, seed=1, duration=40.0)
    p = write_session(tmp_path / "body_only.h5", SessionMetadata(),
                      [ChannelSpec("body_z", role="body")], b.body_accel_mps2[:, None],
                      sample_rate_hz=b.sample_rate_hz)
    with pytest.raises(ChannelNotFoundError, match="no wheel channel"):
        identify_sessions(p, p, added_mass_kg=60.0)


def test_recording_with_a_gap_is_analysed_around_it(tmp_path):
    from fielddiag.channels import ChannelSpec, SessionMetadata
    from fielddiag.session import write_session

    b, a = _pair(dm=60.0, seed=9, duration=150.0)
    fs = b.sample_rate_hz
    paths = []
    for d, name, m in ((b, "b.h5", 0.0), (a, "a.h5", 60.0)):
        keep = np.ones(d.time_s.size, bool)
        keep[int(60 * fs):int(63 * fs)] = False  # 3 s lost
        paths.append(write_session(
            tmp_path / name, SessionMetadata(added_mass_kg=m),
            [ChannelSpec("wheel_z", role="wheel"), ChannelSpec("body_z", role="body")],
            np.column_stack([d.wheel_accel_mps2, d.body_accel_mps2])[keep],
            sample_rate_hz=fs, time_s=d.time_s[keep]))
    res = identify_sessions(*paths, added_mass_kg=60.0)
    _check_within_budget_and_std(res, TRUTH)


def test_cli_loops_at_chosen_frequencies(session_pair, capsys):
    before, after, d = session_pair
    out = d / "loops.json"
    rc = cli_main(["identify", str(before), str(after), "--added-mass", "60", "--json", str(out),
                   "--loops", "1.5", "6"])
    assert rc == 0
    loops = json.loads(out.read_text())["hysteresis"]
    assert sorted({round(lp["freq_hz"], 6) for lp in loops}) == [1.5, 6.0]
    assert len(loops) == 4  # both frequencies in both drives
    assert cli_main(["identify", str(before), str(after), "--loops", "-1"]) == 1
    assert "--loops" in capsys.readouterr().err
