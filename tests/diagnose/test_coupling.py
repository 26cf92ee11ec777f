"""The coupling spring is decided beside a model that takes up the physics the linear model
leaves out.

Seed 1795976902 of the randomized generator (benchmarks/random_cases.py), 60 s drives: a
progressive spring (k3 = 1.28e7 N/m^3, 4.6x the noise floor) on a car coupled to the rest
of the body by 3148 N/m. The linear model alone read the coupling as -803 N/m at 3.6
standard errors and it was left out of every model; the cubic spring was then fitted 12 %
low and a smooth force surface predicted 15 % better than it (``unexplained`` first, for
the library's own effect). The force surface fitted with the coupling reads it at 18
standard errors.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

import random_cases as rc  # noqa: E402

from fielddiag.diagnose.engine import diagnose_drives  # noqa: E402


@pytest.mark.timeout(600)
def test_a_coupling_the_linear_models_misfit_hid_is_kept():
    case = rc.draw_case(1795976902, duration_s=60.0, families=rc.PINNED_FAMILIES)
    assert case.family == "cubic_stiffness" and not case.nuisances
    true_k3 = case.effects[0][1]["cubic_stiffness_n_per_m3"]
    out = diagnose_drives(rc.case_drives(case)).to_dict()
    first = out["findings"][0]
    assert first["effect"] == "cubic_stiffness"
    assert first["parameters"]["cubic_stiffness_n_per_m3"] == pytest.approx(true_k3, rel=0.05)
    # the model with the finding carries the coupling (the linear model's own estimate
    # stays what it read: -803 N/m)
    model = out["augmented_model"]
    assert model["coupling_stiffness_n_per_m"] == pytest.approx(
        case.car.coupling_stiffness_n_per_m, rel=0.1)
    assert model["sprung_mass_kg"] == pytest.approx(case.car.body_mass_kg, rel=0.03)
