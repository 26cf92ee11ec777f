"""A shape no named effect describes is not hidden by a data check.

Two cases of the randomized generator (benchmarks/random_cases.py, drawn from the family
outside the library: a position-sensitive damper, ``-c_p rdot (r / r_ref)^2``), 60 s
drives, that the diagnosis called "adequate" although a smooth force surface predicted
held-out data far better than the linear model:

* seed 1795860400 (9.5x, 0.33 % of the body channel clipped): the structure left was
  judged by the residual's own structure away from the clipped readings (t = 1.1), not by
  the surface's held-out gain (96 %, t = 26): the big events clip the body channel where
  the damper acts most. Now the surface competes with the clipping as physics does (both
  models fitted again away from the clipped readings, and compared there).
* seed 1795860415 (0.4x drawn, a -0.97 % gain change of the body channel): the gain change
  was chosen on its own (t = 1.25 over the linear model) and the surface was never tried
  on the drives corrected for it. Now it is.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

import random_cases as rc  # noqa: E402

from fielddiag.diagnose.engine import diagnose_drives  # noqa: E402

FAMILY = ("travel_dependent_damping",)


def _diagnose(seed: int) -> tuple[rc.Case, dict]:
    case = rc.draw_case(seed, duration_s=60.0, families=FAMILY)
    return case, diagnose_drives(rc.case_drives(case)).to_dict()


def _kinds(out: dict) -> list[str]:
    return [w["kind"] for w in out["warnings"]]


def _is_the_damper_described(finding: dict) -> None:
    assert finding["effect"] == "unexplained"
    words = " ".join(finding["shape_description"])
    assert "damping grows with travel" in words and "position-sensitive damper" in words


@pytest.mark.timeout(600)
def test_a_shape_beside_clipping_competes_with_it_by_its_held_out_gain():
    case, out = _diagnose(1795860400)
    assert [n["kind"] for n in case.nuisances] == ["clipping"]
    assert out["verdict"] == "missing_physics"
    first = out["findings"][0]
    _is_the_damper_described(first)
    assert first["held_out_gain"] > 0.9
    # the clipping is told, and why it does not explain the mismatch
    assert "clipping" in _kinds(out)
    note = next(w["message"] for w in out["warnings"] if w["kind"] == "clipping_explains")
    assert "away from them a smooth force surface still predicts" in note
    assert "not the clipping's" in note


@pytest.mark.timeout(600)
def test_a_shape_is_tried_on_drives_corrected_for_a_data_problem():
    case, out = _diagnose(1795860415)
    assert [n["kind"] for n in case.nuisances] == ["gain_change"]
    true_gain = case.nuisances[0]["value"]
    assert out["verdict"] == "missing_physics"
    first = out["findings"][0]
    _is_the_damper_described(first)
    assert first["held_out_gain"] > 0.5
    # the gain change is still reported, with its size
    gain = next(p for p in out["data_problems"] if p["kind"] == "sensor_gain_changed")
    assert abs(gain["value"] - true_gain) < 2.0 * gain["std"]


@pytest.mark.timeout(900)
def test_a_gain_change_is_judged_with_the_surface_where_named_physics_misses():
    # seed 1795919933 (60 s drives): quadratic damping with damping that grows with
    # travel (outside the library as a pair), the wheel's gain 1.46 % down in the 'after'
    # drive (gravity: -1.5 +- 0.3 %, the body unchanged). Judged with quadratic damping
    # alone the correction predicted worse (t = -4.2) and the gain went unreported; with
    # the surface, which predicts far better than the named physics, it predicts better
    case = rc.draw_case(1795919933, duration_s=60.0, families=rc.PINNED_FAMILIES)
    assert case.family == "quadratic_damping + travel_dependent_damping"
    out = diagnose_drives(rc.case_drives(case)).to_dict()
    assert case.nuisance("gain_change")["channel"] == "wheel"
    assert "sensor_gain_changed" in _kinds(out)
    gain = next(w for w in out["warnings"] if w["kind"] == "sensor_gain_changed")
    assert "+1.5 +- 0.3 %" in gain["message"]  # the body/wheel ratio: 1 / (1 - 0.0146)
    assert [f["effect"] for f in out["findings"]][0] == "unexplained"


@pytest.mark.timeout(900)
def test_a_surface_told_from_named_physics_as_two_explanations_are():
    # seed 1795981380 (60 s drives, no nuisance): damping that grows with travel alone,
    # named quadratic damping (held-out NRMSE 0.049) where the surface predicted 68 %
    # better (0.028, the true model's floor) at t = 2.3: the three blocks with the bumps,
    # 12x better, widened the blocks' spread. Against named physics that passed the
    # selection itself the surface wins as one of two explanations does (t >= 2)
    case = rc.draw_case(1795981380, duration_s=60.0, families=rc.PINNED_FAMILIES)
    assert case.family == "travel_dependent_damping" and not case.nuisances
    out = diagnose_drives(rc.case_drives(case)).to_dict()
    first = out["findings"][0]
    _is_the_damper_described(first)
    assert first["held_out_gain"] > 0.7
    surface = first["force_surface"]
    assert surface["nrmse_validation"] < 0.03 and 2.0 <= surface["t_vs_named"] < 3.0
    # the closest named effect follows, told as a part of it
    assert [f["effect"] for f in out["findings"]][1] == "quadratic_damping"
    assert first["outranks_named"] is True
