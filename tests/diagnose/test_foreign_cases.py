"""The diagnosis on cases of the independent simulator (benchmarks/foreign_cases.py).

Its force laws are the textbook forms, not the library's kernels, and its sensors add
1/f noise and gravity and decimate with a linear-phase FIR. Three failures it showed in
session 41, each a fixed case here (60 s drives):

* a linear car with 1/f noise in its readings was called ``unexplained``: the noisy
  integrated travel and speed tilt the force left along them (seed 1795907655);
* a damper whose slope bends smoothly above a knee was named dry friction, whose fitted
  switch (``Ff tanh(v / v_s)``) is the same curve: the switch 168 mm/s wide, 78 % of the
  suspension's rms speed, is a knee (seed 1795909231);
* free play in the damper's mounting was reported as a body channel 3.7 ms late: the
  lag it makes is larger in the quieter half of the drives (seed 1795907660).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

import foreign_cases as fc  # noqa: E402

from fielddiag.diagnose.engine import diagnose_drives  # noqa: E402


def _diagnose(seed: int, law: str) -> tuple[fc.ForeignCase, dict]:
    case = fc.draw_case(seed)
    assert case.law == law
    return case, diagnose_drives(fc.case_drives(case)).to_dict()


def test_the_foreign_simulator_reads_gravity_and_its_twin_shares_the_noise():
    case = fc.draw_case(1795907655)
    (w, b), (w2, b2) = fc.simulate_pair(case)
    # an accelerometer reads acceleration + g; the drives are 60 s at the drawn rate
    assert b.size == w.size == int(round(case.duration_s * case.rate_hz))
    assert np.mean(b) == pytest.approx(fc.G_MPS2, abs=0.02)
    assert np.mean(w) == pytest.approx(fc.G_MPS2, abs=0.05)
    # the linear twin of a linear case is the case itself, reading for reading
    (tw, tb), _ = fc.simulate_pair(case, linear_twin=True)
    np.testing.assert_array_equal(tb, b)
    # the law is drawn whatever is forced: the rest of the case does not change
    forced = fc.draw_case(1795907655, law="gas_spring")
    assert forced.car == case.car and forced.rate_hz == case.rate_hz


@pytest.mark.timeout(600)
def test_a_linear_car_with_1_over_f_noise_is_adequate():
    case, out = _diagnose(1795907655, "linear")
    assert fc.PINK_SHARE > 0
    assert out["verdict"] == "adequate", [f["effect"] for f in out["findings"]]
    assert out["findings"] == []


@pytest.mark.timeout(600)
def test_a_friction_switch_as_wide_as_the_speeds_is_a_damper_knee():
    case, out = _diagnose(1795909231, "smooth_digressive_damper")
    named = [f["effect"] for f in out["findings"]]
    assert named[0] == "digressive_damping", named
    (note,) = [w["message"] for w in out["warnings"]
               if w["kind"] == "friction_read_as_damper_knee"]
    assert "not friction" in note and "the findings are digressive damping" in note
    knee = out["findings"][0]["parameters"]
    # the knee sits within the smooth law's bend: tanh reaches 76 % of its level at the
    # knee velocity drawn (0.5-1.5 x the rms speed)
    assert 0.05 < knee["compression_knee_mps"] < 0.4
    assert knee["compression_drop_ns_per_m"] > 0


@pytest.mark.timeout(900)
def test_free_play_in_the_damper_is_not_a_late_channel():
    case, out = _diagnose(1795907660, "damper_free_play")
    kinds = [d["kind"] for d in out.get("data_problems", [])]
    assert "channel_time_offset" not in kinds, kinds
    assert out["verdict"] != "adequate"
    # the lag is the suspension's: told so where a delay competed, or taken by physics
    # that lags (since session 43's forward pairs a top mount beside quadratic damping,
    # little force at low speed and a lag: held-out NRMSE 0.317 against the Bouc-Wen
    # loop's 0.357 named before; free play itself is outside the library)
    notes = [w["message"] for w in out["warnings"] if w["kind"] == "lag_of_the_suspension"]
    named = {f["effect"] for f in out["findings"]}
    if notes:
        assert "quieter half" in notes[0] and "livelier half" in notes[0]
    else:
        assert named & {"series_top_mount", "bouc_wen", "hysteretic_spring"}, named


@pytest.mark.timeout(600)
def test_free_play_beside_a_named_hysteresis_is_told_unexplained_with_its_play():
    # the independent simulator's seed 1795947584 (strength 15x): a hysteretic spring
    # describes most of a damper idle in a free play, but what is left depends on the
    # travel since each reversal (11.8 % of the residual, t = 9.8). It was told only
    # "hysteretic_spring"; then (session 42) the rest `unexplained` after it, its shape a
    # damping lower inside a play; now (session 50) a force with memory of each reversal
    # predicts 91 % of the linear model's held-out misfit, far more than the named pair,
    # and the mismatch is told first as what it is: the damping gone after each reversal
    _, out = _diagnose(1795947584, "damper_free_play")
    first = out["findings"][0]
    assert first["effect"] == "unexplained", [f["effect"] for f in out["findings"]]
    assert first["force_surface"]["form"] == "memory_of_reversals"
    play = [w for w in first["shape_description"] if "after each reversal of the motion" in w]
    assert play and "damping" in play[0] and "free play" in play[0], first["shape_description"]
    assert first["held_out_gain"] >= 0.5
    # the named effects that fitted least badly are listed after it, as part of it
    assert "describes only part of it" in first["explanation"]


@pytest.mark.timeout(600)
def test_structure_no_smooth_shape_carries_over_is_not_a_finding():
    # the independent simulator's seed 1795956848: a linear car. The departure map's
    # coarse bins predicted 8.4 % of the held-out residual (t = 4.5), but the smooth model
    # of that shape, the finding's own model, predicted less than nothing there (-3 %):
    # `unexplained` was reported with "the damping fades by 19 % above 0.85 m/s"
    case, out = _diagnose(1795956848, "linear")
    assert out["verdict"] == "adequate", out["findings"]
    assert not out["findings"]


@pytest.mark.timeout(600)
def test_structure_its_smooth_shape_predicts_unsurely_is_not_a_finding():
    # seed 1795964974: a linear car; the map predicted 8.7 % of the held-out residual
    # (t = 4.6), the smooth model of the shape 0.7 %, worse than nothing in most blocks
    # (t = -3.6): "the force rises 40 % softer than the linear spring beyond 23 mm" was
    # reported. The finding's own model must predict held-out data as surely as the map
    case, out = _diagnose(1795964974, "linear")
    assert out["verdict"] == "adequate", out["findings"]
    assert not out["findings"]


@pytest.mark.timeout(600)
def test_free_play_is_told_as_a_force_with_memory_of_each_reversal():
    # the independent simulator's seed 1795986074 (strength 9x): the damper idle in a free
    # play for a few mm after each reversal. No named effect describes it; digressive
    # damping + a hysteretic spring fitted least badly (held-out NRMSE 0.226, the linear
    # model's 0.331) and were named first, the rest `unexplained` (session 48). A force
    # that remembers each reversal, with no name, predicts it far better (0.104, t = 11)
    # and is now the first finding, its shape the damping missing after each reversal
    _, out = _diagnose(1795986074, "damper_free_play")
    first = out["findings"][0]
    assert first["effect"] == "unexplained", [f["effect"] for f in out["findings"]]
    assert first["force_surface"]["form"] == "memory_of_reversals"
    assert first["force_surface"]["nrmse_validation"] < 0.15
    assert first["held_out_gain"] >= 0.8
    words = first["shape_description"][0]
    assert "damping" in words and "after each reversal" in words and "free play" in words
    # the memory travel (the travel over which the damping is lost, in sum) is a few mm
    assert 1e-3 <= first["force_surface"]["memory_travel_m"] <= 6e-3


@pytest.mark.timeout(600)
def test_free_play_read_as_a_late_channel_beside_names_is_the_shapes_lag():
    # the independent simulator's seed 1796009222 (free play, 6x): a body channel 4.36 ms
    # late was chosen beside a digressive damper and a top mount (the free play lags each
    # stroke). The force with memory of each reversal predicts better than those names on
    # the drives as recorded (t = 16.7) and no better with the delay corrected: the delay
    # is the names' misfit, not the channels'. No late channel is reported, the shape first
    _, out = _diagnose(1796009222, "damper_free_play")
    kinds = [d["kind"] for d in out.get("data_problems", [])]
    assert "channel_time_offset" not in kinds, kinds
    assert out["findings"][0]["effect"] == "unexplained"
    assert out["findings"][0]["force_surface"]["form"] == "memory_of_reversals"
    (note,) = [w["message"] for w in out["warnings"] if w["kind"] == "lag_of_the_suspension"]
    assert "a force with memory of each reversal predicts held-out data as well without it" \
        in note
    assert out["augmented"]["nrmse_validation"] < 0.25 < out["baseline"]["nrmse_validation"]


@pytest.mark.timeout(600)
def test_free_play_whose_lag_was_withdrawn_competes_with_the_physics_left():
    # the independent simulator's seed 1795952154 (free play, 1.5x): a top mount beside
    # quadratic damping fitted best of the names on the drives as recorded, and the force
    # with memory predicted better than they (t = 11.2); then a hysteretic spring with a
    # 1.22 ms late channel was chosen, and the delay withdrawn (1.56 ms in the quieter
    # half, 0.83 in the livelier). Left with the hysteretic spring alone, told alone: the
    # shape had competed with the pair only. It competes with what is left now (t = 15.2)
    _, out = _diagnose(1795952154, "damper_free_play")
    assert "channel_time_offset" not in [d["kind"] for d in out.get("data_problems", [])]
    (note,) = [w["message"] for w in out["warnings"] if w["kind"] == "lag_of_the_suspension"]
    assert "quieter half" in note
    first = out["findings"][0]
    assert first["effect"] == "unexplained", [f["effect"] for f in out["findings"]]
    assert first["force_surface"]["form"] == "memory_of_reversals"
    assert any("after each reversal of the motion" in w for w in first["shape_description"])
    assert first["force_surface"]["nrmse_validation"] < 0.75 * min(
        c["nrmse_validation"] for c in out["candidates"] if c["effects"] == ["hysteretic_spring"])
