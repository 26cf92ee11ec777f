"""Rig mode with hysteresis (issue 17): Dahl friction and the build-up hysteresis on
simulated rigs and on the real MR damper, fitted on one record and validated on another of
the same family."""

from __future__ import annotations

import json

import numpy as np
import pytest

from fielddiag.diagnose.rig import (
    _residual_and_jac,
    diagnose_rig,
    rig_data_from_displacement,
)
from fielddiag.sim import make_effect
from fielddiag.sim.rig import simulate_rig

HYSTERESIS = {"dahl_friction", "hysteretic_spring", "bouc_wen", "buildup_hysteresis"}


def _sim(effects, seed, duration_s=30.0, sample_rate_hz=200.0, **kw):
    # 30 s at 200 Hz of a 0.3-8 Hz rod motion (30 mm std): short enough for a quick test
    rec = simulate_rig(effects=effects, seed=seed, duration_s=duration_s,
                       sample_rate_hz=sample_rate_hz, **kw)
    return rig_data_from_displacement(rec.time_s, rec.force_n, rec.displacement_m,
                                      rec.sample_rate_hz)


def _other_nrmse(cand, other):
    """NRMSE of a fitted model on another record (load-cell offset re-estimated there; the
    states warm up on the other record's lead-in, not scored)."""
    res, _ = _residual_and_jac(cand.extra["model"], cand.extra["z"], other,
                               state_jacobian=False)
    return float(np.std(res - res.mean()) / np.std(other.force))


def test_simulated_dahl_friction_named_with_its_parameters_and_carried_to_another_record():
    truth = {"friction_force_n": 60.0, "friction_gradient_n_per_m": 400.0,
             "yield_displacement_m": 5e-4}
    effect = (make_effect("dahl_friction", **truth),)
    data, other = _sim(effect, seed=3), _sim(effect, seed=13)
    diag = diagnose_rig(data)
    out = diag.to_dict()
    top = out["findings"][0]
    assert top["effect"] == "dahl_friction"
    # measured errors 0.1-0.5 % (5 N load-cell noise over ~600 N of force); 3 % and, for
    # the gradient (its force spans only +-36 N over the stroke), 5 %
    assert top["parameters"]["friction_force_n"] == pytest.approx(60.0, rel=0.03)
    assert top["parameters"]["friction_gradient_n_per_m"] == pytest.approx(400.0, rel=0.05)
    assert top["parameters"]["yield_displacement_m"] == pytest.approx(5e-4, rel=0.03)
    p = out["parameters"]
    assert p["stiffness"]["value"] == pytest.approx(20e3, rel=0.01)
    assert p["damping"]["value"] == pytest.approx(1500.0, rel=0.02)
    # on another recording of the same rig the model is at the load-cell noise floor
    # (5 N over the force's spread), far below the linear model
    floor = 5.0 / float(np.std(other.force))
    dahl = _other_nrmse(diag.selection.chosen, other)
    assert dahl < 1.5 * floor
    assert dahl < 0.2 * _other_nrmse(diag.selection.baseline, other)
    assert "friction hysteresis" in top["explanation"]
    json.dumps(out)


def test_simulated_buildup_hysteresis_recovered_and_carried_to_another_record():
    # friction 60 N over 0.5 mm, then 3000 N/m of build-up in compression and 1000 N/m in
    # extension levelling off after 20 mm, released within 1 mm: on a random 0.3-8 Hz
    # motion (reversals of every size) the build-up is told apart from a friction level
    # that depends on the position
    truth = {"friction_force_n": 60.0, "yield_displacement_m": 5e-4,
             "release_displacement_m": 1e-3, "compression_buildup_n_per_m": 3000.0,
             "extension_buildup_n_per_m": 1000.0, "buildup_travel_m": 0.02}
    effect = (make_effect("buildup_hysteresis", **truth),)
    # 20 s at 200 Hz: about 1 mm of travel per sample at the median speed, far less near
    # the reversals, where the pre-yield and release travels act
    data, other = _sim(effect, seed=3, duration_s=20.0), _sim(effect, seed=13, duration_s=20.0)
    diag = diagnose_rig(data)
    out = diag.to_dict()
    top = out["findings"][0]
    assert top["effect"] == "buildup_hysteresis"
    got = {**top["parameters"], **top["shape"]}
    # measured errors (5 N load-cell noise over about 700 N of force): 0.4-2.3 %; the
    # build-up in extension spans only k_e h_y = 20 N of force. Tolerances: about 2.5 times
    for name, rel in (("friction_force_n", 0.02), ("yield_displacement_m", 0.02),
                      ("compression_buildup_n_per_m", 0.05),
                      ("extension_buildup_n_per_m", 0.05), ("release_displacement_m", 0.05),
                      ("buildup_travel_m", 0.06)):
        assert got[name] == pytest.approx(truth[name], rel=rel), name
    floor = 5.0 / float(np.std(other.force))
    hyst = _other_nrmse(diag.selection.chosen, other)
    dahl = next(c for c, _ in diag.selection.ranking if c.effects == ("dahl_friction",))
    assert hyst < 1.5 * floor
    assert hyst < 0.4 * _other_nrmse(dahl, other)
    assert "hysteresis" in top["explanation"] and "travel since the reversal" in (
        top["explanation"])
    json.dumps(out)


@pytest.mark.parametrize("seed", [21, 22])
def test_linear_rig_gives_no_hysteresis(seed):
    out = diagnose_rig(_sim((), seed=seed, stiffness_n_per_m=25e3,
                            damping_ns_per_m=1200.0)).to_dict()
    assert out["findings"] == [] and out["verdict"] == "adequate"
    # the Dahl candidate was fitted and lost: no better on held-out data than linear; so
    # the build-up hysteresis, which refines it, was not tried
    dahl = next(c for c in out["candidates"] if c["effects"] == ["dahl_friction"])
    assert dahl["nrmse_validation"] >= 0.98 * out["baseline"]["nrmse_validation"]
    assert not any("buildup_hysteresis" in c["effects"] for c in out["candidates"])


def test_coulomb_friction_stays_coulomb():
    # a sharp friction step (no pre-yield): the memoryless model is the simpler one that
    # predicts as well, and stays the finding
    out = diagnose_rig(_sim((make_effect("coulomb_friction", friction_force_n=45.0),),
                            seed=4)).to_dict()
    assert out["findings"][0]["effect"] == "coulomb_friction"
    assert out["findings"][0]["parameters"]["friction_force_n"] == pytest.approx(45, rel=0.05)


# fitted on the first record, validated on the second of the same coil-voltage family:
# one low-voltage pair (50 Hz) and one higher-voltage pair (100 Hz)
MR_PAIRS = [("ensaio5", "ensaio6"), ("ensaio7.2.2", "ensaio8.2.2")]


def _mr(name):
    from _real_data import MR_DAMPER

    path = MR_DAMPER / f"{name}.csv"
    if not path.exists():
        pytest.skip(f"{path} not on this machine")
    t, x_mm, f = np.loadtxt(path, delimiter=",", skiprows=1, unpack=True)
    return rig_data_from_displacement(t, f, x_mm * 1e-3, 1.0 / np.median(np.diff(t)))


@pytest.mark.parametrize(("name", "other"), MR_PAIRS)
def test_real_mr_damper_hysteresis_named_and_validated_on_another_record(name, other):
    data, val = _mr(name), _mr(other)
    diag = diagnose_rig(data)
    out = diag.to_dict()
    assert out["findings"][0]["effect"] in HYSTERESIS
    # measured (benchmarks/bench_rig.py): within-record 0.037-0.046, on the other record
    # 0.036-0.049 for these pairs; the target is 0.07 on the other record
    assert out["augmented"]["nrmse_validation"] < 0.06
    hyst = _other_nrmse(diag.selection.chosen, val)
    assert hyst < 0.07
    # the memoryless friction model (fitted alike) leaves clearly more there, the linear
    # model far more
    coulomb = next(c for c, _ in diag.selection.ranking if c.effects == ("coulomb_friction",))
    assert hyst < 0.6 * _other_nrmse(coulomb, val)
    assert hyst < 0.25 * _other_nrmse(diag.selection.baseline, val)


def test_real_mr_damper_buildup_carries_to_a_neighbour_and_to_a_shorter_stroke():
    # ensaio5.2.2 (30 mm stroke, 0.53 Hz) validated on its neighbour ensaio4.2.2 (28 mm)
    # and on ensaio10.2.2 (17 mm, 0.67 Hz) of the same naming group
    data, near, short = _mr("ensaio5.2.2"), _mr("ensaio4.2.2"), _mr("ensaio10.2.2")
    diag = diagnose_rig(data)
    out = diag.to_dict()
    assert out["findings"][0]["effect"] == "buildup_hysteresis"
    top = out["findings"][0]["parameters"]
    # the build-up is in compression (several N per mm), hardly any in extension
    assert top["compression_buildup_n_per_m"] > 10 * top["extension_buildup_n_per_m"]
    chosen = diag.selection.chosen
    dahl = next(c for c, _ in diag.selection.ranking
                if c.effects == ("coulomb_friction", "dahl_friction"))
    # measured (benchmarks/bench_rig.py): 0.037 on the neighbour, 0.049 on the short
    # stroke, where the Dahl friction with a level along the stroke leaves 0.043 and 0.084
    assert _other_nrmse(chosen, near) < 0.045
    assert _other_nrmse(chosen, short) < 0.06
    assert _other_nrmse(chosen, short) < 0.7 * _other_nrmse(dahl, short)
