"""A damper's knee is where the drives reach, with a drop a damper makes.

Seeds of the randomized generator (benchmarks/random_cases.py), 60 s drives:
1795997625, an asymmetric and digressive damper, was reported as a digressive damper with
its rebound knee at 1.9986 m/s (the top of its range) and a rise of 2e8 N s/m there, which
a few peak samples carried; 1795986431, Coulomb friction 5.9x the floor beside a gain
change, a late body channel and clipped wheel readings, was named a digressive damper with
a knee at 1.79 m/s and a rise of 3e6 N s/m.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

import random_cases as rc  # noqa: E402

from fielddiag.diagnose.engine import diagnose_drives  # noqa: E402
from fielddiag.effects.digressive_damping import MAX_SLOPE_CHANGE_NS_PER_M  # noqa: E402


@pytest.mark.timeout(600)
def test_a_knee_at_the_top_of_the_speeds_is_not_reported():
    case = rc.draw_case(1795997625, duration_s=60.0, families=rc.PINNED_FAMILIES)
    assert case.family == "asymmetric_damping + digressive_damping"
    out = diagnose_drives(rc.case_drives(case)).to_dict()
    knee = next(f for f in out["findings"] if f["effect"] == "digressive_damping")
    p = knee["parameters"]
    truth = dict(case.effects)["digressive_damping"]
    for side in ("compression", "rebound"):
        assert p[f"{side}_knee_mps"] < 0.5
        assert 0.0 < p[f"{side}_drop_ns_per_m"] < 3.0 * truth[f"{side}_drop_ns_per_m"]
    assert p["compression_knee_mps"] == pytest.approx(truth["compression_knee_mps"], rel=0.3)


@pytest.mark.timeout(600)
def test_friction_is_not_taken_for_a_knee_rising_by_meganewtons():
    case = rc.draw_case(1795986431, duration_s=60.0, families=rc.PINNED_FAMILIES)
    assert case.family == "coulomb_friction"
    out = diagnose_drives(rc.case_drives(case)).to_dict()
    first = out["findings"][0]
    assert first["effect"] == "coulomb_friction"
    truth = dict(case.effects)["coulomb_friction"]["friction_force_n"]
    # (20 % high: beside clipped wheel readings and two data problems)
    assert first["parameters"]["friction_force_n"] == pytest.approx(truth, rel=0.25)
    for f in out["findings"]:
        for k, v in f["parameters"].items():
            if k.endswith("_drop_ns_per_m"):
                assert abs(v) <= MAX_SLOPE_CHANGE_NS_PER_M
