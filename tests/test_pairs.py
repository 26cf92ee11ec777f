"""A pair is one thing everywhere: the partner rule, the refusals and the warnings, from
the library and through the command line (real subprocesses, real session files)."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest
from _summary_text import values_without_std

from fielddiag.pairs import DriveHeader, PairError, check_pair, find_partner, read_drive_header

SAMPLES = Path(__file__).resolve().parents[1] / "sample_data" / "concealed"


def _h(name: str, mass: float = 0.0, vehicle: str = "car", corner: str = "fl",
       created: str = "2026-01-01T10:00:00Z", rate: float = 500.0, fp: str = "",
       units: tuple = (("body", "m/s^2"), ("wheel", "m/s^2"))) -> DriveHeader:
    return DriveHeader(Path(f"/data/{name}"), vehicle, corner, mass, created, rate, 1000,
                       units, fp)


def test_partner_is_same_vehicle_and_corner_closest_in_time():
    after = _h("after.h5", 60.0, created="2026-01-01T12:00:00Z")
    cands = [_h("b-early.h5", created="2026-01-01T08:00:00Z"),
             _h("b-close.h5", created="2026-01-01T11:30:00Z"),
             _h("b-other-car.h5", vehicle="other", created="2026-01-01T12:00:00Z"),
             _h("b-other-corner.h5", corner="rr", created="2026-01-01T12:00:00Z"),
             _h("a-another-after.h5", 30.0, created="2026-01-01T14:00:00Z")]
    partner, why = find_partner(after, cands)
    assert partner is not None and partner.path.name == "b-close.h5" and why == ""
    # from the before side, the same pair
    back, _ = find_partner(cands[1], [after, *cands])
    assert back is not None and back.path.name == "after.h5"
    # further apart than a day: no partner, and the reason names the closest drive
    far = _h("after.h5", 60.0, created="2026-01-03T12:00:00Z")
    partner, why = find_partner(far, cands)
    assert partner is None and "b-close.h5" in why and "24 h" in why
    partner, why = find_partner(_h("x.h5", 60.0, vehicle="nobody"), cands)
    assert partner is None and "no drive without added mass" in why


@pytest.mark.parametrize(("before", "after", "mass", "words"), [
    (_h("a.h5"), _h("a.h5", 60.0), None, "both the before and the after"),
    (_h("a.h5", fp="x:1"), _h("b.h5", 60.0, fp="x:1"), None, "same recording"),
    (_h("a.h5", 60.0), _h("b.h5"), None, "swapped"),
    (_h("a.h5"), _h("b.h5", 60.0, vehicle="another"), None, "different vehicles"),
    (_h("a.h5"), _h("b.h5", 60.0, corner="rr"), None, "different corners"),
    (_h("a.h5"), _h("b.h5"), None, "record no added mass"),
    (_h("a.h5"), _h("b.h5"), -5.0, "positive number"),
    (_h("a.h5"), _h("b.h5"), float("nan"), "positive number"),
])
def test_pairs_that_cannot_be_are_refused(before, after, mass, words):
    with pytest.raises(PairError, match=words):
        check_pair(before, after, mass)


def test_doubtful_pairs_are_warned():
    ok = check_pair(_h("a.h5"), _h("b.h5", 60.0))
    assert ok.added_mass_kg == 60.0 and ok.warnings == ()
    w = check_pair(_h("a.h5", vehicle=""), _h("b.h5", 60.0, rate=400.0,
                                              units=(("body", "g"), ("wheel", "m/s^2")),
                                              created="2026-01-03T10:00:00Z"), 50.0).warnings
    text = " | ".join(w)
    assert len(w) == 5, w
    assert "record an added mass of 60 kg but 50 kg" in text
    assert "vehicle of one or both drives is not recorded" in text
    assert "different rates (500 and 400 Hz)" in text
    assert "body: m/s^2 and g" in text
    assert "48 h apart" in text
    # 500 against 500.001 Hz is no reason for a warning: a common grid takes care of it
    assert check_pair(_h("a.h5"), _h("b.h5", 60.0, rate=500.001)).warnings == ()


# --------------------------------------------------------------------------------------
# Through the command line, on real session files
# --------------------------------------------------------------------------------------


def _cli(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "fielddiag.cli", *args], capture_output=True,
                          text=True, cwd=cwd, timeout=600)


def _one_line_error(r: subprocess.CompletedProcess, *words: str) -> str:
    assert r.returncode == 1, (r.returncode, r.stdout, r.stderr)
    lines = [ln for ln in r.stderr.splitlines() if ln.strip() and not ln.startswith("  ")]
    assert len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    for w in words:
        assert w in lines[0], lines[0]
    return lines[0]


@pytest.fixture(scope="module")
def drives(tmp_path_factory) -> dict[str, Path]:
    """Simulated drives of one car before/after 60 kg, and of other cars (no vehicle
    metadata, as an imported CSV has none)."""
    from fielddiag import sim
    from fielddiag.simio import drive_to_session

    root = tmp_path_factory.mktemp("pairs")
    out = {}
    for name, mass, seed, car, vehicle in (
            ("before", 0.0, 1, {}, ""),
            ("after", 60.0, 2, {}, ""),
            # a stiffer, lighter car: its body resonance is above the first car's
            ("stiff_after", 60.0, 3, {"body_mass_kg": 300.0,
                                      "suspension_stiffness_n_per_m": 30000.0}, ""),
            # the same spring and mass but half the damping: stiffness says 380 kg, the
            # damping says about 46 kg
            ("soft_damper_after", 60.0, 4, {"suspension_damping_ns_per_m": 900.0}, "")):
        drive = sim.simulate(duration_s=60.0, added_mass_kg=mass, seed=seed,
                             params=sim.QuarterCarParams(**car),
                             sensor=sim.SensorModel(output_rate_hz=200.0, snr_db=40.0))
        out[name] = drive_to_session(drive, root / f"{name}.h5", vehicle=vehicle,
                                     corner="")
    shutil.copy(out["after"], root / "after_copy.h5")
    out["after_copy"] = root / "after_copy.h5"
    return out


def test_cli_refuses_swapped_duplicated_and_copied_drives(drives):
    cwd = drives["before"].parent
    cases = [
        (("identify", "after.h5", "before.h5"), ("swapped",)),
        (("diagnose", "after.h5", "before.h5"), ("swapped",)),
        (("diagnose", "before.h5", "before.h5"), ("both the before and the after",)),
        (("identify", "after.h5", "after_copy.h5", "--added-mass", "60"), ("same recording",)),
        (("diagnose", "before.h5", "after.h5", "--added-mass", "-60"),
         ("--added-mass -60", "more than 0")),
    ]
    with ThreadPoolExecutor(max_workers=3) as pool:  # subprocesses, a few at a time
        runs = list(pool.map(lambda c: _cli(*c[0], cwd=cwd), cases))
    for r, (_, words) in zip(runs, cases, strict=True):
        _one_line_error(r, *words)


def test_cli_flags_a_pair_whose_resonance_rose(drives):
    """Unrelated drives with no metadata to tell: the data show the 'after' car is not the
    'before' car with a mass added (its stiffness per unit mass rose). A spring that
    stiffens as the car sags does that too, so it is a warning naming both, not a gate."""
    cwd = drives["before"].parent
    r = _cli("identify", "before.h5", "stiff_after.h5", cwd=cwd)
    text = r.stdout + r.stderr
    assert r.returncode in (0, 1) and "Traceback" not in text
    line = next(ln for ln in text.splitlines() if "the body resonance rose" in ln)
    assert "swapped or not of the same car corner" in line
    assert "progressive spring" in line and "fielddiag diagnose" in line
    assert not re.search(r"e\+\d\d kg", text)  # no absurd numbers


def test_cli_warns_when_stiffness_and_damping_disagree_on_the_mass(drives):
    cwd = drives["before"].parent
    r = _cli("identify", "before.h5", "soft_damper_after.h5", cwd=cwd)
    assert r.returncode == 0, r.stderr
    warning = next(ln for ln in r.stdout.splitlines()
                   if "do not behave like one corner with 60 kg added" in ln)
    implied = [float(v) for v in re.findall(r"implies a sprung mass of ([\d.]+)|damping ([\d.]+)",
                                            warning)[0] if v]
    assert 340 < implied[0] < 420  # from the stiffness: the true 380 kg
    assert "fielddiag diagnose" in warning and "suspension is not linear" in warning
    # and the matched pair gets no such warning, and its mass within 4 std of 380 kg
    r = _cli("identify", "before.h5", "after.h5", cwd=cwd)
    assert r.returncode == 0 and "do not behave like one corner" not in r.stdout
    m = re.search(r"sprung mass M2 +([\d.]+) \+- ([\d.]+) kg", r.stdout)
    assert m and abs(float(m.group(1)) - 380.0) < 4 * float(m.group(2))


def test_identify_summary_prints_no_value_without_its_std(tmp_path):
    """identify on the committed friction pair, in a fresh process: every mass, stiffness
    and damping printed comes with its standard deviation (the diagnosis's summary is
    checked the same way by tests/diagnose/test_diagnose.py::test_cli_pair_with_plots)."""
    b, a = SAMPLES / "friction_2_before.h5", SAMPLES / "friction_2_after.h5"
    r = _cli("identify", str(b), str(a), "--added-mass", "60", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    result = r.stdout.split("Result", 1)[1].split("Transmissibility")[0]
    assert values_without_std(result) == [], result


def test_read_drive_header_fingerprints_the_body_channel():
    h1 = read_drive_header(SAMPLES / "friction_2_before.h5")
    h2 = read_drive_header(SAMPLES / "friction_2_after.h5")
    assert h1.fingerprint and h1.fingerprint != h2.fingerprint
    assert h1.sample_rate_hz > 0 and dict(h1.role_units).keys() >= {"wheel", "body"}
