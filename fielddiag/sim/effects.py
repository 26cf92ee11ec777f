"""The simulator's view of the effect library: effects with parameter values.

Every effect is defined once, in :mod:`fielddiag.effects` (its force law, parameters,
static contribution and step-size bounds); the simulator adds each one given with values
to the linear spring and damper of the car. This module keeps the simulator's names.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from fielddiag.effects import (
    EFFECTS as _REGISTRY,
)
from fielddiag.effects import (
    AsymmetricDamping,
    BumpStop,
    CoulombFriction,
    CubicStiffness,
    Effect,
    HystereticSpring,
    QuadraticDamping,
    make_effect,
)
from fielddiag.errors import FieldDiagError

__all__ = [
    "EFFECTS",
    "AsymmetricDamping",
    "BumpStop",
    "CoulombFriction",
    "CubicStiffness",
    "Effect",
    "HystereticSpring",
    "QuadraticDamping",
    "effects_from_dicts",
    "make_effect",
]

#: The library's effects (not the linear terms) by public name, as registered at import.
EFFECTS: dict[str, type[Effect]] = {n: c for n, c in _REGISTRY.items() if not c.linear}


def effects_from_dicts(items: Sequence[dict[str, Any]]) -> tuple[Effect, ...]:
    """Inverse of ``[e.to_dict() for e in effects]``."""
    return tuple(make_effect(d["name"], **d.get("params", {}), **d.get("settings", {}))
                 for d in items)


def check_effects(effects: Sequence[Any]) -> tuple[Effect, ...]:
    """The effects as a tuple, each a library effect with parameter values.

    Raises
    ------
    FieldDiagError
        Not an effect, a linear term, or an effect without values.
    """
    out = tuple(effects)
    for e in out:
        if not isinstance(e, Effect) or e.linear:
            raise FieldDiagError(f"effects must be Effect objects (see make_effect), got {e!r}.")
        if e.values is None:
            raise FieldDiagError(
                f"effect {e.name!r} has no parameter values; give them, e.g. "
                f"make_effect({e.name!r}, {e.params[0].name}=...)."
            )
    return out
