"""Suspension force as a sum of terms: the model library of the grey-box fit.

The force of the suspension (and of the coupling to the rest of the car) on the body is

    F(r, rdot, x2; theta) = sum over terms of F_term(r, rdot, x2; theta_term)

with ``r = x2 - x1`` the suspension extension from the static ride height of the car
without added mass (the convention of :mod:`fielddiag.sim`), ``rdot`` its rate and ``x2``
the body position. A model is built like a pysindy feature library::

    model = LinearSpring() + LinearDamper() + CoulombFriction()

Each term is one small class: its parameters (name, SI unit, bounds, typical value,
whether the parameter scales with force), a few constants that are not fitted (e.g. the
corner width of the smoothed bump stop) and one numba-compiled ``kernel``::

    kernel(r, rdot, x2, p, c, dp) -> (F, dF/dr, dF/drdot, dF/dx2)

which also writes ``dF/dp[j]`` into ``dp``. The model assembles the kernels of its terms
into one compiled function (a few lines of generated source, cached per combination of
term classes), which the simulation and sensitivity integrator of
:mod:`fielddiag.identify.greybox` and the on-line estimator call per sample.

Contract of a term: its force is proportional to its force-scaled parameters (those with
``scales_with_force``), so dividing every force-scaled parameter by the mass gives the
same model per unit mass. This is what lets one session identify ratios (K2/M2, C2/M2...)
and two sessions with a known added mass identify absolute values.
"""

from __future__ import annotations

import ast
import hashlib
import importlib
import importlib.util
import math
import os
import sys
import textwrap
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace
from typing import Any, ClassVar

import numpy as np
from numba import njit

from fielddiag.errors import FieldDiagError

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
    "Term",
    "linear_model",
    "make_term",
    "model_from_sim",
]

_INF = math.inf


@dataclass(frozen=True)
class ParamSpec:
    """One parameter of a term.

    Parameters
    ----------
    name : str
        SI name with its unit (``suspension_stiffness_n_per_m``).
    unit : str
        Unit of the absolute value (``N/m``).
    lower, upper : float
        Bounds of the absolute value (``-inf``/``inf`` when free).
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
        ``shape``, and keeps ``parameters`` to the effect's physical quantities.
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

    def per_unit_mass_name(self) -> str:
        """Name of the per-unit-mass value (``..._per_kg`` for force-scaled parameters)."""
        return f"{self.name}_per_kg" if self.scales_with_force else self.name

    def per_unit_mass_unit(self) -> str:
        """Unit of the per-unit-mass value."""
        return f"{self.unit}/kg" if self.scales_with_force else self.unit


class Term:
    """Base class of a force term. Subclasses set the class attributes and a kernel.

    Class attributes
    ----------------
    name : str
        Public name (``linear_spring``); unique in a model.
    params : tuple of ParamSpec
        Fitted parameters, in kernel order.
    constants : dict of str to float
        Fixed settings with their default values (passed to the kernel as ``c``).
    replaces : tuple of str
        Names of terms this one replaces when both are in a model (asymmetric damping
        replaces the linear damper).
    linear_in_params : bool
        True if the force is linear in its force-scaled parameters once the others (shape
        parameters such as a smoothing velocity, which keep their typical values) are
        fixed: then an equation-error least-squares fit of the force-scaled ones is exact
        and gives start values.
    kernel : numba function
        ``kernel(r, rdot, x2, p, c, dp) -> (F, dF/dr, dF/drdot, dF/dx2)``; writes
        ``dF/dp`` into ``dp`` (same length as ``p``).

    Parameters
    ----------
    **constants : float
        Override the class's constants (e.g. ``BumpStop(width_m=2e-3)``).
    """

    name: ClassVar[str]
    params: ClassVar[tuple[ParamSpec, ...]]
    constants: ClassVar[dict[str, float]] = {}
    replaces: ClassVar[tuple[str, ...]] = ()
    linear_in_params: ClassVar[bool] = True
    kernel: ClassVar[Any]

    def __init__(self, **constants: float) -> None:
        unknown = sorted(set(constants) - set(self.constants))
        if unknown:
            raise FieldDiagError(
                f"term {self.name!r} has no setting {unknown}; its settings are "
                f"{sorted(self.constants) or 'none'}"
            )
        values = {**self.constants, **{k: float(v) for k, v in constants.items()}}
        for k, v in values.items():
            if not math.isfinite(v) or v <= 0:
                raise FieldDiagError(f"term {self.name!r}: {k}={v!r} must be a positive number")
        self.settings: dict[str, float] = values

    # ------------------------------------------------------------------ composition
    def __add__(self, other: Term | ForceModel) -> ForceModel:
        return ForceModel([self]) + other

    def __radd__(self, other: Any) -> ForceModel:
        if other == 0:  # sum([...])
            return ForceModel([self])
        return NotImplemented

    # ------------------------------------------------------------------ descriptions
    @property
    def param_names(self) -> tuple[str, ...]:
        """Parameter names, in kernel order."""
        return tuple(p.name for p in self.params)

    def constant_values(self) -> np.ndarray:
        """The constants as the kernel sees them."""
        return np.array([self.settings[k] for k in self.constants], dtype=float)

    def to_dict(self) -> dict[str, Any]:
        """``{"name": ..., "settings": {...}}``; inverse of :func:`make_term`."""
        return {"name": self.name, "settings": dict(self.settings)}

    def __repr__(self) -> str:
        s = ", ".join(f"{k}={v:g}" for k, v in self.settings.items())
        return f"{type(self).__name__}({s})"

    def __eq__(self, other: object) -> bool:
        return type(self) is type(other) and self.settings == other.settings  # type: ignore

    def __hash__(self) -> int:
        return hash((type(self).__name__, tuple(sorted(self.settings.items()))))

    # ------------------------------------------------------------------ numerics
    def force(
        self, r: np.ndarray, rdot: np.ndarray, x2: np.ndarray, values: Sequence[float]
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Force and its derivatives at arrays of states (for tests and plots).

        Returns
        -------
        force : (n,) array
        d_state : (n, 3) array
            dF/dr, dF/drdot, dF/dx2.
        d_params : (n, n_params) array
        """
        return ForceModel([self]).force(r, rdot, x2, values)


def _spec(name, unit, lower, upper, typical, scaled, label, advice, shape=False) -> ParamSpec:
    return ParamSpec(name, unit, lower, upper, typical, scaled, label, advice, shape)


_ADVICE_STIFFNESS = "drive over long undulations or speed humps at moderate speed (body bounce)"
_ADVICE_DAMPING = "drive over sharper bumps (potholes, cobbles, expansion joints)"


# ---------------------------------------------------------------------------- linear terms
@njit(cache=True, nogil=True)
def _linear_spring(r, rd, x2, p, c, dp):  # pragma: no cover - compiled
    dp[0] = -r
    return -p[0] * r, -p[0], 0.0, 0.0


class LinearSpring(Term):
    """Suspension spring ``-K2 r``."""

    name = "linear_spring"
    params = (
        _spec("suspension_stiffness_n_per_m", "N/m", 0.0, _INF, 24e3, True, "stiffness",
              _ADVICE_STIFFNESS),
    )
    kernel = _linear_spring


@njit(cache=True, nogil=True)
def _linear_damper(r, rd, x2, p, c, dp):  # pragma: no cover - compiled
    dp[0] = -rd
    return -p[0] * rd, 0.0, -p[0], 0.0


class LinearDamper(Term):
    """Suspension damper ``-C2 rdot``."""

    name = "linear_damper"
    params = (
        _spec("suspension_damping_ns_per_m", "N s/m", 0.0, _INF, 1.8e3, True, "damping",
              _ADVICE_DAMPING),
    )
    kernel = _linear_damper


@njit(cache=True, nogil=True)
def _coupling_spring(r, rd, x2, p, c, dp):  # pragma: no cover - compiled
    dp[0] = -x2
    return -p[0] * x2, 0.0, 0.0, -p[0]


class CouplingSpring(Term):
    """Coupling of the corner to the rest of the body ``-K3 x2`` (may be negative)."""

    name = "coupling_spring"
    params = (
        _spec("coupling_stiffness_n_per_m", "N/m", -_INF, _INF, 2e3, True,
              "coupling stiffness", "drive over long, slow undulations (low-frequency body "
              "motion)"),
    )
    kernel = _coupling_spring


# ---------------------------------------------------------------------------- effect terms
@njit(cache=True, nogil=True)
def _coulomb_friction(r, rd, x2, p, c, dp):  # pragma: no cover - compiled
    u = rd / p[1]
    th = math.tanh(u)
    s = 1.0 - th * th
    dp[0] = -th
    dp[1] = p[0] * s * u / p[1]
    return -p[0] * th, 0.0, -p[0] * s / p[1], 0.0


class CoulombFriction(Term):
    """Dry friction ``-Ff tanh(rdot / v_s)``, both the force and the smoothing fitted.

    The smoothing velocity ``v_s`` is a parameter, not a constant: what a fit sees is dry
    friction driven by the *modelled* relative velocity, which lacks the vibration above
    the fit band (and between the samples of the analysis rate). That unmodelled ripple
    dithers the real friction across its zero crossings, so on the band-limited velocity
    the force switches more gently than the true one: an effective ``v_s`` of 15-30 mm/s
    on a class B-C road for a true 10 mm/s. With ``v_s`` held at the true value the fit
    explains the gentler switching with a smaller force (7-11 % low); fitting ``v_s``
    lets the data set the knee and keeps ``Ff``, the force at speed, unbiased. Hold it
    with ``fixed={"coulomb_friction.smoothing_velocity_mps": ...}`` when the model sees
    the full-band motion (simulator truth). Not force-scaled; bounded to 1-200 mm/s (below
    1 mm/s the switching cannot be resolved at analysis rates; towards 200 mm/s the term
    turns into a linear damper ``Ff / v_s``).
    """

    name = "coulomb_friction"
    params = (
        _spec("friction_force_n", "N", 0.0, _INF, 50.0, True, "friction",
              "drive slowly over small ripples (small, slow suspension strokes)"),
        _spec("smoothing_velocity_mps", "m/s", 1e-3, 0.2, 0.01, False,
              "friction smoothing velocity",
              "drive slowly over small ripples (many slow reversals of the suspension)",
              shape=True),
    )
    # linear in the force once the smoothing velocity is fixed (what the equation-error
    # start values need)
    linear_in_params = True
    kernel = _coulomb_friction


@njit(cache=True, nogil=True)
def _cubic_stiffness(r, rd, x2, p, c, dp):  # pragma: no cover - compiled
    r2 = r * r
    dp[0] = -r2 * r
    return -p[0] * r2 * r, -3.0 * p[0] * r2, 0.0, 0.0


class CubicStiffness(Term):
    """Progressive (cubic) spring ``-k3 r^3``; negative ``k3`` is a softening spring."""

    name = "cubic_stiffness"
    params = (
        _spec("cubic_stiffness_n_per_m3", "N/m^3", -_INF, _INF, 1e6, True,
              "progressive spring", "drive over larger bumps (large suspension travel)"),
    )
    kernel = _cubic_stiffness


@njit(cache=True, nogil=True)
def _bump_stop(r, rd, x2, p, c, dp):  # pragma: no cover - compiled
    # Smooth version of kb * max(0, -r - gap): kb * w * softplus((-r - gap) / w).
    w = c[0]
    z = (-r - p[0]) / w
    if z > 30.0:
        sp = z
        sig = 1.0
    elif z < -30.0:
        sp = math.exp(z)
        sig = sp
    else:
        sp = math.log1p(math.exp(z))
        sig = 1.0 / (1.0 + math.exp(-z))
    dp[0] = -p[1] * sig
    dp[1] = w * sp
    return p[1] * w * sp, -p[1] * sig, 0.0, 0.0


class BumpStop(Term):
    """Bump stop ``+kb (-r - gap)`` when compressed beyond ``gap``, smoothed.

    The corner of the hinge is rounded by a softplus of width ``width_m`` (1 mm) so that
    the force has continuous derivatives for Gauss-Newton.
    """

    name = "bump_stop"
    params = (
        _spec("gap_m", "m", 0.0, _INF, 0.06, False, "bump-stop gap",
              "drive over a large bump or pothole that compresses the suspension fully"),
        _spec("stiffness_n_per_m", "N/m", 0.0, _INF, 1e5, True, "bump-stop stiffness",
              "drive over a large bump or pothole that compresses the suspension fully"),
    )
    constants = {"width_m": 1e-3}
    linear_in_params = False
    kernel = _bump_stop


@njit(cache=True, nogil=True)
def _asymmetric_damping(r, rd, x2, p, c, dp):  # pragma: no cover - compiled
    if rd < 0.0:
        dp[0] = -rd
        dp[1] = 0.0
        return -p[0] * rd, 0.0, -p[0], 0.0
    dp[0] = 0.0
    dp[1] = -rd
    return -p[1] * rd, 0.0, -p[1], 0.0


class AsymmetricDamping(Term):
    """Damper with different compression (``rdot < 0``) and rebound coefficients.

    Replaces :class:`LinearDamper` in a model that has both.
    """

    name = "asymmetric_damping"
    params = (
        _spec("compression_damping_ns_per_m", "N s/m", 0.0, _INF, 1.2e3, True,
              "compression damping", "drive over sharp bumps (fast compression strokes)"),
        _spec("rebound_damping_ns_per_m", "N s/m", 0.0, _INF, 2.4e3, True,
              "rebound damping", "drive over sharp dips or potholes (fast rebound strokes)"),
    )
    replaces = ("linear_damper",)
    kernel = _asymmetric_damping


#: Registry of terms by public name.
TERMS: dict[str, type[Term]] = {
    cls.name: cls
    for cls in (LinearSpring, LinearDamper, CouplingSpring, CoulombFriction, CubicStiffness,
                BumpStop, AsymmetricDamping)
}


def make_term(name: str, **settings: float) -> Term:
    """A term from its public name (``"coulomb_friction"``) and optional settings.

    Raises
    ------
    FieldDiagError
        Unknown name or setting.
    """
    cls = TERMS.get(name)
    if cls is None:
        raise FieldDiagError(f"unknown model term {name!r}; choose from {', '.join(TERMS)}")
    return cls(**settings)


# ---------------------------------------------------------------------------- the model
_FORCE_CACHE: dict[tuple[type[Term], ...], Any] = {}
_BOUND_CACHE: dict[tuple[tuple[type[Term], ...], str, tuple[str, ...]], Any] = {}
#: Bump when the generated source changes shape.
_GENERATOR_VERSION = "1"


def _force_source(classes: tuple[type[Term], ...]) -> tuple[list[str], list[str]]:
    """(import lines, body lines) of ``model_force`` summing the terms' kernels."""
    imports, lines = [], [
        "def model_force(r, rd, x2, th, cs, dth):",
        "    f = 0.0",
        "    fr = 0.0",
        "    fv = 0.0",
        "    fx = 0.0",
    ]
    p0 = c0 = 0
    for i, cls in enumerate(classes):
        p1, c1 = p0 + len(cls.params), c0 + len(cls.constants)
        fn = cls.kernel.py_func
        imports.append(f"from {fn.__module__} import {fn.__name__} as k{i}")
        lines += [
            f"    a, b, c, d = k{i}(r, rd, x2, th[{p0}:{p1}], cs[{c0}:{c1}], dth[{p0}:{p1}])",
            "    f += a",
            "    fr += b",
            "    fv += c",
            "    fx += d",
        ]
        p0, c0 = p1, c1
    lines.append("    return f, fr, fv, fx")
    return imports, lines


def _assemble_force(classes: tuple[type[Term], ...]) -> Any:
    """Compile ``force(r, rd, x2, theta, consts, dtheta)`` summing the terms' kernels."""
    fn = _FORCE_CACHE.get(classes)
    if fn is not None:
        return fn
    _, lines = _force_source(classes)
    ns: dict[str, Any] = {f"k{i}": cls.kernel for i, cls in enumerate(classes)}
    exec(compile("\n".join(lines), f"<fielddiag model {classes}>", "exec"), ns)
    fn = njit(nogil=True)(ns["model_force"])
    _FORCE_CACHE[classes] = fn
    return fn


def _kernel_dir() -> Path | None:
    """Directory of the generated kernel modules (None: keep them in memory only)."""
    env = os.environ.get("FIELDDIAG_KERNEL_CACHE")
    if env == "":
        return None
    if not env:
        from fielddiag.cachedir import cache_dir

        return cache_dir("kernels")
    base = Path(env)
    try:
        base.mkdir(parents=True, exist_ok=True)
        probe = base / f".probe-{os.getpid()}"
        probe.write_text("")
        probe.unlink()
    except OSError:
        return None
    return base


def _module_text(module_name: str) -> str:
    mod = sys.modules.get(module_name) or importlib.import_module(module_name)
    path = getattr(mod, "__file__", None)
    if not path:
        raise OSError(f"{module_name} has no source file")
    return Path(path).read_text()


def _template_source(text: str, names: Sequence[str], cache: bool) -> list[str]:
    """The named top-level functions of a module's source, each under ``@njit``.

    The functions are found by name in the same text that is hashed for the cache key, so
    the generated module always matches its name even if the file changed meanwhile.
    """
    tree = ast.parse(text)
    found = {node.name: node for node in tree.body if isinstance(node, ast.FunctionDef)}
    out = []
    for name in names:
        if name not in found:
            raise SyntaxError(f"template {name!r} not found")
        src = ast.get_source_segment(text, found[name])
        out += [f"@njit(cache={cache}, nogil=True)", textwrap.dedent(src).rstrip(), "", ""]
    return out


def _compile_templates(classes: tuple[type[Term], ...], module_name: str,
                       names: tuple[str, ...]) -> Any:
    """Compile numba templates (plain functions calling the global ``model_force``) for the
    terms' force; return a namespace holding the compiled functions by name.

    A small module is generated: the terms' kernels imported, ``model_force`` assembled
    from them, then the templates' source, each under ``@njit(cache=True, nogil=True)``, with the
    template module's other globals (constants, helper functions). It is written to the
    kernel cache directory under a name that hashes the generator, the term classes and
    the source files involved, and imported, so numba's on-disk cache compiles each
    combination of terms once, not in every process. Terms defined outside an importable
    module (``__main__``) or an unwritable cache directory fall back to the same source
    compiled in memory, per process.
    """
    key = (classes, module_name, names)
    ns = _BOUND_CACHE.get(key)
    if ns is not None:
        return ns
    tmod_text = _module_text(module_name)
    imports, lines = _force_source(classes)
    kernel_mods = sorted({c.kernel.py_func.__module__ for c in classes})
    header = [
        "from numba import njit",
        f"import {module_name} as _template_module",
        "globals().update({_k: _v for _k, _v in vars(_template_module).items()",
        f"                 if not _k.startswith('__') and _k not in {('model_force', *names)!r}"
        "})",
        *imports,
        "",
        "",
    ]

    def source(cache: bool) -> str:
        return "\n".join([
            f'"""Generated by fielddiag.identify.terms from {module_name} '
            f"({', '.join(names)}) for {' + '.join(c.name for c in classes)}. Do not edit."
            '"""',
            *header, f"@njit(cache={cache}, nogil=True)", *lines, "", "",
            *_template_source(tmod_text, names, cache),
        ])

    directory = _kernel_dir()
    result: Any = None
    if directory is not None and "__main__" not in kernel_mods:
        try:
            digest = hashlib.sha1("|".join(
                [_GENERATOR_VERSION, module_name, *names]
                + [f"{c.__module__}.{c.__qualname__}" for c in classes]
                + [hashlib.sha1(_module_text(m).encode()).hexdigest()
                   for m in sorted({*kernel_mods, __name__})]
                + [hashlib.sha1(tmod_text.encode()).hexdigest()]
            ).encode()).hexdigest()[:24]
            name = f"fielddiag_kernel_{digest}"
            path = directory / f"{name}.py"
            if not path.exists():
                tmp = path.with_name(f".{name}.{os.getpid()}.tmp")
                tmp.write_text(source(True))
                os.replace(tmp, path)
            result = sys.modules.get(name)
            if result is None:
                spec = importlib.util.spec_from_file_location(name, path)
                result = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
                spec.loader.exec_module(result)  # type: ignore[union-attr]
                if not all(hasattr(result, n) for n in names):
                    path.unlink(missing_ok=True)
                    raise ImportError(f"{path} is incomplete")
                sys.modules[name] = result
        except (OSError, ImportError, SyntaxError):
            result = None
    if result is None:
        space: dict[str, Any] = {"__name__": f"fielddiag_kernel_{module_name}"}
        space.update({f"k{i}": c.kernel for i, c in enumerate(classes)})
        body = source(False).replace("\n".join(imports), "")
        exec(compile(body, f"<fielddiag kernel {module_name} {classes}>", "exec"), space)
        result = SimpleNamespace(**{n: space[n] for n in (*names, "model_force")})
    _BOUND_CACHE[key] = result
    return result


def model_force(r, rd, x2, th, cs, dth):  # pragma: no cover - placeholder
    """Placeholder for the templates: replaced by each model's compiled force."""
    raise NotImplementedError("templates are compiled per model by ForceModel.compile")


def _force_many(r, rd, x2, theta, consts):  # pragma: no cover - numba template
    n = r.shape[0]
    f = np.empty(n)
    ds = np.empty((n, 3))
    dp = np.empty((n, theta.shape[0]))
    for i in range(n):
        a, b, c, d = model_force(r[i], rd[i], x2[i], theta, consts, dp[i])
        f[i] = a
        ds[i, 0] = b
        ds[i, 1] = c
        ds[i, 2] = d
    return f, ds, dp


class ForceModel:
    """A sum of force terms (build it with ``+``).

    Parameters
    ----------
    terms : iterable of Term
        The terms. A term listed in another's ``replaces`` is dropped (asymmetric damping
        replaces the linear damper); a term given twice is an error.

    Notes
    -----
    Parameters are addressed by key ``"<term>.<param>"``; :meth:`index` also accepts a
    parameter's plain name when it is unique in the model.
    """

    def __init__(self, terms: Iterable[Term]) -> None:
        terms = list(terms)
        for t in terms:
            if not isinstance(t, Term):
                raise FieldDiagError(f"a model is made of Term objects, got {t!r}")
        names = [t.name for t in terms]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise FieldDiagError(f"model term(s) {dup} given twice; give each term once")
        replaced = {r for t in terms for r in t.replaces}
        self.terms: tuple[Term, ...] = tuple(t for t in terms if t.name not in replaced)
        if not self.terms:
            raise FieldDiagError("a model needs at least one term (e.g. LinearSpring())")
        self._specs: list[tuple[Term, ParamSpec]] = [(t, p) for t in self.terms for p in t.params]

    # ------------------------------------------------------------------ composition
    def __add__(self, other: Term | ForceModel) -> ForceModel:
        if isinstance(other, Term):
            return ForceModel([*self._all_terms(), other])
        if isinstance(other, ForceModel):
            return ForceModel([*self._all_terms(), *other._all_terms()])
        return NotImplemented

    def _all_terms(self) -> tuple[Term, ...]:
        return self.terms

    def __contains__(self, name: str) -> bool:
        return any(t.name == name for t in self.terms)

    def __len__(self) -> int:
        return len(self.terms)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, ForceModel) and self.terms == other.terms

    def __hash__(self) -> int:
        return hash(self.terms)

    def __repr__(self) -> str:
        return " + ".join(repr(t) for t in self.terms)

    def without(self, *names: str) -> ForceModel:
        """The model without the named terms."""
        return ForceModel([t for t in self.terms if t.name not in names])

    # ------------------------------------------------------------------ parameters
    @property
    def n_params(self) -> int:
        return len(self._specs)

    @property
    def specs(self) -> tuple[ParamSpec, ...]:
        """Parameter specifications in model order."""
        return tuple(p for _, p in self._specs)

    @property
    def param_keys(self) -> tuple[str, ...]:
        """``"<term>.<param>"`` for every parameter, in model order."""
        return tuple(f"{t.name}.{p.name}" for t, p in self._specs)

    @property
    def param_terms(self) -> tuple[str, ...]:
        """The term name of every parameter."""
        return tuple(t.name for t, _ in self._specs)

    @property
    def linear_in_params(self) -> bool:
        """True if every term is linear in its force-scaled parameters (see :class:`Term`)."""
        return all(t.linear_in_params for t in self.terms)

    def index(self, name: str) -> int:
        """Position of a parameter given by key or by unique plain (or ``_per_kg``) name."""
        keys = self.param_keys
        if name in keys:
            return keys.index(name)
        hits = [i for i, (_, p) in enumerate(self._specs)
                if name in (p.name, p.per_unit_mass_name())]
        if len(hits) == 1:
            return hits[0]
        if hits:
            raise FieldDiagError(f"parameter name {name!r} is ambiguous; use one of "
                                 f"{[keys[i] for i in hits]}")
        raise FieldDiagError(f"the model has no parameter {name!r}; it has {list(keys)}")

    def vector(self, values: Mapping[str, float] | Sequence[float] | np.ndarray | None = None,
               *, per_unit_mass_kg: float | None = None) -> np.ndarray:
        """Parameter vector from a mapping (missing entries take typical values) or sequence.

        Parameters
        ----------
        values : mapping, sequence or None
            By key or unique name; None gives the typical values.
        per_unit_mass_kg : float or None
            If given, divide the typical values of force-scaled parameters by this mass
            (typical values are absolute).
        """
        if values is not None and not isinstance(values, Mapping):
            v = np.asarray(values, dtype=float).reshape(-1)
            if v.size != self.n_params:
                raise FieldDiagError(f"expected {self.n_params} parameter values "
                                     f"({list(self.param_keys)}), got {v.size}")
            return v.copy()
        out = np.array([p.typical for p in self.specs], dtype=float)
        if per_unit_mass_kg:
            out = np.where(self.force_scaled, out / per_unit_mass_kg, out)
        for k, v in (values or {}).items():
            out[self.index(k)] = float(v)
        return out

    @property
    def force_scaled(self) -> np.ndarray:
        """Boolean mask of the force-scaled parameters."""
        return np.array([p.scales_with_force for p in self.specs], dtype=bool)

    @property
    def lower(self) -> np.ndarray:
        return np.array([p.lower for p in self.specs], dtype=float)

    @property
    def upper(self) -> np.ndarray:
        return np.array([p.upper for p in self.specs], dtype=float)

    def constant_values(self) -> np.ndarray:
        """All terms' constants, concatenated in model order."""
        parts = [t.constant_values() for t in self.terms]
        return np.concatenate(parts) if parts else np.zeros(0)

    # ------------------------------------------------------------------ numerics
    @property
    def kernel(self) -> Any:
        """The compiled ``force(r, rdot, x2, theta, consts, dtheta) -> (F, Fr, Frdot, Fx2)``."""
        return _assemble_force(tuple(type(t) for t in self.terms))

    def compile(self, module_name: str, *names: str) -> Any:
        """Compile numba templates of ``module_name`` for this model's force.

        A template is a plain function (no decorator) that calls the global
        ``model_force(r, rdot, x2, theta, consts, dtheta)``; see
        :func:`_compile_templates`. Returns a namespace of the compiled functions, cached
        in memory and on disk per combination of term classes.
        """
        return _compile_templates(tuple(type(t) for t in self.terms), module_name,
                                  tuple(names))

    def force(
        self,
        r: np.ndarray | float,
        rdot: np.ndarray | float,
        x2: np.ndarray | float,
        values: Mapping[str, float] | Sequence[float] | np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Force on the body and its derivatives at arrays of states.

        Parameters
        ----------
        r, rdot, x2 : array_like
            Suspension extension [m], its rate [m/s] and body position [m] (broadcast).
        values : mapping or sequence
            Parameter values (absolute, or per unit mass for a force per unit mass).

        Returns
        -------
        force : (n,) array
            Force [N] (or per unit mass, m/s2).
        d_state : (n, 3) array
            Derivatives with respect to r, rdot, x2.
        d_params : (n, n_params) array
            Derivatives with respect to the parameters.
        """
        r, rdot, x2 = np.broadcast_arrays(np.asarray(r, float), np.asarray(rdot, float),
                                          np.asarray(x2, float))
        theta = self.vector(values)
        many = self.compile(__name__, "_force_many")._force_many
        return many(np.ascontiguousarray(r.ravel()), np.ascontiguousarray(rdot.ravel()),
                    np.ascontiguousarray(x2.ravel()), theta, self.constant_values())

    # ------------------------------------------------------------------ serialisation
    def to_dict(self) -> dict[str, Any]:
        """``{"terms": [{"name", "settings"}, ...]}``; inverse of :meth:`from_dict`."""
        return {"terms": [t.to_dict() for t in self.terms]}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> ForceModel:
        """Inverse of :meth:`to_dict`."""
        return cls(make_term(t["name"], **t.get("settings", {})) for t in d["terms"])

    @classmethod
    def from_names(cls, names: Iterable[str]) -> ForceModel:
        """A model from term names (``["linear_spring", "linear_damper"]``)."""
        return cls(make_term(n) for n in names)


def linear_model(coupling: bool = False) -> ForceModel:
    """Linear spring + linear damper (+ coupling spring)."""
    m = LinearSpring() + LinearDamper()
    return m + CouplingSpring() if coupling else m


def model_from_sim(params: Any, effects: Sequence[Any] = (), *, coupling: bool | None = None
                   ) -> tuple[ForceModel, dict[str, float]]:
    """The model and absolute parameter values matching a simulated car.

    Parameters
    ----------
    params : fielddiag.sim.QuarterCarParams
        The linear car.
    effects : sequence of fielddiag.sim.Effect
        Effects with a term here (coulomb_friction, cubic_stiffness, bump_stop,
        asymmetric_damping).
    coupling : bool or None
        Include the coupling spring; None: when the car's coupling stiffness is non-zero.

    Returns
    -------
    (ForceModel, dict)
        The model and its parameters by key.
    """
    if coupling is None:
        coupling = params.coupling_stiffness_n_per_m != 0.0
    terms: list[Term] = [LinearSpring(), LinearDamper()]
    if coupling:
        terms.append(CouplingSpring())
    values = {
        "linear_spring.suspension_stiffness_n_per_m": params.suspension_stiffness_n_per_m,
        "linear_damper.suspension_damping_ns_per_m": params.suspension_damping_ns_per_m,
        "coupling_spring.coupling_stiffness_n_per_m": params.coupling_stiffness_n_per_m,
    }
    for e in effects:
        cls = TERMS.get(e.name)
        if cls is None or cls in (LinearSpring, LinearDamper, CouplingSpring):
            raise FieldDiagError(f"effect {e.name!r} has no model term; terms exist for "
                                 "coulomb_friction, cubic_stiffness, bump_stop and "
                                 "asymmetric_damping")
        ed = e.to_dict()["params"]
        settings = {k: ed[k] for k in cls.constants if k in ed}
        terms.append(cls(**settings))
        for p in cls.params:
            values[f"{cls.name}.{p.name}"] = ed[p.name]
    model = ForceModel(terms)
    return model, {k: v for k, v in values.items() if k in model.param_keys}


def split_shape(params: dict[str, float]) -> tuple[dict[str, float], dict[str, float]]:
    """(physical parameters, shape parameters) of an effect's fitted values, by name (see
    :attr:`ParamSpec.shape`); per-kg names of shape parameters are the same names."""
    shape_names = {p.name for cls in TERMS.values() for p in cls.params if p.shape}
    return ({k: v for k, v in params.items() if k not in shape_names},
            {k: v for k, v in params.items() if k in shape_names})
