"""Grey-box fit of the body equation: simulation, sensitivity equations, bounded LM.

Model (Serban & Freeman's time-domain fit, seed 000). The body of one car corner, driven
by the measured wheel motion ``x1(t), v1(t)``::

    (M2 + dM) a2 = F(r, rdot, x2; theta) - dM g,      r = x2 - x1

with ``F`` a :class:`~fielddiag.identify.terms.ForceModel` (linear spring, damper,
coupling, effects) and positions measured from the static equilibrium of the car without
added mass (the convention of :mod:`fielddiag.sim`). The simulation starts from the static
equilibrium ``F(x2 - x1(0), 0, x2) = dM g`` plus a fitted initial offset and velocity of the
body (two nuisance parameters per session), and is integrated by fixed-step RK4 at the
sample rate (or a sub-multiple) with the wheel input interpolated by cubic Hermite
polynomials through the samples of ``x1`` and ``v1``.

Jacobian: the sensitivity equations ``d/dt (dx2/dtheta) = ...`` are integrated with the
same RK4 steps as the state (direct differentiation), which makes them the exact
derivative of the discrete simulation; the initial sensitivities come from differentiating
the static equilibrium (Serban & Freeman eq. 18). State and sensitivities are integrated in
one numba-compiled loop that calls the model's assembled force kernel.

Fit: Levenberg-Marquardt with bounds on the body-acceleration residuals of one or several
sessions, each compared in the same band (zero-phase Butterworth on simulated and measured
acceleration alike; the measured one is already limited by the same band window as the
integrated wheel motion). Parameters are fitted per unit sprung mass (``theta / M2``) and,
when the sessions carry at least two different added masses, with the inverse sprung mass
``1 / M2`` as one more parameter (the acceleration is nearly linear in it); the absolute
values ``M2 * theta`` and ``M2`` are reported. Every parameter is normalised by its start
value so that the normal equations are well conditioned. Before the fit proper, short
continuation stages reset the simulated body to the measured (integrated) body state every
0 / 0.2 / 2 s: with short horizons the cost is nearly convex (at 0 s it is the equation
error), so starts several times off converge; the last stage is the plain simulation.

Uncertainty: the covariance is the sandwich ``A^-1 B A^-1`` with ``A = J^T J`` and ``B``
the long-run covariance of the score ``J^T e`` under the residuals' own autocovariance
(flat-top lag window at least ``2 / f_low`` wide, wider where the residual autocorrelation
lasts longer): honest for coloured residuals, where ``s^2 (J^T J)^-1`` is optimistic by
the factor reported as the variance inflation.

Limits: the model is exact for linear terms; effect terms are evaluated on band-limited
motion. What the band removes matters most for dry friction: the relative velocity above
the band's top (7-16 mm/s rms on class B-C roads with a 30 Hz top; below a 0.5 Hz bottom
only 0.5-2 mm/s) dithers the true friction across its zero crossings, so on the
band-limited velocity it switches more gently. With the smoothing velocity held at its
true 10 mm/s the fitted force comes out 7-11 % low; fitted (as
:class:`~fielddiag.identify.terms.CoulombFriction` does) it settles at an effective
15-30 mm/s and the force within a few per cent. Fixed-step RK4 at the sample rate is exact
to ~1e-7 for the linear model; stiff effects (friction with a small smoothing velocity)
want ``substeps`` 2-4.

Validation: the fitted model is run on data not used in the fit (another segment or
another drive; only the two initial-state nuisances are refitted) and the NRMSE
``rms(residual) / rms(measured)`` of the band-limited body acceleration is reported next
to the one on the fit data.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numba import njit
from scipy import linalg, optimize, signal

from fielddiag.blas import single_threaded_blas
from fielddiag.errors import FieldDiagError, InsufficientDataError
from fielddiag.identify.greybox_results import GreyBoxResult, ParameterEstimate, SessionFit
from fielddiag.identify.terms import ForceModel, linear_model, model_force

__all__ = [
    "GRAVITY_MPS2",
    "GreyBoxData",
    "GreyBoxProblem",
    "accel_unit_factor",
    "default_band_hz",
    "fit_greybox",
    "hac_covariance",
    "levenberg_marquardt",
    "simulate_body",
    "validate_greybox",
]

#: Standard gravity [m/s^2] (the same value as fielddiag.sim and fielddiag.dsp).
GRAVITY_MPS2 = 9.80665
#: Scale of the initial-state nuisances in the fit: 1 mm, 1 cm/s.
_NUISANCE_SCALE = np.array([1e-3, 1e-2])


# ---------------------------------------------------------------------------------------
# Data
# ---------------------------------------------------------------------------------------


@dataclass
class GreyBoxData:
    """One stretch of recording ready for the fit.

    Attributes
    ----------
    sample_rate_hz : float
        Uniform sample rate [Hz].
    wheel_disp_m, wheel_vel_mps : ndarray
        Wheel motion (input of the body model), valid in ``band_hz``.
    body_accel_mps2 : ndarray
        Measured body acceleration without g, limited to the same band as the wheel motion.
    added_mass_kg : float
        Mass added on the body during this recording.
    name : str
        Label for reports (file name, segment).
    body_disp_m, body_vel_mps : ndarray or None
        Integrated body motion (for equation-error start values), if available.
    band_hz : (float, float) or None
        Band in which the signals are valid and the residual is compared; None for
        full-band data (simulator truth).
    start_s : float
        Time of the first sample in the recording.
    """

    sample_rate_hz: float
    wheel_disp_m: np.ndarray
    wheel_vel_mps: np.ndarray
    body_accel_mps2: np.ndarray
    added_mass_kg: float = 0.0
    name: str = ""
    body_disp_m: np.ndarray | None = None
    body_vel_mps: np.ndarray | None = None
    band_hz: tuple[float, float] | None = None
    start_s: float = 0.0

    def __post_init__(self) -> None:
        n = np.asarray(self.body_accel_mps2).size
        for attr in ("wheel_disp_m", "wheel_vel_mps", "body_accel_mps2", "body_disp_m",
                     "body_vel_mps"):
            v = getattr(self, attr)
            if v is None:
                continue
            v = np.ascontiguousarray(v, dtype=float).reshape(-1)
            if v.size != n:
                raise FieldDiagError(f"GreyBoxData: {attr} has {v.size} samples, body "
                                     f"acceleration {n}; give equal-length arrays")
            if not np.all(np.isfinite(v)):
                raise FieldDiagError(f"GreyBoxData {self.name!r}: {attr} holds NaN or inf; "
                                     "cut the segment around gaps or clipped samples")
            setattr(self, attr, v)
        if not (self.sample_rate_hz > 0 and math.isfinite(self.sample_rate_hz)):
            raise FieldDiagError(f"GreyBoxData: sample_rate_hz={self.sample_rate_hz!r} invalid")

    @property
    def n_samples(self) -> int:
        return int(self.body_accel_mps2.size)

    @property
    def duration_s(self) -> float:
        return self.n_samples / self.sample_rate_hz

    def segment(self, start_s: float | None = None, end_s: float | None = None) -> GreyBoxData:
        """The samples with ``start_s <= t < end_s`` (times from this data's first sample)."""
        fs = self.sample_rate_hz
        i0 = 0 if start_s is None else max(0, int(round(start_s * fs)))
        i1 = self.n_samples if end_s is None else min(self.n_samples, int(round(end_s * fs)))
        if i1 - i0 < 2:
            raise InsufficientDataError(f"segment {start_s}-{end_s} s of {self.name!r} holds "
                                        f"fewer than 2 samples; choose a longer segment")

        def cut(a: np.ndarray | None) -> np.ndarray | None:
            return None if a is None else a[i0:i1].copy()

        return replace(self, wheel_disp_m=cut(self.wheel_disp_m),
                       wheel_vel_mps=cut(self.wheel_vel_mps),
                       body_accel_mps2=cut(self.body_accel_mps2),
                       body_disp_m=cut(self.body_disp_m), body_vel_mps=cut(self.body_vel_mps),
                       start_s=self.start_s + i0 / fs,
                       name=f"{self.name}[{(self.start_s + i0 / fs):.1f}-"
                            f"{(self.start_s + i1 / fs):.1f} s]")

    def split(self, fit_fraction: float = 0.75) -> tuple[GreyBoxData, GreyBoxData]:
        """(first ``fit_fraction`` of the record, the rest) for fit and validation."""
        if not 0.0 < fit_fraction < 1.0:
            raise FieldDiagError(f"fit_fraction={fit_fraction} must be in (0, 1)")
        cut = self.duration_s * fit_fraction
        return self.segment(None, cut), self.segment(cut, None)

    # ------------------------------------------------------------------ constructors
    @classmethod
    def from_accelerations(
        cls,
        wheel_accel_mps2: np.ndarray,
        body_accel_mps2: np.ndarray,
        sample_rate_hz: float,
        *,
        band_hz: tuple[float, float] | None = None,
        added_mass_kg: float = 0.0,
        name: str = "",
        start_s: float = 0.0,
    ) -> GreyBoxData:
        """Integrate two accelerometer readings (g, bias and drift included) into fit data.

        Both channels go through the same band-limited frequency-domain integration
        (:func:`fielddiag.dsp.integrate_pair`), so the measured body acceleration is limited
        by the same filter as the wheel motion that drives the model.

        Parameters
        ----------
        band_hz : (float, float) or None
            Valid band; None chooses it with :func:`default_band_hz`.
        """
        from fielddiag import dsp

        wheel = np.asarray(wheel_accel_mps2, float)
        body = np.asarray(body_accel_mps2, float)
        if wheel.size != body.size:
            raise FieldDiagError("wheel and body readings must have the same number of samples")
        if band_hz is None:
            band_hz = default_band_hz(sample_rate_hz, wheel.size)
        min_n = int(4.0 * sample_rate_hz / band_hz[0])
        if wheel.size < min_n:
            raise InsufficientDataError(
                f"{name or 'recording'}: {wheel.size / sample_rate_hz:.1f} s is too short for "
                f"a fit down to {band_hz[0]:g} Hz; record at least {min_n / sample_rate_hz:.0f} s"
            )
        if not (np.all(np.isfinite(wheel)) and np.all(np.isfinite(body))):
            raise FieldDiagError(f"{name or 'recording'}: readings hold NaN or inf; cut them out")
        try:
            w, b = dsp.integrate_pair(wheel, body, sample_rate_hz, band_hz)
        except ValueError as exc:
            raise FieldDiagError(f"cannot integrate {name or 'recording'}: {exc}") from None
        return cls(sample_rate_hz=w.sample_rate_hz, wheel_disp_m=w.displacement_m,
                   wheel_vel_mps=w.velocity_mps, body_accel_mps2=b.acceleration_mps2,
                   added_mass_kg=float(added_mass_kg), name=name, body_disp_m=b.displacement_m,
                   body_vel_mps=b.velocity_mps, band_hz=(float(band_hz[0]), float(band_hz[1])),
                   start_s=start_s)

    @classmethod
    def from_drive(cls, drive: Any, *, truth: bool = False,
                   band_hz: tuple[float, float] | None = None, name: str = "") -> GreyBoxData:
        """Fit data from a :class:`fielddiag.sim.SimulatedDrive`.

        Parameters
        ----------
        truth : bool
            True: the simulator's true wheel motion and body acceleration, full band
            ("perfect data"). False: the accelerometer readings, integrated like a recording.
        """
        name = name or f"sim seed {drive.seed}"
        if truth:
            return cls(sample_rate_hz=drive.sample_rate_hz, wheel_disp_m=drive.wheel_disp_m,
                       wheel_vel_mps=drive.wheel_vel_mps,
                       body_accel_mps2=drive.body_acc_true_mps2,
                       added_mass_kg=drive.added_mass_kg, name=name,
                       body_disp_m=drive.body_disp_m, body_vel_mps=drive.body_vel_mps)
        return cls.from_accelerations(drive.wheel_accel_mps2, drive.body_accel_mps2,
                                      drive.sample_rate_hz, band_hz=band_hz,
                                      added_mass_kg=drive.added_mass_kg, name=name)

    @classmethod
    def from_session(cls, path: str | os.PathLike, *, start_s: float | None = None,
                     end_s: float | None = None, band_hz: tuple[float, float] | None = None,
                     added_mass_kg: float | None = None) -> GreyBoxData:
        """Fit data from a session file (channels with roles ``wheel`` and ``body``).

        Parameters
        ----------
        added_mass_kg : float or None
            Overrides the session's ``added_mass_kg`` attribute.
        """
        from fielddiag.session import SessionReader

        with SessionReader(path) as s:
            if s.time_base != "uniform":
                t = s.time_s(start_s, end_s)
                if t.size > 2:
                    dt = np.diff(t)
                    if np.max(np.abs(dt * s.sample_rate_hz - 1.0)) > 0.5:
                        raise FieldDiagError(
                            f"{s.path.name} has gaps or an irregular time base between "
                            f"{t[0]:.2f} and {t[-1]:.2f} s; fit a segment without gaps "
                            "(--start/--end)")
            wch, bch = s.channel_for_role("wheel"), s.channel_for_role("body")
            wheel = s.read(wch.name, start_s, end_s) * accel_unit_factor(wch.unit, wch.name)
            body = s.read(bch.name, start_s, end_s) * accel_unit_factor(bch.unit, bch.name)
            i0, _ = s.index_range(start_s, end_s)
            t0 = float(s.time_at(i0, i0 + 1)[0]) if wheel.size else 0.0
            dm = s.metadata.added_mass_kg if added_mass_kg is None else added_mass_kg
            fs = s.sample_rate_hz
            name = s.path.name
        return cls.from_accelerations(wheel, body, fs, band_hz=band_hz, added_mass_kg=dm,
                                      name=name, start_s=t0)


#: Acceleration units understood, and their factor to m/s^2.
ACCEL_UNITS = {"m/s2": 1.0, "m/s^2": 1.0, "m/s²": 1.0, "m s-2": 1.0, "mps2": 1.0,
               "g": GRAVITY_MPS2, "mg": 1e-3 * GRAVITY_MPS2}


def accel_unit_factor(unit: str, channel: str = "") -> float:
    """Factor from a channel's acceleration unit to m/s^2 (``g`` -> 9.80665).

    Raises
    ------
    FieldDiagError
        The unit is not an acceleration.
    """
    key = unit.strip()
    if key in ACCEL_UNITS:
        return ACCEL_UNITS[key]
    raise FieldDiagError(
        f"channel {channel!r} is in {unit!r}, not an acceleration; the fit needs "
        f"accelerometers in one of {', '.join(ACCEL_UNITS)} (fix the unit on import)")


def default_band_hz(sample_rate_hz: float, n_samples: int | None = None) -> tuple[float, float]:
    """Band for the fit when none is given: 0.5 Hz (or 8 cycles of the record) to 30 Hz.

    It spans the body bounce (~1-2 Hz) and the wheel hop (~10-15 Hz) of a car corner,
    keeps twice-integrated accelerometer noise and drift out below 0.5 Hz, and stays below
    the anti-alias filter of any DAQ sampling at 100 Hz or more.
    """
    lo = 0.5
    if n_samples:
        lo = max(lo, 8.0 * sample_rate_hz / n_samples)
    hi = min(30.0, 0.3 * sample_rate_hz)
    if hi <= lo * 4:
        raise InsufficientDataError(
            f"a recording at {sample_rate_hz:g} Hz of {n_samples} samples leaves no band for "
            "the fit; record longer and at 100 Hz or more")
    return lo, hi


# ---------------------------------------------------------------------------------------
# Simulation with sensitivities (numba)
# ---------------------------------------------------------------------------------------

_EMPTY = np.zeros(1)


@njit(cache=True, nogil=True)
def _hermite_basis(nsub):  # pragma: no cover - compiled
    """Cubic Hermite weights of x(tau) and x'(tau)*h at tau = q / (2 nsub), q = 0..2 nsub."""
    m = 2 * nsub + 1
    b = np.empty((m, 8))
    for q in range(m):
        t = q / (2.0 * nsub)
        t2 = t * t
        t3 = t2 * t
        b[q, 0] = 2 * t3 - 3 * t2 + 1  # x0
        b[q, 1] = t3 - 2 * t2 + t  # h v0
        b[q, 2] = -2 * t3 + 3 * t2  # x1
        b[q, 3] = t3 - t2  # h v1
        b[q, 4] = 6 * t2 - 6 * t  # derivative weights (divide by h)
        b[q, 5] = 3 * t2 - 4 * t + 1
        b[q, 6] = -6 * t2 + 6 * t
        b[q, 7] = 3 * t2 - 2 * t
    return b


def _stage(x, v, sx, sv, xin, vin, theta, consts, mass, load, dth, out_ksv,
           n_par, sens):  # pragma: no cover - numba template
    """Body acceleration at one stage and, if ``sens``, d/dt of the velocity sensitivities."""
    f, fr, fv, fx = model_force(x - xin, v - vin, x, theta, consts, dth)
    a = (f - load) / mass
    if sens:
        ax = (fr + fx) / mass
        av = fv / mass
        q = sx.shape[0]
        for j in range(q):
            out_ksv[j] = ax * sx[j] + av * sv[j]
        for j in range(n_par):
            out_ksv[j] += dth[j] / mass
        out_ksv[n_par] -= a / mass
    return a


def _simulate(x1, v1, h, nsub, theta, consts, mass, load, dx0, dv0, sens,
              reset_every, x2r, v2r, reset_static):  # pragma: no cover - numba template
    """RK4 of the body driven by (x1, v1), with sensitivities if ``sens``.

    With ``reset_every`` > 0 the body state is reset to the measured one (``x2r``, ``v2r``;
    plus the static deflection if ``reset_static``) every ``reset_every`` samples: short
    simulation horizons for the continuation stages of the fit.

    Returns a2 (n,) and J (n, P + 3): d a2 / d(theta, mass, dx0, dv0).
    """
    n = x1.shape[0]
    p = theta.shape[0]
    q = p + 3
    a_out = np.empty(n)
    jac = np.zeros((n if sens else 1, q))
    dth = np.zeros(max(p, 1))
    # static equilibrium F(x - x1[0], 0, x) = load, damped Newton
    x = x1[0]
    dg = 0.0
    for _ in range(200):
        f, fr, fv, fx = model_force(x - x1[0], 0.0, x, theta, consts, dth)
        dg = fr + fx
        if dg == 0.0:
            break
        step = (f - load) / dg
        if step > 0.05:
            step = 0.05
        elif step < -0.05:
            step = -0.05
        x -= step
        if abs(step) < 1e-14 * (1.0 + abs(x)):
            break
    f, fr, fv, fx = model_force(x - x1[0], 0.0, x, theta, consts, dth)
    dg = fr + fx
    sx = np.zeros(q)
    sv = np.zeros(q)
    if sens and dg != 0.0:
        for j in range(p):
            sx[j] = -dth[j] / dg
    sx[p + 1] = 1.0
    sv[p + 2] = 1.0
    r_static = x - x1[0]
    sx_static = sx.copy()
    sx_static[p + 1] = 0.0
    x += dx0
    v = dv0
    bas = _hermite_basis(nsub)
    hs = h / nsub
    k = np.zeros((4, 2, q))  # stage derivatives of (sx, sv)
    tx = np.zeros(q)
    tv = np.zeros(q)
    xin = np.empty(3)
    vin = np.empty(3)
    for i in range(n):
        if reset_every > 0 and i > 0 and i % reset_every == 0:
            x = x2r[i] + (r_static if reset_static else 0.0)
            v = v2r[i]
            for j in range(q):
                sx[j] = sx_static[j] if reset_static else 0.0
                sv[j] = 0.0
        # output at the knot; it is also stage 1 of the first sub-step
        a1 = _stage(x, v, sx, sv, x1[i], v1[i], theta, consts, mass, load, dth,
                    k[0, 1], p, sens)
        a_out[i] = a1
        if sens:
            for j in range(q):
                jac[i, j] = k[0, 1, j]
            # k[0,1] holds d(sv)/dt, which equals d a2 / d params at the knot
        if i == n - 1:
            break
        x0k, x1k = x1[i], x1[i + 1]
        hv0, hv1 = h * v1[i], h * v1[i + 1]
        for s in range(nsub):
            for m in range(3):
                b = bas[2 * s + m]
                xin[m] = b[0] * x0k + b[1] * hv0 + b[2] * x1k + b[3] * hv1
                vin[m] = (b[4] * x0k + b[5] * hv0 + b[6] * x1k + b[7] * hv1) / h
            if s > 0:
                a1 = _stage(x, v, sx, sv, xin[0], vin[0], theta, consts, mass, load,
                            dth, k[0, 1], p, sens)
            kx1, kv1 = v, a1
            if sens:
                for j in range(q):
                    k[0, 0, j] = sv[j]
                    tx[j] = sx[j] + 0.5 * hs * k[0, 0, j]
                    tv[j] = sv[j] + 0.5 * hs * k[0, 1, j]
            xs, vs = x + 0.5 * hs * kx1, v + 0.5 * hs * kv1
            a2 = _stage(xs, vs, tx, tv, xin[1], vin[1], theta, consts, mass, load, dth,
                        k[1, 1], p, sens)
            kx2, kv2 = vs, a2
            if sens:
                for j in range(q):
                    k[1, 0, j] = tv[j]
                    tx[j] = sx[j] + 0.5 * hs * k[1, 0, j]
                    tv[j] = sv[j] + 0.5 * hs * k[1, 1, j]
            xs, vs = x + 0.5 * hs * kx2, v + 0.5 * hs * kv2
            a3 = _stage(xs, vs, tx, tv, xin[1], vin[1], theta, consts, mass, load, dth,
                        k[2, 1], p, sens)
            kx3, kv3 = vs, a3
            if sens:
                for j in range(q):
                    k[2, 0, j] = tv[j]
                    tx[j] = sx[j] + hs * k[2, 0, j]
                    tv[j] = sv[j] + hs * k[2, 1, j]
            xs, vs = x + hs * kx3, v + hs * kv3
            a4 = _stage(xs, vs, tx, tv, xin[2], vin[2], theta, consts, mass, load, dth,
                        k[3, 1], p, sens)
            kx4, kv4 = vs, a4
            x += hs / 6.0 * (kx1 + 2.0 * kx2 + 2.0 * kx3 + kx4)
            v += hs / 6.0 * (kv1 + 2.0 * kv2 + 2.0 * kv3 + kv4)
            if sens:
                for j in range(q):
                    k[3, 0, j] = tv[j]
                    sx[j] += hs / 6.0 * (k[0, 0, j] + 2.0 * k[1, 0, j] + 2.0 * k[2, 0, j]
                                         + k[3, 0, j])
                    sv[j] += hs / 6.0 * (k[0, 1, j] + 2.0 * k[1, 1, j] + 2.0 * k[2, 1, j]
                                         + k[3, 1, j])
    return a_out, jac


def _kernels(model: ForceModel) -> Any:
    """The simulation templates compiled for ``model`` (cached per term combination)."""
    return model.compile(__name__, "_stage", "_simulate")


def simulate_body(
    model: ForceModel,
    theta: Mapping[str, float] | Sequence[float] | np.ndarray,
    wheel_disp_m: np.ndarray,
    wheel_vel_mps: np.ndarray,
    sample_rate_hz: float,
    *,
    mass_kg: float = 1.0,
    added_mass_kg: float = 0.0,
    initial_offset_m: float = 0.0,
    initial_velocity_mps: float = 0.0,
    sensitivities: bool = False,
    substeps: int = 1,
) -> tuple[np.ndarray, np.ndarray | None]:
    """Simulate the body driven by the wheel motion, from static equilibrium.

    Parameters
    ----------
    model : ForceModel
        Force terms.
    theta : mapping or sequence
        Model parameters; absolute with ``mass_kg`` = the sprung mass, or per unit mass
        with ``mass_kg`` = 1 and ``added_mass_kg`` = 0.
    wheel_disp_m, wheel_vel_mps : ndarray
        Wheel motion at the samples.
    sample_rate_hz : float
        Sample rate [Hz].
    mass_kg : float
        Sprung mass M2 (without the added mass).
    added_mass_kg : float
        Added mass dM; its weight ``dM g`` loads the suspension.
    initial_offset_m, initial_velocity_mps : float
        Deviation of the body's initial state from static equilibrium.
    sensitivities : bool
        Also return ``d a2 / d(theta, total mass, initial offset, initial velocity)``.
    substeps : int
        RK4 steps per sample interval.

    Returns
    -------
    a2 : (n,) ndarray
        Body acceleration without g [m/s^2].
    jac : (n, P + 3) ndarray or None
        Sensitivities, if asked for.
    """
    th = model.vector(theta)
    a, j = _kernels(model)._simulate(np.ascontiguousarray(wheel_disp_m, dtype=float),
                     np.ascontiguousarray(wheel_vel_mps, dtype=float), 1.0 / sample_rate_hz,
                     int(substeps), th, model.constant_values(), float(mass_kg + added_mass_kg),
                     float(added_mass_kg * GRAVITY_MPS2), float(initial_offset_m),
                     float(initial_velocity_mps), bool(sensitivities), 0, _EMPTY, _EMPTY, False)
    return a, (j if sensitivities else None)


# ---------------------------------------------------------------------------------------
# Levenberg-Marquardt with bounds
# ---------------------------------------------------------------------------------------


@dataclass
class LMOutcome:
    """What :func:`levenberg_marquardt` returns."""

    x: np.ndarray
    residual: np.ndarray
    jacobian: np.ndarray
    cost: float
    iterations: int
    evaluations: int
    converged: bool
    message: str
    cost_history: list[float]
    active: np.ndarray


def levenberg_marquardt(
    fun: Any,
    x0: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    *,
    max_iterations: int = 50,
    xtol: float = 1e-8,
    ftol: float = 1e-8,
    gtol: float = 1e-12,
    callback: Any = None,
) -> LMOutcome:
    """Minimise ``0.5 |r(x)|^2`` within bounds; ``fun(x) -> (r, J)`` gives both at once.

    Stops when the step is below ``xtol`` (relative, in the scaled parameters), when the
    cost falls by less than ``ftol`` (relative) or the undamped Gauss-Newton step could
    not lower it by more, or when the scaled gradient is below ``gtol``.

    Each iteration solves the damped, bounded linear least-squares step
    ``min |J d + r|^2 + lam |D d|^2, lower <= x + d <= upper`` on the small triangular
    factor of ``J`` (QR, then BVLS) with Marquardt's scaling ``D`` (column norms of
    ``J``, never decreasing) and Nielsen's update of ``lam``. Every trial point costs one
    evaluation of ``fun``; its Jacobian is reused when the step is accepted.

    Returns
    -------
    LMOutcome
    """
    x = np.clip(np.asarray(x0, float), lower, upper)
    r, jac = fun(x)
    evaluations = 1
    cost = 0.5 * float(r @ r)
    history = [cost]
    dscale = np.sqrt(np.maximum(np.einsum("ij,ij->j", jac, jac), 1e-300))
    lam = 1e-3
    nu = 2.0
    converged = False
    message = "iteration limit reached"
    it = 0
    n = x.size
    bounded = bool(np.any(np.isfinite(lower)) or np.any(np.isfinite(upper)))
    for it in range(1, max_iterations + 1):
        if not (np.all(np.isfinite(jac)) and np.all(np.isfinite(r))):
            # the simulation blew up at the current point: no step can be computed
            message = "stopped: the model diverged (non-finite residual or Jacobian)"
            it -= 1
            break
        g = jac.T @ r
        free = ~(((x <= lower) & (g > 0)) | ((x >= upper) & (g < 0)))
        if np.max(np.abs(g[free]) / dscale[free], initial=0.0) <= gtol * max(
                math.sqrt(2 * cost), 1e-300):
            converged, message = True, "gradient below tolerance"
            it -= 1
            break
        qmat, rmat = linalg.qr(jac, mode="economic", check_finite=False)
        qtr = qmat.T @ r
        if 0.5 * float(qtr @ qtr) <= ftol * cost:
            # even the undamped Gauss-Newton step could not reduce the cost by more
            converged, message = True, "Gauss-Newton decrement below tolerance"
            it -= 1
            break
        a = np.vstack([rmat, np.diag(math.sqrt(lam) * dscale)])
        b = np.concatenate([-qtr, np.zeros(n)])
        if bounded:
            sol = optimize.lsq_linear(a, b, bounds=(lower - x, upper - x), method="bvls",
                                      lsmr_tol=None, max_iter=200)
            d = sol.x
        else:
            d = linalg.lstsq(a, b, check_finite=False)[0]
        d = np.clip(x + d, lower, upper) - x
        # predicted reduction of the linearised model (the part of r outside the range of
        # J cannot be reduced and is left out of both terms)
        pred = 0.5 * (float(qtr @ qtr) - float(np.sum((rmat @ d + qtr) ** 2)))
        x_new = x + d
        r_new, jac_new = fun(x_new)
        evaluations += 1
        cost_new = 0.5 * float(r_new @ r_new) if np.all(np.isfinite(r_new)) else math.inf
        ared = cost - cost_new
        rho = ared / pred if pred > 0 else -1.0
        step_small = np.linalg.norm(d * dscale) <= xtol * (np.linalg.norm(x * dscale) + xtol)
        if rho > 1e-4:
            x, r, jac, cost = x_new, r_new, jac_new, cost_new
            history.append(cost)
            dscale = np.maximum(dscale, np.sqrt(np.einsum("ij,ij->j", jac, jac)))
            lam *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
            nu = 2.0
            if callback is not None:
                callback(it, x, cost)
            if step_small:
                converged, message = True, "step below tolerance"
                break
            if ared <= ftol * cost_new or cost_new == 0.0:
                converged, message = True, "cost reduction below tolerance"
                break
        else:
            if step_small or (pred <= ftol * cost and abs(ared) <= ftol * cost):
                converged, message = True, "no further reduction possible"
                break
            lam *= nu
            nu *= 2.0
    g = jac.T @ r
    active = ((x <= lower) & (g > 0)) | ((x >= upper) & (g < 0))
    return LMOutcome(x, r, jac, cost, it, evaluations, converged, message, history, active)


# ---------------------------------------------------------------------------------------
# Honest covariance for coloured residuals
# ---------------------------------------------------------------------------------------


def _autocovariance(e: np.ndarray, max_lag: int) -> np.ndarray:
    n = e.size
    nfft = 1 << int(math.ceil(math.log2(2 * n)))
    spec = np.fft.rfft(e - e.mean(), nfft)
    acov = np.fft.irfft(spec * np.conj(spec), nfft)[: max_lag + 1] / n
    return acov


def _lag_window_width(rho: np.ndarray, n: int) -> int:
    """Politis' empirical rule: the smallest lag after which ``K`` consecutive sample
    autocorrelations stay within ``2 sqrt(log10(n) / n)``, ``K = max(5, sqrt(log10 n))``."""
    thresh = 2.0 * math.sqrt(math.log10(max(n, 10)) / n)
    run = max(5, int(math.ceil(math.sqrt(math.log10(max(n, 10))))))
    small = np.abs(rho) < thresh
    lmax = rho.size - 1
    for lag in range(1, lmax - run):
        if small[lag + 1:lag + 1 + run].all():
            return lag
    return lmax


def _hac_meat(jac: np.ndarray, e: np.ndarray, max_lag: int | None = None, min_lag: int = 0
              ) -> tuple[np.ndarray, np.ndarray, int]:
    """(B, white B = s^2 J^T J, lag L) of one contiguous record."""
    n, p = jac.shape
    max_lag = max(4, min(n // 4 if max_lag is None else max_lag, n - 1))
    acov = _autocovariance(e, max_lag)
    if acov[0] <= 0:
        z = np.zeros((p, p))
        return z, z, 0
    lag = min(max(_lag_window_width(acov / acov[0], n), min_lag), max_lag // 2)
    w = np.clip(2.0 - np.arange(2 * lag + 1) / max(lag, 1), 0.0, 1.0)
    g = acov[: 2 * lag + 1] * w
    kernel = np.concatenate([g[:0:-1], g])
    gj = signal.fftconvolve(jac, kernel[:, None], mode="same", axes=0)
    b = jac.T @ gj
    return 0.5 * (b + b.T), acov[0] * (jac.T @ jac), int(lag)


def _psd_clip(b: np.ndarray) -> np.ndarray:
    """A flat-top window can give a slightly indefinite B: clip its eigenvalues at 0."""
    ev, vec = np.linalg.eigh(b)
    return (vec * np.maximum(ev, 0.0)) @ vec.T


def hac_covariance(jacobian: np.ndarray, residual: np.ndarray, *, max_lag: int | None = None,
                   min_lag: int = 0) -> tuple[np.ndarray, dict[str, Any]]:
    """Sandwich covariance of least-squares estimates with autocorrelated residuals.

    ``cov = A^-1 B A^-1``, ``A = J^T J``, ``B = J^T G J`` where ``G`` is the Toeplitz
    matrix of the residual autocovariance tapered by a flat-top lag window (weight 1 up to
    the lag ``L`` where the autocorrelation has died out, falling linearly to 0 at ``2 L``;
    ``L`` by Politis' empirical rule). ``G J`` is computed as a convolution (FFT).

    Parameters
    ----------
    jacobian : (n, p) ndarray
        d residual / d parameters at the solution.
    residual : (n,) ndarray
        Residuals at the solution, in time order (one contiguous record).
    max_lag : int or None
        Upper limit for ``2 L`` (default n // 4).
    min_lag : int
        Lower limit for ``L``: residuals limited to a band ``[f_lo, f_hi]`` stay correlated
        for about ``2 / f_lo`` (weak but long correlations that Politis' rule, which looks
        at one lag at a time, does not see; they matter for slowly varying Jacobians).

    Returns
    -------
    cov : (p, p) ndarray
    info : dict
        ``lag_window_samples`` (L), ``white_covariance`` (``s^2 (J^T J)^-1``, the formula
        that assumes white residuals).
    """
    jac = np.asarray(jacobian, float)
    e = np.asarray(residual, float)
    b, bw, lag = _hac_meat(jac, e, max_lag, min_lag)
    ainv = np.linalg.pinv(jac.T @ jac)
    return ainv @ _psd_clip(b) @ ainv, {"lag_window_samples": lag,
                                         "white_covariance": ainv @ bw @ ainv}


# ---------------------------------------------------------------------------------------
# The problem
# ---------------------------------------------------------------------------------------


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
    ) -> None:
        if not data:
            raise FieldDiagError("give at least one session to fit")
        if model.n_states:
            stateful = [t.name for t in model.terms if t.n_states]
            raise FieldDiagError(
                f"the grey-box fit cannot fit {stateful} yet: effects with an internal state "
                "(hysteresis) are simulated but not fitted; leave them out of the model")
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
        self.evaluations = 0
        #: Simulation horizon [s] of a continuation stage (None: the whole record).
        self.horizon_s: float | None = None
        self._prep = [self._prepare(d) for d in self.data]

    # ------------------------------------------------------------------ data
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
        return _Prepared(d, sos, np.ascontiguousarray(meas[keep]), keep)

    @property
    def n_residuals(self) -> int:
        return sum(pr.measured.size for pr in self._prep)

    # ------------------------------------------------------------------ parameter maps
    def _mass_for_unit(self, d: GreyBoxData) -> tuple[float, float]:
        """(mass, load) of a session in per-unit-mass mode."""
        if d.added_mass_kg and self.body_mass_guess_kg:
            return 1.0, GRAVITY_MPS2 * d.added_mass_kg / (self.body_mass_guess_kg
                                                           + d.added_mass_kg)
        return 1.0, 0.0

    def unpack(self, z: np.ndarray) -> tuple[np.ndarray, float | None, np.ndarray]:
        """Fitted vector -> (per-unit-mass model parameters, M2 or None, nuisances (s, 2))."""
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
        z = [theta_unit[self.free_model]]
        if self.has_mass:
            z.append([1.0 / float(mass)])
        if self.fit_initial_state:
            z.append(np.zeros(2 * len(self.data)) if nuis is None else np.ravel(nuis))
        return np.concatenate([np.asarray(a, float) for a in z])

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        lo = [self.model.lower[self.free_model]]
        hi = [self.model.upper[self.free_model]]
        if self.has_mass:  # fitted as the inverse mass 1/M2 [1/kg] (nearly linear)
            lo.append([1e-9])
            hi.append([1e3])
        if self.fit_initial_state:
            lo.append(np.full(2 * len(self.data), -np.inf))
            hi.append(np.full(2 * len(self.data), np.inf))
        return np.concatenate(lo), np.concatenate(hi)

    # ------------------------------------------------------------------ residuals
    def simulate(self, z: np.ndarray, sens: bool) -> list[tuple[np.ndarray, np.ndarray | None]]:
        """Per session: (filtered, trimmed a2_sim, filtered trimmed d a2 / d z)."""
        theta_u, mass, nuis = self.unpack(z)
        kern = _kernels(self.model)._simulate
        consts = self.model.constant_values()
        out = []
        nf = self.free_model.size
        for s, pr in enumerate(self._prep):
            d = pr.data
            if self.absolute:
                m_tot = mass + d.added_mass_kg
                load = d.added_mass_kg * GRAVITY_MPS2
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
            self.evaluations += 1
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
            out.append((a[pr.keep], None if jz is None else jz[pr.keep]))
        return out

    def residual_and_jacobian(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Stacked residuals (simulated - measured) and their Jacobian wrt ``z``."""
        sims = self.simulate(z, True)
        r = np.concatenate([a - pr.measured for (a, _), pr in zip(sims, self._prep,
                                                                    strict=True)])
        j = np.vstack([jz for _, jz in sims])
        return r, j

    def residual(self, z: np.ndarray) -> np.ndarray:
        """Stacked residuals only (no sensitivities): for finite-difference comparisons."""
        sims = self.simulate(z, False)
        return np.concatenate([a - pr.measured for (a, _), pr in zip(sims, self._prep,
                                                                      strict=True)])

    def session_slices(self) -> list[slice]:
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
                _, _, dp = model.force(r, rd, d.body_disp_m, typical_u)
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


# ---------------------------------------------------------------------------------------
# Fit
# ---------------------------------------------------------------------------------------


def _to_unit(model: ForceModel, values: Mapping[str, float], absolute: bool,
             mass: float | None) -> dict[int, float]:
    out = {}
    for k, v in values.items():
        if k == "body_mass_kg":
            continue
        i = model.index(k)
        out[i] = v / mass if (absolute and model.force_scaled[i] and mass) else float(v)
    return out


@single_threaded_blas
def fit_greybox(
    data: GreyBoxData | Sequence[GreyBoxData],
    model: ForceModel | None = None,
    *,
    initial: Mapping[str, float] | None = None,
    fixed: Mapping[str, float] | None = None,
    absolute: bool | None = None,
    body_mass_kg: float | None = None,
    validation: Sequence[GreyBoxData] = (),
    max_iterations: int = 50,
    xtol: float = 1e-8,
    fit_initial_state: bool = True,
    substeps: int = 1,
    horizons_s: Sequence[float] | None = (0.0, 0.2, 2.0),
    stage_iterations: int = 4,
    stage_xtol: float = 1e-3,
    callback: Any = None,
) -> GreyBoxResult:
    """Fit the model to one or more sessions by Levenberg-Marquardt on sensitivities.

    Parameters
    ----------
    data : GreyBoxData or sequence of them
        Fit data. Two or more different added masses give absolute parameters and the
        sprung mass; otherwise parameters per unit sprung mass.
    model : ForceModel or None
        Default: linear spring + linear damper.
    initial : mapping or None
        Start values by parameter key or name (absolute values plus ``body_mass_kg`` in
        absolute mode, per unit mass otherwise). Missing ones come from an equation-error
        least-squares fit (or typical values).
    fixed : mapping or None
        Parameters held constant (same units as ``initial``).
    absolute : bool or None
        Force or forbid the absolute fit; None decides from the added masses.
    body_mass_kg : float or None
        Sprung-mass guess (see :class:`GreyBoxProblem`).
    validation : sequence of GreyBoxData
        Held-out data (another segment or drive) for the validation NRMSE.
    max_iterations : int
        Levenberg-Marquardt iteration limit.
    xtol : float
        Relative step tolerance on the normalised parameters.
    fit_initial_state : bool
        Fit each session's initial body offset and velocity.
    substeps : int
        RK4 steps per sample interval.
    horizons_s : sequence of float or None
        Continuation: before the fit proper, short fits in which the simulated body is
        reset to the measured (integrated) body state every ``horizon`` seconds, with
        growing horizons (0: every sample, i.e. the equation error). Short horizons make
        the cost nearly convex, so starts far from the answer still converge; the last
        stage is always the plain simulation from static equilibrium. None or () to skip.
    stage_iterations : int
        Iteration limit of each continuation stage.
    stage_xtol : float
        Step tolerance of the continuation stages.
    callback : callable or None
        ``callback(iteration, reported_values_dict, cost)`` after each accepted step of the
        final stage.

    Returns
    -------
    GreyBoxResult

    Raises
    ------
    InsufficientDataError
        Too little data, or an absolute fit without two added masses.
    """
    t_start = time.perf_counter()
    data = [data] if isinstance(data, GreyBoxData) else list(data)
    model = model or linear_model()
    prob = GreyBoxProblem(model, data, absolute=absolute, fixed=fixed,
                          body_mass_kg=body_mass_kg, fit_initial_state=fit_initial_state,
                          substeps=substeps)
    initial = dict(initial or {})
    th0, m0 = prob.equation_error_start()
    if prob.absolute:
        m_init = initial.get("body_mass_kg", prob.fixed_mass or m0 or body_mass_kg or 380.0)
        m_init = float(m_init)
        # equation-error values are per unit mass of the session without added mass
    else:
        m_init = None
    for i, v in _to_unit(model, initial, prob.absolute, m_init).items():
        th0[i] = v
    for i, v in _to_unit(model, fixed or {}, prob.absolute,
                         prob.fixed_mass or m_init).items():
        th0[i] = v
    z0 = prob.pack(th0, m_init)
    lo, hi = prob.bounds()
    z0 = np.clip(z0, lo, hi)
    # normalisation: every fitted quantity relative to its start value
    typ_u = model.vector(per_unit_mass_kg=(m_init or body_mass_kg or 380.0))
    scale = np.abs(z0)
    nominal = np.concatenate([typ_u[prob.free_model],
                              [1.0 / (m_init or 1.0)] if prob.has_mass else [],
                              np.tile(_NUISANCE_SCALE, len(data)) if fit_initial_state else []])
    scale = np.where(scale > 1e-6 * np.abs(nominal), scale, np.abs(nominal))
    scale = np.where(scale > 0, scale, 1.0)
    if fit_initial_state:
        scale[prob.nuis_index:] = np.tile(_NUISANCE_SCALE, len(data))

    def fun(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r, j = prob.residual_and_jacobian(q * scale)
        return r, j * scale

    cb = None
    if callback is not None:
        def cb(it: int, q: np.ndarray, cost: float) -> None:
            th, m, _ = prob.unpack(q * scale)
            callback(it, _reported_values(model, th, m), cost)

    q = z0 / scale
    stages: list[dict[str, Any]] = []
    total_it = total_ev = 0
    if horizons_s is None:
        horizons_s = ()
    can_reset = all(d.body_disp_m is not None and d.body_vel_mps is not None for d in data)
    shortest = min(d.duration_s for d in data)
    for hz in horizons_s if can_reset else ():
        if hz >= 0.5 * shortest:
            break
        prob.horizon_s = float(hz)
        st = levenberg_marquardt(fun, q, lo / scale, hi / scale,
                                 max_iterations=stage_iterations, xtol=stage_xtol,
                                 ftol=stage_xtol)
        q = st.x
        total_it += st.iterations
        total_ev += st.evaluations
        stages.append({"horizon_s": float(hz), "iterations": st.iterations,
                       "cost": float(st.cost)})
    prob.horizon_s = None
    out = levenberg_marquardt(fun, q, lo / scale, hi / scale,
                              max_iterations=max_iterations, xtol=xtol, callback=cb)
    stages.append({"horizon_s": None, "iterations": out.iterations, "cost": float(out.cost)})
    out.iterations += total_it
    out.evaluations += total_ev
    z = out.x * scale
    theta_u, mass, nuis = prob.unpack(z)

    # ---- covariance (sandwich per session, summed), in z units
    jz = out.jacobian / scale  # d r / d z
    bmat = np.zeros((jz.shape[1], jz.shape[1]))
    white = np.zeros_like(bmat)
    lags = []
    for sl, pr in zip(prob.session_slices(), prob._prep, strict=True):
        band = pr.data.band_hz
        min_lag = 0 if band is None else int(round(2.0 * pr.data.sample_rate_hz / band[0]))
        b_s, w_s, lag = _hac_meat(jz[sl], out.residual[sl], min_lag=min_lag)
        bmat += b_s
        white += w_s
        lags.append(lag / pr.data.sample_rate_hz)
    ainv = np.linalg.pinv((jz.T @ jz) * np.outer(scale, scale)) * np.outer(scale, scale)
    cov_z = ainv @ _psd_clip(bmat) @ ainv
    cov_white = ainv @ white @ ainv

    result = _build_result(prob, out, z, theta_u, mass, nuis, cov_z, cov_white, lags)
    result.uncertainty["stages"] = stages
    if validation:
        result.sessions.extend(validate_greybox(result, validation, substeps=substeps))
    result.wall_time_s = time.perf_counter() - t_start
    return result


def _reported_values(model: ForceModel, theta_u: np.ndarray, mass: float | None
                     ) -> dict[str, float]:
    vals = {}
    for i, key in enumerate(model.param_keys):
        vals[key] = float(theta_u[i] * mass if (mass and model.force_scaled[i]) else theta_u[i])
    if mass is not None:
        vals["body_mass_kg"] = float(mass)
    return vals


def _build_result(prob: GreyBoxProblem, out: LMOutcome, z: np.ndarray, theta_u: np.ndarray,
                  mass: float | None, nuis: np.ndarray, cov_z: np.ndarray,
                  cov_white: np.ndarray, lags: list[float]) -> GreyBoxResult:
    model = prob.model
    p = model.n_params
    nf = prob.free_model.size
    # Reported vector y = g(z_model_part): absolute values (theta_u * M) and M, or theta_u.
    # Jacobian T = dy / dz over the fitted non-nuisance entries.
    n_rep = p + (1 if prob.absolute else 0)
    t = np.zeros((n_rep, prob.n_fit))
    y = np.empty(n_rep)
    for i in range(p):
        sc = prob.absolute and model.force_scaled[i]
        y[i] = theta_u[i] * mass if sc else theta_u[i]
        pos = np.flatnonzero(prob.free_model == i)
        if pos.size:
            t[i, pos[0]] = mass if sc else 1.0
            if sc and prob.has_mass:  # y = theta_u / rho, rho = 1/M fitted
                t[i, nf] = -theta_u[i] * mass * mass
    if prob.absolute:
        y[p] = mass
        if prob.has_mass:
            t[p, nf] = -mass * mass
    cov_y = t @ cov_z @ t.T
    cov_yw = t @ cov_white @ t.T
    std = np.sqrt(np.maximum(np.diag(cov_y), 0.0))
    fixed_mask = np.array([i in prob.fixed_values for i in range(p)]
                          + ([prob.fixed_mass is not None] if prob.absolute else []))
    std[fixed_mask] = 0.0
    lo, hi = prob.bounds()
    at_bound_z = (z <= lo) | (z >= hi)
    params: list[ParameterEstimate] = []
    keys, terms = model.param_keys, model.param_terms
    for i, spec in enumerate(model.specs):
        absn = prob.absolute
        name = spec.name if (absn or not spec.scales_with_force) else spec.per_unit_mass_name()
        unit = spec.unit if (absn or not spec.scales_with_force) else spec.per_unit_mass_unit()
        pos = np.flatnonzero(prob.free_model == i)
        params.append(ParameterEstimate(
            name=name, key=keys[i], term=terms[i], unit=unit, value=float(y[i]),
            std=float(std[i]), rel_std_pct=_rel(std[i], y[i]), fixed=bool(fixed_mask[i]),
            at_bound=bool(pos.size and at_bound_z[pos[0]]), label=spec.label))
    if prob.absolute:
        params.append(ParameterEstimate(
            name="body_mass_kg", key="body_mass_kg", term="body", unit="kg", value=float(mass),
            std=float(std[p]), rel_std_pct=_rel(std[p], mass), fixed=bool(fixed_mask[p]),
            at_bound=bool(prob.has_mass and at_bound_z[nf]), label="sprung mass"))
    free_rep = np.flatnonzero(~fixed_mask)
    sub = cov_y[np.ix_(free_rep, free_rep)]
    d = np.sqrt(np.maximum(np.diag(sub), 1e-300))
    corr = sub / np.outer(d, d)
    # per unit mass values and their std (what the on-line estimator sees)
    t_u = np.zeros((p, prob.n_fit))
    for i in range(p):
        pos = np.flatnonzero(prob.free_model == i)
        if pos.size:
            t_u[i, pos[0]] = 1.0
    std_u = np.sqrt(np.maximum(np.diag(t_u @ cov_z @ t_u.T), 0.0))
    inflation = {}
    dw = np.diag(cov_yw)
    for i in free_rep:
        if dw[i] > 0:
            inflation[params[i].name] = float(cov_y[i, i] / dw[i])
    sessions = []
    for s, (sl, pr) in enumerate(zip(prob.session_slices(), prob._prep, strict=True)):
        res = out.residual[sl]
        sessions.append(SessionFit(
            name=pr.data.name, role="fit", added_mass_kg=float(pr.data.added_mass_kg),
            samples=int(pr.data.n_samples), duration_s=float(pr.data.duration_s),
            sample_rate_hz=float(pr.data.sample_rate_hz), nrmse=_nrmse(res, pr.measured),
            residual_rms_mps2=float(np.sqrt(np.mean(res**2))),
            initial_offset_m=float(nuis[s, 0]), initial_velocity_mps=float(nuis[s, 1])))
    bands = [pr.data.band_hz for pr in prob._prep]
    band = None if bands[0] is None else [float(bands[0][0]), float(bands[0][1])]
    return GreyBoxResult(
        model=model.to_dict(),
        mode="absolute" if prob.absolute else "per_unit_mass",
        parameters=params,
        correlation=corr.tolist(),
        correlation_names=[params[i].name for i in free_rep],
        per_unit_mass={k: float(v) for k, v in zip(keys, theta_u, strict=True)},
        per_unit_mass_std={k: float(v) for k, v in zip(keys, std_u, strict=True)},
        sessions=sessions,
        iterations=out.iterations,
        model_evaluations=out.evaluations,
        converged=out.converged,
        message=out.message,
        cost_history=[float(c) for c in out.cost_history],
        band_hz=band,
        uncertainty={
            "method": "sandwich A^-1 B A^-1 with the residual autocovariance under a flat-top "
                      "lag window (HAC), per session",
            "lag_window_s": lags,
            "variance_inflation_over_white": inflation,
            "residuals": int(out.residual.size),
        },
    )


def _rel(std: float, value: float) -> float:
    return float(100.0 * std / abs(value)) if value != 0 else math.inf


def _nrmse(residual: np.ndarray, measured: np.ndarray) -> float:
    m = signal.detrend(measured, type="linear")
    den = float(np.sqrt(np.mean(m * m)))
    return float(np.sqrt(np.mean(residual * residual)) / den) if den > 0 else math.inf


def validate_greybox(result: GreyBoxResult, data: Sequence[GreyBoxData], *,
                     substeps: int = 1) -> list[SessionFit]:
    """NRMSE of a fitted model on data not used in the fit (see :func:`validation_runs`)."""
    return [run[0] for run in validation_runs(result, data, substeps=substeps)]


def validation_runs(result: GreyBoxResult, data: Sequence[GreyBoxData], *,
                    substeps: int = 1
                    ) -> list[tuple[SessionFit, np.ndarray, np.ndarray, np.ndarray]]:
    """NRMSE of a fitted model on data not used in the fit.

    Only each session's initial body offset and velocity are fitted (they are not model
    parameters); the model parameters stay as fitted.

    Parameters
    ----------
    result : GreyBoxResult
        A fit (absolute or per unit mass).
    data : sequence of GreyBoxData
        Held-out segments or drives. In per-unit-mass mode their added mass must equal the
        fit data's.

    Returns
    -------
    list of (SessionFit, measured, residual, time_s)
        One per session, ``role="validation"``, with the band-limited measured body
        acceleration, the residual (measured - simulated) and the recording time of each
        residual sample (edges trimmed by the band filter are left out).
    """
    model = ForceModel.from_dict(result.model)
    theta_u = np.array([result.per_unit_mass[k] for k in model.param_keys])
    absolute = result.mode == "absolute"
    mass = result.body_mass_kg
    fit_dm = {round(s.added_mass_kg, 9) for s in result.fit_sessions()}
    out = []
    for d in data:
        if not absolute and round(d.added_mass_kg, 9) not in fit_dm:
            raise FieldDiagError(
                f"{d.name}: added mass {d.added_mass_kg:g} kg differs from the fit data; a "
                "per-unit-mass fit can only be validated on data with the same mass")
        if absolute:
            # per unit of the session's total mass M + dM, loaded by dM g
            m_tot = mass + d.added_mass_kg
            unit = np.where(model.force_scaled, theta_u * mass / m_tot, theta_u)
            guess = mass
        else:
            unit, guess = theta_u, None
        prob = GreyBoxProblem(model, [d], absolute=False,
                              fixed=dict(zip(model.param_keys, unit, strict=True)),
                              body_mass_kg=guess, substeps=substeps)
        sc = _NUISANCE_SCALE

        def fun(q: np.ndarray, _p: GreyBoxProblem = prob) -> tuple[np.ndarray, np.ndarray]:
            r, j = _p.residual_and_jacobian(q * _NUISANCE_SCALE)
            return r, j * _NUISANCE_SCALE

        lm = levenberg_marquardt(fun, np.zeros(2), np.full(2, -np.inf), np.full(2, np.inf),
                                 max_iterations=20)
        pr = prob._prep[0]
        out.append((SessionFit(
            name=d.name, role="validation", added_mass_kg=float(d.added_mass_kg),
            samples=int(d.n_samples), duration_s=float(d.duration_s),
            sample_rate_hz=float(d.sample_rate_hz), nrmse=_nrmse(lm.residual, pr.measured),
            residual_rms_mps2=float(np.sqrt(np.mean(lm.residual**2))),
            initial_offset_m=float(lm.x[0] * sc[0]), initial_velocity_mps=float(lm.x[1] * sc[1])),
            np.asarray(pr.measured), np.asarray(lm.residual),
            d.start_s + (np.arange(len(lm.residual)) + (pr.keep.start or 0)) / d.sample_rate_hz))
    return out
