"""Boundary-perturbation identification: sprung mass, stiffness and damping from two drives.

Body equation (DESIGN.md): ``M2 a2 = -K2 r - C2 rdot - K3 x2``. With ``T = A2/A1`` and the
mass ``dM`` added in the second session,

    D(w) T = N(w),   N = K2 + j w C2,   D = K2 + K3 - w^2 (M2 + dM) + j w C2.

One session fixes only ratios to the mass; the known ``dM`` fixes the scale. Both
sessions' equations are solved together for ``theta = [M2, K2, C2, K3]`` by two routes:

* **frequency**: maximum likelihood for errors in variables (Pintelon & Schoukens) over
  the Welch lines of the band. Per line and session the cost is
  ``n * E|D Y - N X|^2 / (|D|^2 Ny + |N|^2 Nx)`` with the averaged spectra and the
  white-noise densities ``Nx`` (wheel) and ``Ny`` (body). Its expectation is minimal at the
  true parameters whatever the noise on the *input* (wheel) channel, unlike ordinary
  least squares on the stacked equations or a fit to H1, which are biased towards a
  lower mass.
* **time**: the body is simulated from the measured wheel acceleration over the whole
  record (the model's frequency response applied to the band-limited wheel spectrum), and
  the error against the measured body acceleration, prewhitened by the noise model
  ``1/sqrt(Ny + |T|^2 Nx)``, is minimised sample by sample (prewhitened output error,
  which is again the errors-in-variables likelihood, on the unaveraged record).

Standard deviations come from a delete-a-block jackknife over time blocks of each session:
the spectra (and the noise floors) are recomputed without the block and the fit repeated
(frequency route), or one Gauss-Newton step is taken without the block's samples (time
route). This is honest when the residuals are correlated over lines or samples, where the
least-squares covariance is too small; the least-squares value is kept as a floor, as a
jackknife over few blocks is sometimes low by chance.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import fft as sp_fft
from scipy import optimize

from fielddiag.dsp import BlockCrossSpectra, CrossSpectra, band_window, remove_offset_and_drift
from fielddiag.identify.transmissibility import hv_transmissibility

#: Names of theta = [M2, K2, C2, K3] in SI units.
THETA_NAMES = (
    "sprung_mass_kg",
    "suspension_stiffness_n_per_m",
    "suspension_damping_ns_per_m",
    "coupling_stiffness_n_per_m",
)


def model_transmissibility(theta: Sequence[float], freq_hz: np.ndarray,
                           added_mass_kg: float = 0.0) -> np.ndarray:
    """Linear body/wheel transmissibility ``(K2 + jwC2) / (K2 + K3 - w^2 (M2+dM) + jwC2)``.

    Parameters
    ----------
    theta : sequence of float
        ``[M2 kg, K2 N/m, C2 N s/m, K3 N/m]`` (:data:`THETA_NAMES`).
    freq_hz : ndarray
        Frequencies [Hz].
    added_mass_kg : float
        Mass dM added on the body [kg].

    Returns
    -------
    numpy.ndarray
        Complex T = A2/A1 (dimensionless) at each frequency.

    Examples
    --------
    ::

        t = model_transmissibility([380.0, 24e3, 1.8e3, 0.0], np.linspace(0.5, 20, 200))
        abs(t).max()   # resonance peak of the body on its spring
    """
    m2, k2, c2, k3 = theta
    w = 2 * np.pi * np.asarray(freq_hz, dtype=float)
    return (k2 + 1j * w * c2) / (k2 + k3 - w * w * (m2 + added_mass_kg) + 1j * w * c2)


def natural_frequency_hz(theta: Sequence[float]) -> float:
    """Undamped body frequency ``sqrt((K2 + K3) / M2) / 2 pi`` (wheel held still).

    Parameters
    ----------
    theta : sequence of float
        ``[M2 kg, K2 N/m, C2 N s/m, K3 N/m]``.

    Returns
    -------
    float
        Frequency [Hz]; 0 when K2 + K3 <= 0, NaN when M2 <= 0.
    """
    m2, k2, _, k3 = theta
    return math.sqrt(max(k2 + k3, 0.0) / m2) / (2 * math.pi) if m2 > 0 else float("nan")


def damping_ratio(theta: Sequence[float]) -> float:
    """``C2 / (2 sqrt((K2 + K3) M2))``.

    Parameters
    ----------
    theta : sequence of float
        ``[M2 kg, K2 N/m, C2 N s/m, K3 N/m]``.

    Returns
    -------
    float
        Damping ratio (dimensionless); NaN when K2 + K3 <= 0 or M2 <= 0.
    """
    m2, k2, c2, k3 = theta
    k = k2 + k3
    return c2 / (2 * math.sqrt(k * m2)) if k > 0 and m2 > 0 else float("nan")


DERIVED: dict[str, Callable[[Sequence[float]], float]] = {
    "body_natural_frequency_hz": natural_frequency_hz,
    "damping_ratio": damping_ratio,
}


# ---------------------------------------------------------------------------------------
# Frequency route
# ---------------------------------------------------------------------------------------


@dataclass
class SessionLines:
    """The in-band lines of one session, ready for the frequency-domain fit.

    Parameters
    ----------
    freq_hz : ndarray
        Frequencies of the lines [Hz].
    gxx, gyy : ndarray
        Averaged auto-spectra of the wheel and body accelerations [(m/s^2)^2/Hz].
    gxy : ndarray
        Averaged cross-spectrum wheel -> body [(m/s^2)^2/Hz], complex.
    n_averages : int
        Welch segments averaged.
    noise_x, noise_y : float
        White-noise densities of the wheel and body accelerometers [(m/s^2)^2/Hz].
    added_mass_kg : float
        Mass added on the body in this session [kg].
    """

    freq_hz: np.ndarray
    gxx: np.ndarray
    gyy: np.ndarray
    gxy: np.ndarray
    n_averages: int
    noise_x: float
    noise_y: float
    added_mass_kg: float

    @classmethod
    def from_spectra(cls, spectra: CrossSpectra, band_hz: tuple[float, float], noise_x: float,
                     noise_y: float, added_mass_kg: float) -> SessionLines:
        """The lines of ``spectra`` inside ``band_hz``.

        Parameters
        ----------
        spectra : CrossSpectra
            Averaged wheel (x) and body (y) acceleration spectra of one session.
        band_hz : (float, float)
            Band [Hz], edges included.
        noise_x, noise_y : float
            White-noise densities of the wheel and body accelerometers [(m/s^2)^2/Hz].
        added_mass_kg : float
            Mass added on the body for this session [kg].

        Returns
        -------
        SessionLines
        """
        m = (spectra.freq_hz >= band_hz[0]) & (spectra.freq_hz <= band_hz[1])
        return cls(spectra.freq_hz[m], spectra.gxx[m], spectra.gyy[m], spectra.gxy[m],
                   spectra.n_averages, float(noise_x), float(noise_y), float(added_mass_kg))

    def _cholesky(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        # S = [[gyy, gxy], [conj(gxy), gxx]] = L L^H with L = [[l11, 0], [l21, l22]]
        l11 = np.sqrt(self.gyy)
        l21 = np.conj(self.gxy) / l11
        l22 = np.sqrt(np.maximum(self.gxx - np.abs(l21) ** 2, 1e-30 * self.gxx))
        return l11, l21, l22


@dataclass
class FitOutcome:
    """One least-squares fit: parameters, cost, and the least-squares covariance.

    Parameters
    ----------
    theta : ndarray
        ``[M2 kg, K2 N/m, C2 N s/m, K3 N/m]`` (:data:`THETA_NAMES`); K3 = 0 when not fitted.
    cost : float
        Sum of squared (prewhitened, dimensionless) residuals at the solution.
    n_residuals : int
        Number of residuals.
    include_k3 : bool
        K3 was fitted.
    covariance : ndarray
        ``(4, 4)`` least-squares covariance of ``theta`` (SI units squared).
    converged : bool
        The optimiser reported success.
    message : str
        The optimiser's message.
    """

    theta: np.ndarray
    cost: float
    n_residuals: int
    include_k3: bool
    covariance: np.ndarray
    converged: bool
    message: str = ""


def _theta_full(p: np.ndarray, scale: np.ndarray, include_k3: bool) -> np.ndarray:
    th = p * scale[: p.size]
    return th if include_k3 else np.append(th, 0.0)


def _ml_residuals(theta: np.ndarray, lines: Sequence[SessionLines],
                  chol: Sequence[tuple[np.ndarray, ...]]) -> np.ndarray:
    m2, k2, c2, k3 = theta
    out = []
    for s, (l11, l21, l22) in zip(lines, chol, strict=True):
        w = 2 * np.pi * s.freq_hz
        num = k2 + 1j * w * c2
        den = num + k3 - w * w * (m2 + s.added_mass_kg)
        var = np.abs(den) ** 2 * s.noise_y + np.abs(num) ** 2 * s.noise_x
        sc = np.sqrt(s.n_averages / np.maximum(var, 1e-300))
        u1, u2 = np.conj(den), -np.conj(num)
        r1 = (np.conj(l11) * u1 + np.conj(l21) * u2) * sc
        r2 = np.conj(l22) * u2 * sc
        out += [r1.real, r1.imag, r2.real, r2.imag]
    return np.concatenate(out)


def linear_start(lines: Sequence[SessionLines], include_k3: bool) -> np.ndarray:
    """Starting values: the stacked equations in T = H-v, each line scaled by |w^2 T|.

    Real and imaginary parts of ``-w^2 T M2 + (T - 1) K2 + jw (T - 1) C2 + T K3 = w^2 dM T``
    over the lines of both sessions. Biased (noise in the regressors), so only a start.

    Parameters
    ----------
    lines : sequence of SessionLines
        The in-band lines of both sessions (with their added masses).
    include_k3 : bool
        Fit K3; otherwise it is held at 0.

    Returns
    -------
    numpy.ndarray
        ``[M2 kg, K2 N/m, C2 N s/m, K3 N/m]``.
    """
    rows, rhs = [], []
    for s in lines:
        sp = CrossSpectra(s.freq_hz, s.gxx, s.gyy, s.gxy, s.n_averages, 0.0, 0.0)
        t = hv_transmissibility(sp, s.noise_x, s.noise_y)
        w = 2 * np.pi * s.freq_hz
        a = np.column_stack([-w * w * t, t - 1, 1j * w * (t - 1), t])
        b = w * w * s.added_mass_kg * t
        wt = 1.0 / np.maximum(np.abs(w * w * t), 1e-12)
        rows.append(a * wt[:, None])
        rhs.append(b * wt)
    a = np.concatenate(rows)
    b = np.concatenate(rhs)
    if not include_k3:
        a = a[:, :3]
    aa = np.vstack([a.real, a.imag])
    bb = np.concatenate([b.real, b.imag])
    th = np.linalg.lstsq(aa, bb, rcond=None)[0]
    return th if include_k3 else np.append(th, 0.0)


def _param_scale(theta0: np.ndarray) -> np.ndarray:
    m = max(abs(theta0[0]), 1.0)
    k = max(abs(theta0[1]), 1.0)
    c = max(abs(theta0[2]), 1.0)
    return np.array([m, k, c, k])


def _lsq_cov(jac: np.ndarray, residuals: np.ndarray, scale: np.ndarray, n_par: int,
             *, likelihood: bool = False) -> np.ndarray:
    """Least-squares covariance; ``likelihood``: the cost is a negative log-likelihood, so
    the covariance is the inverse of its Gauss-Newton Hessian ``2 J^T J``."""
    dof = max(residuals.size - n_par, 1)
    s2 = 0.5 if likelihood else float(residuals @ residuals) / dof
    try:
        cov_p = np.linalg.inv(jac.T @ jac) * s2
    except np.linalg.LinAlgError:
        cov_p = np.full((n_par, n_par), np.nan)
    cov = np.full((4, 4), np.nan)
    sc = scale[:n_par]
    cov[:n_par, :n_par] = cov_p * np.outer(sc, sc)
    if n_par == 3:
        cov[3, :] = 0.0
        cov[:, 3] = 0.0
    return cov


def fit_frequency_ml(lines: Sequence[SessionLines], *, include_k3: bool = False,
                     theta0: np.ndarray | None = None) -> FitOutcome:
    """Errors-in-variables maximum-likelihood fit of theta over the lines of all sessions.

    Parameters
    ----------
    lines : sequence of SessionLines
        One per session (at least one with ``added_mass_kg != 0`` to fix the scale).
    include_k3 : bool
        Fit K3, else hold it at 0.
    theta0 : ndarray or None
        Start; default :func:`linear_start`.

    Returns
    -------
    FitOutcome
    """
    chol = [s._cholesky() for s in lines]
    if theta0 is None:
        theta0 = linear_start(lines, include_k3)
        if not np.all(np.isfinite(theta0)) or theta0[0] <= 0 or theta0[1] <= 0:
            theta0 = np.array([300.0, 20e3, 1500.0, 0.0])
    theta0 = np.asarray(theta0, float).copy()
    if not include_k3:
        theta0[3] = 0.0
    scale = _param_scale(theta0)
    n_par = 4 if include_k3 else 3
    p0 = theta0[:n_par] / scale[:n_par]

    def fun(p: np.ndarray) -> np.ndarray:
        return _ml_residuals(_theta_full(p, scale, include_k3), lines, chol)

    res = optimize.least_squares(fun, p0, method="lm", xtol=1e-10, ftol=1e-10, max_nfev=400)
    theta = _theta_full(res.x, scale, include_k3)
    cov = _lsq_cov(res.jac, res.fun, scale, n_par, likelihood=True)
    return FitOutcome(theta, float(res.fun @ res.fun), int(res.fun.size), include_k3, cov,
                      bool(res.success), str(res.message))


@dataclass
class RouteEstimate:
    """Result of one identification route with jackknife standard deviations.

    ``theta`` and ``std`` follow :data:`THETA_NAMES`; ``std`` is the larger of the
    jackknife and the least-squares (asymptotic) standard deviation ``lsq_std``: the
    jackknife is honest when residuals are correlated but, with few blocks, is itself
    uncertain and sometimes low by chance. ``derived`` holds (value, jackknife std) of the
    body natural frequency and damping ratio. ``replicates`` are the jackknife estimates,
    one row per left-out block.

    Parameters
    ----------
    name : str
        ``"frequency"`` or ``"time"``.
    theta, std, lsq_std : ndarray
        ``[M2 kg, K2 N/m, C2 N s/m, K3 N/m]`` (:data:`THETA_NAMES`),
        their standard deviations and the least-squares ones (same units).
    include_k3 : bool
        K3 was fitted (else held at 0).
    derived : dict of str to (float, float)
        ``body_natural_frequency_hz`` [Hz] and ``damping_ratio`` with their std.
    replicates : ndarray
        ``(n_blocks, 4)`` jackknife estimates.
    cost : float
        Final cost (sum of squared prewhitened residuals, dimensionless).
    n_residuals : int
        Number of residuals.
    notes : list of str
        Remarks (a fit that did not converge).
    """

    name: str
    theta: np.ndarray
    std: np.ndarray
    lsq_std: np.ndarray
    include_k3: bool
    derived: dict[str, tuple[float, float]]
    replicates: np.ndarray
    cost: float
    n_residuals: int
    notes: list[str] = field(default_factory=list)


def _jackknife(full: np.ndarray, groups: Sequence[np.ndarray]) -> np.ndarray:
    """Variance from per-session delete-a-block replicates (sessions independent)."""
    var = np.zeros_like(full, dtype=float)
    for reps in groups:
        b = reps.shape[0]
        if b < 2:
            continue
        var += (b - 1) / b * np.sum((reps - reps.mean(axis=0)) ** 2, axis=0)
    return var


def _derived_with_std(theta: np.ndarray, groups: Sequence[np.ndarray]
                      ) -> dict[str, tuple[float, float]]:
    out = {}
    for name, fn in DERIVED.items():
        reps = [np.array([[fn(r)] for r in g]) for g in groups]
        var = _jackknife(np.array([fn(theta)]), reps)
        out[name] = (float(fn(theta)), float(math.sqrt(var[0])))
    return out


def frequency_route(
    blocks: Sequence[BlockCrossSpectra],
    added_masses_kg: Sequence[float],
    band_hz: tuple[float, float],
    noise: Sequence[tuple[float, float]],
    replicate_noise: Sequence[Sequence[tuple[float, float]]],
    *,
    include_k3: bool,
    theta0: np.ndarray | None = None,
) -> RouteEstimate:
    """Frequency-domain ML fit over both sessions with a delete-a-block jackknife.

    Parameters
    ----------
    blocks : sequence of BlockCrossSpectra
        Per session, wheel = x, body = y.
    added_masses_kg : sequence of float
        Mass added on the body in each session (0 for the reference drive).
    band_hz : (float, float)
        Lines used.
    noise : sequence of (noise_x, noise_y)
        Per session, the white-noise densities of the wheel and body channels.
    replicate_noise : sequence of sequences of (noise_x, noise_y)
        Per session and left-out block, the noise densities re-estimated without the
        block, so that their uncertainty enters the standard deviations.
    include_k3 : bool
        Fit the coupling stiffness K3.
    theta0 : ndarray or None
        Start of the full-data fit.

    Returns
    -------
    RouteEstimate
    """
    totals = [b.total() for b in blocks]
    lines = [SessionLines.from_spectra(sp, band_hz, nx, ny, dm)
             for sp, (nx, ny), dm in zip(totals, noise, added_masses_kg, strict=True)]
    fit = fit_frequency_ml(lines, include_k3=include_k3, theta0=theta0)
    groups = []
    for s, blk in enumerate(blocks):
        reps = []
        for b in range(blk.n_blocks):
            nx, ny = replicate_noise[s][b]
            rep_lines = list(lines)
            rep_lines[s] = SessionLines.from_spectra(blk.leave_out(b), band_hz, nx, ny,
                                                     added_masses_kg[s])
            reps.append(fit_frequency_ml(rep_lines, include_k3=include_k3,
                                         theta0=fit.theta).theta)
        groups.append(np.array(reps))
    var = _jackknife(fit.theta, groups)
    notes = [] if fit.converged else [f"frequency fit did not converge: {fit.message}"]
    lsq = np.sqrt(np.abs(np.diag(fit.covariance)))
    return RouteEstimate("frequency", fit.theta, np.maximum(np.sqrt(var), lsq), lsq,
                         include_k3, _derived_with_std(fit.theta, groups), np.vstack(groups),
                         fit.cost, fit.n_residuals, notes)


# ---------------------------------------------------------------------------------------
# Time route
# ---------------------------------------------------------------------------------------


@dataclass
class TimeRoutePiece:
    """One contiguous stretch of one session, band-limited, for the time-domain fit.

    ``wheel_spec``/``body_spec`` are the band lines of the zero-padded record's FFT
    (band window applied, scaled for an inverse FFT of length ``n_fft_out``); the
    residual is evaluated on the output samples ``keep`` (record ends trimmed), whose
    jackknife block is ``block_of``.

    Parameters
    ----------
    session : int
        Index of the session (0 before, 1 after).
    freq_hz : ndarray
        Frequencies of the FFT lines kept [Hz].
    wheel_spec, body_spec : ndarray
        Windowed FFT lines of the wheel and body accelerations (m/s^2 per line, complex).
    n_fft_out : int
        Length of the inverse FFT (sets the output rate).
    keep : slice
        Output samples used in the residual.
    block_of : ndarray
        Jackknife block of each kept sample.
    noise_x, noise_y : float
        White-noise densities of the wheel and body accelerometers [(m/s^2)^2/Hz].
    added_mass_kg : float
        Mass added on the body in this session [kg].
    norm : float
        RMS per output sample of prewhitened band-limited unit white noise (the residual
        is divided by it).
    output_rate_hz : float
        Sample rate of the residual [Hz].
    """

    session: int
    freq_hz: np.ndarray
    wheel_spec: np.ndarray
    body_spec: np.ndarray
    n_fft_out: int
    keep: slice
    block_of: np.ndarray
    noise_x: float
    noise_y: float
    added_mass_kg: float
    norm: float
    output_rate_hz: float


def prepare_time_piece(
    wheel_mps2: np.ndarray,
    body_mps2: np.ndarray,
    sample_rate_hz: float,
    band_hz: tuple[float, float],
    *,
    session: int,
    noise_x: float,
    noise_y: float,
    added_mass_kg: float,
    block_edges_s: np.ndarray,
    start_s: float = 0.0,
    output_rate_hz: float | None = None,
    taper: float = 0.3,
) -> TimeRoutePiece | None:
    """Band-limit and resample one contiguous stretch for :func:`time_route`.

    Returns None when the stretch is too short to keep anything after trimming its ends
    (3 periods of the lower band edge each side).

    Parameters
    ----------
    wheel_mps2, body_mps2 : ndarray
        Wheel and body accelerometer readings of the stretch [m/s^2] (offset and drift are
        removed here).
    sample_rate_hz : float
        Sample rate [Hz].
    band_hz : (float, float)
        Analysis band [Hz]; a cosine taper of ``taper`` (relative) extends it on both sides.
    session : int
        Index of the session (0 before, 1 after).
    noise_x, noise_y : float
        White-noise densities of the wheel and body accelerometers [(m/s^2)^2/Hz].
    added_mass_kg : float
        Mass added on the body in this session [kg].
    block_edges_s : ndarray
        Edges of the session's jackknife time blocks [s].
    start_s : float
        Time of the stretch's first sample in the session [s].
    output_rate_hz : float or None
        Resample the residual to about this rate [Hz] (None: the input rate).
    taper : float
        Relative width of the band window's tapers.

    Returns
    -------
    TimeRoutePiece or None
    """
    n = wheel_mps2.size
    lo, hi = band_hz
    pad = int(min(n, math.ceil(4.0 / (lo * (1 - taper)) * sample_rate_hz)))
    nfft = sp_fft.next_fast_len(n + pad, real=True)
    freq = np.fft.rfftfreq(nfft, 1.0 / sample_rate_hz)
    n_lines = min(int(np.searchsorted(freq, hi * (1 + taper))) + 2, freq.size)
    fs_out = sample_rate_hz if output_rate_hz is None else min(output_rate_hz, sample_rate_hz)
    n_fft_out = int(round(nfft * fs_out / sample_rate_hz))
    n_fft_out += n_fft_out % 2
    n_lines = min(n_lines, n_fft_out // 2)
    fs_out = sample_rate_hz * n_fft_out / nfft
    n_out = int(math.floor(n * n_fft_out / nfft))
    trim = int(math.ceil(3.0 / lo * fs_out))
    if n_out - 2 * trim < 10:
        return None
    win = band_window(freq[:n_lines], band_hz, taper) * (n_fft_out / nfft)
    wspec = sp_fft.rfft(remove_offset_and_drift(wheel_mps2), nfft)[:n_lines] * win
    bspec = sp_fft.rfft(remove_offset_and_drift(body_mps2), nfft)[:n_lines] * win
    keep = slice(trim, n_out - trim)
    t = start_s + np.arange(trim, n_out - trim) / fs_out
    block_of = np.clip(np.searchsorted(block_edges_s, t, side="right") - 1, 0,
                       block_edges_s.size - 2)
    # variance per output sample of prewhitened band-limited white noise: int W^2 df
    w01 = band_window(freq[:n_lines], band_hz, taper)
    norm = math.sqrt(float(np.sum(w01**2)) * sample_rate_hz / nfft)
    return TimeRoutePiece(session, freq[:n_lines], wspec, bspec, n_fft_out, keep, block_of,
                          float(noise_x), float(noise_y), float(added_mass_kg), norm, fs_out)


def _time_residuals(theta: np.ndarray, pieces: Sequence[TimeRoutePiece]) -> np.ndarray:
    out = []
    for p in pieces:
        t = model_transmissibility(theta, p.freq_hz, p.added_mass_kg)
        pw = 1.0 / np.sqrt(p.noise_y + np.abs(t) ** 2 * p.noise_x)
        spec = np.zeros(p.n_fft_out // 2 + 1, dtype=complex)
        spec[: p.freq_hz.size] = (p.body_spec - t * p.wheel_spec) * pw
        out.append(sp_fft.irfft(spec, p.n_fft_out)[p.keep] / p.norm)
    return np.concatenate(out)


def prewhitened_signal_power(theta: np.ndarray, pieces: Sequence[TimeRoutePiece]) -> float:
    """Mean power of the body signal in the time route's noise units.

    The body acceleration prewhitened like the route's residual (by the noise the model
    ``theta`` expects at each line): a linear car's residual power is about 1 in these
    units, so ``(misfit - 1) / prewhitened_signal_power`` is the share of the body signal
    a misfit of ``misfit`` leaves unexplained.

    Parameters
    ----------
    theta : ndarray
        Linear model (M2, K2, C2, K3) as the route fits it.
    pieces : sequence of TimeRoutePiece
        The route's stretches.

    Returns
    -------
    float
        Mean square of the prewhitened body acceleration per output sample (1 = noise).
    """
    out = []
    for p in pieces:
        t = model_transmissibility(theta, p.freq_hz, p.added_mass_kg)
        pw = 1.0 / np.sqrt(p.noise_y + np.abs(t) ** 2 * p.noise_x)
        spec = np.zeros(p.n_fft_out // 2 + 1, dtype=complex)
        spec[: p.freq_hz.size] = p.body_spec * pw
        out.append(sp_fft.irfft(spec, p.n_fft_out)[p.keep] / p.norm)
    x = np.concatenate(out)
    return float(np.mean(x * x))


def time_route(pieces: Sequence[TimeRoutePiece], theta0: np.ndarray, *, include_k3: bool
               ) -> RouteEstimate:
    """Prewhitened output-error fit in the time domain with a one-step block jackknife.

    Parameters
    ----------
    pieces : sequence of TimeRoutePiece
        All stretches of all sessions (see :func:`prepare_time_piece`).
    theta0 : ndarray
        Start (for example the frequency-route estimate).
    include_k3 : bool
        Fit K3, else hold it at 0.

    Returns
    -------
    RouteEstimate
    """
    theta0 = np.asarray(theta0, float).copy()
    if not include_k3:
        theta0[3] = 0.0
    scale = _param_scale(theta0)
    n_par = 4 if include_k3 else 3

    def fun(p: np.ndarray) -> np.ndarray:
        return _time_residuals(_theta_full(p, scale, include_k3), pieces)

    res = optimize.least_squares(fun, theta0[:n_par] / scale[:n_par], method="lm",
                                 xtol=1e-10, ftol=1e-10, max_nfev=200)
    theta = _theta_full(res.x, scale, include_k3)
    jac, r = res.jac, res.fun
    h = jac.T @ jac
    sess = np.concatenate([np.full(p.keep.stop - p.keep.start, p.session) for p in pieces])
    blk = np.concatenate([p.block_of for p in pieces])
    groups = []
    for s in np.unique(sess):
        reps = []
        for b in np.unique(blk[sess == s]):
            m = (sess == s) & (blk == b)
            jb, rb = jac[m], r[m]
            try:
                step = np.linalg.solve(h - jb.T @ jb, jb.T @ rb)
            except np.linalg.LinAlgError:
                continue
            reps.append(_theta_full(res.x + step, scale, include_k3))
        if reps:
            groups.append(np.array(reps))
    var = _jackknife(theta, groups)
    lsq = np.sqrt(np.abs(np.diag(_lsq_cov(jac, r, scale, n_par))))
    notes = [] if res.success else [f"time fit did not converge: {res.message}"]
    return RouteEstimate("time", theta, np.maximum(np.sqrt(var), lsq), lsq, include_k3,
                         _derived_with_std(theta, groups),
                         np.vstack(groups) if groups else np.zeros((0, 4)),
                         float(r @ r), int(r.size), notes)


def route_agreement(a: RouteEstimate, b: RouteEstimate) -> dict[str, float]:
    """Difference of two routes in units of their combined std, per parameter.

    The routes use the same data, so this is conservative: a value above 3 means they
    disagree by more than their uncertainties allow.

    Parameters
    ----------
    a, b : RouteEstimate
        The two routes' estimates (``frequency`` and ``time``).

    Returns
    -------
    dict of str to float
        ``|theta_a - theta_b| / hypot(std_a, std_b)`` by :data:`THETA_NAMES` (dimensionless).
    """
    out = {}
    for i, name in enumerate(THETA_NAMES):
        s = math.hypot(a.std[i], b.std[i])
        d = a.theta[i] - b.theta[i]
        out[name] = float(abs(d) / s) if s > 0 else (0.0 if d == 0 else float("inf"))
    return out


# ---------------------------------------------------------------------------------------
# Do the two drives belong together?
# ---------------------------------------------------------------------------------------


def _fit_ratios(lines: SessionLines, start: np.ndarray) -> np.ndarray:
    """``[K2/M2, C2/M2]`` of one session alone (its mass set to 1, K3 held at 0).

    The errors-in-variables residuals do not change when theta is scaled, so one session
    fixes the ratios to the mass (DESIGN.md) and nothing else.
    """
    one = SessionLines(lines.freq_hz, lines.gxx, lines.gyy, lines.gxy, lines.n_averages,
                       lines.noise_x, lines.noise_y, 0.0)
    chol = [one._cholesky()]
    scale = np.maximum(np.abs(start), 1e-9)

    def fun(p: np.ndarray) -> np.ndarray:
        return _ml_residuals(np.array([1.0, p[0] * scale[0], p[1] * scale[1], 0.0]), [one],
                             chol)

    res = optimize.least_squares(fun, np.ones(2), method="lm", xtol=1e-10, ftol=1e-10,
                                 max_nfev=200)
    return res.x * scale


@dataclass
class PairConsistency:
    """The sprung mass implied by each drive's own ratios, from stiffness and from damping.

    With ``k = K2/M2`` and ``c = C2/M2`` of the drive before and after adding ``dM``, the
    stiffness implies ``M2 = dM k_after / (k_before - k_after)`` and the damping
    ``M2 = dM c_after / (c_before - c_after)``. One corner of one car, with the mass added
    and nothing else changed, gives the same M2 both ways (within their std); drives of
    different cars or corners, swapped drives, or a suspension whose damping is not linear
    (friction: its equivalent damping depends on the amplitude) do not.

    Parameters
    ----------
    ratios_before, ratios_after : (float, float)
        ``(K2/M2 [1/s^2], C2/M2 [1/s])`` of each drive alone.
    mass_from_stiffness_kg, mass_from_stiffness_std_kg : float
        M2 implied by the stiffness ratios and its jackknife std [kg].
    mass_from_damping_kg, mass_from_damping_std_kg : float
        M2 implied by the damping ratios and its std [kg].
    stiffness_drop_z : float
        ``(k_before - k_after) / std``: positive when the mass was added.
    """

    ratios_before: tuple[float, float]
    ratios_after: tuple[float, float]
    mass_from_stiffness_kg: float
    mass_from_stiffness_std_kg: float
    mass_from_damping_kg: float
    mass_from_damping_std_kg: float
    stiffness_drop_z: float  # (k_before - k_after) / std: positive when the mass was added

    @property
    def disagreement_z(self) -> float:
        """|M2 from stiffness - M2 from damping| in units of their combined std (dimensionless)."""
        s = math.hypot(self.mass_from_stiffness_std_kg, self.mass_from_damping_std_kg)
        d = abs(self.mass_from_stiffness_kg - self.mass_from_damping_kg)
        return d / s if s > 0 else float("inf")


def pair_consistency(
    blocks: Sequence[BlockCrossSpectra],
    added_masses_kg: Sequence[float],
    band_hz: tuple[float, float],
    noise: Sequence[tuple[float, float]],
    theta: np.ndarray,
) -> PairConsistency:
    """Fit each drive's ratios alone and compare the masses they imply (see the class).

    Parameters
    ----------
    blocks : two BlockCrossSpectra
        Before and after, wheel = x, body = y.
    added_masses_kg : two floats
        0 and the added mass [kg].
    band_hz : (float, float)
        Lines used [Hz].
    noise : two (noise_x, noise_y)
        White-noise densities of each drive's wheel and body channels.
    theta : ndarray
        The joint fit ``[M2, K2, C2, K3]``, to start from.

    Returns
    -------
    PairConsistency
        Standard deviations from a delete-a-block jackknife in each drive.
    """
    dm = float(added_masses_kg[1] - added_masses_kg[0])
    starts = [np.array([theta[1], theta[2]]) / (theta[0] + m) for m in added_masses_kg]
    full, reps = [], []
    for blk, (nx, ny), start in zip(blocks, noise, starts, strict=True):
        lines = SessionLines.from_spectra(blk.total(), band_hz, nx, ny, 0.0)
        r = _fit_ratios(lines, start)
        full.append(r)
        reps.append(np.array([
            _fit_ratios(SessionLines.from_spectra(blk.leave_out(b), band_hz, nx, ny, 0.0), r)
            for b in range(blk.n_blocks)]))

    def masses(rb: np.ndarray, ra: np.ndarray) -> np.ndarray:
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.array([dm * ra[0] / (rb[0] - ra[0]), dm * ra[1] / (rb[1] - ra[1]),
                             rb[0] - ra[0]])

    value = masses(full[0], full[1])
    groups = [np.array([masses(r, full[1]) for r in reps[0]]),
              np.array([masses(full[0], r) for r in reps[1]])]
    std = np.sqrt(_jackknife(value, groups))
    return PairConsistency(
        (float(full[0][0]), float(full[0][1])), (float(full[1][0]), float(full[1][1])),
        float(value[0]), float(std[0]), float(value[1]), float(std[1]),
        float(value[2] / std[2]) if std[2] > 0 else float("inf"))
