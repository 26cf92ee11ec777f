"""A digressive damper whose compression knee is near the low end of real knees.

The randomized generator's seed 1795910646 (60 s drives): knees 0.055 m/s in compression
and 0.25 m/s in rebound at 3.2x the noise floor. With the knee's lower bound at 0.05 m/s
the fitted knee (0.053 m/s) counted as pinned at it, the damper was not allowed, and the
diagnosis named dry friction with a 179 mm/s wide switch and a bump stop (session 41).
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

import random_cases as rc  # noqa: E402

from fielddiag.diagnose.engine import diagnose_drives  # noqa: E402


@pytest.mark.timeout(600)
def test_a_low_compression_knee_is_a_digressive_damper():
    case = rc.draw_case(1795910646, duration_s=60.0)
    ((name, true),) = case.effects
    assert name == "digressive_damping"
    out = diagnose_drives(rc.case_drives(case)).to_dict()
    first = out["findings"][0]
    assert first["effect"] == "digressive_damping", [f["effect"] for f in out["findings"]]
    for key in ("compression_knee_mps", "rebound_knee_mps", "compression_drop_ns_per_m",
                "rebound_drop_ns_per_m"):
        assert first["parameters"][key] == pytest.approx(true[key], rel=0.1), key
