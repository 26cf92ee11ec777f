"""A data problem that acts everywhere must not hide physics that acts in a few events.

The randomized generator's seed 1795817438 (60 s drives at 886 Hz): a bump stop struck
in a few bumps, a wheel channel 2.6 ms late and a wheel gain 3.4 % up in the 'after'
drive. Before session 35 the diagnosis said "adequate": the delay's correction improved
the typical block of held-out data by 45 % (paired-block t = 7.2) but raised the held-out
mean square by 5 %, which the bump-stop blocks dominate, so it failed the gain per
parameter; and on the drives as recorded every effect's fit was pinned at a bound or
worse than the linear model. Now a correction of the recording is judged by its gain in
the typical block, and the physics is looked for again on the corrected drives.

Nor may physics bend the size of a late channel: the delay is measured against the linear
model, whose misfit the left-out physics leans (seed 1795825075: a bump stop beside a body
channel 1.72 ms late, measured 3.48 ms against the linear model). It is measured against
the chosen physics too, and that estimate competes beside that physics.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

import random_cases as rc  # noqa: E402

from fielddiag.diagnose.engine import diagnose_drives  # noqa: E402

SEED = 1795817438


def _refined_ms(lines: list[str], against: str = "") -> list[float]:
    """The delays [ms] (the body channel's, signed) the progress lines say the delay was
    refined to: against the linear model (``against`` empty) or against ``against``."""
    head = f"  refined against {against} to " if against else "  refined to "
    return [float(m[1]) for m in (re.match(re.escape(head) + r"([+-][\d.]+) \+-", s)
                                  for s in lines) if m]


def test_a_bump_stop_behind_a_late_channel_is_found():
    case = rc.draw_case(SEED, duration_s=60.0, families=rc.PINNED_FAMILIES)
    ((effect, truth),) = case.effects
    assert effect == "bump_stop"
    (late,) = [n for n in case.nuisances if n["kind"] == "time_offset"]
    assert late["channel"] == "wheel"
    lines: list[str] = []
    out = diagnose_drives(rc.case_drives(case), progress=lines.append).to_dict()
    assert ("looking for physics behind the time offset between the wheel and body channels "
            "and the sensor gain change between the drives") in lines
    assert out["verdict"] == "missing_physics"
    finding = out["findings"][0]
    assert finding["effect"] == "bump_stop"
    assert finding["parameters"]["gap_m"] == pytest.approx(truth["gap_m"], rel=0.15)
    # the late wheel channel is reported with its size (the truth within 3 std), and the
    # wheel's gain change beside it
    (offset,) = [w for w in out["warnings"] if w["kind"] == "channel_time_offset"]
    assert offset["message"].startswith("the wheel channel lags the other by ")
    problems = {d["kind"]: d for d in out["data_problems"]}
    assert set(problems) == {"channel_time_offset", "sensor_gain_changed"}
    delay = problems["channel_time_offset"]
    assert abs(abs(delay["value"]) - late["value"]) < 3 * delay["std"]
    # the bump stop explains most of what the linear model leaves
    assert out["augmented"]["nrmse_validation"] < 0.4 * out["baseline"]["nrmse_validation"]


def test_a_late_channel_is_measured_against_the_physics_beside_it():
    case = rc.draw_case(1795825075, duration_s=60.0, families=rc.PINNED_FAMILIES)
    ((effect, _),) = case.effects
    assert effect == "bump_stop"
    (late,) = [n for n in case.nuisances if n["kind"] == "time_offset"]
    assert late["channel"] == "body" and late["value"] == pytest.approx(1.72e-3, abs=0.01e-3)
    lines: list[str] = []
    diag = diagnose_drives(rc.case_drives(case), progress=lines.append)
    out = diag.to_dict()
    against_linear = _refined_ms(lines)
    against_bump = _refined_ms(lines, "bump_stop")
    # against the linear model the delay comes out twice its size; against the bump stop
    # within 0.5 ms (two std) of the truth
    assert against_linear[-1] > 3.0
    assert against_bump[-1] == pytest.approx(1e3 * late["value"], abs=0.55)
    assert out["findings"][0]["effect"] == "bump_stop"
    # the findings assume that delay (a top mount explains it nearly as well: told)
    assert diag.chosen.data is not None and diag.chosen.data.kind == "channel_time_offset"
    assert diag.chosen.data.value == pytest.approx(late["value"], abs=0.55e-3)
    assert diag.chosen.data.refined_with == ("bump_stop",)
    assert out["augmented"]["nrmse_validation"] < 0.2 * out["baseline"]["nrmse_validation"]


def test_a_lone_delay_is_refined_against_the_physics_found_behind_it():
    # seed 1795973140 (60 s drives at 974 Hz): a progressive spring 3.2x the noise and a
    # wheel channel 2.02 ms late. On the drives as recorded no effect beats the linear
    # model; the delay, refined against the linear model to 1.31 ms, wins alone, and the
    # cubic spring is found behind it. Before session 47 the findings kept that 1.31 ms
    # (k3 32 % low); now the delay is refined again against the spring found behind it
    case = rc.draw_case(1795973140, duration_s=60.0, families=rc.PINNED_FAMILIES)
    ((effect, truth),) = case.effects
    assert effect == "cubic_stiffness"
    (late,) = [n for n in case.nuisances if n["kind"] == "time_offset"]
    assert late["channel"] == "wheel" and late["value"] == pytest.approx(2.02e-3, abs=0.01e-3)
    lines: list[str] = []
    diag = diagnose_drives(rc.case_drives(case), progress=lines.append)
    out = diag.to_dict()
    against_linear = [-d for d in _refined_ms(lines)]  # the wheel channel lags
    assert against_linear[-1] < 1.5  # leaned by the spring the linear model misses
    assert out["findings"][0]["effect"] == "cubic_stiffness"
    assert diag.chosen.data is not None and diag.chosen.data.kind == "channel_time_offset"
    assert diag.chosen.data.refined_with == ("cubic_stiffness",)
    assert -diag.chosen.data.value == pytest.approx(late["value"], rel=0.1)
    k3 = out["findings"][0]["parameters"]["cubic_stiffness_n_per_m3"]
    assert k3 == pytest.approx(truth["cubic_stiffness_n_per_m3"], rel=0.1)
    (told,) = [w for w in out["warnings"] if w["kind"] == "channel_time_offset"]
    assert -told["value"] == pytest.approx(late["value"], rel=0.1)


def test_a_delay_the_recorded_physics_disputes_is_refined_though_its_first_step_is_small():
    # seed 1795968869 (60 s drives): Coulomb friction 3.6x the noise and a wheel channel
    # 1.96 ms late. Against the linear model the delay is leaned to 2.87 +- 0.26 ms;
    # the friction fitted to the drives corrected for it sees 0.48 ms left (within two
    # std: "the same"), but the friction on the drives as recorded sees 1.96 ms. Before
    # session 47 the 2.87 ms stood; now the steps go on to where the friction sees none
    case = rc.draw_case(1795968869, duration_s=60.0, families=rc.PINNED_FAMILIES)
    ((effect, _),) = case.effects
    assert effect == "coulomb_friction"
    (late,) = [n for n in case.nuisances if n["kind"] == "time_offset"]
    assert late["channel"] == "wheel" and late["value"] == pytest.approx(1.96e-3, abs=0.01e-3)
    lines: list[str] = []
    out = diagnose_drives(rc.case_drives(case), progress=lines.append).to_dict()
    against_linear = [-d for d in _refined_ms(lines)]  # the wheel channel lags
    assert against_linear[-1] > 2.6  # leaned by the friction the linear model misses
    assert _refined_ms(lines, "coulomb_friction")[-1] < 0
    assert out["findings"][0]["effect"] == "coulomb_friction"
    (told,) = [w for w in out["warnings"] if w["kind"] == "channel_time_offset"]
    assert -told["value"] == pytest.approx(late["value"], rel=0.25)
