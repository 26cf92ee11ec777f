"""fielddiag.web.services: one explicit operation per back-end; nothing guessed, nothing
dropped, an unknown argument refused with its name."""

from __future__ import annotations

from pathlib import Path

import pytest

from fielddiag.errors import FieldDiagError, InvalidValueError
from fielddiag.web import services
from fielddiag.web.services import (
    diagnose_drives,
    diagnosis_backend,
    identification_backend,
    identify_pair,
)


def _pair(root: Path) -> tuple[Path, Path]:
    return root / "car-a" / "before.h5", root / "car-a" / "after.h5"


def test_an_unknown_argument_is_refused_with_its_name() -> None:
    with pytest.raises(TypeError, match="unexpected keyword argument 'band_hz'"):
        identify_pair("before.h5", "after.h5", added_mass_kg=60.0, band_hz=(1.0, 5.0))
    with pytest.raises(TypeError, match="unexpected keyword argument 'config'"):
        diagnose_drives(["drive.h5"], config=None)
    # the mass of a pair is never implied: leaving it out is an error too
    with pytest.raises(TypeError, match="'added_mass_kg'"):
        identify_pair("before.h5", "after.h5")  # type: ignore[call-arg]
    # and no positional argument can slip into the mass
    with pytest.raises(TypeError, match="positional argument"):
        identify_pair("before.h5", "after.h5", 60.0)  # type: ignore[misc]


def test_a_mass_with_one_drive_and_three_drives_are_refused(tmp_path: Path) -> None:
    with pytest.raises(InvalidValueError,
                       match="added_mass_kg=60: an added mass belongs to a pair"):
        diagnose_drives([tmp_path / "drive.h5"], added_mass_kg=60.0)
    with pytest.raises(InvalidValueError, match="not 3 sessions"):
        diagnose_drives([tmp_path / f"{k}.h5" for k in "abc"])


def test_the_backends_are_the_explicit_operations() -> None:
    ident, diag = identification_backend(), diagnosis_backend()
    assert ident.available and ident.target is identify_pair and ident.reason == ""
    assert diag.available and diag.target is diagnose_drives
    from fielddiag.identify.online import OnlineEstimator
    from fielddiag.recorder import Recorder

    assert services.recorder_backend().target is Recorder
    assert services.observability_backend().target is OnlineEstimator
    assert not hasattr(services, "call_with_supported")  # no more dropping arguments


def test_a_part_that_cannot_be_loaded_says_why() -> None:
    b = services._backend("x", "fielddiag.no_such_part", lambda: print, "The x part")
    assert not b.available and b.target is None
    assert b.reason == ("The x part cannot be loaded here (fielddiag.no_such_part: "
                        "ModuleNotFoundError: No module named 'fielddiag.no_such_part')")


def test_the_added_mass_given_is_the_one_used(sessions_root: Path) -> None:
    """The simulated pair has 60 kg added and M2 = 380 kg: the sprung mass identified is
    proportional to the added mass passed (380 kg with 60 kg, 190 kg with 30 kg), so the
    argument reaches the pipeline; so does the progress callback."""
    before, after = _pair(sessions_root)
    calls: list[tuple[float, str]] = []
    full = identify_pair(before, after, added_mass_kg=60.0,
                         progress=lambda f, m: calls.append((f, m))).to_dict()
    half = identify_pair(before, after, added_mass_kg=30.0).to_dict()
    m60, m30 = full["sprung_mass_kg"], half["sprung_mass_kg"]
    assert abs(m60["value"] - 380.0) < 4 * m60["std"] and m60["std"] < 0.02 * 380.0
    assert m30["value"] == pytest.approx(m60["value"] / 2, rel=1e-6)
    assert any("60" in w and "30" in w for w in half["warnings"])  # recorded 60 kg
    fractions = [f for f, _ in calls]
    assert len(calls) >= 3 and fractions == sorted(fractions) and 0 < fractions[0] < 1


def test_a_bad_mass_reaches_the_pair_check_of_both_operations(sessions_root: Path) -> None:
    before, after = _pair(sessions_root)
    for call in (lambda: identify_pair(before, after, added_mass_kg=-3.0),
                 lambda: diagnose_drives([before, after], added_mass_kg=-3.0)):
        with pytest.raises(FieldDiagError, match="-3"):
            call()
