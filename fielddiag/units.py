"""Physical constants and unit conversions to SI, defined once for the whole project.

Every module that needs gravity or converts a unit written in a file (a DBC signal's
unit, a CSV or MDF column's unit) to SI imports it from here. The tables map a unit as
files spell it (lower case) to its factor to the SI unit of its quantity:
``value_si = value * factor``.

>>> to_si("km/h")
(0.2777777777777778, 'm/s')
>>> to_si("g") == (GRAVITY_MPS2, "m/s2")
True
>>> to_si("%")  # not a unit this project converts: kept as written
(1.0, '%')
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from types import MappingProxyType

#: Standard gravity [m/s^2] (CGPM 1901, exact). An upward accelerometer at rest reads
#: ``+GRAVITY_MPS2``.
GRAVITY_MPS2 = 9.80665

#: Metres per second in one km/h.
KMH_TO_MPS = 1 / 3.6
#: Metres per second in one mile per hour (1 mile = 1609.344 m, exact).
MPH_TO_MPS = 0.44704
#: Radians in one degree.
DEG_TO_RAD = math.pi / 180
#: Radians per second in one revolution per minute.
RPM_TO_RADPS = 2 * math.pi / 60


def _table(factors: dict[str, float]) -> Mapping[str, float]:
    return MappingProxyType(factors)


#: Acceleration units -> factor to m/s2.
ACCEL_UNITS = _table({
    "m/s2": 1.0,
    "m/s^2": 1.0,
    "m/s²": 1.0,
    "m s-2": 1.0,
    "m/s/s": 1.0,
    "mps2": 1.0,
    "g": GRAVITY_MPS2,
    "mg": 1e-3 * GRAVITY_MPS2,
})
#: Speed units -> factor to m/s.
SPEED_UNITS = _table({
    "m/s": 1.0,
    "km/h": KMH_TO_MPS,
    "mph": MPH_TO_MPS,
    "kph": KMH_TO_MPS,
    "kmh": KMH_TO_MPS,
    "km/hr": KMH_TO_MPS,
})
#: Angle units -> factor to rad.
ANGLE_UNITS = _table({
    "rad": 1.0,
    "deg": DEG_TO_RAD,
    "degree": DEG_TO_RAD,
    "degrees": DEG_TO_RAD,
    "°": DEG_TO_RAD,
})
#: Angular rate units (rotation speed included) -> factor to rad/s.
ANGULAR_RATE_UNITS = _table({
    "rad/s": 1.0,
    "deg/s": DEG_TO_RAD,
    "deg/sec": DEG_TO_RAD,
    "°/s": DEG_TO_RAD,
    "rpm": RPM_TO_RADPS,
    "1/min": RPM_TO_RADPS,
})
#: Time units -> factor to s.
TIME_UNITS = _table({"s": 1.0, "ms": 1e-3, "us": 1e-6})

#: Each table with the SI unit its factors lead to.
QUANTITIES: Mapping[str, tuple[Mapping[str, float], str]] = MappingProxyType({
    "acceleration": (ACCEL_UNITS, "m/s2"),
    "speed": (SPEED_UNITS, "m/s"),
    "angle": (ANGLE_UNITS, "rad"),
    "angular rate": (ANGULAR_RATE_UNITS, "rad/s"),
    "time": (TIME_UNITS, "s"),
})

_TO_SI: dict[str, tuple[float, str]] = {
    unit: (factor, si) for table, si in QUANTITIES.values() for unit, factor in table.items()
}


def to_si(unit: str | None) -> tuple[float, str]:
    """Factor to SI and the SI unit of a unit as a file writes it.

    Parameters
    ----------
    unit : str or None
        The unit as written (``"km/h"``, ``"deg/s"``, ``"g"``...); case and surrounding
        blanks are ignored.

    Returns
    -------
    factor : float
        Multiply a value in ``unit`` by it to get the value in the SI unit.
    si_unit : str
        ``"m/s"``, ``"m/s2"``, ``"rad"``, ``"rad/s"`` or ``"s"``; a unit of no table
        (``"%"``, ``"Nm"``, ``"m"``) is returned unchanged (stripped) with factor 1.

    Examples
    --------
    >>> to_si("rpm")[1], round(to_si("rpm")[0] * 3000, 6)
    ('rad/s', 314.159265)
    >>> to_si(None)
    (1.0, '')
    """
    key = (unit or "").strip()
    return _TO_SI.get(key.lower(), (1.0, key))


def factor_to_si(unit: str, quantity: str) -> float:
    """Factor from ``unit`` to the SI unit of ``quantity``, or KeyError if ``unit`` is not one.

    Parameters
    ----------
    unit : str
        The unit as written; case and surrounding blanks are ignored.
    quantity : {"acceleration", "speed", "angle", "angular rate", "time"}

    Returns
    -------
    float
        ``value_si = value * factor``.

    Raises
    ------
    KeyError
        ``unit`` is not a unit of ``quantity``; callers turn it into a message that lists
        ``QUANTITIES[quantity][0]``.

    Examples
    --------
    >>> factor_to_si("mph", "speed")
    0.44704
    """
    return QUANTITIES[quantity][0][unit.strip().lower()]


__all__ = [
    "ACCEL_UNITS",
    "ANGLE_UNITS",
    "ANGULAR_RATE_UNITS",
    "DEG_TO_RAD",
    "GRAVITY_MPS2",
    "KMH_TO_MPS",
    "MPH_TO_MPS",
    "QUANTITIES",
    "RPM_TO_RADPS",
    "SPEED_UNITS",
    "TIME_UNITS",
    "factor_to_si",
    "to_si",
]
