"""Friction beside a late channel and a gain change: the three are told apart.

The randomized generator's seed 1795875860 (60 s drives): Coulomb friction at 7.9x the
noise floor, the body channel 2.91 ms late in both drives, its gain 2.9 % down in the
'after' drive (and a bias drift). On the drives as recorded a top mount's lag takes up the
delay and a hysteretic spring the friction; corrected for the delay and the gain together,
only the mount's pair had been fitted, so the tool named a hysteretic spring and a top
mount and said nothing of the delay (session 38). Now the delay is measured again on the
drives corrected for the decisive gain change, and the physics behind the two is looked
for where the physics first chosen holds what looks like one of them.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

import random_cases as rc  # noqa: E402

from fielddiag.diagnose.engine import diagnose_drives  # noqa: E402

SEED = 1795875860


@pytest.mark.timeout(900)
def test_friction_a_late_channel_and_a_gain_change_are_told_apart():
    case = rc.draw_case(SEED, duration_s=60.0, families=rc.PINNED_FAMILIES)
    ((effect, truth),) = case.effects
    assert effect == "coulomb_friction"
    nuisance = {n["kind"]: n for n in case.nuisances}
    late, gain = nuisance["time_offset"], nuisance["gain_change"]
    assert late["channel"] == "body" and late["value"] == pytest.approx(2.91e-3, abs=0.01e-3)
    assert gain["channel"] == "body" and gain["value"] == pytest.approx(-0.0287, abs=1e-4)
    lines: list[str] = []
    out = diagnose_drives(rc.case_drives(case), progress=lines.append).to_dict()
    assert any(s.startswith("testing a time offset between the wheel and body channels")
               and s.endswith("on top of the gain change") for s in lines)
    assert any(s.startswith("looking for physics behind the sensor gain change between the "
                            "drives and the time offset") for s in lines)
    named = [f["effect"] for f in out["findings"]]
    assert named == ["coulomb_friction"], named
    # 294 N for 250 N: the smoothing velocity is not fitted, so the force takes up its part
    assert out["findings"][0]["parameters"]["friction_force_n"] == pytest.approx(
        truth["friction_force_n"], rel=0.25)
    problems = {d["kind"]: d for d in out["data_problems"]}
    assert set(problems) == {"channel_time_offset", "sensor_gain_changed"}
    # 2.90 ms for 2.91 (the chain delay, gain); the gain -3.3 +- 0.4 % for -2.9 %
    assert problems["channel_time_offset"]["value"] == pytest.approx(late["value"], abs=0.1e-3)
    assert problems["sensor_gain_changed"]["value"] == pytest.approx(gain["value"], abs=0.01)


@pytest.mark.timeout(900)
def test_a_gain_change_beside_a_mount_and_the_delay_it_leaves_is_told():
    # seed 1795973094 (60 s drives): a top mount 6.2x the noise, the body channel 2.70 ms
    # late and its gain 4.8 % up in the 'after' drive. The delay the mount leaves beside
    # it (2.90 ms) was chosen with the mount, but the gain had been tested only on top of
    # the linear model's delay (9 ms, the mount's lag in it): it went unsaid, the mount's
    # damping and stiffness 65-72 % high (session 46). Now the gain that stood on the
    # mount is tested on top of the delay chosen beside it
    case = rc.draw_case(1795973094, duration_s=60.0, families=rc.PINNED_FAMILIES)
    ((effect, truth),) = case.effects
    assert effect == "series_top_mount"
    kinds = {n["kind"]: n for n in case.nuisances}
    assert kinds["gain_change"]["channel"] == "body"
    assert kinds["gain_change"]["value"] == pytest.approx(0.048, abs=0.001)
    assert kinds["time_offset"]["value"] == pytest.approx(2.70e-3, abs=0.01e-3)
    out = diagnose_drives(rc.case_drives(case)).to_dict()
    assert [f["effect"] for f in out["findings"]] == ["series_top_mount"]
    told = {w["kind"]: w for w in out["warnings"]}
    assert told["sensor_gain_changed"]["value"] == pytest.approx(0.048, abs=0.005)
    assert told["channel_time_offset"]["value"] == pytest.approx(2.70e-3, rel=0.25)
    found = out["findings"][0]["parameters"]
    for name in ("suspension_damping_ns_per_m", "mount_stiffness_n_per_m"):
        assert found[name] == pytest.approx(truth[name], rel=0.15)
