"""The grey-box fit's names for the effect library (kept for existing imports).

Every effect is defined once, in :mod:`fielddiag.effects`; this module only re-exports it
under the names the identification code has used (a *term* is an effect in a model).
"""

from __future__ import annotations

from fielddiag.effects import (
    EFFECTS,
    AsymmetricDamping,
    BumpStop,
    CoulombFriction,
    CouplingSpring,
    CubicStiffness,
    Effect,
    ForceModel,
    LinearDamper,
    LinearSpring,
    ParamSpec,
    QuadraticDamping,
    get_effect,
    linear_model,
    model_from_sim,
    split_shape,
)
from fielddiag.effects.compose import model_force

__all__ = [
    "TERMS",
    "AsymmetricDamping",
    "BumpStop",
    "CouplingSpring",
    "CoulombFriction",
    "CubicStiffness",
    "ForceModel",
    "LinearDamper",
    "LinearSpring",
    "ParamSpec",
    "QuadraticDamping",
    "Term",
    "linear_model",
    "make_term",
    "model_force",
    "model_from_sim",
    "split_shape",
]

#: An effect as a term of a model to fit.
Term = Effect
#: The registry (linear terms and effects by public name).
TERMS = EFFECTS


def make_term(name: str, **settings: float) -> Effect:
    """A term of a model from its public name (``"coulomb_friction"``) and optional settings.

    Parameters
    ----------
    name : str
        Registered effect or linear-term name.
    **settings : float
        Fit settings of the term (``width_m`` of the bump stop [m]).

    Returns
    -------
    Effect
        The term, without parameter values.

    Raises
    ------
    FieldDiagError
        Unknown name or setting.
    """
    return get_effect(name)(**settings)
