"""The abstract suspension effect, its parameter specification and the registry.

An effect is one term of the force of the suspension (and of the coupling to the rest of
the car) on the body::

    F(r, rdot, x2; theta) = sum over effects of F_effect(r, rdot, x2; theta_effect)

with ``r = x2 - x1`` the suspension extension from the static ride height of the car
without added mass, ``rdot`` its rate and ``x2`` the body position (the conventions of
:mod:`fielddiag.sim`). One class per effect, in one file of :mod:`fielddiag.effects`,
holds everything the simulator, the grey-box fit and the diagnosis need:

* ``params``: the fitted parameters (:class:`ParamSpec`: SI name and unit, bounds, typical
  value, whether the force is proportional to it, a label and driving advice);
* ``kernel``: the force law as a numba function (see :class:`Effect`), which also returns
  the derivatives with respect to the states and the parameters (the sensitivity
  equations of the grey-box fit); the vectorised numpy form :meth:`Effect.force` runs the
  same kernel over arrays, so the law is written once;
* :meth:`Effect.static_force_n`: its contribution at rest (static equilibrium);
* :meth:`Effect.speed_bounds`: the stiffness, damping and rate it can add (the
  simulator's step-size check);
* ``description`` and :meth:`Effect.explain`: plain language for the diagnosis.

An instance either describes a term of a model to fit (``CoulombFriction()``) or, given
parameter values, an effect to simulate (``CoulombFriction(friction_force_n=80.0)``).

Effects with an internal state (hysteresis: Dahl, Bouc-Wen; a series top mount) set
``n_states`` > 0; their kernel then also receives the state ``z`` and writes its rate
``dz/dt`` (see :class:`Effect`). The simulator, the grey-box fit and rig mode integrate
the states along the motion (:meth:`ForceModel.force_along_path`); the fit propagates
the states' sensitivities through the same RK4 steps, from the partial derivatives its
``state_partials`` kernel gives (forward differences of the whole simulation for an
effect without one).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from fielddiag.errors import FieldDiagError

if TYPE_CHECKING:  # pragma: no cover
    from fielddiag.effects.model import ForceModel

__all__ = [
    "EFFECTS",
    "RATE_BOUND_MPS",
    "TRAVEL_BOUND_M",
    "Effect",
    "ParamSpec",
    "diagnosis_effects",
    "get_effect",
    "make_effect",
    "register_effect",
    "unregister_effect",
]

INF = math.inf
#: Bounds on suspension travel [m] and rate [m/s] over which :meth:`Effect.speed_bounds`
#: estimates the largest stiffness and damping an effect adds.
TRAVEL_BOUND_M = 0.15
RATE_BOUND_MPS = 2.0


@dataclass(frozen=True)
class ParamSpec:
    """One parameter of an effect.

    Parameters
    ----------
    name : str
        SI name with its unit (``suspension_stiffness_n_per_m``).
    unit : str
        Unit of the absolute value (``N/m``).
    lower, upper : float
        Bounds of the absolute value in a fit (``-inf``/``inf`` when free).
    typical : float
        A typical absolute value for a passenger-car corner (start value, scale).
    scales_with_force : bool
        True if the force is proportional to this parameter (stiffness, damping, friction
        force); then the per-unit-mass value is ``value / mass``. False for geometric
        parameters (a gap in m).
    label : str
        Short name for people (``stiffness``, ``damping``).
    advice : str
        How to drive so that this parameter becomes observable.
    shape : bool
        True for a parameter of the fitted *form* rather than of the physics a technician
        acts on (friction's smoothing velocity): a diagnosis reports it apart, under
        ``shape``, and only its upper bound makes a fit unphysical.
    default : float or None
        Value a simulated effect takes when it is not given (None: it must be given).
    valid_low : float or None
        Lowest value a simulated effect accepts (None: ``lower`` if finite, else any).
    valid_strict : bool
        ``valid_low`` itself is not accepted (a stiffness must be > 0).
    significant : bool
        A fitted value within two standard deviations of zero (or negative) means the
        effect is not there: the diagnosis calls it unphysical.
    resolved_travel : bool
        A travel over which an internal state changes (a hysteresis's yield travel). A
        fit keeps it at or above the travel the data resolve
        (:data:`fielddiag.effects.model.RESOLVED_FRACTION` of the
        suspension's rms travel per sample): shorter, the loop closes between two samples,
        the data cannot tell it from its limit (friction) and the state would need
        ever more substeps.
    """

    name: str
    unit: str
    lower: float
    upper: float
    typical: float
    scales_with_force: bool
    label: str
    advice: str
    shape: bool = False
    default: float | None = None
    valid_low: float | None = None
    valid_strict: bool = False
    significant: bool = False
    resolved_travel: bool = False

    def per_unit_mass_name(self) -> str:
        """Name of the per-unit-mass value (``..._per_kg`` for force-scaled parameters).

        Returns
        -------
        str
            ``name + "_per_kg"`` if ``scales_with_force``, else ``name``.
        """
        return f"{self.name}_per_kg" if self.scales_with_force else self.name

    def per_unit_mass_unit(self) -> str:
        """Unit of the per-unit-mass value.

        Returns
        -------
        str
            ``unit + "/kg"`` if ``scales_with_force`` (``N/m/kg``), else ``unit``.
        """
        return f"{self.unit}/kg" if self.scales_with_force else self.unit

    def check(self, owner: str, value: float) -> None:
        """Raise FieldDiagError unless ``value`` is valid for a simulated effect.

        Valid means finite and at least ``valid_low`` (strictly above it if ``valid_strict``);
        without ``valid_low`` the finite ``lower`` bound, if any, is the limit.

        Parameters
        ----------
        owner : str
            Name of the effect, for the message.
        value : float
            The absolute value in the parameter's unit (``unit``).

        Raises
        ------
        FieldDiagError
            The value is not finite or below the limit.
        """
        low = self.valid_low
        if low is None and math.isfinite(self.lower):
            low = self.lower
        ok = math.isfinite(value)
        if ok and low is not None:
            ok = value > low if self.valid_strict else value >= low
        if not ok:
            bound = "" if low is None else f" {'>' if self.valid_strict else '>='} {low:g}"
            raise FieldDiagError(
                f"{owner}: {self.name}={value!r} is invalid; give a finite number{bound}."
            )


class Effect:
    """Base class of the suspension effects. Subclasses set the class attributes and a kernel.

    Class attributes
    ----------------
    name : str
        Public name (``coulomb_friction``); unique in a model and in the registry; part of
        the JSON interface.
    params : tuple of ParamSpec
        Fitted parameters, in kernel order.
    constants : dict of str to float
        Fixed settings of a fit with their default values (passed to the kernel as ``c``).
    truth_constants : dict of str to float
        Settings a *simulated* effect (one given parameter values) takes by default, where
        they differ from ``constants`` (the bump stop's sharp hinge).
    replaces : tuple of str
        Names of effects this one replaces when both are in a model (asymmetric damping
        replaces the linear damper).
    linear_in_params : bool
        True if the force is linear in its force-scaled parameters once the others are
        fixed at typical values: then an equation-error least-squares fit is exact and
        gives start values.
    linear : bool
        Part of the linear model (spring, damper, coupling), not an effect a diagnosis
        names or the simulator adds.
    diagnosable : bool
        Tried by default as a candidate by the diagnosis.
    diagnosis_rank : int
        Order among the diagnosis's candidates (lower first; ties by name).
    names_physics : bool
        A law of some physics (False for a shape that names nothing, the force surface:
        not drawn as a concealed effect, never reported by name).
    n_states : int
        Internal states (0 for a memoryless force law).
    description : str
        One plain-language line (``dry friction in the strut``).
    kernel : numba function
        Memoryless (``n_states == 0``)::

            kernel(r, rdot, x2, p, c, dp) -> (F, dF/dr, dF/drdot, dF/dx2)

        writing ``dF/dp`` into ``dp`` (same length as ``p``); ``F`` in N (or N/kg when the
        force-scaled parameters are per unit mass). With internal states::

            kernel(r, rdot, x2, z, p, c, dp, dz) -> (F, dF/dr, dF/drdot, dF/dx2)

        where ``z`` holds the effect's states and ``dz`` receives ``dz/dt``.
    data_twins : tuple of str
        Data problems (:mod:`fielddiag.diagnose.data_hypotheses` kinds) this physics
        looks like: where the data suggest one, the effect is fitted whatever its
        screening said, so that the two compete (a top mount's lag and a late channel).
    state_partials : numba function or None
        Effects with internal states: the partial derivatives the sensitivity equations
        of the states need (the exact Jacobian of the grey-box fit and of
        :meth:`~fielddiag.effects.model.ForceModel.force_along_path`)::

            state_partials(r, rdot, x2, z, p, c, dfz, dgs, dgz, dgp)

        writing ``dF/dz`` into ``dfz`` ``(n_states,)``, and the derivatives of the state
        rates ``g = dz/dt`` with respect to ``(r, rdot, x2)`` into ``dgs``
        ``(n_states, 3)``, to the states into ``dgz`` ``(n_states, n_states)`` and to the
        parameters into ``dgp`` ``(n_states, n_params)`` (every entry written at every
        call). None: those derivatives are taken by forward differences of the whole
        simulation (one more run per parameter).

    Parameters
    ----------
    *values : float
        Parameter values in ``params`` order (a simulated effect).
    **kw : float
        Parameter values and settings by name. Without any parameter value the instance is
        a term of a model to fit.

    Raises
    ------
    FieldDiagError
        Too many values, an unknown name, a setting that is not a number >= 0, a missing
        parameter, or a value :meth:`ParamSpec.check` refuses.

    Examples
    --------
    ::

        CoulombFriction()                          # a term of a model to fit
        CoulombFriction(friction_force_n=80.0)     # an effect to simulate (v_s default)
        LinearSpring() + LinearDamper() + CoulombFriction()   # a ForceModel
    """

    name: ClassVar[str]
    params: ClassVar[tuple[ParamSpec, ...]]
    constants: ClassVar[dict[str, float]] = {}
    truth_constants: ClassVar[dict[str, float]] = {}
    replaces: ClassVar[tuple[str, ...]] = ()
    linear_in_params: ClassVar[bool] = True
    linear: ClassVar[bool] = False
    diagnosable: ClassVar[bool] = False
    diagnosis_rank: ClassVar[int] = 100
    names_physics: ClassVar[bool] = True
    n_states: ClassVar[int] = 0
    state_partials: ClassVar[Any] = None
    data_twins: ClassVar[tuple[str, ...]] = ()
    description: ClassVar[str] = ""
    kernel: ClassVar[Any]

    def __init__(self, *values: float, **kw: Any) -> None:
        names = [p.name for p in self.params]
        if len(values) > len(names):
            raise FieldDiagError(
                f"effect {self.name!r} takes {len(names)} parameter(s) {names}, "
                f"got {len(values)} values"
            )
        given: dict[str, Any] = dict(zip(names, values, strict=False))
        settings: dict[str, Any] = {}
        unknown = []
        for k, v in kw.items():
            if k in names:
                given[k] = v
            elif k in self.constants:
                settings[k] = v
            else:
                unknown.append(k)
        if unknown:
            raise FieldDiagError(
                f"term {self.name!r} has no setting or parameter {sorted(unknown)}; its "
                f"parameters are {names} and its settings {sorted(self.constants) or 'none'}"
            )
        base = dict(self.constants)
        if given:
            base.update(self.truth_constants)
        base.update(settings)
        self.settings: dict[str, float] = {}
        for k, v in base.items():
            v = _as_float(self.name, k, v)
            if not math.isfinite(v) or v < 0:
                raise FieldDiagError(f"term {self.name!r}: {k}={v!r} must be a number >= 0")
            self.settings[k] = v
        self.values: dict[str, float] | None = None
        if given:
            missing = [p.name for p in self.params if p.name not in given and p.default is None]
            if missing:
                raise FieldDiagError(
                    f"effect {self.name!r}: missing {missing}; its parameters are {names} "
                    "(SI units as named)."
                )
            vals = {}
            for p in self.params:
                v = _as_float(self.name, p.name, given.get(p.name, p.default))
                p.check(self.name, v)
                vals[p.name] = v
            self.values = vals

    # ------------------------------------------------------------------ composition
    def __add__(self, other: Effect | ForceModel) -> ForceModel:
        from fielddiag.effects.model import ForceModel

        return ForceModel([self]) + other

    def __radd__(self, other: Any) -> ForceModel:
        from fielddiag.effects.model import ForceModel

        if other == 0:  # sum([...])
            return ForceModel([self])
        return NotImplemented

    # ------------------------------------------------------------------ descriptions
    @property
    def param_names(self) -> tuple[str, ...]:
        """Parameter names, in kernel order."""
        return tuple(p.name for p in self.params)

    def constant_values(self) -> np.ndarray:
        """The settings as the kernel sees them (``constants`` order).

        Returns
        -------
        numpy.ndarray
            ``(len(constants),)`` values of the settings (SI, e.g. ``width_m`` [m]).
        """
        return np.array([self.settings[k] for k in self.constants], dtype=float)

    def value_vector(self, values: Mapping[str, float] | Sequence[float] | None = None
                     ) -> np.ndarray:
        """Parameter values in kernel order: given, else the instance's, else typical.

        Parameters
        ----------
        values : mapping, sequence or None
            A sequence is taken as the vector itself (kernel order); a mapping by parameter name
            overrides the instance's values; missing names take ``ParamSpec.typical``.

        Returns
        -------
        numpy.ndarray
            ``(n_params,)`` values in the parameters' units (absolute, or per unit mass if
            given so).
        """
        if values is not None and not isinstance(values, Mapping):
            return np.asarray(values, dtype=float).reshape(-1)
        own = self.values or {}
        vals = values or {}
        return np.array([float(vals.get(p.name, own.get(p.name, p.typical)))
                         for p in self.params])

    def to_dict(self) -> dict[str, Any]:
        """``{"name", "settings"}`` of a term, or ``{"name", "params"}`` of a simulated effect
        (plus ``settings`` where they differ from the defaults); inverse of
        :func:`make_effect` / :func:`effect_from_dict`.

        Returns
        -------
        dict
            JSON-ready; parameter values in SI units by their SI names.
        """
        if self.values is None:
            return {"name": self.name, "settings": dict(self.settings)}
        out: dict[str, Any] = {"name": self.name, "params": dict(self.values)}
        default = {**self.constants, **self.truth_constants}
        if self.settings != default:
            out["settings"] = dict(self.settings)
        return out

    def __getattr__(self, item: str) -> float:
        vals = self.__dict__.get("values")
        if vals and item in vals:
            return vals[item]
        raise AttributeError(f"{type(self).__name__} has no attribute {item!r}")

    def __repr__(self) -> str:
        parts = [f"{k}={v:g}" for k, v in (self.values or {}).items()]
        parts += [f"{k}={v:g}" for k, v in self.settings.items()]
        return f"{type(self).__name__}({', '.join(parts)})"

    def __eq__(self, other: object) -> bool:
        return (type(self) is type(other) and self.settings == other.settings  # type: ignore
                and self.values == other.values)  # type: ignore[attr-defined]

    def __hash__(self) -> int:
        return hash((type(self).__name__, tuple(sorted(self.settings.items())),
                     tuple(sorted((self.values or {}).items()))))

    def as_term(self) -> Effect:
        """The same effect as a term of a model to fit (no values, the fit's settings).

        Returns
        -------
        Effect
            A new instance of the same class without parameter values.
        """
        return type(self)()

    # ------------------------------------------------------------------ numerics
    def force(self, r: np.ndarray | float, rdot: np.ndarray | float,
              x2: np.ndarray | float = 0.0,
              values: Mapping[str, float] | Sequence[float] | None = None,
              states: np.ndarray | None = None,
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The force law and its derivatives at arrays of states (the kernel, vectorised).

        Parameters
        ----------
        r, rdot, x2 : array_like
            Suspension extension [m], its rate [m/s] and body position [m] (broadcast).
        values : mapping, sequence or None
            Parameter values (SI, or per unit mass for a force per unit mass); None: the
            instance's values, else typical values.
        states : (n, n_states) array or None
            Internal states (effects with ``n_states`` > 0; default zeros).

        Returns
        -------
        force : (n,) array
            Force on the body [N] (positive up).
        d_state : (n, 3) array
            dF/dr [N/m], dF/drdot [N s/m], dF/dx2 [N/m].
        d_params : (n, n_params) array
            Derivatives with respect to the parameters.
        """
        from fielddiag.effects.model import ForceModel

        return ForceModel([self]).force(r, rdot, x2, self.value_vector(values), states=states)

    def static_states(self, r: float, values: Sequence[float]) -> np.ndarray:
        """Internal states at rest at extension ``r`` [m] (loaded slowly from r = 0).

        Parameters
        ----------
        r : float
            Suspension extension [m].
        values : sequence of float
            Parameter values in kernel order.

        Returns
        -------
        numpy.ndarray
            ``(n_states,)``; empty for a memoryless effect.
        """
        return np.zeros(self.n_states)

    def static_force_n(self, r: np.ndarray | float, x2: np.ndarray | float = 0.0,
                       values: Mapping[str, float] | Sequence[float] | None = None
                       ) -> np.ndarray:
        """Contribution to the static equilibrium: the force at rest (``rdot`` = 0).

        Evaluated by the kernel's plain-Python form (no compilation): meant for the few
        evaluations of an equilibrium search, not for long arrays.

        Parameters
        ----------
        r, x2 : array_like
            Suspension extension and body position [m] (broadcast).
        values : mapping, sequence or None
            Parameter values (as :meth:`force`).

        Returns
        -------
        numpy.ndarray
            Force on the body at rest [N]; 0 for effects that act only in motion.
        """
        th = self.value_vector(values)
        c = self.constant_values()
        dp = np.zeros(max(th.size, 1))
        fn = self.kernel.py_func
        r_a, x_a = np.broadcast_arrays(np.asarray(r, float), np.asarray(x2, float))
        out = np.empty(r_a.shape)
        for i, (rv, xv) in enumerate(zip(r_a.ravel(), x_a.ravel(), strict=True)):
            if self.n_states:
                z = self.static_states(float(rv), th)
                out.flat[i] = fn(float(rv), 0.0, float(xv), z, th, c, dp, np.zeros_like(z))[0]
            else:
                out.flat[i] = fn(float(rv), 0.0, float(xv), th, c, dp)[0]
        return out

    def speed_bounds(self, values: Sequence[float]) -> tuple[float, float, float]:
        """Largest stiffness [N/m], damping [N s/m] and rate [1/s] the effect can add.

        Over suspension travel up to :data:`TRAVEL_BOUND_M` and rates up to
        :data:`RATE_BOUND_MPS`; the simulator chooses its step from them.

        Parameters
        ----------
        values : sequence of float
            Parameter values in kernel order.

        Returns
        -------
        (float, float, float)
        """
        return 0.0, 0.0, 0.0

    def relaxation_rate_per_s(self, values: Sequence[float]) -> float:
        """Rate [1/s] at which the internal states relax whatever the suspension's speed
        (a linear state equation's eigenvalue; 0: none). The grey-box simulation's RK4
        substeps keep ``step * rate`` within RK4's stability beside the speed-scaled rate
        of :meth:`speed_bounds`.

        Parameters
        ----------
        values : sequence of float
            Parameter values in kernel order.

        Returns
        -------
        float
        """
        return 0.0

    def resolved_upper(self, values: Sequence[float], shortest_time_s: float
                       ) -> np.ndarray | None:
        """Upper bounds (kernel order) that keep the states' relaxation no faster than the
        data resolve: a relaxation time of at least ``shortest_time_s`` at the other
        parameters' ``values`` (None: no such limit, the default).

        Parameters
        ----------
        values : sequence of float
            Parameter values in kernel order (where the fit starts).
        shortest_time_s : float
            Shortest relaxation time kept [s] (the sample interval over
            :data:`fielddiag.effects.model.MAX_RELAXATION_STEPS`).

        Returns
        -------
        ndarray or None
        """
        return None

    # ------------------------------------------------------------------ diagnosis
    def start_values(self, r_m: np.ndarray, start: Mapping[str, float]) -> dict[str, float]:
        """Start values of a screening fit on the measured travel ``r_m`` [m].

        Parameters
        ----------
        r_m : ndarray
            Measured suspension extension [m].
        start : mapping
            Values already known by model key (``linear_damper.suspension_damping_ns_per_m``).

        Returns
        -------
        dict
            Absolute start value by parameter name (missing ones: typical values).
        """
        return {}

    def twin_start(self, kind: str, value: float, start: Mapping[str, float]
                   ) -> dict[str, float]:
        """Start values that make the effect look like the data problem ``kind`` of size
        ``value`` (one of :attr:`data_twins`), so that a fit of it competing with that data
        problem starts where the two predict alike.

        Parameters
        ----------
        kind : str
            The data problem (``channel_time_offset``).
        value : float
            Its size (a delay [s]).
        start : mapping
            Values already known by model key.

        Returns
        -------
        dict
            Absolute start value by parameter name (empty: no such start, the default).
        """
        return {}

    @classmethod
    def looks_like_data(cls, kind: str, value: float) -> bool:
        """Whether the effect can look like the data problem ``kind`` of size ``value``
        (one of :attr:`data_twins`, of a sign the physics can make).

        Parameters
        ----------
        kind : str
            The data problem (``channel_time_offset``).
        value : float
            Its size (a delay of the body channel [s]).

        Returns
        -------
        bool
            ``kind in data_twins`` (the default; subclasses add the sign).
        """
        return kind in cls.data_twins

    def unphysical(self, values: Mapping[str, float], std: Mapping[str, float]) -> bool:
        """True if the fitted effect as a whole is not physical (beyond single parameters).

        The base class never says so; subclasses add tests that involve several parameters
        (asymmetric damping whose two coefficients agree).

        Parameters
        ----------
        values, std : mapping
            Fitted values and standard deviations by parameter name.

        Returns
        -------
        bool
        """
        return False

    def explain(self, params: Mapping[str, float], per: str = "", hidden: str = "") -> str:
        """A sentence a technician can act on.

        The base class lists the values after ``description``; subclasses word it for their
        physics.

        Parameters
        ----------
        params : mapping
            Fitted physical parameters by name (``_per_kg`` names in per-unit-mass mode).
        per : str
            Unit suffix for per-unit-mass values (`` per kg of sprung mass``) or "".
        hidden : str
            How the linear fit distorted its parameters to absorb the effect, or "".

        Returns
        -------
        str
        """
        vals = ", ".join(f"{k} = {v:.3g}" for k, v in params.items())
        return f"{self.description} ({vals}{per}){hidden}"


def _as_float(owner: str, name: str, v: Any) -> float:
    try:
        return float(v)
    except (TypeError, ValueError):
        raise FieldDiagError(
            f"effect {owner!r}: {name}={v!r} is not a number; give e.g. {name}=100."
        ) from None


# ---------------------------------------------------------------------------- registry
#: Every known effect (and linear term) by public name, in registration order.
EFFECTS: dict[str, type[Effect]] = {}


def register_effect(cls: type[Effect]) -> type[Effect]:
    """Add an effect class to :data:`EFFECTS` (usable as a class decorator).

    Parameters
    ----------
    cls : type
        An :class:`Effect` subclass with a unique ``name``.

    Returns
    -------
    type
        ``cls`` itself.

    Raises
    ------
    FieldDiagError
        Another class is registered under the same name.
    """
    old = EFFECTS.get(cls.name)
    if old is not None and old is not cls:
        raise FieldDiagError(f"an effect named {cls.name!r} is already registered ({old})")
    EFFECTS[cls.name] = cls
    return cls


def unregister_effect(name: str) -> None:
    """Remove an effect from the registry (tests that register throw-away effects).

    Parameters
    ----------
    name : str
        Public name of the effect; unknown names are ignored.
    """
    EFFECTS.pop(name, None)


def _usage(linear: bool = False) -> str:
    parts = []
    for name, cls in EFFECTS.items():
        if cls.linear and not linear:
            continue
        ps = ", ".join(p.name if p.default is None else f"[{p.name}]" for p in cls.params)
        parts.append(f"{name}({ps})")
    return "; ".join(parts)


def get_effect(name: str) -> type[Effect]:
    """The effect class registered under ``name``.

    Parameters
    ----------
    name : str
        Public name (``"coulomb_friction"``).

    Returns
    -------
    type
        The :class:`Effect` subclass.

    Raises
    ------
    FieldDiagError
        Unknown name.
    """
    cls = EFFECTS.get(name)
    if cls is None:
        raise FieldDiagError(f"unknown model term {name!r}; choose from {', '.join(EFFECTS)}")
    return cls


def make_effect(name: str, **params: Any) -> Effect:
    """A simulated effect from its public name and parameter values (strings converted).

    Parameters
    ----------
    name : str
        Registered effect name (not a linear term).
    **params : float or str
        Parameter values by SI name; optional ones take their default.

    Returns
    -------
    Effect

    Raises
    ------
    FieldDiagError
        Unknown name, unknown or missing parameter, or a value that is not a valid number.
    """
    cls = EFFECTS.get(name)
    if cls is None or cls.linear:
        raise FieldDiagError(
            f"unknown effect {name!r}; valid effects (optional params in brackets): {_usage()}."
        )
    valid = {p.name: p for p in cls.params}
    unknown = sorted(set(params) - set(valid) - set(cls.constants))
    missing = sorted(n for n, p in valid.items() if n not in params and p.default is None)
    if unknown or missing:
        raise FieldDiagError(
            f"effect {name!r}: unknown parameter(s) {unknown}, missing {missing}; "
            f"its parameters are {list(valid)} (SI units as named)."
        )
    return cls(**params)


def diagnosis_effects() -> tuple[str, ...]:
    """Names of the effects the diagnosis tries by default, by ``diagnosis_rank``.

    Returns
    -------
    tuple of str
        Registered effects with ``diagnosable`` set and not ``linear``, lowest rank first
        (ties by name).
    """
    found = [(c.diagnosis_rank, n) for n, c in EFFECTS.items() if c.diagnosable and not c.linear]
    return tuple(n for _, n in sorted(found))
