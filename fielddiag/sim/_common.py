"""Constants and argument checks shared by the simulator modules."""

from __future__ import annotations

import math

import numpy as np

from fielddiag.errors import FieldDiagError
from fielddiag.units import GRAVITY_MPS2 as G_MPS2  # noqa: F401 - the simulator's name

#: Lowest internal integration rate [Hz].
MIN_INTERNAL_RATE_HZ = 4000.0

# Step-size check: RK4 is run with |lambda| * dt <= MAX_LAMBDA_DT for the fastest mode,
# estimated from each effect's speed_bounds (over fielddiag.effects.TRAVEL_BOUND_M and
# RATE_BOUND_MPS).
MAX_LAMBDA_DT = 0.5


def check_number(
    owner: str, name: str, value: float, *, low: float | None = None, strict: bool = False
) -> None:
    """Raise FieldDiagError unless ``value`` is a finite number above ``low``."""
    ok = isinstance(value, int | float | np.floating | np.integer) and math.isfinite(value)
    if ok and low is not None:
        ok = value > low if strict else value >= low
    if not ok:
        bound = "" if low is None else f" {'>' if strict else '>='} {low:g}"
        raise FieldDiagError(f"{owner}: {name}={value!r} is invalid; give a finite number{bound}.")
