"""The grey-box problem: parametrisation, band-limited residuals and their Jacobian,
bounds and equation-error start values, over one or several sessions.

Parameters are fitted per unit sprung mass (``theta / M2``) and, when the sessions carry
at least two different added masses, with the inverse sprung mass ``1 / M2`` as one more
parameter (the acceleration is nearly linear in it); each session adds two nuisance
parameters (initial body offset and velocity). Simulated and measured acceleration are
compared in the same band (zero-phase Butterworth on both).
"""

from __future__ import annotations

import math
import threading
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy import signal
from scipy.ndimage import maximum_filter1d

from fielddiag.effects import ForceModel
from fielddiag.effects.model import sensitivities_exploded
from fielddiag.errors import FieldDiagError, InsufficientDataError
from fielddiag.identify.greybox_data import GRAVITY_MPS2, GreyBoxData
from fielddiag.identify.greybox_sensitivities import (
    _EMPTY,
    _kernels,
    _kernels_sens,
    static_equilibrium,
    static_equilibrium_jacobian,
)
from fielddiag.threads import map_threads

__all__ = ["GreyBoxProblem"]

#: Scale of the initial-state nuisances in the fit: 1 mm, 1 cm/s.
_NUISANCE_SCALE = np.array([1e-3, 1e-2])


# ---------------------------------------------------------------------------------------
# The problem
# ---------------------------------------------------------------------------------------


#: How long an initial body offset or velocity is felt [s]: a passenger car body's free
#: response (damping ratio >= 0.2 at >= 1 Hz) decays as exp(-1.26 t), to 3e-6 in 10 s.
#: Models with internal states whose effects give no state partials take the derivatives
#: (forward differences) with respect to them over this span only (an approximation of
#: the Jacobian, not of the residual: the fit's result is the same, a very lightly damped
#: body converges a little slower).
INITIAL_STATE_MEMORY_S = 10.0
#: The RK4 substeps of a simulation with internal states follow the measured suspension
#: rate's largest value within this many seconds either side of each interval
#: (:meth:`GreyBoxProblem._rate_envelope`) ...
SUBSTEP_WINDOW_S = 0.25
#: ... times this margin (at most the whole run's largest rate).
SUBSTEP_RATE_MARGIN = 2.0


def _band_sos(band_hz: tuple[float, float] | None, fs: float, order: int = 4) -> np.ndarray | None:
    if band_hz is None:
        return None
    lo, hi = band_hz
    return signal.butter(order, [lo, min(hi, 0.45 * fs)], "bandpass", fs=fs, output="sos")


@dataclass
class _Prepared:
    data: GreyBoxData
    sos: np.ndarray | None
    measured: np.ndarray  # filtered measured a2 (trimmed)
    keep: slice
    #: orthonormal columns spanning the data's disturbance basis (filtered, trimmed):
    #: the residual is taken orthogonal to them (None: no disturbances)
    disturbances: np.ndarray | None = None

    def project(self, a: np.ndarray) -> np.ndarray:
        """``a`` (residual or Jacobian rows) without its part in the disturbances."""
        q = self.disturbances
        return a if q is None else a - q @ (q.T @ a)


def _orthonormal(basis: np.ndarray | None, sos: np.ndarray | None, keep: slice
                 ) -> np.ndarray | None:
    """Orthonormal columns spanning ``basis`` as the residual sees it (band-filtered like
    the simulated acceleration, trimmed like it); None for no basis or an empty span."""
    if basis is None or basis.shape[1] == 0:
        return None
    b = basis if sos is None else signal.sosfiltfilt(sos, basis, axis=0)
    u, sv, _ = np.linalg.svd(b[keep], full_matrices=False)
    rank = int(np.sum(sv > 1e-9 * sv[0])) if sv.size and sv[0] > 0 else 0
    return np.ascontiguousarray(u[:, :rank]) if rank else None


class GreyBoxProblem:
    """The residual function of the grey-box fit and its parametrisation.

    Parameters
    ----------
    model : ForceModel
        Force terms.
    data : sequence of GreyBoxData
        Sessions fitted together (shared model parameters).
    absolute : bool or None
        Fit the sprung mass as well (needs at least two different added masses). None:
        whenever the data allow it.
    fixed : mapping or None
        Parameters held constant, by key or unique name (absolute values in absolute
        mode, per unit mass otherwise; ``body_mass_kg`` fixes the mass).
    body_mass_kg : float or None
        Sprung mass guess: start value in absolute mode; in per-unit-mass mode only used to
        load a session with added mass (``dM g / (M2 + dM)`` per unit mass).
    fit_initial_state : bool
        Fit each session's initial body offset and velocity (two nuisance parameters).
    mass_bounds_kg : (float, float) or None
        Range of the fitted sprung mass in absolute mode [kg]; None: 1 g to 1e9 kg
        (practically free). A bounded range keeps a model that cannot describe the data
        from running off to absurd masses.
    substeps : int
        RK4 steps per sample interval.
    trim_s : float or None
        Seconds left out of the residual at both ends of every session (filter edges).
        None: one period of the lower band edge (0 for full-band data).
    """

    def __init__(
        self,
        model: ForceModel,
        data: Sequence[GreyBoxData],
        *,
        absolute: bool | None = None,
        fixed: Mapping[str, float] | None = None,
        body_mass_kg: float | None = None,
        fit_initial_state: bool = True,
        substeps: int = 1,
        trim_s: float | None = None,
        mass_bounds_kg: tuple[float, float] | None = None,
    ) -> None:
        if not data:
            raise FieldDiagError("give at least one session to fit")
        self.model = model
        self.data = list(data)
        masses = sorted({round(float(d.added_mass_kg), 9) for d in self.data})
        can_abs = len(masses) >= 2
        if absolute is None:
            absolute = can_abs
        if absolute and not can_abs:
            raise InsufficientDataError(
                "the sprung mass (and absolute stiffness and damping) needs two sessions with "
                "different added masses; give a second session recorded with a known mass "
                "on the body (--added-mass), or fit per unit mass")
        if not absolute and len(masses) > 1:
            raise FieldDiagError(
                "sessions with different added masses need the absolute fit (absolute=True)")
        self.absolute = bool(absolute)
        self.mass_bounds_kg = (1e-3, 1e9) if mass_bounds_kg is None else (
            float(mass_bounds_kg[0]), float(mass_bounds_kg[1]))
        if not 0 < self.mass_bounds_kg[0] < self.mass_bounds_kg[1]:
            raise FieldDiagError(f"mass_bounds_kg={mass_bounds_kg!r}: give 0 < low < high")
        self.body_mass_guess_kg = body_mass_kg
        self.substeps = int(substeps)
        if self.substeps < 1:
            raise FieldDiagError("substeps must be >= 1")
        self.fit_initial_state = fit_initial_state
        p = model.n_params
        self.n_model = p
        self.scaled = model.force_scaled
        fixed = dict(fixed or {})
        self.fixed_mass = fixed.pop("body_mass_kg", None)
        self.fixed_values: dict[int, float] = {}
        for k, v in fixed.items():
            i = model.index(k)
            self.fixed_values[i] = float(v)  # reporting units; converted in _per_unit_fixed
        # fitted vector: free model params (per unit mass) | M2 | (dx0, dv0) per session
        self.free_model = np.array([i for i in range(p) if i not in self.fixed_values], int)
        self.has_mass = self.absolute and self.fixed_mass is None
        n_free = self.free_model.size + (1 if self.has_mass else 0)
        self.nuis_index = n_free
        self.n_fit = n_free + (2 * len(self.data) if fit_initial_state else 0)
        #: Simulations run (each session's counts; sessions run on threads: counted under
        #: a lock, :meth:`_count`).
        self.evaluations = 0
        self._count_lock = threading.Lock()
        #: Simulation horizon [s] of a continuation stage (None: the whole record).
        self.horizon_s: float | None = None
        self._prep = [self._prepare(d) for d in self.data]
        #: The suspension's rms travel per sample [m] and the sample interval [s] in the
        #: session that resolves least (:meth:`ForceModel.resolved_bounds`).
        self.travel_per_sample_m = min(d.travel_per_sample_m for d in self.data)
        self.sample_interval_s = max(1.0 / d.sample_rate_hz for d in self.data)
        #: Parameters (per unit mass where force-scaled) the fit starts from: the states'
        #: relaxation limits are relative to them (None: no such limits).
        self.start_theta: np.ndarray | None = None
        self._equilibria: dict[tuple, tuple[float, np.ndarray]] = {}
        self._rate_envelopes: dict[int, np.ndarray] = {}
        self._equilibrium_jacobians: dict[tuple, tuple[np.ndarray, np.ndarray]] = {}

    # ------------------------------------------------------------------ data
    def _count(self) -> None:
        """One more simulation (sessions simulated on threads count under a lock)."""
        with self._count_lock:
            self.evaluations += 1

    def _prepare(self, d: GreyBoxData) -> _Prepared:
        sos = _band_sos(d.band_hz, d.sample_rate_hz)
        if d.band_hz is None:
            trim = 0
        else:
            trim = int(round(d.sample_rate_hz / d.band_hz[0]))
        if 2 * trim >= d.n_samples - 10:
            raise InsufficientDataError(f"{d.name}: {d.duration_s:.1f} s is too short for a "
                                        f"fit in {d.band_hz} Hz; record longer")
        keep = slice(trim, d.n_samples - trim)
        meas = d.body_accel_mps2 if sos is None else signal.sosfiltfilt(sos, d.body_accel_mps2)
        return _Prepared(d, sos, np.ascontiguousarray(meas[keep]), keep,
                         _orthonormal(d.disturbance_basis, sos, keep))

    @property
    def n_residuals(self) -> int:
        """Number of residuals over all sessions (trimmed samples)."""
        return sum(pr.measured.size for pr in self._prep)

    # ------------------------------------------------------------------ parameter maps
    def _mass_for_unit(self, d: GreyBoxData) -> tuple[float, float]:
        """(mass, load) of a session in per-unit-mass mode."""
        if d.added_mass_kg and self.body_mass_guess_kg and not d.ride_height_restored:
            return 1.0, GRAVITY_MPS2 * d.added_mass_kg / (self.body_mass_guess_kg
                                                           + d.added_mass_kg)
        return 1.0, 0.0

    def unpack(self, z: np.ndarray) -> tuple[np.ndarray, float | None, np.ndarray]:
        """Fitted vector -> (per-unit-mass model parameters, M2 or None, nuisances (s, 2)).

        Parameters
        ----------
        z : ndarray
            ``(n_fit,)``: free model parameters per unit mass, then ``1/M2`` [1/kg] when the mass
            is fitted, then per session the initial body offset [m] and velocity [m/s].

        Returns
        -------
        theta : ndarray
            ``(n_model,)`` model parameters per unit mass (fixed ones filled in).
        mass : float or None
            Sprung mass M2 [kg] in absolute mode, else None.
        nuisances : ndarray
            ``(n_sessions, 2)`` initial offset [m] and velocity [m/s] (zeros when not fitted).
        """
        theta = np.empty(self.n_model)
        theta[self.free_model] = z[: self.free_model.size]
        mass = None
        if self.absolute:
            mass = 1.0 / float(z[self.free_model.size]) if self.has_mass else float(
                self.fixed_mass)
        for i, v in self.fixed_values.items():
            theta[i] = v / mass if (self.absolute and self.scaled[i]) else v
        nuis = np.zeros((len(self.data), 2))
        if self.fit_initial_state:
            nuis[:] = z[self.nuis_index:].reshape(-1, 2)
        return theta, mass, nuis

    def pack(self, theta_unit: np.ndarray, mass: float | None,
             nuis: np.ndarray | None = None) -> np.ndarray:
        """Inverse of :meth:`unpack`: the fitted vector ``z``.

        Parameters
        ----------
        theta_unit : ndarray
            ``(n_model,)`` model parameters per unit mass (only the free ones are used).
        mass : float or None
            Sprung mass M2 [kg] (used when it is fitted; stored as ``1/M2``).
        nuis : ndarray or None
            ``(n_sessions, 2)`` initial offset [m] and velocity [m/s]; None: zeros.

        Returns
        -------
        numpy.ndarray
            ``(n_fit,)``.
        """
        z = [theta_unit[self.free_model]]
        if self.has_mass:
            z.append([1.0 / float(mass)])
        if self.fit_initial_state:
            z.append(np.zeros(2 * len(self.data)) if nuis is None else np.ravel(nuis))
        return np.concatenate([np.asarray(a, float) for a in z])

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper bounds of the fitted vector ``z``.

        The model parameters take their :class:`~fielddiag.effects.ForceModel` bounds narrowed
        to what the data resolve (:meth:`~fielddiag.effects.ForceModel.resolved_bounds`), ``1/M2``
        the inverse of the mass range [1/kg], the nuisances none.

        Returns
        -------
        (numpy.ndarray, numpy.ndarray)
            ``(n_fit,)`` each.
        """
        # the force-scaled parameters are fitted per unit mass: their SI bounds hold for
        # every mass in range
        lower, upper = self.model.resolved_bounds(self.travel_per_sample_m,
                                                  self.sample_interval_s, self.start_theta,
                                                  per_unit_mass_kg=self.mass_bounds_kg)
        lo = [lower[self.free_model]]
        hi = [upper[self.free_model]]
        if self.has_mass:  # fitted as the inverse mass 1/M2 [1/kg] (nearly linear)
            lo.append([1.0 / self.mass_bounds_kg[1]])
            hi.append([1.0 / self.mass_bounds_kg[0]])
        if self.fit_initial_state:
            lo.append(np.full(2 * len(self.data), -np.inf))
            hi.append(np.full(2 * len(self.data), np.inf))
        return np.concatenate(lo), np.concatenate(hi)

    # ------------------------------------------------------------------ residuals
    def simulate(self, z: np.ndarray, sens: bool) -> list[tuple[np.ndarray, np.ndarray | None]]:
        """Per session: (filtered, trimmed a2_sim, filtered trimmed d a2 / d z).

        Parameters
        ----------
        z : ndarray
            The fitted vector (see :meth:`unpack`).
        sens : bool
            Also integrate the sensitivity equations for the Jacobian.

        Returns
        -------
        list of (ndarray, ndarray or None)
            Per session the simulated body acceleration [m/s^2] (band-filtered like the
            measurement, ends trimmed) and its Jacobian ``(n, n_fit)`` (None without ``sens``).
        """
        if self.model.n_states:
            return self._simulate_stateful(z, sens)
        theta_u, mass, nuis = self.unpack(z)
        kern = _kernels(self.model)._simulate
        consts = self.model.constant_values()
        nf = self.free_model.size

        def session(s: int) -> tuple[np.ndarray, np.ndarray | None]:
            pr = self._prep[s]
            d = pr.data
            if self.absolute:
                m_tot = mass + d.added_mass_kg
                load = 0.0 if d.ride_height_restored else d.added_mass_kg * GRAVITY_MPS2
                theta_abs = np.where(self.scaled, theta_u * mass, theta_u)
            else:
                m_tot, load = self._mass_for_unit(d)
                theta_abs = theta_u
            every = 0
            if self.horizon_s is not None and d.body_disp_m is not None:
                every = max(1, int(round(self.horizon_s * d.sample_rate_hz)))  # 0 s: 1 sample
            a, jac = kern(d.wheel_disp_m, d.wheel_vel_mps, 1.0 / d.sample_rate_hz,
                               self.substeps, theta_abs, consts, m_tot, load, nuis[s, 0],
                               nuis[s, 1], sens, every,
                               d.body_disp_m if every else _EMPTY,
                               d.body_vel_mps if every else _EMPTY, d.band_hz is not None)
            self._count()
            jz = None
            if sens:
                p = self.n_model
                jz = np.zeros((a.size, self.n_fit))
                jt = jac[:, :p]
                if self.absolute:
                    col_scale = np.where(self.scaled, mass, 1.0)
                    jz[:, :nf] = jt[:, self.free_model] * col_scale[self.free_model]
                    if self.has_mass:  # d/d(1/M) = -M^2 d/dM
                        jz[:, nf] = -mass * mass * (jt[:, self.scaled] @ theta_u[self.scaled]
                                                    + jac[:, p])
                else:
                    jz[:, :nf] = jt[:, self.free_model]
                if self.fit_initial_state:
                    jz[:, self.nuis_index + 2 * s] = jac[:, p + 1]
                    jz[:, self.nuis_index + 2 * s + 1] = jac[:, p + 2]
            if pr.sos is not None:
                a = signal.sosfiltfilt(pr.sos, a)
                if jz is not None:
                    jz = signal.sosfiltfilt(pr.sos, jz, axis=0)
            return a[pr.keep], None if jz is None else jz[pr.keep]

        # the sessions are independent: simulated on threads where the budget allows
        return map_threads(session, range(len(self._prep)))

    def _session_setup(self, d: GreyBoxData, theta_u: np.ndarray, mass: float | None
                       ) -> tuple[np.ndarray, float, float]:
        """(absolute or per-unit-mass parameters, total mass, load) of one session."""
        if self.absolute:
            load = 0.0 if d.ride_height_restored else d.added_mass_kg * GRAVITY_MPS2
            return (np.where(self.scaled, theta_u * mass, theta_u), mass + d.added_mass_kg,
                    load)
        m_tot, load = self._mass_for_unit(d)
        return theta_u, m_tot, load

    def _rate_envelope(self, s: int) -> np.ndarray:
        """The suspension's rate [m/s] that sets the RK4 substeps of session ``s`` in each
        interval: the measured rate where the body's motion is known (else twice the
        wheel's), its largest within :data:`SUBSTEP_WINDOW_S` either side, times
        :data:`SUBSTEP_RATE_MARGIN`, and at most the whole run's largest (cached).

        The simulated rate is not the measured one interval by interval: substeps that
        follow the measured rate sample by sample, as on a given path, let a simulation
        that lags it go unstable. The window and the margin keep the simulation's own
        peaks, a little late or a little larger, inside the steps; a road's few bumps no
        longer set the steps of every quiet interval (the rate's peak is 1.4-9 times its
        99th percentile on six drives of the randomized generator)."""
        env = self._rate_envelopes.get(s)
        if env is None:
            d = self._prep[s].data
            if d.body_vel_mps is not None:
                rate = np.abs(d.body_vel_mps - d.wheel_vel_mps)
            else:
                rate = 2.0 * np.abs(d.wheel_vel_mps)
            width = 2 * int(round(SUBSTEP_WINDOW_S * d.sample_rate_hz)) + 1
            env = np.minimum(SUBSTEP_RATE_MARGIN * maximum_filter1d(rate, width),
                             float(np.max(rate)) if rate.size else 0.0)
            self._rate_envelopes[s] = env
        return env

    def _stateful_setup(self, s: int, z: np.ndarray) -> dict:
        """What a simulation of session ``s`` with internal states needs: parameters,
        masses, the static equilibrium (cached), the RK4 substeps and the resets."""
        theta_u, mass, nuis = self.unpack(z)
        d = self._prep[s].data
        theta, m_tot, load = self._session_setup(d, theta_u, mass)
        key = (theta.tobytes(), float(d.wheel_disp_m[0]), load)
        eq = self._equilibria.get(key)
        if eq is None:
            eq = static_equilibrium(self.model, theta, float(d.wheel_disp_m[0]), load)
            if len(self._equilibria) > 256:
                self._equilibria.clear()
            self._equilibria[key] = eq
        x_eq, z_eq = eq
        h = 1.0 / d.sample_rate_hz
        nsub = np.maximum(self.substeps, self.model.state_substeps(
            theta, self._rate_envelope(s), h)).astype(np.int64)
        every = 0
        if self.horizon_s is not None and d.body_disp_m is not None:
            every = max(1, int(round(self.horizon_s * d.sample_rate_hz)))
        r_static = x_eq - float(d.wheel_disp_m[0]) if d.band_hz is not None else 0.0
        return {"d": d, "theta_u": theta_u, "mass": mass, "nuis": nuis[s], "theta": theta,
                "m_tot": m_tot, "load": load, "key": key, "x_eq": x_eq,
                "z_eq": np.ascontiguousarray(z_eq, dtype=float), "h": h, "nsub": nsub,
                "every": every, "r_static": r_static}

    def _simulate_session_z(self, s: int, z: np.ndarray, n_max: int | None = None
                            ) -> np.ndarray:
        """Body acceleration of session ``s`` (unfiltered, untrimmed; its first ``n_max``
        samples if given) for a model with internal states."""
        st = self._stateful_setup(s, z)
        d, every = st["d"], st["every"]
        self._count()
        n = d.n_samples if n_max is None else min(int(n_max), d.n_samples)
        return _kernels(self.model)._simulate_z(
            d.wheel_disp_m[:n], d.wheel_vel_mps[:n], st["h"], st["nsub"], st["theta"],
            self.model.constant_values(), st["m_tot"], st["load"], st["x_eq"], st["z_eq"],
            st["nuis"][0], st["nuis"][1], every, d.body_disp_m if every else _EMPTY,
            d.body_vel_mps if every else _EMPTY, st["r_static"])

    def _simulate_session_zs(self, s: int, z: np.ndarray
                             ) -> tuple[np.ndarray, np.ndarray | None]:
        """Body acceleration of session ``s`` and its Jacobian ``(n, n_fit)`` with respect
        to the fitted vector (unfiltered, untrimmed) for a model with internal states whose
        effects give their state partials: the states' sensitivities integrated in the
        same run (:func:`~fielddiag.identify.greybox_sensitivities._simulate_zs`). The
        Jacobian is None where those sensitivities have grown without bound (a chaotic
        discrete state, :data:`~fielddiag.effects.model.SENSITIVITY_GROWTH_LIMIT`)."""
        st = self._stateful_setup(s, z)
        d, every, theta, mass, theta_u = st["d"], st["every"], st["theta"], st["mass"], \
            st["theta_u"]
        jac_eq = self._equilibrium_jacobians.get(st["key"])
        if jac_eq is None:
            jac_eq = static_equilibrium_jacobian(self.model, theta, float(d.wheel_disp_m[0]),
                                                 st["load"], st["x_eq"])
            if len(self._equilibrium_jacobians) > 256:
                self._equilibrium_jacobians.clear()
            self._equilibrium_jacobians[st["key"]] = jac_eq
        dx_eq, dz_eq = jac_eq
        # columns: parameters (absolute values of the session), total mass, dx0, dv0
        with_mass = self.absolute and self.has_mass
        tcols = np.union1d(self.free_model, np.flatnonzero(self.scaled) if with_mass
                           else np.zeros(0, int)).astype(np.int64)
        nt = tcols.size
        q = nt + (1 if with_mass else 0) + 2
        s0 = np.zeros((2 + self.model.n_states, q))  # rows: position, velocity, states
        s0[0, :nt] = dx_eq[tcols]
        s0[2:, :nt] = dz_eq[:, tcols]
        s0[0, q - 2] = 1.0
        s0[1, q - 1] = 1.0
        sx_reset = np.zeros(q)
        if d.band_hz is not None:  # r_static moves with the equilibrium
            sx_reset[:nt] = dx_eq[tcols]
        self._count()
        a, jac = _kernels_sens(self.model)._simulate_zs(
            d.wheel_disp_m, d.wheel_vel_mps, st["h"], st["nsub"], theta,
            self.model.constant_values(), st["m_tot"], st["load"], st["x_eq"], st["z_eq"],
            st["nuis"][0], st["nuis"][1], every, d.body_disp_m if every else _EMPTY,
            d.body_vel_mps if every else _EMPTY, st["r_static"], tcols, with_mass, s0,
            sx_reset)
        size = np.concatenate([np.where(theta[tcols] != 0, theta[tcols], 1.0),
                               [st["m_tot"]] if with_mass else [], _NUISANCE_SCALE])
        if sensitivities_exploded(jac, size, a):
            return a, None
        pos = np.full(self.n_model, -1, dtype=int)
        pos[tcols] = np.arange(nt)
        nf = self.free_model.size
        jz = np.zeros((a.size, self.n_fit))
        jt = jac[:, pos[self.free_model]]
        if self.absolute:
            col_scale = np.where(self.scaled, mass, 1.0)
            jz[:, :nf] = jt * col_scale[self.free_model]
            if with_mass:  # d/d(1/M) = -M^2 d/dM
                sc = np.flatnonzero(self.scaled)
                jz[:, nf] = -mass * mass * (jac[:, pos[sc]] @ theta_u[sc] + jac[:, nt])
        else:
            jz[:, :nf] = jt
        if self.fit_initial_state:
            jz[:, self.nuis_index + 2 * s] = jac[:, q - 2]
            jz[:, self.nuis_index + 2 * s + 1] = jac[:, q - 1]
        return a, jz

    def _simulate_stateful(self, z: np.ndarray, sens: bool
                           ) -> list[tuple[np.ndarray, np.ndarray | None]]:
        """:meth:`simulate` for models with internal states: the Jacobian from the states'
        sensitivities integrated in the same run where the effects give their state
        partials (and the steps were within RK4's stability for the states), else by
        forward differences of the same discrete simulation (one more run per fitted value;
        a session's initial-state columns re-run that session only)."""
        exact = sens and self.model.has_state_partials

        def session(s: int) -> tuple[np.ndarray, np.ndarray | None]:
            pr = self._prep[s]
            # (the acceleration is the same either way, operation for operation)
            a, jz = self._simulate_session_zs(s, z) if exact else (
                self._simulate_session_z(s, z), None)
            if sens and jz is None and not np.all(np.isfinite(a)):
                # the simulation diverged here: no step is taken from this point, so its
                # forward differences (one more run per fitted value) would be wasted
                jz = np.full((a.size, self.n_fit), np.nan)
            if sens and jz is None:
                jz = np.zeros((a.size, self.n_fit))
                for j in range(self.nuis_index):
                    step = 1e-6 * abs(z[j]) if z[j] else 1e-9
                    zz = z.copy()
                    zz[j] += step
                    jz[:, j] = (self._simulate_session_z(s, zz) - a) / step
                if self.fit_initial_state:
                    # the initial offset and velocity act through the body's free response
                    # only, gone after INITIAL_STATE_MEMORY_S
                    n0 = int(INITIAL_STATE_MEMORY_S * pr.data.sample_rate_hz)
                    for j in (self.nuis_index + 2 * s, self.nuis_index + 2 * s + 1):
                        step = 1e-6 * max(abs(z[j]), 1e-3)
                        zz = z.copy()
                        zz[j] += step
                        part = (self._simulate_session_z(s, zz, n0) - a[:n0]) / step
                        jz[: part.size, j] = part
            if pr.sos is not None:
                a = signal.sosfiltfilt(pr.sos, a)
                if jz is not None:
                    jz = signal.sosfiltfilt(pr.sos, jz, axis=0)
            return a[pr.keep], None if jz is None else jz[pr.keep]

        return map_threads(session, range(len(self._prep)))

    def residual_and_jacobian(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Stacked residuals (simulated - measured) and their Jacobian wrt ``z``.

        Parameters
        ----------
        z : ndarray
            The fitted vector (see :meth:`unpack`).

        Returns
        -------
        residual : ndarray
            ``(n_residuals,)`` body acceleration [m/s^2], sessions one after the other.
        jacobian : ndarray
            ``(n_residuals, n_fit)``.
        """
        sims = self.simulate(z, True)
        r = np.concatenate([pr.project(a - pr.measured) for (a, _), pr in zip(
            sims, self._prep, strict=True)])
        j = np.vstack([pr.project(jz) for (_, jz), pr in zip(sims, self._prep, strict=True)])
        return r, j

    def residual(self, z: np.ndarray) -> np.ndarray:
        """Stacked residuals only (no sensitivities): for finite-difference comparisons.

        Parameters
        ----------
        z : ndarray
            The fitted vector (see :meth:`unpack`).

        Returns
        -------
        numpy.ndarray
            ``(n_residuals,)`` simulated - measured body acceleration [m/s^2].
        """
        sims = self.simulate(z, False)
        return np.concatenate([pr.project(a - pr.measured) for (a, _), pr in zip(
            sims, self._prep, strict=True)])

    def session_slices(self) -> list[slice]:
        """Where each session's residuals lie in the stacked residual vector.

        Returns
        -------
        list of slice
            One per session, in order.
        """
        out, i = [], 0
        for pr in self._prep:
            out.append(slice(i, i + pr.measured.size))
            i += pr.measured.size
        return out

    # ------------------------------------------------------------------ start values
    def equation_error_start(self) -> tuple[np.ndarray, float | None]:
        """Start values by linear least squares on the equation error (needs body motion).

        Per session group of equal added mass, regress the band-limited body acceleration
        on the force derivatives of the linear-in-parameter terms at typical values; the
        sprung mass follows from the ratio of the first force-scaled parameter between
        the two groups. Falls back to typical values where this fails.

        Returns
        -------
        theta : ndarray
            ``(n_model,)`` model parameters per unit mass, clipped to the bounds.
        mass : float or None
            Sprung mass M2 [kg] in absolute mode (the guess, 380 kg by default, if the two
            groups do not give one), else None.
        """
        model = self.model
        guess_mass = self.body_mass_guess_kg or 380.0
        typical_u = model.vector(per_unit_mass_kg=guess_mass)
        per_group: dict[float, np.ndarray] = {}
        for dm in sorted({round(d.added_mass_kg, 9) for d in self.data}):
            rows, ys = [], []
            for pr in self._prep:
                d = pr.data
                if round(d.added_mass_kg, 9) != dm or d.body_disp_m is None:
                    continue
                r = d.body_disp_m - d.wheel_disp_m
                rd = d.body_vel_mps - d.wheel_vel_mps
                _, _, dp, _ = model.force_along_path(r, rd, d.body_disp_m, typical_u,
                                                   d.sample_rate_hz)
                if pr.sos is not None:
                    dp = signal.sosfiltfilt(pr.sos, dp, axis=0)
                rows.append(dp[pr.keep])
                ys.append(pr.measured)
            if not rows:
                continue
            a = np.vstack(rows)
            y = np.concatenate(ys)
            lin = np.array([t.linear_in_params for t in model.terms for _ in t.params])
            cols = np.flatnonzero(lin & model.force_scaled)
            if cols.size == 0:
                continue
            sol = np.linalg.lstsq(a[:, cols], y, rcond=None)[0]
            th = typical_u.copy()
            th[cols] = sol
            per_group[dm] = th
        if not per_group:
            return np.clip(typical_u, model.lower, model.upper), (
                guess_mass if self.absolute else None)
        groups = sorted(per_group)
        mass = None
        th = per_group[groups[0]]
        if self.absolute:
            mass = guess_mass
            k = int(np.flatnonzero(model.force_scaled)[0])
            a0, a1 = per_group[groups[0]][k], per_group[groups[-1]][k]
            dm0, dm1 = groups[0], groups[-1]
            # theta/(M + dm0) = a0, theta/(M + dm1) = a1  ->  M
            if a0 > a1 > 0:
                m = (a1 * dm1 - a0 * dm0) / (a0 - a1)
                if m > 0 and math.isfinite(m):
                    mass = m
            th = per_group[groups[0]] * np.where(model.force_scaled, (mass + dm0) / mass, 1.0)
        th = np.clip(th, model.lower, model.upper)
        return th, mass
