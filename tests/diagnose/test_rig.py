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
