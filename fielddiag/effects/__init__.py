"""The effect library: every physical effect of the suspension force, defined once.

Each effect is one class in one module of this package (its force law as a numba kernel
with the derivatives the grey-box sensitivity equations need, its parameters with SI
units and bounds, its static contribution, its step-size bounds for the simulator and its
plain-language description and explanation); see :mod:`fielddiag.effects.base`. The
simulator (:mod:`fielddiag.sim`), the grey-box fit (:mod:`fielddiag.identify.greybox`),
the on-line estimator and the diagnosis (:mod:`fielddiag.diagnose`) all take effects from
the registry :data:`EFFECTS`. Adding an effect means adding one module here (and its
import below), or registering a class with :func:`register_effect` from anywhere.
"""

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
from fielddiag.effects.linear import CouplingSpring, LinearDamper, LinearSpring  # noqa: I001
from fielddiag.effects.coulomb_friction import CoulombFriction
from fielddiag.effects.cubic_stiffness import CubicStiffness
from fielddiag.effects.bump_stop import BumpStop
from fielddiag.effects.asymmetric_damping import AsymmetricDamping
from fielddiag.effects.quadratic_damping import QuadraticDamping
from fielddiag.effects.hysteretic_spring import HystereticSpring
from fielddiag.effects.model import ForceModel, linear_model, model_from_sim, split_shape

__all__ = [
    "EFFECTS",
    "RATE_BOUND_MPS",
    "TRAVEL_BOUND_M",
    "AsymmetricDamping",
    "BumpStop",
    "CoulombFriction",
    "CouplingSpring",
    "CubicStiffness",
    "Effect",
    "ForceModel",
    "HystereticSpring",
    "LinearDamper",
    "LinearSpring",
    "ParamSpec",
    "QuadraticDamping",
    "diagnosis_effects",
    "get_effect",
    "linear_model",
    "make_effect",
    "model_from_sim",
    "register_effect",
    "split_shape",
    "unregister_effect",
]
