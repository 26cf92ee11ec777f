"""Rig mode: diagnose one degree of freedom driven by a measured force.

On a damper or spring test rig (or a shaker) a load cell measures the force and a sensor
the displacement (or the acceleration) of the moving end. The model is::

    force = F0 + m a - F(r, rdot)          r = displacement, rdot its rate

with ``F`` the same force-term library as the vehicle model (linear spring ``-k r``,
linear damper ``-c rdot`` and the candidate effects), ``m`` the moving mass and ``F0`` a
preload or load-cell offset. The model is linear in every parameter but a bump stop's
gap, so fits are quick; held-out data (the last part of the recording) decide which
effects are real, with the rule of :mod:`fielddiag.diagnose.selection`.

The band is read from the data (:mod:`fielddiag.diagnose.rig_band`): the displacement's
signal-to-noise and the force/displacement coherence give the highest frequency the
motion carries, and one zero-phase low-pass (or none, when the signal fills the band to
Nyquist) acts alike on both sides of the force equation. The motion is filtered and
differentiated spectrally (exact at any sample-rate/resonance ratio); the *residual*
``force - model(motion)`` is filtered by the same filter, so whatever the filter takes out
of the measured force (the harmonics of a friction step or of a cubic spring above the
cut-off) it takes out of the model's force too, and no parameter is biased by it. The
moving mass ``m`` stays in the model when the data show inertia (significant, at least
1 % of the force, and seen in the frequency response: a resonance, or ``Re(F/X)``
falling as ``k - m w^2``); otherwise it is fixed at zero.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy import optimize

from fielddiag.blas import single_threaded_blas
from fielddiag.diagnose.locate import departure_map
from fielddiag.diagnose.rig_band import RigBand, choose_rig_band, lowpass, zero_phase
from fielddiag.diagnose.selection import (
    CandidateFit,
    Selection,
    compare,
    confidence,
    nrmse,
    select_model,
)
from fielddiag.effects import get_effect
from fielddiag.errors import FieldDiagError, InsufficientDataError
from fielddiag.identify.terms import ForceModel, make_term, split_shape

#: Effect terms tried by default, in the diagnosis library's names.
RIG_EFFECTS = ("coulomb_friction", "cubic_stiffness", "bump_stop", "asymmetric_damping",
               "dahl_friction", "buildup_hysteresis")
#: Effects that refine another (the build-up hysteresis is Dahl friction plus a build-up
#: along the stroke): where that one is a candidate too, tried only where it alone predicts
#: the held-out data significantly better than the linear model, and started from its fit.
REFINES = {"buildup_hysteresis": "dahl_friction"}
#: Parameters that are physical anywhere in their range, bounds included, and so never
#: make a fit unphysical: a build-up in one direction only (the other at zero), one that
#: never levels off (its travel at the upper bound), a release within any travel.
FREE_FORM_PARAMS = ("compression_buildup_n_per_m", "extension_buildup_n_per_m",
                    "buildup_travel_m", "release_displacement_m")
#: The moving mass is kept when its force is at least this share of the force's spread.
MIN_INERTIA_SHARE = 0.01
#: Warm-up [s]: the internal states of a hysteresis start at rest, unknown to the data, so
#: a record's first this long of motion (after any still start) and the same span before
#: any part of it only carry the states; their force is not scored (for every model alike).
WARMUP_S = 0.5
#: Smallest yield travel a rig fit resolves, as a share of the largest travel per sample.
MIN_YIELD_SAMPLE_TRAVEL = 0.05
#: Samples a hysteresis' nonlinear parameters are searched on (the first of a longer record).
MAX_SEARCH_SAMPLES = 6000
#: Start values of a hysteresis' yield travel, as shares of the displacement's std
#: (screened: the search starts from the best).
YIELD_STARTS = tuple(np.geomspace(0.002, 0.3, 7))
#: The rig counts as moving once its speed exceeds this share of its 99th-percentile speed.
MOTION_START_SHARE = 0.05


@dataclass(frozen=True)
class RigData:
    """Synchronous rig samples on a uniform time base (SI or the units recorded).

    Attributes
    ----------
    sample_rate_hz : float
        Sample rate [Hz].
    time_s : numpy.ndarray
        Sample times [s].
    force : numpy.ndarray
        Measured force through the band's filter, over this record (or part).
    displacement, velocity, acceleration : numpy.ndarray
        Motion through the same filter, the rates spectral derivatives.
    force_unit, displacement_unit : str
        Units as recorded.
    force_raw : numpy.ndarray or None
        Measured force as recorded (None: ``force`` is unfiltered).
    band : RigBand or None
        The analysis band and why it was chosen (None: no filter, nothing chosen).
    """

    sample_rate_hz: float
    time_s: np.ndarray
    force: np.ndarray
    displacement: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    force_unit: str = "N"
    displacement_unit: str = "m"
    force_raw: np.ndarray | None = None
    band: RigBand | None = None
    lead_displacement: np.ndarray | None = None
    lead_velocity: np.ndarray | None = None

    @property
    def n_lead(self) -> int:
        """Samples of motion before the first one (the internal states' warm-up)."""
        return 0 if self.lead_displacement is None else int(self.lead_displacement.size)

    @property
    def warmup_samples(self) -> int:
        """Samples the internal states run through before a part's first sample."""
        return int(np.ceil(WARMUP_S * self.sample_rate_hz))

    def path(self) -> tuple[np.ndarray, np.ndarray]:
        """Displacement and velocity with the lead-in in front (the states' whole path).

        Returns
        -------
        (numpy.ndarray, numpy.ndarray)
            ``n_lead + n`` samples each.
        """
        if not self.n_lead:
            return self.displacement, self.velocity
        return (np.concatenate((self.lead_displacement, self.displacement)),
                np.concatenate((self.lead_velocity, self.velocity)))

    @property
    def cutoff_hz(self) -> float | None:
        """The low-pass acting on both sides of the force equation (None: no filter)."""
        return None if self.band is None else self.band.cutoff_hz

    def lowpass(self, x: np.ndarray) -> np.ndarray:
        """``x`` (samples of this record, or columns of them) through the band's filter.

        Parameters
        ----------
        x : numpy.ndarray, shape (n,) or (n, k)

        Returns
        -------
        numpy.ndarray
            Same shape; ``x`` itself when there is no filter.
        """
        return lowpass(x, self.sample_rate_hz, self.cutoff_hz)

    def part(self, start: int, stop: int) -> RigData:
        """Samples ``start:stop``; the force is filtered again over the part alone, as the
        fit filters its residual there (the same filter on both sides, same ends).

        Parameters
        ----------
        start, stop : int
            Sample range.

        Returns
        -------
        RigData
        """
        sl = slice(start, stop)
        raw = None if self.force_raw is None else self.force_raw[sl]
        # the motion just before the part (at most the warm-up): the internal states of a
        # hysteresis run through it, its force is not scored
        px, pv = self.path()
        s0 = self.n_lead + start
        lead = slice(max(0, s0 - self.warmup_samples), s0)
        force = self.force[sl] if raw is None else self.lowpass(raw)
        return RigData(
            self.sample_rate_hz,
            self.time_s[sl],
            force,
            self.displacement[sl],
            self.velocity[sl],
            self.acceleration[sl],
            self.force_unit,
            self.displacement_unit,
            raw,
            self.band,
            px[lead].copy() if s0 > lead.start else None,
            pv[lead].copy() if s0 > lead.start else None,
        )

    @property
    def measured_force(self) -> np.ndarray:
        """The force as recorded (before the band's filter)."""
        return self.force if self.force_raw is None else self.force_raw

    @property
    def n(self) -> int:
        """Number of samples."""
        return int(self.force.size)


def _edge_margin(sample_rate_hz: float, cutoff_hz: float | None, n: int) -> int:
    """Samples dropped at each end of a record: the filter's settling near the ends."""
    settle = 8 if cutoff_hz is None else int(np.ceil(2.0 * sample_rate_hz / cutoff_hz))
    return int(min(max(settle, 8), n // 20))


def _after_warmup(data: RigData) -> RigData:
    """The record from the end of its warm-up on: the still samples at its start and the
    first :data:`WARMUP_S` of motion become the lead-in (at most a third of the record).

    Parameters
    ----------
    data : RigData

    Returns
    -------
    RigData
    """
    speed = np.abs(data.velocity)
    moving = np.flatnonzero(speed > MOTION_START_SHARE * np.quantile(speed, 0.99))
    start = (int(moving[0]) if moving.size else 0) + data.warmup_samples
    return data.part(min(start, data.n // 3), data.n)


def rig_data_from_displacement(
    time_s: np.ndarray,
    force: np.ndarray,
    displacement: np.ndarray,
    sample_rate_hz: float,
    *,
    cutoff_hz: float | None = None,
    force_unit: str = "N",
    displacement_unit: str = "m",
) -> RigData:
    """Rig samples from a measured force and displacement, in a band read from the data.

    The band (:func:`fielddiag.diagnose.rig_band.choose_rig_band`) comes from the
    displacement's signal-to-noise and the force/displacement coherence; the same
    zero-phase low-pass (or none) then acts on the displacement, whose velocity and
    acceleration are its exact spectral derivatives, and on the force. The fit filters its
    residual with it too, so a friction step or a cubic spring's harmonics above the
    cut-off leave the measured and the modelled force alike. The displacement keeps its
    absolute zero (a bump stop's gap is measured from the rig's zero). A few samples at
    each end, where the filter settles, are dropped.

    Parameters
    ----------
    time_s, force, displacement : array_like
        Samples on a uniform time base.
    sample_rate_hz : float
        Sample rate [Hz].
    cutoff_hz : float or None
        Force a cut-off [Hz] instead of choosing one (``inf``: no filter).
    force_unit, displacement_unit : str
        Units as recorded.

    Returns
    -------
    RigData
    """
    fs = float(sample_rate_hz)
    f = np.asarray(force, float)
    x_raw = np.asarray(displacement, float)
    band = choose_rig_band(f, x_raw, fs)
    if cutoff_hz is not None:
        given = None if not np.isfinite(cutoff_hz) or cutoff_hz >= fs / 2 else float(cutoff_hz)
        band = RigBand(given, band.motion_edge_hz, band.snr_edge_hz, band.coherent_band_hz,
                       band.resonance_hz, fs, f"cut-off given: {given or 'none'}",
                       band.displacement_noise_psd, band.frf_mass)
    x, v, a = zero_phase(lowpass(x_raw, fs, band.cutoff_hz), fs, None, (0, 1, 2))
    data = RigData(fs, np.asarray(time_s, float), f, x, v, a, force_unit,
                   displacement_unit, f, band)
    k = _edge_margin(fs, band.cutoff_hz, data.n)
    return _after_warmup(data.part(k, data.n - k))


def rig_data_from_acceleration(
    time_s: np.ndarray,
    force: np.ndarray,
    acceleration: np.ndarray,
    sample_rate_hz: float,
    *,
    band_hz: tuple[float, float] | None = None,
    force_unit: str = "N",
) -> RigData:
    """Rig samples from a measured force and acceleration, in a band read from the data.

    The band is chosen from the force and the acceleration as for a displacement
    (:func:`rig_data_from_displacement`; coherence does not change under integration);
    the acceleration is low-passed by that band's filter (the same one the force and the
    model's force get) and integrated from half the lowest coherent frequency (at least
    0.2 Hz) up. The absolute position is lost:
    ``r`` is measured from the mean position. The displacement noise floor is not that of
    a sensor here, so the fit makes no errors-in-variables correction.

    Parameters
    ----------
    time_s, force, acceleration : array_like
        Samples on a uniform time base (acceleration in m/s^2).
    sample_rate_hz : float
        Sample rate [Hz].
    band_hz : (float, float) or None
        Force the integration band [Hz] instead of choosing the upper edge from the data
        (the force is then not filtered).
    force_unit : str
        Unit of the force as recorded.

    Returns
    -------
    RigData
    """
    from fielddiag.dsp import integrate_acceleration

    fs = float(sample_rate_hz)
    f = np.asarray(force, float)
    acc = np.asarray(acceleration, float)
    if band_hz is not None:
        motion = integrate_acceleration(acc, fs, band_hz, method="frequency")
        band = None
        low_passed = acc
    else:
        band = choose_rig_band(f, acc, fs, motion="acceleration")
        band = RigBand(band.cutoff_hz, band.motion_edge_hz, band.snr_edge_hz,
                       band.coherent_band_hz, band.resonance_hz, fs,
                       band.reason + " (read from the acceleration)", 0.0, band.frf_mass)
        low_passed = lowpass(acc, fs, band.cutoff_hz)
        # integration from half the lowest coherent frequency: below it the double
        # integral would be noise amplified as 1/w^4
        lo = 0.2 if band.coherent_band_hz is None else max(0.2, 0.5 * band.coherent_band_hz[0])
        motion = integrate_acceleration(low_passed, fs, (lo, 0.49 * fs), method="frequency")
    data = RigData(
        fs,
        np.asarray(time_s, float),
        f,
        motion.displacement_m,
        motion.velocity_mps,
        motion.acceleration_mps2,
        force_unit,
        "m",
        f if band is not None else None,
        band,
    )
    k = _edge_margin(fs, None if band is None else band.cutoff_hz, data.n)
    return _after_warmup(data.part(k, data.n - k))


# ----------------------------------------------------------------------------- fitting
def _model_for(effects: Sequence[str]) -> ForceModel:
    names = ["linear_spring", "linear_damper", *effects]
    model = ForceModel(make_term(n) for n in names)
    return model


def model_force(model: ForceModel, theta: np.ndarray, data: RigData, *,
                state_jacobian: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """The model's force ``F(r, rdot)`` over a record and its derivatives in ``theta``.

    A memoryless model is evaluated sample by sample. A model with internal states (a
    hysteresis) integrates them along the measured motion
    (:meth:`~fielddiag.effects.model.ForceModel.force_along_path`), starting at rest at the
    first sample of the record's lead-in (:attr:`RigData.n_lead`), and keeps the samples
    after it.

    Parameters
    ----------
    model : ForceModel
    theta : numpy.ndarray
        Parameter values in model order.
    data : RigData
        The record (or part).
    state_jacobian : bool
        Derivatives through the states (forward differences, one more integration per
        parameter of a stateful term); False leaves the kernels' derivatives at frozen
        states, which are exact for a parameter the states do not depend on.

    Returns
    -------
    force : numpy.ndarray, shape (n,)
    d_params : numpy.ndarray, shape (n, n_params)
    """
    if model.n_states == 0:
        zeros = np.zeros_like(data.displacement)
        f, _, dth = model.force(data.displacement, data.velocity, zeros, theta)
        return f, dth
    x, v = data.path()
    f, _, dth, _ = model.force_along_path(x, v, 0.0, theta, data.sample_rate_hz,
                                          state_jacobian=state_jacobian)
    k = data.n_lead
    return f[k:], dth[k:]


def _residual_and_jac(model: ForceModel, z: np.ndarray, data: RigData, *,
                      state_jacobian: bool = True):
    """Residual ``force - (F0 + m a - F)`` and its Jacobian in ``z``, both through the
    band's filter (the measured force went through it; the model's force goes too)."""
    f0, m, theta = z[0], z[1], z[2:]
    fm, dth = model_force(model, theta, data, state_jacobian=state_jacobian)
    pred_raw = m * data.acceleration - fm
    jac = np.empty((data.n, z.size))
    jac[:, 0] = -1.0
    jac[:, 1] = -data.acceleration
    jac[:, 2:] = dth
    if data.cutoff_hz is not None:
        filt = data.lowpass(np.column_stack([pred_raw, jac[:, 1:]]))
        pred_raw, jac[:, 1:] = filt[:, 0], filt[:, 1:]
    res = data.force - f0 - pred_raw
    return res, jac


def _start_values(model: ForceModel, data: RigData, linear: dict[str, float]) -> list[np.ndarray]:
    """Start vectors: the linear fit's values plus typical/ data-scaled effect values."""
    base = []
    for key, spec in zip(model.param_keys, model.specs, strict=True):
        if key in linear:
            base.append(linear[key])
        elif spec.name == "friction_force_n":
            base.append(0.1 * float(np.std(data.force)))
        elif spec.name == "compression_damping_ns_per_m" or spec.name == "rebound_damping_ns_per_m":
            base.append(linear.get("linear_damper.suspension_damping_ns_per_m", spec.typical))
        elif spec.name == "cubic_stiffness_n_per_m3":
            base.append(0.0)
        elif spec.name == "stiffness_n_per_m":
            base.append(5.0 * linear.get("linear_spring.suspension_stiffness_n_per_m", 2e4))
        elif spec.name == "gap_m":
            base.append(float(np.quantile(-data.displacement, 0.9)))
        elif spec.name in ("yield_displacement_m", "release_displacement_m"):
            # a release (of a build-up) over about twice the pre-yield travel
            share = float(np.median(YIELD_STARTS)) * float(np.std(data.displacement))
            base.append(share * (2.0 if spec.name == "release_displacement_m" else 1.0))
        elif spec.name == "buildup_travel_m":
            # the build-up levels off after about the stroke's span
            base.append(float(np.clip(np.ptp(data.displacement), 1.1 * spec.lower,
                                      0.5 * spec.upper)))
        else:
            base.append(spec.typical)
    starts = [np.array([linear.get("f0", 0.0), linear.get("m", 0.0), *base])]
    for key in model.param_keys:
        if key.endswith(".yield_displacement_m") and key not in linear:
            # a hysteresis' yield travel: anywhere from far below a sample's travel (a
            # sharp friction-like loop) to a good share of the stroke
            j = 2 + model.index(key)
            rel = key.replace("yield_displacement_m", "release_displacement_m")
            grid = []
            for st in starts:
                for q in YIELD_STARTS:
                    st = st.copy()
                    st[j] = q * float(np.std(data.displacement))
                    if rel in model.param_keys:
                        st[2 + model.index(rel)] = 2.0 * st[j]
                    grid.append(st)
            starts = grid
    if "bump_stop.gap_m" in model.param_keys:
        j = 2 + model.index("bump_stop.gap_m")
        for q in (0.7, 0.97):
            s = starts[0].copy()
            s[j] = max(float(np.quantile(-data.displacement, q)), 1e-4)
            starts.append(s)
    return starts


def _inside(z0: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """Move a start vector strictly inside finite bounds (least_squares needs it)."""
    z = np.array(z0, float)
    step = 1e-6 * np.maximum(np.abs(z), 1.0)
    z = np.where(np.isfinite(lower) & (z <= lower), lower + step, z)
    z = np.where(np.isfinite(upper) & (z >= upper), upper - step, z)
    return z


def fit_rig_model(
    effects: Sequence[str],
    data: RigData,
    linear: dict[str, float] | None = None,
    *,
    fit_mass: bool = True,
) -> tuple[ForceModel, np.ndarray, np.ndarray, float]:
    """Least-squares fit of ``F0, m`` and the model's parameters to the force.

    Parameters
    ----------
    effects : sequence of str
        Effects added to the linear spring and damper.
    data : RigData
        The samples to fit (the residual is filtered by ``data``'s band).
    linear : dict or None
        Start values by parameter key (``f0``, ``m`` and the model's keys).
    fit_mass : bool
        Fit the moving mass; False fixes it at zero (no inertia in the data).

    Returns
    -------
    model : ForceModel
    z : numpy.ndarray
        ``[F0, m, theta...]``.
    covariance : numpy.ndarray
        Of ``z`` (zero row and column for a fixed mass).
    residual_variance : float
    """
    model = _model_for(effects)
    lower = np.concatenate(([-np.inf, 0.0], model.lower))
    upper = np.concatenate(([np.inf, np.inf], model.upper))
    for key in model.param_keys:
        if key.endswith((".yield_displacement_m", ".release_displacement_m")):
            # a pre-yield travel far below the travel of one sample is not resolved by
            # the data (the loop is then a step), and would only cost integration steps
            j = 2 + model.index(key)
            travel = float(np.max(np.abs(data.velocity))) / data.sample_rate_hz
            lower[j] = max(lower[j], MIN_YIELD_SAMPLE_TRAVEL * travel)
    # variable projection: the force is proportional to each force-scaled parameter
    # (ParamSpec.scales_with_force) whose term's states, if any, do not depend on it (a
    # hysteresis' force level, given its state), so linear in F0, m and those; only the
    # rest (a bump stop's gap, friction's smoothing velocity, a hysteresis' yield travel)
    # is searched, the linear ones solved by bounded least squares at every step of it
    starts = _start_values(model, data, linear or {})
    # a hysteresis' states are integrated along the whole path at every step of the search:
    # on a long record the nonlinear parameters are searched on its first part only
    search = data
    if model.n_states and data.n > MAX_SEARCH_SAMPLES:
        search = data.part(0, MAX_SEARCH_SAMPLES)
    state_free = _state_free_params(model, starts[0][2:], search)
    linear_mask = np.concatenate(([True, True], [
        spec.scales_with_force and ok for spec, ok in zip(model.specs, state_free, strict=True)
    ]))
    free = np.ones(lower.size, bool)
    free[1] = fit_mass
    lin = linear_mask & free
    nonlin = ~linear_mask & free

    lin_idx = np.flatnonzero(lin)
    term_of = np.array(["", "", *model.param_terms])
    moving = np.isin(term_of[lin_idx], sorted({term_of[i] for i in np.flatnonzero(nonlin)}))

    def make_solver(d: RigData):
        noise_cov = _noise_covariance(model, d, lin_idx)
        base: dict[str, np.ndarray] = {}

        def solve_linear(z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            """Best linear parameters for the nonlinear ones in ``z``; (z, filtered
            residual) over ``d``.

            With every force-scaled parameter at zero the model's force is zero, so the
            residual is the filtered force and the filtered Jacobian columns are the
            basis; only the columns of terms with a nonlinear parameter change between
            calls."""
            z = z.copy()
            z[lin] = 0.0
            if "a" not in base:
                _, jac = _residual_and_jac(model, z, d, state_jacobian=False)
                base["a"] = -jac[:, lin_idx]
            elif moving.any():
                _, dth = model_force(model, z[2:], d, state_jacobian=False)
                cols = dth[:, lin_idx[moving] - 2]
                base["a"][:, moving] = -d.lowpass(cols)
            a = base["a"]
            with np.errstate(over="ignore", invalid="ignore"):
                scale = np.sqrt(np.sum(a * a, axis=0))
            if not (np.all(np.isfinite(a)) and np.all(np.isfinite(scale))):
                # states integrated out of their stable range (a yield travel far below
                # a sample's travel): a poor, finite cost steers the search back
                return z, 10.0 * d.force
            scale[scale == 0] = 1.0
            a_s = a / scale
            bounds = (lower[lin] * scale, upper[lin] * scale)
            sol = None
            if noise_cov is not None:
                # errors in variables: the sensor noise in x, v, a (and x^3) adds
                # n * Sigma to A'A; minimise t'(A'A - n Sigma)t - 2 t'A'b, written as a
                # least-squares problem with the Cholesky factor (falls back when not
                # positive definite)
                m_mat = a_s.T @ a_s - d.n * noise_cov / np.outer(scale, scale)
                try:
                    chol = np.linalg.cholesky(m_mat).T
                    rhs = np.linalg.solve(chol.T, a_s.T @ d.force)
                    sol = optimize.lsq_linear(chol, rhs, bounds=bounds, method="bvls")
                except np.linalg.LinAlgError:
                    sol = None
            if sol is None:
                sol = optimize.lsq_linear(a_s, d.force, bounds=bounds, method="bvls")
            z[lin] = sol.x / scale
            return z, d.force - a_s @ sol.x

        return solve_linear

    solve_linear = make_solver(data)
    solve_search = solve_linear if search is data else make_solver(search)

    starts = [_inside(z0, lower, upper) for z0 in starts]
    for z0 in starts:
        z0[~free] = 0.0
    if model.n_states and len(starts) > 1:
        # a hysteresis' yield travel: screened on a grid (one integration of the states
        # each), the search started from the best point only
        costs = [float(np.sum(solve_search(z0)[1] ** 2)) for z0 in starts]
        starts = [starts[int(np.argmin(costs))]]
    best_z, best_cost = None, np.inf
    for z0 in starts:
        if nonlin.any():
            def reduced(q: np.ndarray, z0=z0) -> np.ndarray:
                zz = z0.copy()
                zz[nonlin] = q
                return solve_search(zz)[1]

            sol = optimize.least_squares(reduced, z0[nonlin], bounds=(lower[nonlin],
                                         upper[nonlin]), x_scale=np.abs(z0[nonlin]) + 1e-6,
                                         method="trf", diff_step=1e-3, max_nfev=25,
                                         xtol=1e-4, ftol=1e-6)
            z0 = z0.copy()
            z0[nonlin] = sol.x
        z, res = solve_linear(z0)
        cost = float(res @ res)
        if cost < best_cost:
            best_z, best_cost = z, cost
    z = best_z
    res, jac = _residual_and_jac(model, z, data)
    jac = jac[:, free]
    dof = max(data.n - int(free.sum()), 1)
    s2 = float(res @ res) / dof
    cov = np.zeros((z.size, z.size))
    try:
        cov[np.ix_(free, free)] = np.linalg.pinv(jac.T @ jac) * s2
    except np.linalg.LinAlgError:
        cov[np.ix_(free, free)] = np.nan
    return model, z, cov, s2


def _state_free_params(model: ForceModel, theta: np.ndarray, data: RigData) -> list[bool]:
    """For each parameter: True unless it belongs to a term with internal states whose
    states change with it (checked along the record: the states with the parameter at
    zero and at ``theta`` or its typical value). A force-scaled parameter the states do
    not depend on enters the force linearly (Dahl's stiffness, Bouc-Wen's force level).

    Parameters
    ----------
    model : ForceModel
    theta : numpy.ndarray
        Parameter values (start values) in model order.
    data : RigData

    Returns
    -------
    list of bool
    """
    out = [True] * model.n_params
    if model.n_states == 0:
        return out
    x, v = data.path()
    fs = data.sample_rate_hz
    th = np.array(theta, float)
    for j, (term, spec) in enumerate(zip(model.param_terms, model.specs, strict=True)):
        if not any(t.name == term and t.n_states for t in model.terms):
            continue
        if not spec.scales_with_force:
            out[j] = False
            continue
        a, b = th.copy(), th.copy()
        a[j] = 0.0
        b[j] = th[j] if th[j] else spec.typical
        za = model.force_along_path(x, v, 0.0, a, fs, state_jacobian=False)[3]
        zb = model.force_along_path(x, v, 0.0, b, fs, state_jacobian=False)[3]
        out[j] = bool(np.array_equal(za, zb))
    return out


#: Columns of the linear fit that white displacement noise enters, by parameter key.
_NOISY_COLUMNS = {
    "linear_spring.suspension_stiffness_n_per_m": "x",
    "linear_damper.suspension_damping_ns_per_m": "v",
    "cubic_stiffness.cubic_stiffness_n_per_m3": "x3",
}


def _noise_covariance(model: ForceModel, data: RigData, lin_idx: np.ndarray
                      ) -> np.ndarray | None:
    """Covariance per sample of the displacement-noise part of the linear columns
    (``a``, ``x``, ``v``; ``x^3`` to first order, ``3 x^2 n``), from the band's measured
    noise floor; None without one."""
    band = data.band
    if band is None or band.displacement_noise_psd <= 0:
        return None
    vx, cxa, vv, va = band.noise_moments()
    x2 = float(np.mean(data.displacement**2))
    x4 = float(np.mean(data.displacement**4))
    keys = ("", "a", *[_NOISY_COLUMNS.get(k, "") for k in model.param_keys])
    kinds = [keys[i] for i in lin_idx]
    table = {
        ("x", "x"): vx, ("a", "a"): va, ("v", "v"): vv, ("x", "a"): cxa,
        ("x3", "x3"): 9.0 * x4 * vx, ("x3", "x"): 3.0 * x2 * vx, ("x3", "a"): 3.0 * x2 * cxa,
    }
    cov = np.zeros((len(kinds), len(kinds)))
    for i, ki in enumerate(kinds):
        for j, kj in enumerate(kinds):
            cov[i, j] = table.get((ki, kj), table.get((kj, ki), 0.0))
    return cov if np.any(cov) else None


def _named(model: ForceModel, z: np.ndarray) -> dict[str, float]:
    out = {"preload_n": float(z[0]), "moving_mass_kg": float(z[1])}
    for key, v in zip(model.param_keys, z[2:], strict=True):
        out[key] = float(v)
    return out


def _at_bound(
    model: ForceModel, z: np.ndarray, std: np.ndarray, effects: Sequence[str],
    displacement: np.ndarray | None = None,
) -> tuple[str, ...]:
    """Effect parameters not significantly away from a bound (a physical limit), or
    unphysical over the recorded ``displacement`` (a friction level turning negative)."""
    pinned = []
    for i, (key, spec) in enumerate(zip(model.param_keys, model.specs, strict=True)):
        if key.split(".")[0] not in effects:
            continue
        v, s = z[2 + i], std[2 + i]
        if spec.name in FREE_FORM_PARAMS:
            continue
        if spec.name == "smoothing_velocity_mps":
            # a loosely determined shape parameter: only its upper end (friction turned
            # into a linear damper) is telling
            if v >= 0.98 * spec.upper:
                pinned.append(key)
            continue
        for b in (spec.lower, spec.upper):
            if np.isfinite(b) and abs(v - b) <= max(2.0 * s, 1e-9 * max(abs(b), 1.0)):
                pinned.append(key)
        if spec.name == "cubic_stiffness_n_per_m3" and v < 0:
            pinned.append(key)  # a softening spring is not a progressive spring
        if spec.name == "friction_gradient_n_per_m" and displacement is not None:
            # the friction level F_f + g r must stay positive over the stroke
            level0 = z[2 + model.index(key.replace("friction_gradient_n_per_m",
                                                   "friction_force_n"))]
            ends = level0 + v * np.array([np.min(displacement), np.max(displacement)])
            if np.min(ends) <= 0.0:
                pinned.append(key)
    return tuple(pinned)


def _candidate(
    effects: Sequence[str],
    fit: RigData,
    val: RigData,
    linear: dict[str, float],
    fit_mass: bool = True,
) -> CandidateFit:
    model, z, cov, _ = fit_rig_model(effects, fit, linear, fit_mass=fit_mass)
    std = np.sqrt(np.clip(np.diag(cov), 0, None))
    res_fit, _ = _residual_and_jac(model, z, fit, state_jacobian=False)
    res_val, _ = _residual_and_jac(model, z, val, state_jacobian=False)
    names = _named(model, z)
    stds = dict(zip(names, std.tolist(), strict=True))
    return CandidateFit(
        effects=tuple(effects),
        values=names,
        std=stds,
        nrmse_fit=nrmse(res_fit, fit.force),
        nrmse_validation=nrmse(res_val, val.force),
        residual_validation=res_val,
        n_params=z.size,
        at_bound=_at_bound(model, z, std, effects, fit.displacement),
        extra={"model": model, "z": z},
    )


@dataclass
class RigDiagnosis:
    """Outcome of :func:`diagnose_rig`; ``to_dict`` gives the JSON of ``fielddiag diagnose``."""

    selection: Selection
    data: RigData
    split_index: int
    unexplained: dict | None
    inertia_kept: bool = True

    def to_dict(self) -> dict:
        """The JSON of ``fielddiag diagnose`` in rig mode.

        Returns
        -------
        dict
            ``mode``, ``verdict``, ``baseline``, ``augmented``, ``parameters``,
            ``findings``, ``candidates``, ``validation``, ``band`` (the filter, its
            cut-off, the motion edge, coherent band, resonance, whether the moving mass
            is in the model, and why) and ``warnings``.
        """
        sel = self.selection
        base, chosen = sel.baseline, sel.chosen
        verdict = "adequate" if (chosen is base and self.unexplained is None) else "missing_physics"
        unit_k = f"{self.data.force_unit}/{self.data.displacement_unit}"
        findings = []
        if chosen is not base:
            explained = 1.0 - chosen.mse_validation / base.mse_validation
            for eff in self.effects_by_weight():
                params, shape = split_shape({
                    k.split(".", 1)[1]: v
                    for k, v in chosen.values.items()
                    if k.startswith(eff + ".")
                })
                findings.append(
                    {
                        "effect": eff,
                        "confidence": confidence(sel.comparison, explained / max(explained, 0.3)),
                        "parameters": params,
                        "shape": shape,
                        "std": {
                            k.split(".", 1)[1]: v
                            for k, v in chosen.std.items()
                            if k.startswith(eff + ".")
                        },
                        "where": {"region": self._region(chosen)},
                        "explanation": _rig_explanation(eff, params, self.data, shape),
                    }
                )
        if self.unexplained is not None:
            findings.append(self.unexplained)
        lin = {**base.values, **chosen.values}
        lin_std = {**base.std, **chosen.std}
        return {
            "mode": "rig",
            "verdict": verdict,
            "baseline": {"nrmse": base.nrmse_fit, "nrmse_validation": base.nrmse_validation},
            "augmented": {"nrmse": chosen.nrmse_fit, "nrmse_validation": chosen.nrmse_validation},
            "parameters": {
                "stiffness": {
                    "value": lin.get("linear_spring.suspension_stiffness_n_per_m"),
                    "std": lin_std.get("linear_spring.suspension_stiffness_n_per_m"),
                    "unit": unit_k,
                },
                "damping": {
                    "value": lin.get("linear_damper.suspension_damping_ns_per_m"),
                    "std": lin_std.get("linear_damper.suspension_damping_ns_per_m"),
                    "unit": f"{self.data.force_unit} s/{self.data.displacement_unit}",
                },
                "moving_mass_kg": {"value": lin["moving_mass_kg"],
                                   "std": lin_std.get("moving_mass_kg")},
                "preload": {"value": lin["preload_n"], "std": lin_std.get("preload_n"),
                            "unit": self.data.force_unit},
            },
            "findings": findings,
            "candidates": [
                {
                    "effects": list(c.effects),
                    "nrmse_validation": c.nrmse_validation,
                    "t": cmp.t,
                    "physical": c.physical,
                }
                for c, cmp in sel.ranking
            ],
            "validation": {"split_time_s": float(self.data.time_s[self.split_index])},
            "band": self._band(),
            "warnings": [],
        }

    def effects_by_weight(self) -> list[str]:
        """The chosen model's effects, the one that alone predicts the held-out data best
        first (for a pair, the effect whose removal would cost the most).

        Returns
        -------
        list of str
        """
        single = {c.effects[0]: c.mse_validation for c, _ in self.selection.ranking
                  if len(c.effects) == 1}
        return sorted(self.selection.chosen.effects, key=lambda e: single.get(e, np.inf))

    def _band(self) -> dict:
        band = self.data.band
        out = band.to_dict() if band is not None else {"filter": "none", "cutoff_hz": None,
                                                       "reason": "samples given as is"}
        out["inertia_kept"] = self.inertia_kept
        out["inertia"] = (
            "the moving mass is in the model (inertia shows in the force)"
            if self.inertia_kept
            else "no inertia in the force at these frequencies: the moving mass is fixed at 0"
        )
        return out

    def _region(self, cand: CandidateFit) -> dict | None:
        base = self.selection.baseline
        val = self.data.part(self.split_index, self.data.n)
        dmap = departure_map(
            val.displacement, val.velocity, base.residual_validation - cand.residual_validation
        )
        reg = dmap.region()
        return None if reg is None else {"displacement": reg["r_m"], "velocity": reg["rdot_mps"]}


def _rig_explanation(effect: str, p: dict[str, float], data: RigData,
                     shape: dict[str, float] | None = None) -> str:
    fu, du = data.force_unit, data.displacement_unit
    if effect == "coulomb_friction":
        return (
            f"dry friction of about {p['friction_force_n']:.3g} {fu}: a force step at every "
            "reversal of motion"
        )
    if effect == "cubic_stiffness":
        return (
            f"progressive spring: stiffness rises with deflection (cubic term "
            f"{p['cubic_stiffness_n_per_m3']:.3g} {fu}/{du}^3)"
        )
    if effect == "bump_stop":
        return (
            f"bump stop engaging {p['gap_m']:.3g} {du} into compression with "
            f"{p['stiffness_n_per_m']:.3g} {fu}/{du}"
        )
    if effect == "asymmetric_damping":
        return (
            f"damping differs by direction: {p['compression_damping_ns_per_m']:.4g} in "
            f"compression, {p['rebound_damping_ns_per_m']:.4g} in rebound ({fu} s/{du})"
        )
    try:
        return get_effect(effect)().explain({**p, **(shape or {})})
    except (KeyError, ValueError, FieldDiagError):  # pragma: no cover - unknown name
        return effect


def _unexplained_structure(
    base: CandidateFit, chosen: CandidateFit, fit: RigData, val: RigData
) -> dict | None:
    """Is there force left that depends on (r, rdot) but no candidate explains?

    A binned map of the chosen model's fit residual over (r, rdot) is applied to the
    held-out part; if it predicts the held-out residual significantly, structure is left.
    """
    model, z = chosen.extra["model"], chosen.extra["z"]
    res_fit, _ = _residual_and_jac(model, z, fit, state_jacobian=False)
    dmap = departure_map(fit.displacement, fit.velocity, res_fit, bins=12)
    i = np.clip(np.searchsorted(dmap.r_edges_m, val.displacement) - 1, 0, dmap.mean.shape[0] - 1)
    j = np.clip(np.searchsorted(dmap.rdot_edges_mps, val.velocity) - 1, 0, dmap.mean.shape[1] - 1)
    pred = np.nan_to_num(dmap.mean[i, j])
    res_val = chosen.residual_validation
    from fielddiag.diagnose.selection import paired_block_t

    t = paired_block_t(res_val, res_val - pred)
    gain = 1.0 - np.mean((res_val - pred) ** 2) / np.mean(res_val**2)
    if t < 4.0 or gain < 0.1:
        return None
    reg = dmap.region()
    return {
        "effect": "unexplained",
        "confidence": float(min(1.0, gain)),
        "parameters": {},
        "where": {
            "region": None
            if reg is None
            else {"displacement": reg["r_m"], "velocity": reg["rdot_mps"]}
        },
        "explanation": (
            f"{100 * gain:.0f} % of the remaining force error depends on displacement and "
            "velocity in a way no effect in the library describes; look at the departure map"
        ),
    }


@single_threaded_blas
def diagnose_rig(
    data: RigData,
    *,
    effects: Sequence[str] = RIG_EFFECTS,
    holdout_fraction: float = 0.3,
    max_pair: bool = True,
) -> RigDiagnosis:
    """Fit the linear rig model and every candidate (single effects and pairs), and choose.

    Every model is fitted on the first part of the record and scored on the rest, with
    the rule of :mod:`fielddiag.diagnose.selection` (and, where the linear model stands,
    once more on whitened held-out residuals). The moving mass is fitted only where the
    data show inertia (:func:`inertia_shown`).

    Parameters
    ----------
    data : RigData
        The record, in its band (:func:`rig_data_from_displacement`,
        :func:`rig_data_from_acceleration`).
    effects : sequence of str
        Candidate effects (library names).
    holdout_fraction : float
        Fraction of the record, at its end, held out for validation.
    max_pair : bool
        Also try every pair of effects.

    Returns
    -------
    RigDiagnosis

    Raises
    ------
    InsufficientDataError
        When the recording is too short or the motion too small to say anything.
    """
    if data.n < 500:
        raise InsufficientDataError(
            f"the rig recording has {data.n} samples; record at least 500 (several cycles)"
        )
    if np.std(data.velocity) <= 0 or np.std(data.force) <= 0:
        raise InsufficientDataError("the rig did not move or the force is constant")
    split = int(round(data.n * (1 - holdout_fraction)))
    fit, val = data.part(0, split), data.part(split, data.n)
    baseline = _candidate((), fit, val, {})
    fit_mass = inertia_shown(baseline, fit)
    if not fit_mass:
        baseline = _candidate((), fit, val, {}, fit_mass=False)
    sel = _select_among(effects, baseline, fit, val, fit_mass, max_pair)
    if not fit_mass and sel.chosen is not baseline and _inertia_in(sel.chosen, fit, val):
        # the linear model's mass was not trusted (it soaks up unmodelled force such as a
        # hysteresis), but the chosen model, which explains that force, shows inertia:
        # everything again with the mass in the model
        fit_mass = True
        baseline = _candidate((), fit, val, {})
        sel = _select_among(effects, baseline, fit, val, fit_mass, max_pair)
    unexplained = _unexplained_structure(baseline, sel.chosen, fit, val)
    return RigDiagnosis(sel, data, split, unexplained, fit_mass)


def _select_among(effects: Sequence[str], baseline: CandidateFit, fit: RigData, val: RigData,
                  fit_mass: bool, max_pair: bool) -> Selection:
    """Fit every single effect and pair, and choose (:func:`_select_whitened`).

    A pair with an effect that has internal states (a hysteresis, the costly fits) is tried
    only where both its effects alone predict the held-out data significantly better than
    the linear model."""
    linear = {k: v for k, v in baseline.values.items()}
    linear["f0"], linear["m"] = baseline.values["preload_n"], baseline.values["moving_mass_kg"]
    singles: dict[str, CandidateFit] = {}
    for e in sorted(effects, key=lambda e: e in REFINES):
        base = REFINES.get(e)
        if base is None or base not in effects:
            singles[e] = _candidate((e,), fit, val, linear, fit_mass)
            continue
        if not _helps(baseline, singles[base]):
            continue
        # started from the refined effect's fit: its friction and pre-yield travel, a
        # release over twice that travel
        start = dict(linear)
        for k, v in singles[base].values.items():
            if k.startswith(base + "."):
                start[e + k[len(base):]] = v
        if f"{e}.yield_displacement_m" in start:
            start[f"{e}.release_displacement_m"] = 2.0 * start[f"{e}.yield_displacement_m"]
        singles[e] = _candidate((e,), fit, val, start, fit_mass)
    effects = [e for e in effects if e in singles]
    candidates = list(singles.values())
    if max_pair:
        helps = {e: _helps(baseline, c) for e, c in singles.items()}
        for pair in itertools.combinations(effects, 2):
            n_stateful = sum(bool(get_effect(e).n_states) for e in pair)
            if n_stateful and not all(helps[e] for e in pair):
                continue
            if n_stateful > 1:
                # two hysteresis models of the same loop (each has its friction state)
                continue
            # started from the two single fits (a hysteresis' yield travel then needs no
            # screening)
            start = dict(linear)
            for e in pair:
                start.update({k: v for k, v in singles[e].values.items()
                              if k.startswith(e + ".")})
            candidates.append(_candidate(pair, fit, val, start, fit_mass))
    return _other_hysteresis(_select_whitened(baseline, candidates, fit))


def _helps(baseline: CandidateFit, cand: CandidateFit) -> bool:
    """Does ``cand`` predict the held-out data significantly better than the linear model?"""
    return compare(baseline, cand).beats(cand.n_params - baseline.n_params)


def _other_hysteresis(sel: Selection) -> Selection:
    """The chosen model with its hysteresis swapped for another hysteresis model, where that
    predicts the held-out data significantly better by a margin worth its extra parameters.

    The selection ranks single effects first and then only pairs that contain the chosen
    single one; two hysteresis models (Dahl friction, the build-up hysteresis) are
    alternatives for the same loop, so the pair with the other one is compared here by the
    same held-out rule (:meth:`~fielddiag.diagnose.selection.Comparison.beats`)."""
    chosen = sel.chosen
    if chosen is sel.baseline:
        return sel
    stateful = {e for e in chosen.effects if get_effect(e).n_states}
    if len(stateful) != 1:
        return sel
    rest = set(chosen.effects) - stateful
    best = chosen
    for c, _ in sel.ranking:
        swapped = set(c.effects) - rest
        if (c is chosen or not c.physical or len(c.effects) != len(chosen.effects)
                or not rest <= set(c.effects) or len(swapped) != 1
                or swapped == stateful or not get_effect(swapped.pop()).n_states):
            continue
        if compare(best, c).beats(c.n_params - best.n_params):
            best = c
    if best is chosen:
        return sel
    return Selection(best, sel.baseline, compare(sel.baseline, best), sel.ranking,
                     sel.rejected_unphysical)


def _inertia_in(chosen: CandidateFit, fit: RigData, val: RigData) -> bool:
    """Does the chosen model, refitted with the moving mass free, show inertia (mass at
    least 3 standard deviations above zero, its force at least :data:`MIN_INERTIA_SHARE`
    of the force's spread)?"""
    linear = dict(chosen.values)
    linear["f0"], linear["m"] = chosen.values["preload_n"], chosen.values["moving_mass_kg"]
    c = _candidate(chosen.effects, fit, val, linear, True)
    m, sd = c.values["moving_mass_kg"], c.std.get("moving_mass_kg", np.inf)
    share = m * float(np.std(fit.acceleration)) / max(float(np.std(fit.force)), 1e-300)
    return bool(m > 3.0 * sd and share >= MIN_INERTIA_SHARE)


#: Order of the autoregressive whitening filter of the held-out comparison.
WHITENING_ORDER = 12


def whitening_filter(residual: np.ndarray, order: int = WHITENING_ORDER) -> np.ndarray:
    """Prediction-error filter ``[1, -a1, ..., -ap]`` of an autoregressive model of a
    residual (Yule-Walker), which turns it into nearly white noise.

    Parameters
    ----------
    residual : numpy.ndarray
        The linear model's residual on the fitted part.
    order : int
        Autoregressive order.

    Returns
    -------
    numpy.ndarray
        FIR coefficients (``[1.0]`` when the record is too short or the residual zero).
    """
    from scipy.linalg import solve_toeplitz

    r = np.asarray(residual, float) - float(np.mean(residual))
    if r.size < 20 * order or not np.any(r):
        return np.array([1.0])
    acf = np.array([r[: r.size - k] @ r[k:] for k in range(order + 1)]) / r.size
    try:
        a = solve_toeplitz(acf[:-1], acf[1:])
    except np.linalg.LinAlgError:
        return np.array([1.0])
    return np.concatenate(([1.0], -a)) if np.all(np.isfinite(a)) else np.array([1.0])


def _select_whitened(baseline: CandidateFit, candidates: list[CandidateFit], fit: RigData
                     ) -> Selection:
    """:func:`select_model` on the plain held-out residuals; where the linear model stands
    there, once more on residuals whitened by one filter (from the linear model's residual
    on the fitted part), then the plain residuals put back.

    Sensor noise reaches the force residual coloured (displacement noise through ``m a``
    grows as ``w^2``), so a few noisy frequencies can dominate the block test and hide a
    weak effect; whitening, one linear filter for every candidate, weighs all frequencies
    by their noise. Where the residual is model error rather than noise (a real damper's
    hysteresis) whitening weighs the wrong thing, hence the plain test first."""
    from scipy.signal import lfilter

    plain_sel = select_model(baseline, candidates, simplest_alike=False)
    if plain_sel.chosen is not baseline:
        return plain_sel
    res_fit, _ = _residual_and_jac(baseline.extra["model"], baseline.extra["z"], fit)
    w = whitening_filter(res_fit)
    if w.size == 1:
        return plain_sel
    plain = {id(c): c.residual_validation for c in (baseline, *candidates)}
    for c in (baseline, *candidates):
        c.residual_validation = lfilter(w, [1.0], plain[id(c)])[w.size:]
    try:
        white_sel = select_model(baseline, candidates, simplest_alike=False)
    finally:
        for c in (baseline, *candidates):
            c.residual_validation = plain[id(c)]
    return white_sel if white_sel.chosen is not baseline else plain_sel


def inertia_shown(baseline: CandidateFit, fit: RigData) -> bool:
    """Do the data show the moving mass? Its estimate (linear model with mass) must be
    at least 3 standard deviations above zero and its force ``m a`` at least
    :data:`MIN_INERTIA_SHARE` of the force's spread; and the frequency response must
    show it: a resonance, or ``Re(F/X)`` falling as ``k - m w^2`` with a mass within a
    factor 2 of the time-domain one.

    Parameters
    ----------
    baseline : CandidateFit
        The linear model fitted with the mass free.
    fit : RigData
        The fitted samples.

    Returns
    -------
    bool
    """
    m = baseline.values["moving_mass_kg"]
    sd = baseline.std.get("moving_mass_kg", np.inf)
    share = m * float(np.std(fit.acceleration)) / max(float(np.std(fit.force)), 1e-300)
    if not (m > 3.0 * sd and share >= MIN_INERTIA_SHARE):
        return False
    band = fit.band
    if band is None or band.resonance_hz is not None:
        return True
    # without a resonance, the frequency response must show the same mass: Re(F/X)
    # falling as k - m w^2 (a mass that only soaks up unmodelled force, such as an MR
    # damper's hysteresis on a sinusoidal stroke, does not)
    return band.frf_mass is not None and 0.5 <= band.frf_mass / m <= 2.0


def rig_data_from_session(reader) -> RigData:
    """Rig samples from a session with a ``force`` channel and a ``displacement`` (or
    ``acceleration``) channel, on its time base.

    Raises
    ------
    ChannelNotFoundError
        Without a force channel, or with neither displacement nor acceleration.
    """
    from fielddiag.errors import ChannelNotFoundError

    force_spec = reader.channel_for_role("force")
    t = reader.time_s()
    force = reader.read(force_spec.name)
    fs = reader.sample_rate_hz
    if reader.channels_for_role("displacement"):
        spec = reader.channel_for_role("displacement")
        return rig_data_from_displacement(
            t,
            force,
            reader.read(spec.name),
            fs,
            force_unit=force_spec.unit or "N",
            displacement_unit=spec.unit or "m",
        )
    if reader.channels_for_role("acceleration"):
        spec = reader.channel_for_role("acceleration")
        return rig_data_from_acceleration(
            t, force, reader.read(spec.name), fs, force_unit=force_spec.unit or "N"
        )
    raise ChannelNotFoundError(
        f"{reader.path.name} has a force channel but no displacement or acceleration channel; "
        "import the rig's motion with --role displacement=COL (or --role acceleration=COL)"
    )
