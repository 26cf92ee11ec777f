"""The verdict's words in the CLI summary (and the dashboard, which uses the same words)."""

from __future__ import annotations

from fielddiag.diagnose.report import adequate_words, format_summary


def _out(warnings):
    return {"verdict": "adequate", "mode": "pair", "findings": [], "warnings": warnings,
            "baseline": {"nrmse": 0.1, "nrmse_validation": 0.11},
            "augmented": {"nrmse": 0.1, "nrmse_validation": 0.11},
            "linear_model": {}, "linear_model_std": {}, "augmented_model": {},
            "augmented_model_std": {}, "data_problems": []}


def test_an_adequate_verdict_beside_a_tie_of_a_data_problem_and_physics_says_so():
    tie = {"kind": "data_problem_or_physics",
           "message": "a time offset ... or a series top mount ...: these data cannot tell"}
    plain, tied = _out([]), _out([tie])
    assert adequate_words(plain) == "the linear model is adequate (no missing physics found)"
    assert "not ruled out" in adequate_words(tied)
    assert "no missing physics found" not in adequate_words(tied)
    first = format_summary(tied).splitlines()[0]
    assert first.startswith("suspension: the linear model is adequate on the drives corrected")
