"""A pair one linear car cannot describe, with physics outside the library: never 'adequate'.

A damper whose damping grows with compression (``travel_dependent_damping``, which the
diagnosis does not try) on a car that sags into it under the added mass: the linear
model's sprung mass runs to its bound. Before, the verdict was 'adequate' beside a
'linear model inadequate' warning; the finding is now ``unexplained`` between the drives,
with the shape of the force left modelled.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

import random_cases as rc  # noqa: E402

from fielddiag.diagnose.engine import diagnose_drives  # noqa: E402

#: The families when the seed was chosen (keeps the case fixed as the library grows).
FAMILIES = ("asymmetric_damping", "bouc_wen", "bump_stop", "coulomb_friction",
            "cubic_stiffness", "dahl_friction", "digressive_damping", "hysteretic_spring",
            "quadratic_damping", "series_top_mount", "travel_dependent_damping")
SEED = 881010  # travel-dependent damping, 325 Hz, 29 dB, 8 % added mass


def test_inadequate_linear_model_without_a_named_effect_is_missing_physics():
    case = rc.draw_case(SEED, duration_s=120.0, families=FAMILIES)
    assert [n for n, _ in case.effects] == ["travel_dependent_damping"]
    out = diagnose_drives(rc.case_drives(case)).to_dict()
    assert "linear_model_inadequate" in [w["kind"] for w in out["warnings"]]
    assert out["verdict"] == "missing_physics"
    (f,) = out["findings"]
    assert f["effect"] == "unexplained" and f["where"]["between_drives"] is True
    assert "cannot describe these drives with one sprung mass" in f["explanation"]
    assert f["shape_description"]  # its shape in words, and the model of it
    assert f["model"]["force_unit"] == "N"
    # the attached model predicts part of the held-out force left
    assert 0.0 < f["held_out_gain"] < 1.0
