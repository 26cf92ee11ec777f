"""Rig mode: one degree of freedom driven by a measured force, on simulated rig tests."""

from __future__ import annotations

import json

import numpy as np
import pytest

from fielddiag.channels import ChannelSpec, SessionMetadata
from fielddiag.cli import main
from fielddiag.diagnose.rig import diagnose_rig, rig_data_from_displacement
from fielddiag.session import write_session
from fielddiag.sim import make_effect
from fielddiag.sim.rig import simulate_rig

CASES = {
    "coulomb_friction": [("coulomb_friction", {"friction_force_n": 45.0})],
    "cubic_stiffness": [("cubic_stiffness", {"cubic_stiffness_n_per_m3": 2.0e6})],
    "bump_stop": [("bump_stop", {"gap_m": 0.045, "stiffness_n_per_m": 8e4})],
    "asymmetric_damping": [("asymmetric_damping", {"compression_damping_ns_per_m": 1100.0,
                                                   "rebound_damping_ns_per_m": 2000.0})],
}


def _diagnose(effects, seed, **kw):
    rec = simulate_rig(effects=tuple(make_effect(n, **p) for n, p in effects), seed=seed, **kw)
    data = rig_data_from_displacement(rec.time_s, rec.force_n, rec.displacement_m,
                                      rec.sample_rate_hz)
    return diagnose_rig(data).to_dict()


def test_linear_rig_is_adequate_and_parameters_are_exact():
    out = _diagnose([], seed=11, stiffness_n_per_m=31e3, damping_ns_per_m=900.0)
    assert out["verdict"] == "adequate" and out["findings"] == []
    p = out["parameters"]
    assert p["stiffness"]["value"] == pytest.approx(31e3, rel=0.01)
    assert p["damping"]["value"] == pytest.approx(900.0, rel=0.03)
    assert p["preload"]["value"] == pytest.approx(150.0, abs=2.0)
    assert out["augmented"]["nrmse_validation"] == out["baseline"]["nrmse_validation"]


@pytest.mark.parametrize("name", sorted(CASES))
def test_each_effect_is_named_with_its_parameters(name):
    effects = CASES[name]
    out = _diagnose(effects, seed=5)
    assert out["verdict"] == "missing_physics"
    top = out["findings"][0]
    assert top["effect"] == name
    for key, true in effects[0][1].items():
        assert top["parameters"][key] == pytest.approx(true, rel=0.05), key
    assert out["augmented"]["nrmse_validation"] < 0.7 * out["baseline"]["nrmse_validation"]
    json.dumps(out)


def test_two_effects_at_once_are_both_named():
    effects = [("coulomb_friction", {"friction_force_n": 50.0}),
               ("asymmetric_damping", {"compression_damping_ns_per_m": 1000.0,
                                       "rebound_damping_ns_per_m": 2100.0})]
    out = _diagnose(effects, seed=8)
    named = {f["effect"]: f["parameters"] for f in out["findings"]}
    assert set(named) == {"coulomb_friction", "asymmetric_damping"}
    assert named["coulomb_friction"]["friction_force_n"] == pytest.approx(50.0, rel=0.1)
    assert named["asymmetric_damping"]["rebound_damping_ns_per_m"] == pytest.approx(2100, rel=0.1)


def test_effect_outside_the_library_is_unexplained():
    out = _diagnose([("quadratic_damping", {"damping_ns2_per_m2": 2500.0})], seed=2)
    assert out["verdict"] == "missing_physics"
    assert out["findings"][-1]["effect"] == "unexplained"
    region = out["findings"][-1]["where"]["region"]
    assert region is not None and len(region["velocity"]) == 2


def test_rig_session_through_the_cli(tmp_path, capsys):
    rec = simulate_rig(effects=(make_effect("coulomb_friction", friction_force_n=60.0),), seed=4)
    path = tmp_path / "rig.h5"
    write_session(path, SessionMetadata(vehicle="damper D-17"),
                  [ChannelSpec("force", unit="N", role="force"),
                   ChannelSpec("displacement", unit="m", role="displacement")],
                  np.column_stack([rec.force_n, rec.displacement_m]),
                  sample_rate_hz=rec.sample_rate_hz)
    out_json = tmp_path / "rig.json"
    assert main(["diagnose", str(path), "--json", str(out_json)]) == 0
    out = json.loads(out_json.read_text())
    assert out["mode"] == "rig" and out["findings"][0]["effect"] == "coulomb_friction"
    assert out["findings"][0]["parameters"]["friction_force_n"] == pytest.approx(60.0, rel=0.1)
    assert "coulomb_friction" in capsys.readouterr().out


# ------------------------------------------------------------ band read from the data
# A force-driven oscillator (issue 16: a real 610 Hz electronic Duffing oscillator with its
# resonance near 60 Hz was called "adequate" when the band was fixed at 0.1 fs).
def _oscillator(seed, excitation="noise", k3=None, **kw):
    from fielddiag.sim.oscillator import simulate_oscillator

    effects = () if k3 is None else (make_effect("cubic_stiffness",
                                                 cubic_stiffness_n_per_m3=k3),)
    rec = simulate_oscillator(effects=effects, excitation=excitation, seed=seed,
                              preload_n=5.0, **kw)
    return rec, rig_data_from_displacement(rec.time_s, rec.force_n, rec.displacement_m,
                                           rec.sample_rate_hz)


def _other_record_nrmse(cand, other):
    """Held-out NRMSE of a fitted candidate on another record (offset re-estimated)."""
    from fielddiag.diagnose.rig import _residual_and_jac

    res, _ = _residual_and_jac(cand.extra["model"], cand.extra["z"], other)
    return float(np.std(res - res.mean()) / np.std(other.force))


@pytest.mark.parametrize("seed", [101, 202])
def test_duffing_610hz_cubic_named_with_k3_and_validated_on_another_record(seed):
    # cubic force at 2.5 displacement std ~ 10 % of the spring's (x std ~ 0.9 mm)
    k3 = 1.5e9
    rec, fit = _oscillator(seed, "noise", k3)
    _, other = _oscillator(seed + 1, "multisine", k3)
    diag = diagnose_rig(fit)
    out = diag.to_dict()
    assert out["findings"][0]["effect"] == "cubic_stiffness"
    # 5 %: the requirement (measured here -1..-2 %, see benchmarks/bench_rig.py)
    assert out["findings"][0]["parameters"]["cubic_stiffness_n_per_m3"] == pytest.approx(
        k3, rel=0.05)
    assert out["parameters"]["moving_mass_kg"]["value"] == pytest.approx(0.5, rel=0.02)
    band = out["band"]
    # the filter must pass the resonance and the drive (to 120 Hz): cut-off above both
    assert band["cutoff_hz"] is None or band["cutoff_hz"] > 1.2 * 120.0
    assert band["resonance_hz"] == pytest.approx(rec.resonance_hz, rel=0.1)
    assert band["inertia_kept"] is True
    # validated on a multisine record of the same oscillator: the cubic carries over,
    # down to the sensor-noise floor there (what the model fitted on that record itself
    # leaves), while the linear model leaves clearly more
    from fielddiag.diagnose.rig import fit_rig_model

    cubic = _other_record_nrmse(diag.selection.chosen, other)
    linear = _other_record_nrmse(diag.selection.baseline, other)
    _, _, _, s2 = fit_rig_model(("cubic_stiffness",), other)
    floor = np.sqrt(s2) / np.std(other.force)
    assert cubic < 1.1 * floor
    assert cubic < 0.75 * linear
    json.dumps(out)


@pytest.mark.parametrize("ratio", [5, 20, 100])
def test_linear_oscillator_gives_no_finding_at_any_rate_ratio(ratio):
    fs = 610.0
    f_res = fs / ratio
    rec, data = _oscillator(7 + ratio, "noise", None, resonance_hz=f_res, sample_rate_hz=fs,
                            band_hz=(0.1 * f_res, min(2 * f_res, fs / 6)))
    out = diagnose_rig(data).to_dict()
    assert out["findings"] == [] and out["verdict"] == "adequate"
    p = out["parameters"]
    assert p["stiffness"]["value"] == pytest.approx(rec.recipe["stiffness_n_per_m"], rel=0.02)
    assert p["moving_mass_kg"]["value"] == pytest.approx(0.5, rel=0.03)


def test_band_of_a_slow_motion_driven_rig_is_low_and_filters_force_and_motion_alike():
    # rod motion 0.3-8 Hz at 500 Hz: the motion edge is near 8 Hz, the cut-off 1.5 x that
    rec = simulate_rig(effects=(make_effect("coulomb_friction", friction_force_n=45.0),),
                       seed=3)
    data = rig_data_from_displacement(rec.time_s, rec.force_n, rec.displacement_m,
                                      rec.sample_rate_hz)
    assert 8.0 <= data.band.motion_edge_hz <= 12.0
    assert data.cutoff_hz == pytest.approx(1.5 * data.band.motion_edge_hz)
    # the force went through the same filter: no content left far above the cut-off
    spec = np.abs(np.fft.rfft(data.force - data.force.mean()))
    f = np.fft.rfftfreq(data.n, 1.0 / data.sample_rate_hz)
    assert spec[f > 3 * data.cutoff_hz].max() < 1e-3 * spec.max()
    out = diagnose_rig(data).to_dict()
    assert out["band"]["filter"] == "zero-phase low-pass" and out["band"]["reason"]


MR_RECORDS = [("ensaio10", "ensaio11"), ("ensaio3.1", "ensaio3"),
              ("ensaio5.2", "ensaio6.2.2"), ("ensaio7.2.2", "ensaio7.2")]


def _mr(name):
    from _real_data import MR_DAMPER

    path = MR_DAMPER / f"{name}.csv"
    if not path.exists():
        pytest.skip(f"{path} not on this machine")
    t, x_mm, f = np.loadtxt(path, delimiter=",", skiprows=1, unpack=True)
    return rig_data_from_displacement(t, f, x_mm * 1e-3, 1.0 / np.median(np.diff(t)))


@pytest.mark.parametrize(("name", "other"), MR_RECORDS)
def test_real_mr_damper_friction_first_and_validated_on_another_record(name, other):
    data, val = _mr(name), _mr(other)
    diag = diagnose_rig(data)
    out = diag.to_dict()
    # friction first: since issue 17 in a hysteretic form (Dahl friction, or the build-up
    # hysteresis that adds a force growing with the travel since the reversal)
    assert out["findings"][0]["effect"] in ("coulomb_friction", "dahl_friction",
                                            "buildup_hysteresis")
    assert out["band"]["inertia_kept"] is False  # 0.5-2 Hz strokes: no inertia to see
    fric = _other_record_nrmse(diag.selection.chosen, val)
    lin = _other_record_nrmse(diag.selection.baseline, val)
    # friction must carry over to another record of the family; hysteresis (issue 17) is
    # what is left: the README's within-record figure for friction is 0.18-0.29
    assert fric < 0.8 * lin and fric < 0.35
