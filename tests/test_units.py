"""fielddiag.units: gravity and the unit tables, defined once for the whole project."""

from __future__ import annotations

import math
import re
from pathlib import Path

import pytest

from fielddiag import units
from fielddiag.units import (
    ACCEL_UNITS,
    GRAVITY_MPS2,
    QUANTITIES,
    SPEED_UNITS,
    factor_to_si,
    to_si,
)

REPO = Path(__file__).resolve().parents[1]


def test_gravity_is_standard_gravity():
    assert GRAVITY_MPS2 == 9.80665  # CGPM 1901, exact by definition


@pytest.mark.parametrize(
    "value,unit,si_value,si_unit",
    [
        (100.0, "km/h", 27.777777777777778, "m/s"),
        (60.0, "mph", 26.8224, "m/s"),  # 1 mile = 1609.344 m exactly
        (36.0, " KPH ", 10.0, "m/s"),  # case and blanks do not matter
        (180.0, "deg", math.pi, "rad"),
        (-45.0, "°", -math.pi / 4, "rad"),
        (90.0, "deg/s", math.pi / 2, "rad/s"),
        (3000.0, "rpm", 100 * math.pi, "rad/s"),  # 314.16 rad/s
        (1.0, "g", 9.80665, "m/s2"),
        (250.0, "mg", 2.4516625, "m/s2"),
        (9.5, "m/s^2", 9.5, "m/s2"),
        (1500.0, "ms", 1.5, "s"),
    ],
)
def test_to_si_with_real_numbers(value, unit, si_value, si_unit):
    factor, unit_si = to_si(unit)
    assert unit_si == si_unit
    assert value * factor == pytest.approx(si_value, rel=1e-15)


def test_units_of_no_table_are_kept():
    assert to_si("%") == (1.0, "%")
    assert to_si(" Nm ") == (1.0, "Nm")
    assert to_si("m") == (1.0, "m")
    assert to_si(None) == (1.0, "")


def test_factor_to_si_checks_the_quantity():
    assert factor_to_si("km/h", "speed") == pytest.approx(1 / 3.6, rel=1e-15)
    assert factor_to_si("G", "acceleration") == GRAVITY_MPS2
    with pytest.raises(KeyError):
        factor_to_si("km/h", "acceleration")  # a speed is not an acceleration
    with pytest.raises(KeyError):
        factor_to_si("knots", "speed")


def test_tables_are_read_only_and_consistent():
    with pytest.raises(TypeError):
        ACCEL_UNITS["furlong/fortnight2"] = 1.0  # type: ignore[index]
    # the most common units first: error messages list them in this order
    assert list(SPEED_UNITS)[:3] == ["m/s", "km/h", "mph"]
    for table, si in QUANTITIES.values():
        assert table[si] == 1.0  # each table holds its SI unit with factor 1
        for unit in table:
            assert unit == unit.strip().lower()  # keys as to_si looks them up
            assert to_si(unit)[1] == si


def test_gravity_and_unit_factors_are_written_only_in_units_py():
    """The guard of issue 15: gravity (and the factors only unit tables need: mph, degrees,
    rpm) are written once. (km/h <-> m/s for display, ``* 3.6``, is not looked for.)"""
    literal = re.compile(r"(?<![\d.])(9\.80665|9\.81|0\.44704)(?!\d)|pi ?/ ?180|pi ?/ ?60")
    found = []
    for folder in ("fielddiag", "drivers"):
        for path in sorted((REPO / folder).rglob("*.py")):
            if path == Path(units.__file__).resolve():
                continue
            for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
                if literal.search(line.split("#")[0]):
                    found.append(f"{path.relative_to(REPO)}:{n}: {line.strip()}")
    assert found == []


def test_the_examples_in_the_docstrings_hold():
    import doctest

    assert doctest.testmod(units).failed == 0
