"""Mismatch diagnosis on before/after pairs with known, concealed physics.

Each case comes from fielddiag.scenarios (the same catalogue as the benchmark and
sample_data/concealed); the full sweep over every case is benchmarks/bench_diagnose.py.
"""

from __future__ import annotations

import json

import pytest

from fielddiag.cli import main
from fielddiag.diagnose.engine import (
    BLOCKING_WARNINGS,
    Drive,
    _data_warnings,
    _transmissibility_warnings,
    diagnose_drives,
)
from fielddiag.scenarios import SCENARIOS, simulate_scenario, write_scenario


def _diagnose(name: str) -> dict:
    before, after = simulate_scenario(SCENARIOS[name])
    drives = [
        Drive(
            label,
            name,
            d.sample_rate_hz,
            0.0,
            d.wheel_accel_mps2,
            d.body_accel_mps2,
            d.added_mass_kg,
        )
        for label, d in (("before", before), ("after", after))
    ]
    return diagnose_drives(drives).to_dict()


def _true_params(name: str, effect: str) -> dict[str, float]:
    return dict(next(p for n, p in SCENARIOS[name].effects if n == effect))


@pytest.mark.parametrize("name", ["friction_2", "bump_stop_1"])
def test_concealed_effect_is_named_with_its_size(name):
    out = _diagnose(name)
    sc = SCENARIOS[name]
    effect = sc.expected_effects[0]
    # concealed: the linear model alone already tracks the body well by eye
    assert out["baseline"]["nrmse_validation"] < 0.25
    assert out["verdict"] == "missing_physics"
    assert out["findings"][0]["effect"] == effect
    for key, true in _true_params(name, effect).items():
        assert out["findings"][0]["parameters"][key] == pytest.approx(true, rel=0.2), key
    assert out["augmented"]["nrmse_validation"] < 0.7 * out["baseline"]["nrmse_validation"]
    assert out["warnings"] == []
    json.dumps(out)


def test_linear_car_is_adequate():
    out = _diagnose("linear_plain")
    assert out["verdict"] == "adequate" and out["findings"] == []
    assert out["augmented"] == out["baseline"]
    lin = out["linear_model"]
    assert lin["sprung_mass_kg"] == pytest.approx(380.0, rel=0.03)
    assert lin["suspension_stiffness_n_per_m"] == pytest.approx(24e3, rel=0.03)


def test_effect_outside_the_library_is_unexplained():
    out = _diagnose("quadratic_damping")
    assert out["verdict"] == "missing_physics"
    assert [f["effect"] for f in out["findings"]][-1] == "unexplained"
    where = out["findings"][-1]["where"]
    assert where["region"] is not None and len(where["region"]["rdot_mps"]) == 2


def test_channel_time_offset_is_a_data_warning_not_physics():
    out = _diagnose("channel_time_offset")
    kinds = [w["kind"] for w in out["warnings"]]
    assert "channel_time_offset" in kinds
    assert out["verdict"] == "adequate" and out["findings"] == []


def _warnings_of(name: str) -> list:
    before, after = simulate_scenario(SCENARIOS[name])
    drives = [
        Drive(
            label,
            name,
            d.sample_rate_hz,
            0.0,
            d.wheel_accel_mps2,
            d.body_accel_mps2,
            d.added_mass_kg,
        )
        for label, d in (("before", before), ("after", after))
    ]
    return _data_warnings(drives) + _transmissibility_warnings(drives)


@pytest.mark.parametrize(
    "name, kind, value",
    [
        ("sensor_gain_changed", "sensor_gain_changed", 0.08),
        ("channel_time_offset", "channel_time_offset", 0.004),
        ("clipping", "clipping", None),
        ("linear_bias_drift", "bias_drift", None),
    ],
)
def test_each_sensor_problem_is_a_data_warning(name, kind, value):
    warnings = _warnings_of(name)
    found = [w for w in warnings if w.kind == kind]
    assert found, [w.kind for w in warnings]
    if value is not None:  # the size, within a factor of 2
        assert 0.5 * value < abs(found[0].value) < 2.0 * value
    # problems that corrupt the comparison withhold physics findings; a drift does not
    assert (kind in BLOCKING_WARNINGS) == (kind != "bias_drift")


def test_linear_drives_raise_no_data_warning():
    assert _warnings_of("linear_plain") == []


def test_cli_pair_with_plots(tmp_path, capsys):
    before, after, _ = write_scenario(SCENARIOS["asymmetric_2"], tmp_path)
    out_json = tmp_path / "d.json"
    assert (
        main(
            [
                "diagnose",
                str(before),
                str(after),
                "--added-mass",
                "60",
                "--json",
                str(out_json),
                "--plots",
                str(tmp_path / "plots"),
            ]
        )
        == 0
    )
    out = json.loads(out_json.read_text())
    assert out["verdict"] == "missing_physics"
    f = out["findings"][0]
    assert f["effect"] == "asymmetric_damping"
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
