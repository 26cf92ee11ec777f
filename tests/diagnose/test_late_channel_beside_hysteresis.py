"""A late body channel beside a hysteresis is not told as a top mount.

On the drives as recorded a top mount's lag takes up both the late channel and the
hysteresis's lag, and beats the delay alone; the hysteresis on the drives corrected for
the delay must compete with it. The randomized generator's seed 1795866980 (60 s drives):
Bouc-Wen hysteresis at 1.4x the noise floor, the body channel 2.17 ms late. Before
session 38 the tool named a top mount and said nothing of the delay.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

import random_cases as rc  # noqa: E402

from fielddiag.diagnose.engine import diagnose_drives  # noqa: E402

SEED = 1795866980


@pytest.mark.timeout(900)
def test_a_late_channel_beside_a_hysteresis_is_not_a_top_mount():
    case = rc.draw_case(SEED, duration_s=60.0, families=rc.PINNED_FAMILIES)
    assert [e for e, _ in case.effects] == ["bouc_wen"]
    (late,) = [n for n in case.nuisances if n["kind"] == "time_offset"]
    assert late["channel"] == "body" and late["value"] == pytest.approx(2.17e-3, abs=0.01e-3)
    lines = []
    out = diagnose_drives(rc.case_drives(case), progress=lines.append).to_dict()
    # the physics behind the delay was looked for although a mount was chosen first
    assert any(s.startswith("looking for physics behind the time offset") for s in lines)
    named = [f["effect"] for f in out["findings"]]
    assert "series_top_mount" not in named, named
    assert named and named[0] in ("bouc_wen", "hysteretic_spring"), named
    (offset,) = [d for d in out["data_problems"] if d["kind"] == "channel_time_offset"]
    # 2.42 ms: the hysteresis's own lag (a hysteretic spring fits Bouc-Wen's loop) is
    # still in it, within 0.3 ms
    assert offset["value"] == pytest.approx(late["value"], abs=0.3e-3)
    assert "lag_of_the_suspension" not in [w["kind"] for w in out["warnings"]]


@pytest.mark.timeout(900)
def test_a_late_channel_beside_a_digressive_damper_is_not_a_hysteretic_spring_and_a_mount():
    # seed 1795895726 + 100 = 1795895826 of session 40's run (60 s drives): digressive
    # damping at 6.7x the noise floor, the body channel 2.93 ms late. On the drives as
    # recorded a hysteretic spring and a top mount took both (the mount the delay, the
    # loop the damper's bend); since the physics first chosen held a mount *beside* other
    # physics, the physics behind the delay was never looked for, and the delay refined
    # against the hysteretic spring alone (2.07 ms) lost to the pair
    case = rc.draw_case(1795895826, duration_s=60.0, families=rc.PINNED_FAMILIES)
    assert [e for e, _ in case.effects] == ["digressive_damping"]
    (late,) = [n for n in case.nuisances if n["kind"] == "time_offset"]
    assert late["channel"] == "body" and late["value"] == pytest.approx(2.93e-3, abs=0.01e-3)
    out = diagnose_drives(rc.case_drives(case)).to_dict()
    named = [f["effect"] for f in out["findings"]]
    assert named == ["digressive_damping"], named
    knees = out["findings"][0]["parameters"]
    truth = dict(case.effects)["digressive_damping"]
    for key in ("compression_knee_mps", "rebound_knee_mps"):
        assert knees[key] == pytest.approx(truth[key], rel=0.15)
    (offset,) = [d for d in out["data_problems"] if d["kind"] == "channel_time_offset"]
    assert offset["value"] == pytest.approx(late["value"], abs=0.2e-3)
