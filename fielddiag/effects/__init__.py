"""The effect library: every physical effect of the suspension force, defined once.

Each effect is one class in one module of this package (its force law as a numba kernel
with the derivatives the grey-box sensitivity equations need, its parameters with SI
units and bounds, its static contribution, its step-size bounds for the simulator and its
plain-language description and explanation); see :mod:`fielddiag.effects.base`. The
simulator (:mod:`fielddiag.sim`), the grey-box fit (:mod:`fielddiag.identify.greybox`),
the on-line estimator and the diagnosis (:mod:`fielddiag.diagnose`) all take effects from
the registry :data:`EFFECTS`. Adding an effect means adding one module here (every
module of the package is imported and registers its classes), or registering a class with
:func:`register_effect` from anywhere.
"""

from fielddiag.effects.asymmetric_damping import AsymmetricDamping
from fielddiag.effects.base import (
    EFFECTS,
    RATE_BOUND_MPS,
    TRAVEL_BOUND_M,
    Effect,
    ParamSpec,
    diagnosis_effects,
    get_effect,
    make_effect,
    register_effect,
    unregister_effect,
)
from fielddiag.effects.bouc_wen import BoucWen
from fielddiag.effects.bump_stop import BumpStop
from fielddiag.effects.coulomb_friction import CoulombFriction
from fielddiag.effects.cubic_stiffness import CubicStiffness
from fielddiag.effects.digressive_damping import DigressiveDamping
from fielddiag.effects.hysteretic_spring import HystereticSpring
from fielddiag.effects.linear import CouplingSpring, LinearDamper, LinearSpring
from fielddiag.effects.model import ForceModel, linear_model, model_from_sim, split_shape
from fielddiag.effects.quadratic_damping import QuadraticDamping
from fielddiag.effects.series_top_mount import SeriesTopMount
from fielddiag.effects.travel_dependent_damping import TravelDependentDamping

_INFRASTRUCTURE = {"base", "compose", "model"}


def _import_all() -> None:
    """Import every effect module of this package (each registers its classes), so that a
    new effect needs only its file."""
    import importlib
    import pkgutil

    for m in pkgutil.iter_modules(__path__):
        if m.name not in _INFRASTRUCTURE and not m.name.startswith("_"):
            importlib.import_module(f"{__name__}.{m.name}")


_import_all()

__all__ = [
    "EFFECTS",
    "RATE_BOUND_MPS",
    "TRAVEL_BOUND_M",
    "AsymmetricDamping",
    "BoucWen",
    "BumpStop",
    "CoulombFriction",
    "CouplingSpring",
    "CubicStiffness",
    "DigressiveDamping",
    "Effect",
    "ForceModel",
    "HystereticSpring",
    "LinearDamper",
    "LinearSpring",
    "ParamSpec",
    "QuadraticDamping",
    "SeriesTopMount",
    "TravelDependentDamping",
    "diagnosis_effects",
    "get_effect",
    "linear_model",
    "make_effect",
    "model_from_sim",
    "register_effect",
    "split_shape",
    "unregister_effect",
]
