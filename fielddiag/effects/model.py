"""A model of the suspension force: a sum of effects (built with ``+``).

Like a pysindy feature library::

    model = LinearSpring() + LinearDamper() + CoulombFriction()

Contract of an effect: its force is proportional to its force-scaled parameters (those
with ``scales_with_force``), so dividing every force-scaled parameter by the mass gives
the same model per unit mass. This is what lets one session identify ratios (K2/M2,
C2/M2...) and two sessions with a known added mass identify absolute values.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np
from numba import njit

from fielddiag.effects.base import EFFECTS, Effect, ParamSpec, get_effect
from fielddiag.effects.compose import (
    compile_templates,
    model_force,
    model_force_z,
    model_state_partials,
)
from fielddiag.errors import FieldDiagError

__all__ = ["ForceModel", "linear_model", "model_from_sim", "split_shape"]

#: Largest product of an internal state's rate [1/s] and the RK4 step [s] (see
#: :meth:`ForceModel.state_substeps`).
STATE_RATE_STEP = 1.0
#: Fastest state rate integrated [1/s]: a fit that wanders to a faster one (a yield travel
#: of microns, a top mount far stiffer than its damper) is integrated as if at this rate.
MAX_STATE_RATE_PER_S = 2e4
#: Internal states are held within +-STATE_LIMIT (far beyond any physical state: a
#: normalised hysteresis lies in [-1, 1], a deflection within metres).
STATE_LIMIT = 1e3
#: Exact sensitivities of the internal states are used where no parameter's column says
#: that a relative change of the parameter by 1e-6 (a forward difference's step) would move
#: the output by more than its whole range (``|d out / d theta| |theta| <= 1e6 max|out|``;
#: ~10 in a regular run). Beyond it the discrete states follow the motion chaotically (a
#: fit exploring a yield travel of microns, a simulated body started far faster than the
#: measured one: RK4 steps beyond the states' stability) and their exact sensitivities
#: grow without bound (1e120 was met): the derivatives through the states are then taken
#: by forward differences of the whole run instead (finite steps, as before them).
SENSITIVITY_GROWTH_LIMIT = 1e6
#: A travel an internal state changes over (a yield travel,
#: :attr:`~fielddiag.effects.base.ParamSpec.resolved_travel`) is kept at or above this
#: fraction of the suspension's rms travel per sample. Shorter, the loop closes within a
#: sample: the data see its limit (friction) and cannot tell the two apart, while the
#: state's RK4 substeps grow without bound (a fit wandering there took minutes).
RESOLVED_FRACTION = 0.5
#: A state's relaxation time (a top mount's c / k_m,
#: :meth:`~fielddiag.effects.base.Effect.resolved_upper`) is kept at or above the sample
#: interval over this many: at most this many RK4 substeps for it. (Unlike a yield
#: travel, a relaxation far shorter than a sample still shows, as a delay: a 0.6 ms mount
#: sampled at 100 Hz. A fit that wandered to a rigid mount took 180 s.)
MAX_RELAXATION_STEPS = 32


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


def _force_many_z(r, rd, x2, z, theta, consts):  # pragma: no cover - numba template
    n = r.shape[0]
    f = np.empty(n)
    ds = np.empty((n, 3))
    dp = np.empty((n, theta.shape[0]))
    dz = np.empty(z.shape)
    for i in range(n):
        a, b, c, d = model_force_z(r[i], rd[i], x2[i], z[i], theta, consts, dp[i], dz[i])
        f[i] = a
        ds[i, 0] = b
        ds[i, 1] = c
        ds[i, 2] = d
    return f, ds, dp, dz


def _force_path_z(r, rd, x2, z0, theta, consts, h, nsub):  # pragma: no cover - numba template
    """The force along a measured path, the internal states integrated by RK4 (``nsub[i]``
    steps in the interval after sample ``i``, r, rdot and x2 linear between samples)."""
    n = r.shape[0]
    nz = z0.shape[0]
    f = np.empty(n)
    ds = np.empty((n, 3))
    dp = np.empty((n, theta.shape[0]))
    zs = np.empty((n, nz))
    z = z0.copy()
    zt = np.empty(nz)
    k1 = np.empty(nz)
    k2 = np.empty(nz)
    k3 = np.empty(nz)
    k4 = np.empty(nz)
    scratch = np.empty(max(theta.shape[0], 1))
    for i in range(n):
        for j in range(nz):
            zs[i, j] = z[j]
        a, b, c, d = model_force_z(r[i], rd[i], x2[i], z, theta, consts, dp[i], k1)
        f[i] = a
        ds[i, 0] = b
        ds[i, 1] = c
        ds[i, 2] = d
        if i == n - 1:
            break
        ns = nsub[i]
        hs = h / ns
        for s in range(ns):
            w0 = s / ns
            wm = (s + 0.5) / ns
            w1 = (s + 1.0) / ns
            ra = r[i] + w0 * (r[i + 1] - r[i])
            va = rd[i] + w0 * (rd[i + 1] - rd[i])
            xa = x2[i] + w0 * (x2[i + 1] - x2[i])
            rm = r[i] + wm * (r[i + 1] - r[i])
            vm = rd[i] + wm * (rd[i + 1] - rd[i])
            xm = x2[i] + wm * (x2[i + 1] - x2[i])
            rb = r[i] + w1 * (r[i + 1] - r[i])
            vb = rd[i] + w1 * (rd[i + 1] - rd[i])
            xb = x2[i] + w1 * (x2[i + 1] - x2[i])
            if s > 0:
                model_force_z(ra, va, xa, z, theta, consts, scratch, k1)
            for j in range(nz):
                zt[j] = z[j] + 0.5 * hs * k1[j]
            model_force_z(rm, vm, xm, zt, theta, consts, scratch, k2)
            for j in range(nz):
                zt[j] = z[j] + 0.5 * hs * k2[j]
            model_force_z(rm, vm, xm, zt, theta, consts, scratch, k3)
            for j in range(nz):
                zt[j] = z[j] + hs * k3[j]
            model_force_z(rb, vb, xb, zt, theta, consts, scratch, k4)
            for j in range(nz):
                z[j] += hs / 6.0 * (k1[j] + 2.0 * (k2[j] + k3[j]) + k4[j])
                # a fit exploring a state rate beyond MAX_STATE_RATE_PER_S: keep it finite
                if not abs(z[j]) <= STATE_LIMIT:
                    z[j] = STATE_LIMIT if z[j] > 0 else -STATE_LIMIT
    return f, ds, dp, zs


def sensitivities_exploded(jac: np.ndarray, scale: np.ndarray, out: np.ndarray) -> bool:
    """Whether exact sensitivities have grown without bound (see
    :data:`SENSITIVITY_GROWTH_LIMIT`).

    Parameters
    ----------
    jac : ndarray
        ``(n, q)`` derivatives of ``out`` with respect to ``q`` parameters.
    scale : ndarray
        ``(q,)`` the parameters' sizes (their values; 1 where a value is 0).
    out : ndarray
        ``(n,)`` the output they are derivatives of.

    Returns
    -------
    bool
        True if a derivative is not finite or a column times its parameter's size exceeds
        ``SENSITIVITY_GROWTH_LIMIT`` times the output's largest magnitude.
    """
    if not np.all(np.isfinite(jac)):
        return True
    if jac.size == 0:
        return False
    growth = np.max(np.abs(jac), axis=0) * np.abs(scale)
    return bool(np.any(growth > SENSITIVITY_GROWTH_LIMIT * max(float(np.max(np.abs(out))),
                                                                 1e-300)))


@njit(cache=True, nogil=True)
def state_sensitivity_rate(dgz, dgp, sz, out):  # pragma: no cover - compiled
    """``out = dgz @ sz + dgp``: d/dt of the states' sensitivities ``sz`` (n_states, q) to
    ``q`` parameters along a given path (``dgz``: d(dz/dt)/dz, ``dgp``: d(dz/dt)/dtheta)."""
    nz, q = sz.shape
    for k in range(nz):
        for j in range(q):
            acc = dgp[k, j]
            for m in range(nz):
                acc += dgz[k, m] * sz[m, j]
            out[k, j] = acc


def _force_path_zs(r, rd, x2, z0, sz0, theta, consts, h, nsub):  # pragma: no cover - template
    """:func:`_force_path_z` with the derivatives through the states: the states'
    sensitivities to the parameters (``sz0`` at the first sample) integrated by the same RK4
    steps, so that ``dp`` is the exact derivative of the discrete path's force."""
    n = r.shape[0]
    nz = z0.shape[0]
    p = theta.shape[0]
    f = np.empty(n)
    ds = np.empty((n, 3))
    dp = np.empty((n, p))
    zs = np.empty((n, nz))
    z = z0.copy()
    sz = sz0.copy()
    zt = np.empty(nz)
    st = np.empty((nz, p))
    k1 = np.empty(nz)
    k2 = np.empty(nz)
    k3 = np.empty(nz)
    k4 = np.empty(nz)
    s1 = np.empty((nz, p))
    s2 = np.empty((nz, p))
    s3 = np.empty((nz, p))
    s4 = np.empty((nz, p))
    dfz = np.zeros(nz)
    dgs = np.zeros((nz, 3))
    dgz = np.zeros((nz, nz))
    dgp = np.zeros((nz, p))
    scratch = np.empty(max(p, 1))
    for i in range(n):
        for j in range(nz):
            zs[i, j] = z[j]
        a, b, c, d = model_force_z(r[i], rd[i], x2[i], z, theta, consts, dp[i], k1)
        model_state_partials(r[i], rd[i], x2[i], z, theta, consts, dfz, dgs, dgz, dgp)
        for j in range(p):
            acc = dp[i, j]
            for k in range(nz):
                acc += dfz[k] * sz[k, j]
            dp[i, j] = acc
        f[i] = a
        ds[i, 0] = b
        ds[i, 1] = c
        ds[i, 2] = d
        if i == n - 1:
            break
        ns = nsub[i]
        hs = h / ns
        for s in range(ns):
            w0 = s / ns
            wm = (s + 0.5) / ns
            w1 = (s + 1.0) / ns
            ra = r[i] + w0 * (r[i + 1] - r[i])
            va = rd[i] + w0 * (rd[i + 1] - rd[i])
            xa = x2[i] + w0 * (x2[i + 1] - x2[i])
            rm = r[i] + wm * (r[i + 1] - r[i])
            vm = rd[i] + wm * (rd[i + 1] - rd[i])
            xm = x2[i] + wm * (x2[i + 1] - x2[i])
            rb = r[i] + w1 * (r[i + 1] - r[i])
            vb = rd[i] + w1 * (rd[i + 1] - rd[i])
            xb = x2[i] + w1 * (x2[i + 1] - x2[i])
            if s > 0:
                model_force_z(ra, va, xa, z, theta, consts, scratch, k1)
                model_state_partials(ra, va, xa, z, theta, consts, dfz, dgs, dgz, dgp)
            state_sensitivity_rate(dgz, dgp, sz, s1)
            for j in range(nz):
                zt[j] = z[j] + 0.5 * hs * k1[j]
                for m in range(p):
                    st[j, m] = sz[j, m] + 0.5 * hs * s1[j, m]
            model_force_z(rm, vm, xm, zt, theta, consts, scratch, k2)
            model_state_partials(rm, vm, xm, zt, theta, consts, dfz, dgs, dgz, dgp)
            state_sensitivity_rate(dgz, dgp, st, s2)
            for j in range(nz):
                zt[j] = z[j] + 0.5 * hs * k2[j]
                for m in range(p):
                    st[j, m] = sz[j, m] + 0.5 * hs * s2[j, m]
            model_force_z(rm, vm, xm, zt, theta, consts, scratch, k3)
            model_state_partials(rm, vm, xm, zt, theta, consts, dfz, dgs, dgz, dgp)
            state_sensitivity_rate(dgz, dgp, st, s3)
            for j in range(nz):
                zt[j] = z[j] + hs * k3[j]
                for m in range(p):
                    st[j, m] = sz[j, m] + hs * s3[j, m]
            model_force_z(rb, vb, xb, zt, theta, consts, scratch, k4)
            model_state_partials(rb, vb, xb, zt, theta, consts, dfz, dgs, dgz, dgp)
            state_sensitivity_rate(dgz, dgp, st, s4)
            for j in range(nz):
                z[j] += hs / 6.0 * (k1[j] + 2.0 * (k2[j] + k3[j]) + k4[j])
                for m in range(p):
                    sz[j, m] += hs / 6.0 * (s1[j, m] + 2.0 * (s2[j, m] + s3[j, m]) + s4[j, m])
                if not abs(z[j]) <= STATE_LIMIT:  # held at the limit: no sensitivity
                    z[j] = STATE_LIMIT if z[j] > 0 else -STATE_LIMIT
                    for m in range(p):
                        sz[j, m] = 0.0
    return f, ds, dp, zs


class ForceModel:
    """A sum of force terms (build it with ``+``).

    Parameters
    ----------
    terms : iterable of Effect
        The terms. A term listed in another's ``replaces`` is dropped (asymmetric damping
        replaces the linear damper); a term given twice is an error.

    Raises
    ------
    FieldDiagError
        A term that is not an :class:`Effect`, a term given twice, or no term left.

    Notes
    -----
    Parameters are addressed by key ``"<term>.<param>"``; :meth:`index` also accepts a
    parameter's plain name when it is unique in the model.

    Examples
    --------
    ::

        model = LinearSpring() + LinearDamper() + CoulombFriction()
        model.param_keys[2]            # 'coulomb_friction.friction_force_n'
        model.vector({"friction_force_n": 80.0})   # the others at typical values
    """

    def __init__(self, terms: Iterable[Effect]) -> None:
        terms = list(terms)
        for t in terms:
            if not isinstance(t, Effect):
                raise FieldDiagError(f"a model is made of Effect objects, got {t!r}")
        names = [t.name for t in terms]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise FieldDiagError(f"model term(s) {dup} given twice; give each term once")
        replaced = {r for t in terms for r in t.replaces}
        self.terms: tuple[Effect, ...] = tuple(t for t in terms if t.name not in replaced)
        if not self.terms:
            raise FieldDiagError("a model needs at least one term (e.g. LinearSpring())")
        self._specs: list[tuple[Effect, ParamSpec]] = [
            (t, p) for t in self.terms for p in t.params]

    # ------------------------------------------------------------------ composition
    def __add__(self, other: Effect | ForceModel) -> ForceModel:
        if isinstance(other, Effect):
            return ForceModel([*self._all_terms(), other])
        if isinstance(other, ForceModel):
            return ForceModel([*self._all_terms(), *other._all_terms()])
        return NotImplemented

    def _all_terms(self) -> tuple[Effect, ...]:
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
        """The model without the named terms.

        Parameters
        ----------
        *names : str
            Term names (``"coulomb_friction"``); unknown names are ignored.

        Returns
        -------
        ForceModel
        """
        return ForceModel([t for t in self.terms if t.name not in names])

    # ------------------------------------------------------------------ parameters
    @property
    def n_params(self) -> int:
        """Number of parameters of all terms together."""
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
        """True if every term is linear in its force-scaled parameters (see :class:`Effect`)."""
        return all(t.linear_in_params for t in self.terms)

    def index(self, name: str) -> int:
        """Position of a parameter given by key or by unique plain (or ``_per_kg``) name.

        Parameters
        ----------
        name : str
            ``"<term>.<param>"``, or a parameter name unique in the model.

        Returns
        -------
        int
            Index into the parameter vector.

        Raises
        ------
        FieldDiagError
            The name is ambiguous or not in the model.
        """
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
            By key or unique name; None gives the typical values. A sequence must have
            ``n_params`` entries and is copied as is.
        per_unit_mass_kg : float or None
            If given, divide the typical values of force-scaled parameters by this mass [kg]
            (typical values are absolute).

        Returns
        -------
        numpy.ndarray
            ``(n_params,)`` in the parameters' units (per kg for force-scaled ones when
            ``per_unit_mass_kg`` is given).

        Raises
        ------
        FieldDiagError
            A sequence of the wrong length, or an unknown name.
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
    def resolved_travel(self) -> np.ndarray:
        """Boolean mask of the travels the data must resolve
        (:attr:`~fielddiag.effects.base.ParamSpec.resolved_travel`)."""
        return np.array([p.resolved_travel for p in self.specs], dtype=bool)

    def resolved_bounds(self, travel_per_sample_m: float, sample_interval_s: float,
                        theta: np.ndarray | None = None,
                        per_unit_mass_kg: tuple[float, float] | None = None
                        ) -> tuple[np.ndarray, np.ndarray]:
        """Parameter bounds narrowed to what the data resolve (:data:`RESOLVED_FRACTION`,
        :data:`MAX_RELAXATION_STEPS`).

        Parameters
        ----------
        travel_per_sample_m : float
            The suspension's rms travel per sample interval [m] (least over the sessions).
        sample_interval_s : float
            Sample interval of the data fitted [s].
        theta : ndarray or None
            Parameter vector the fit starts from (the relaxation limits of
            :meth:`~fielddiag.effects.base.Effect.resolved_upper` are relative to it;
            None: no such limits).
        per_unit_mass_kg : (float, float) or None
            The range of the mass [kg] when the force-scaled parameters are fitted per unit
            mass (their SI bounds then hold for every mass in it); None: absolute values.

        Returns
        -------
        (ndarray, ndarray)
            Lower and upper bounds, ``(n_params,)`` each (lower <= upper).
        """
        lower, upper = self.lower, self.upper.copy()
        if per_unit_mass_kg is not None:
            m_lo, m_hi = per_unit_mass_kg
            scaled = self.force_scaled
            lower = np.where(scaled & (lower > 0), lower / m_hi, lower)
            lower = np.where(scaled & (lower < 0), lower / m_lo, lower)
            upper = np.where(scaled & (upper > 0), upper / m_lo, upper)
            upper = np.where(scaled & (upper < 0), upper / m_hi, upper)
        lower = np.where(self.resolved_travel,
                         np.maximum(lower, RESOLVED_FRACTION * travel_per_sample_m), lower)
        if theta is not None:
            theta = np.abs(np.asarray(theta, float))
            p0 = 0
            for t in self.terms:
                p1 = p0 + len(t.params)
                hi = t.resolved_upper(theta[p0:p1], sample_interval_s / MAX_RELAXATION_STEPS)
                if hi is not None:
                    upper[p0:p1] = np.maximum(np.minimum(upper[p0:p1], hi), lower[p0:p1])
                p0 = p1
        return np.minimum(lower, upper), upper

    @property
    def lower(self) -> np.ndarray:
        """Lower bounds of the parameters (absolute SI values; ``-inf`` when free)."""
        return np.array([p.lower for p in self.specs], dtype=float)

    @property
    def upper(self) -> np.ndarray:
        """Upper bounds of the parameters (absolute SI values; ``inf`` when free)."""
        return np.array([p.upper for p in self.specs], dtype=float)

    def constant_values(self) -> np.ndarray:
        """All terms' constants, concatenated in model order.

        Returns
        -------
        numpy.ndarray
            The settings of every term (SI, e.g. the bump stop's ``width_m`` [m]).
        """
        parts = [t.constant_values() for t in self.terms]
        return np.concatenate(parts) if parts else np.zeros(0)

    # ------------------------------------------------------------------ numerics
    def compile(self, module_name: str, *names: str, error_model: str = "python") -> Any:
        """Compile numba templates of ``module_name`` for this model's force.

        A template is a plain function (no decorator) that calls the global
        ``model_force(r, rdot, x2, theta, consts, dtheta)``; see
        :func:`fielddiag.effects.compose.compile_templates`.

        Parameters
        ----------
        module_name : str
            Importable module holding the templates.
        *names : str
            Template function names.
        error_model : str
            numba's error model (``"python"`` or ``"numpy"``).

        Returns
        -------
        namespace
            The compiled functions by name, cached in memory and on disk per combination of
            effect classes.
        """
        return compile_templates(tuple(type(t) for t in self.terms), module_name,
                                 tuple(names), error_model)

    @property
    def n_states(self) -> int:
        """Internal states of all effects together."""
        return sum(t.n_states for t in self.terms)

    @property
    def has_state_partials(self) -> bool:
        """True if the model has internal states and every effect with states gives the
        partial derivatives of its state rates (:attr:`Effect.state_partials`): the states'
        sensitivities are then integrated exactly instead of by forward differences."""
        stateful = [t for t in self.terms if t.n_states]
        return bool(stateful) and all(t.state_partials is not None for t in stateful)

    def static_states_jacobian(self, r: float, values: Sequence[float] | np.ndarray
                               ) -> tuple[np.ndarray, np.ndarray]:
        """Derivatives of :meth:`static_states` with respect to ``r`` and the parameters.

        Central differences of the closed-form (or finely integrated) loading curves,
        steps of 1e-6 of each value (1e-9 m for ``r``, 1e-12 for a zero parameter).

        Parameters
        ----------
        r : float
            Suspension extension [m].
        values : sequence of float
            Parameter vector in model order.

        Returns
        -------
        d_r : ndarray
            ``(n_states,)`` d states / d r [1/m].
        d_params : ndarray
            ``(n_states, n_params)`` d states / d theta.
        """
        th = self.vector(values)
        hr = 1e-6 * max(abs(r), 1e-3)
        d_r = (self.static_states(r + hr, th) - self.static_states(r - hr, th)) / (2 * hr)
        d_p = np.zeros((self.n_states, self.n_params))
        p0 = 0
        for t in self.terms:
            p1 = p0 + len(t.params)
            if t.n_states:
                for j in range(p0, p1):
                    step = 1e-6 * abs(th[j]) if th[j] else 1e-12
                    tp, tm = th.copy(), th.copy()
                    tp[j] += step
                    tm[j] -= step
                    d_p[:, j] = (self.static_states(r, tp) - self.static_states(r, tm)) / (
                        2 * step)
            p0 = p1
        return d_r, d_p

    def force(
        self,
        r: np.ndarray | float,
        rdot: np.ndarray | float,
        x2: np.ndarray | float,
        values: Mapping[str, float] | Sequence[float] | np.ndarray,
        *,
        states: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Force on the body and its derivatives at arrays of states.

        Parameters
        ----------
        r, rdot, x2 : array_like
            Suspension extension [m], its rate [m/s] and body position [m] (broadcast).
        values : mapping or sequence
            Parameter values (absolute, or per unit mass for a force per unit mass).
        states : (n, n_states) array or None
            Internal states of the effects that have them (default zeros).

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
        # copies: views from broadcast_arrays are flagged read-only-to-be for numba
        args = (np.array(r.ravel()), np.array(rdot.ravel()), np.array(x2.ravel()))
        if self.n_states == 0:
            many = self.compile(__name__, "_force_many")._force_many
            return many(*args, theta, self.constant_values())
        return self.force_and_state_rates(r, rdot, x2, theta, states)[:3]

    def force_and_state_rates(
        self, r: np.ndarray | float, rdot: np.ndarray | float, x2: np.ndarray | float,
        values: Mapping[str, float] | Sequence[float] | np.ndarray,
        states: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`force` plus the rates ``dz/dt`` (n, n_states) of the internal states.

        Parameters
        ----------
        r, rdot, x2 : array_like
            Suspension extension [m] (positive in rebound), its rate [m/s] and body position [m]
            (broadcast).
        values : mapping or sequence
            Parameter values (absolute, or per unit mass for a force per unit mass).
        states : (n, n_states) array or None
            Internal states (default zeros; broadcast over the n points).

        Returns
        -------
        force : (n,) array
            Force on the body [N] (or per unit mass, m/s^2).
        d_state : (n, 3) array
            dF/dr, dF/drdot, dF/dx2.
        d_params : (n, n_params) array
            Derivatives with respect to the parameters.
        state_rates : (n, n_states) array
            ``dz/dt`` of the internal states.
        """
        r, rdot, x2 = np.broadcast_arrays(np.asarray(r, float), np.asarray(rdot, float),
                                          np.asarray(x2, float))
        n = r.size
        z = np.zeros((n, self.n_states)) if states is None else np.asarray(states, float)
        z = np.array(np.broadcast_to(z.reshape(-1, self.n_states) if z.size else z,
                                     (n, self.n_states)), dtype=float, order="C")
        many = self.compile(__name__, "_force_many_z")._force_many_z
        return many(np.array(r.ravel()), np.array(rdot.ravel()), np.array(x2.ravel()), z,
                    self.vector(values),
                    self.constant_values())

    def state_substeps(self, theta: np.ndarray, max_rate_mps: float | np.ndarray,
                       step_s: float) -> int | np.ndarray:
        """RK4 steps per interval ``step_s`` that keep the internal states stable and accurate.

        Parameters
        ----------
        theta : ndarray
            Parameter vector (absolute values).
        max_rate_mps : float or ndarray
            Largest suspension rate on the path [m/s] (an array: in each interval).
        step_s : float
            Sample interval [s].

        Returns
        -------
        int or ndarray of int64
            ``ceil(step_s * rate / STATE_RATE_STEP)`` with ``rate`` the fastest state rate
            the effects report (:meth:`~fielddiag.effects.base.Effect.speed_bounds`,
            scaled from :data:`~fielddiag.effects.base.RATE_BOUND_MPS` to
            ``max_rate_mps``, and at least the states' relaxation rate,
            :meth:`~fielddiag.effects.base.Effect.relaxation_rate_per_s`; at most
            :data:`MAX_STATE_RATE_PER_S`). RK4 is stable to a
            step of 2.8 / rate; the
            states relax towards their saturation, so 1 / rate keeps them accurate.
        """
        from fielddiag.effects.base import RATE_BOUND_MPS

        speed = np.maximum(np.asarray(max_rate_mps, float), 1e-6)
        rate, p0 = np.zeros_like(speed), 0
        for t in self.terms:
            p1 = p0 + len(t.params)
            if t.n_states:
                own = np.abs(theta[p0:p1])
                q = float(t.speed_bounds(own)[2])
                rate = np.maximum(rate, np.maximum(q * speed / RATE_BOUND_MPS,
                                                   float(t.relaxation_rate_per_s(own))))
            p0 = p1
        rate = np.where(np.isfinite(rate), np.minimum(rate, MAX_STATE_RATE_PER_S),
                        MAX_STATE_RATE_PER_S)
        nsub = np.maximum(1, np.ceil(step_s * rate / STATE_RATE_STEP)).astype(np.int64)
        return int(nsub) if nsub.ndim == 0 else nsub

    def path_substeps(self, theta: np.ndarray, rdot: np.ndarray, step_s: float) -> np.ndarray:
        """RK4 steps in each interval of a given path (:meth:`state_substeps` at the
        interval's own largest rate: few where the suspension moves slowly).

        Parameters
        ----------
        theta : ndarray
            Parameter vector (absolute values).
        rdot : ndarray
            ``(n,)`` suspension rate at the samples [m/s] (linear between them).
        step_s : float
            Sample interval [s].

        Returns
        -------
        ndarray of int64
            ``(n,)`` substeps in the interval after each sample (the last: its neighbour's).
        """
        a = np.abs(np.asarray(rdot, float))
        speed = np.maximum(a, np.concatenate([a[1:], a[-1:]])) if a.size else np.zeros(1)
        return np.ascontiguousarray(self.state_substeps(theta, speed, step_s), dtype=np.int64)

    def force_along_path(
        self,
        r: np.ndarray,
        rdot: np.ndarray,
        x2: np.ndarray | float,
        values: Mapping[str, float] | Sequence[float] | np.ndarray,
        sample_rate_hz: float,
        *,
        initial_states: np.ndarray | None = None,
        state_jacobian: bool = True,
        follow_rate: bool = False,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The force along a measured path, with the internal states integrated along it.

        A memoryless model gives :meth:`force`. With internal states (hysteresis, a series
        top mount) the states start at ``initial_states`` (default: at rest at ``r[0]``,
        :meth:`static_states`) and follow the path (RK4, ``r``, ``rdot`` and ``x2`` linear
        between samples). The force then depends on a parameter of a stateful term through
        the states too: where the effects give their state partials
        (:attr:`~fielddiag.effects.base.Effect.state_partials`) the states' sensitivities
        are integrated along with them (the exact derivative of the discrete path),
        otherwise (or where those sensitivities have grown without bound,
        :data:`SENSITIVITY_GROWTH_LIMIT`) those columns of ``d_params`` are forward
        differences of the whole path (one more integration per such parameter).

        Parameters
        ----------
        r, rdot : ndarray
            Suspension extension [m] and its rate [m/s] at the samples.
        x2 : ndarray or float
            Body position [m].
        values : mapping or sequence
            Parameter values (absolute, or per unit mass for a force per unit mass).
        sample_rate_hz : float
            Sample rate of the path [Hz].
        initial_states : ndarray or None
            ``(n_states,)`` states at the first sample.
        state_jacobian : bool
            Compute the stateful terms' parameter columns (False: leave the kernels'
            explicit derivatives, faster when only the force is wanted).
        follow_rate : bool
            RK4 substeps interval by interval (:meth:`path_substeps`: about 2.5x fewer on
            a road, 0.3 % of the force's range from a fine run) instead of the fastest
            interval's count everywhere (:meth:`state_substeps`, 1e-5): for screening.

        Returns
        -------
        force : (n,) ndarray
            Force on the body [N] (or per unit mass).
        d_state : (n, 3) ndarray
            dF/dr, dF/drdot, dF/dx2 at frozen states.
        d_params : (n, n_params) ndarray
            Derivatives with respect to the parameters (through the states as well).
        states : (n, n_states) ndarray
            The internal states along the path.
        """
        r = np.ascontiguousarray(r, dtype=float).ravel()
        rdot = np.ascontiguousarray(rdot, dtype=float).ravel()
        x2 = np.ascontiguousarray(np.broadcast_to(np.asarray(x2, float), r.shape), dtype=float)
        theta = self.vector(values)
        if self.n_states == 0:
            f, ds, dp = self.force(r, rdot, x2, theta)
            return f, ds, dp, np.zeros((r.size, 0))
        h = 1.0 / float(sample_rate_hz)
        if follow_rate:
            nsub = self.path_substeps(theta, rdot, h)
        else:
            fastest = float(np.max(np.abs(rdot))) if r.size else 0.0
            nsub = np.full(max(r.size, 1), self.state_substeps(theta, fastest, h), dtype=np.int64)
        path = self.compile(__name__, "_force_path_z", error_model="numpy")._force_path_z

        def run(th: np.ndarray) -> tuple[np.ndarray, ...]:
            z0 = (self.static_states(float(r[0]) if r.size else 0.0, th)
                  if initial_states is None else np.asarray(initial_states, float).ravel())
            return path(r, rdot, x2, np.ascontiguousarray(z0), th, self.constant_values(), h,
                        nsub)

        if state_jacobian and self.has_state_partials:
            r0 = float(r[0]) if r.size else 0.0
            if initial_states is None:
                z0 = self.static_states(r0, theta)
                sz0 = self.static_states_jacobian(r0, theta)[1]
            else:
                z0 = np.asarray(initial_states, float).ravel()
                sz0 = np.zeros((self.n_states, self.n_params))
            exact = self.compile(__name__, "_force_path_zs", error_model="numpy")._force_path_zs
            out = exact(r, rdot, x2, np.ascontiguousarray(z0), np.ascontiguousarray(sz0), theta,
                        self.constant_values(), h, nsub)
            if not sensitivities_exploded(out[2], np.where(theta != 0, theta, 1.0), out[0]):
                return out
        f, ds, dp, zs = run(theta)
        if state_jacobian:
            p0 = 0
            for t in self.terms:
                p1 = p0 + len(t.params)
                if t.n_states:
                    for j in range(p0, p1):
                        step = 1e-6 * max(abs(theta[j]), 1e-12) if theta[j] else 1e-9
                        th = theta.copy()
                        th[j] += step
                        dp[:, j] = (run(th)[0] - f) / step
                p0 = p1
        return f, ds, dp, zs

    def static_states(self, r: float, values: Sequence[float] | np.ndarray) -> np.ndarray:
        """Internal states of all effects at rest at extension ``r`` [m] (loaded slowly).

        Parameters
        ----------
        r : float
            Suspension extension [m].
        values : sequence of float
            Parameter vector in model order.

        Returns
        -------
        numpy.ndarray
            ``(n_states,)``; empty for a memoryless model.
        """
        th = self.vector(values)
        parts, p0 = [], 0
        for t in self.terms:
            p1 = p0 + len(t.params)
            if t.n_states:
                parts.append(np.asarray(t.static_states(r, th[p0:p1]), float))
            p0 = p1
        return np.concatenate(parts) if parts else np.zeros(0)

    def static_force(self, r: float, x2: float,
                     values: Sequence[float] | np.ndarray) -> float:
        """Force at rest [N] at extension ``r`` and body position ``x2`` [m]: the sum of the
        effects' :meth:`~fielddiag.effects.base.Effect.static_force_n`.

        Parameters
        ----------
        r : float
            Suspension extension [m] (positive in rebound).
        x2 : float
            Body position [m].
        values : sequence of float
            Parameter vector in model order (absolute, or per unit mass for N/kg).

        Returns
        -------
        float
            Force on the body with ``rdot`` = 0 [N] (or [N/kg]).
        """
        th = self.vector(values)
        total, p0 = 0.0, 0
        for t in self.terms:
            p1 = p0 + len(t.params)
            total += float(t.static_force_n(r, x2, th[p0:p1])[()])
            p0 = p1
        return total

    def values_of(self, overrides: Mapping[str, float] | None = None) -> np.ndarray:
        """Parameter vector from the values the effects carry (simulated effects), then
        ``overrides`` by key or name; typical values for the rest.

        Parameters
        ----------
        overrides : mapping or None
            Values by key or unique name (SI units as named).

        Returns
        -------
        numpy.ndarray
            ``(n_params,)`` absolute values in model order.
        """
        out = np.concatenate([t.value_vector() for t in self.terms]) if self.terms else \
            np.zeros(0)
        for k, v in (overrides or {}).items():
            out[self.index(k)] = float(v)
        return out

    # ------------------------------------------------------------------ serialisation
    def to_dict(self) -> dict[str, Any]:
        """``{"terms": [{"name", "settings"}, ...]}``; inverse of :meth:`from_dict`.

        Returns
        -------
        dict
            JSON-ready; settings in SI units.
        """
        return {"terms": [t.to_dict() for t in self.terms]}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> ForceModel:
        """Inverse of :meth:`to_dict`.

        Parameters
        ----------
        d : mapping
            ``{"terms": [{"name": ..., "settings": {...}}, ...]}``.

        Returns
        -------
        ForceModel

        Raises
        ------
        FieldDiagError
            An unknown term name or setting.
        """
        return cls(get_effect(t["name"])(**t.get("settings", {})) for t in d["terms"])

    @classmethod
    def from_names(cls, names: Iterable[str]) -> ForceModel:
        """A model from term names (``["linear_spring", "linear_damper"]``).

        Parameters
        ----------
        names : iterable of str
            Registered term names; each term takes its fit settings.

        Returns
        -------
        ForceModel

        Raises
        ------
        FieldDiagError
            An unknown term name.
        """
        return cls(get_effect(n)() for n in names)


def linear_model(coupling: bool = False) -> ForceModel:
    """Linear spring + linear damper (+ coupling spring).

    Parameters
    ----------
    coupling : bool
        Add the coupling spring ``-K3 x2``.

    Returns
    -------
    ForceModel
        Parameters K2 [N/m], C2 [N s/m] (and K3 [N/m]).

    Examples
    --------
    ::

        linear_model(coupling=True).param_keys
        # ('linear_spring.suspension_stiffness_n_per_m',
        #  'linear_damper.suspension_damping_ns_per_m',
        #  'coupling_spring.coupling_stiffness_n_per_m')
    """
    m = get_effect("linear_spring")() + get_effect("linear_damper")()
    return m + get_effect("coupling_spring")() if coupling else m


def model_from_sim(params: Any, effects: Sequence[Effect] = (), *, coupling: bool | None = None
                   ) -> tuple[ForceModel, dict[str, float]]:
    """The model to fit and the absolute parameter values matching a simulated car.

    Parameters
    ----------
    params : fielddiag.sim.QuarterCarParams
        The linear car.
    effects : sequence of Effect
        Simulated effects (with values).
    coupling : bool or None
        Include the coupling spring; None: when the car's coupling stiffness is non-zero.

    Returns
    -------
    (ForceModel, dict)
        The model (effects with the fit's settings) and its parameters by key.

    Raises
    ------
    FieldDiagError
        A linear term given as an effect.
    """
    if coupling is None:
        coupling = params.coupling_stiffness_n_per_m != 0.0
    terms: list[Effect] = list(linear_model(coupling).terms)
    values = {
        "linear_spring.suspension_stiffness_n_per_m": params.suspension_stiffness_n_per_m,
        "linear_damper.suspension_damping_ns_per_m": params.suspension_damping_ns_per_m,
        "coupling_spring.coupling_stiffness_n_per_m": params.coupling_stiffness_n_per_m,
    }
    for e in effects:
        if e.linear:
            raise FieldDiagError(f"{e.name!r} is a linear term, not an effect; give it "
                                 "through the car's parameters")
        terms.append(e.as_term())
        for name, v in (e.values or {}).items():
            values[f"{e.name}.{name}"] = v
    model = ForceModel(terms)
    return model, {k: v for k, v in values.items() if k in model.param_keys}


def split_shape(params: dict[str, float]) -> tuple[dict[str, float], dict[str, float]]:
    """(physical parameters, shape parameters) of an effect's fitted values, by name (see
    :attr:`ParamSpec.shape`); per-kg names of shape parameters are the same names.

    Parameters
    ----------
    params : dict
        Fitted values by parameter name.

    Returns
    -------
    (dict, dict)
        The physical parameters and the shape parameters (such as
        ``smoothing_velocity_mps`` [m/s]), by name.
    """
    shape_names = {p.name for cls in EFFECTS.values() for p in cls.params if p.shape}
    return ({k: v for k, v in params.items() if k not in shape_names},
            {k: v for k, v in params.items() if k in shape_names})
