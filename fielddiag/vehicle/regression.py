"""The full-vehicle model written linear in its parameters, and its weighted least squares.

Pure numerics over arrays (no I/O). Conventions: :mod:`fielddiag.vehicle.geometry` and
:mod:`fielddiag.vehicle.dynamics`. With the body's heave, pitch and roll ``q`` at the
origin, the strut points' motion ``z_i = [1, x_i, y_i] q``, the suspension extensions
``r_i = z_i - z_hub,i`` and the added mass ``dM`` at ``(x_a, y_a)`` (its acceleration
``a_a = [1, x_a, y_a] q''``), the three body equations are, per sample::

    M q0'' + Sx q1'' + Sy q2''          + sum_i     (K_i r_i + C_i r_i')          = -dM a_a
    Sx q0'' + Jp q1'' + Jpr q2''        + sum_i x_i (K_i r_i + C_i r_i') + Hp a_long = -dM x_a a_a
    Sy q0'' + Jpr q1'' + Jr q2''        + sum_i y_i (K_i r_i + C_i r_i')
        + t_f k_f (r_fl - r_fr) + t_r k_r (r_rl - r_rr) - Hr a_lat                   = -dM y_a a_a

linear in ``theta = [M, Sx, Sy, Jp, Jr, Jpr, K_fl..K_rr, C_fl..C_rr, k_f, k_r, Hp, Hr]``
(first moments ``Sx = M x_cg``, ``Sy = M y_cg``; inertias about the origin ``Jp = I_p +
M x_cg^2``, ``Jr = I_r + M y_cg^2``, ``Jpr = M x_cg y_cg`` (+ a product of inertia);
``Hp``, ``Hr`` the pitch and roll moment arms times the mass, ``M h``). The drive without
added mass has a zero right-hand side; the known ``dM`` fixes the scale.

Weighted least squares (Gautier, seed 003): an ordinary fit, then each equation of each
drive weighted by the inverse of its residual standard deviation and solved again. The
covariance is a delete-a-block jackknife over time blocks (the band-passed residuals are
correlated in time, so the textbook ``sigma^2 (W^T W)^-1`` would be too optimistic, and
the noise compensation makes the estimator nonlinear in the data); optionally the
jackknife's bias estimate is removed from the estimate.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from fielddiag.channels import CORNERS

__all__ = ["EQUATION_PAIRS", "PARAM_NAMES", "DriveNoise", "DriveRegressors", "WlsResult",
           "band_split", "band_split_signals", "block_grams", "compensated_least_squares",
           "equation_error_transfer", "equation_rows", "noise_gram", "noise_normal_equations",
           "predict_body_accel", "regressors", "weighted_least_squares"]

#: The parameters of the linear-in-parameters model, in order.
PARAM_NAMES = ("mass_kg", "first_moment_x_kgm", "first_moment_y_kgm", "pitch_inertia_origin_kgm2",
               "roll_inertia_origin_kgm2", "product_inertia_origin_kgm2",
               *(f"stiffness_{c}_n_per_m" for c in CORNERS),
               *(f"damping_{c}_ns_per_m" for c in CORNERS),
               "anti_roll_front_n_per_m", "anti_roll_rear_n_per_m",
               "pitch_arm_kgm", "roll_arm_kgm")
N_PARAMS = len(PARAM_NAMES)


@dataclass
class DriveRegressors:
    """One drive's band-passed motion at the analysis rate.

    Attributes
    ----------
    qdd : ndarray (3, n)
        Body heave/pitch/roll accelerations at the origin.
    r, rd : ndarray (4, n)
        Suspension extension [m] and rate [m/s] per corner.
    a_long, a_lat : ndarray (n,)
        Car accelerations [m/s^2] (band-passed like the rest).
    body_accel : ndarray (4, n)
        The body sensors' band-passed accelerations [m/s^2] (for predictions).
    corner_x, corner_y : ndarray (4,)
        Strut positions [m].
    sensor_matrix : ndarray (4, 3)
        Body sensors' ``[1, x, y]``.
    added_mass_kg : float
    added_mass_at_m : (float, float)
    rate_hz : float
        Analysis rate [Hz].
    wheel_disp, wheel_vel : ndarray (4, n) or None
        Hub displacement [m] and velocity [m/s] (band-passed; for simulating the body).
    """

    qdd: np.ndarray
    r: np.ndarray
    rd: np.ndarray
    a_long: np.ndarray
    a_lat: np.ndarray
    body_accel: np.ndarray
    corner_x: np.ndarray
    corner_y: np.ndarray
    sensor_matrix: np.ndarray
    added_mass_kg: float
    added_mass_at_m: tuple[float, float]
    rate_hz: float
    wheel_disp: np.ndarray | None = None
    wheel_vel: np.ndarray | None = None

    @property
    def n(self) -> int:
        """Samples."""
        return int(self.qdd.shape[1])


def equation_rows(d: DriveRegressors) -> tuple[np.ndarray, np.ndarray]:
    """Regressor ``A`` (3, n, N_PARAMS) and right-hand side ``b`` (3, n) of one drive.

    Returns
    -------
    A : ndarray (3, n, N_PARAMS)
        Rows of the heave, pitch and roll equations.
    b : ndarray (3, n)
        ``-dM [1, x_a, y_a] a_a``.
    """
    n = d.n
    a = np.zeros((3, n, N_PARAMS))
    q0, q1, q2 = d.qdd
    x, y = d.corner_x, d.corner_y
    lever = np.array([np.ones(4), x, y])  # (3, 4)
    a[0, :, 0], a[0, :, 1], a[0, :, 2] = q0, q1, q2
    a[1, :, 1], a[1, :, 3], a[1, :, 5] = q0, q1, q2
    a[2, :, 2], a[2, :, 5], a[2, :, 4] = q0, q1, q2
    for e in range(3):
        a[e, :, 6:10] = (lever[e][:, None] * d.r).T
        a[e, :, 10:14] = (lever[e][:, None] * d.rd).T
    tf = y[0] - y[1]
    tr = y[2] - y[3]
    a[2, :, 14] = tf * (d.r[0] - d.r[1])
    a[2, :, 15] = tr * (d.r[2] - d.r[3])
    a[1, :, 16] = d.a_long
    a[2, :, 17] = -d.a_lat
    xa, ya = d.added_mass_at_m
    acc_a = q0 + xa * q1 + ya * q2
    b = -d.added_mass_kg * np.array([acc_a, xa * acc_a, ya * acc_a])
    return a, b


def mass_matrix(theta: np.ndarray, added_mass_kg: float = 0.0,
                added_mass_at_m: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    """The body's (3, 3) mass matrix about the origin from ``theta`` plus the added mass."""
    m, sx, sy, jp, jr, jpr = theta[:6]
    dm, (xa, ya) = added_mass_kg, added_mass_at_m
    return np.array([[m + dm, sx + dm * xa, sy + dm * ya],
                     [sx + dm * xa, jp + dm * xa * xa, jpr + dm * xa * ya],
                     [sy + dm * ya, jpr + dm * xa * ya, jr + dm * ya * ya]])


def predict_body_accel(theta: np.ndarray, d: DriveRegressors) -> np.ndarray:
    """The body sensors' accelerations the model predicts from the measured suspension
    motion and car accelerations (equation error: the seed's ``W X`` against ``Y``).

    Returns
    -------
    ndarray (4, n)
        Predicted band-passed body accelerations [m/s^2].
    """
    a, _ = equation_rows(d)
    th = np.nan_to_num(np.asarray(theta, float))
    # generalised forces: everything but the inertial terms, moved to the right
    inert = np.zeros_like(th)
    inert[:6] = th[:6]
    forces = -(a @ (th - inert))  # (3, n)
    xa, ya = d.added_mass_at_m
    qdd = np.linalg.solve(mass_matrix(th, d.added_mass_kg, (xa, ya)), forces)
    return d.sensor_matrix @ qdd


def regressors(drives: Sequence[DriveRegressors]) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                          np.ndarray]:
    """Stack drives: rows ``A`` (N, N_PARAMS), ``b`` (N,), equation-group id and time index.

    Rows are ordered drive, equation, sample; the group id is ``3 * drive + equation``;
    the time index counts samples within the drive.
    """
    rows, rhs, group, tidx = [], [], [], []
    for k, d in enumerate(drives):
        a, b = equation_rows(d)
        for e in range(3):
            rows.append(a[e])
            rhs.append(b[e])
            group.append(np.full(d.n, 3 * k + e))
            tidx.append(np.arange(d.n) + 10**9 * k)
    return np.vstack(rows), np.concatenate(rhs), np.concatenate(group), np.concatenate(tidx)


@dataclass
class WlsResult:
    """Weighted least-squares estimate.

    Attributes
    ----------
    theta : ndarray (N_PARAMS,)
        Estimates (NaN for parameters not fitted).
    cov : ndarray (N_PARAMS, N_PARAMS)
        Covariance (zero rows/columns for parameters not fitted).
    fitted : ndarray of bool
        Which parameters were fitted.
    group_sigma : ndarray
        Residual standard deviation of each equation group (unweighted units).
    n_blocks : int
        Time blocks of the jackknife.
    scale_std : float
        Relative systematic uncertainty of the common scale included in ``cov``.
    hub_noise_s2 : ndarray (drives, components, bands) or None
        The hub channels' noise the compensation used, per drive and frequency band: each
        hub's variance as that of white noise at the recording's rate with the same
        density there, then the covariances (:class:`DriveNoise`) [m^2/s^4]
        (:func:`compensated_least_squares`).
    """

    theta: np.ndarray
    cov: np.ndarray
    fitted: np.ndarray
    group_sigma: np.ndarray
    n_blocks: int
    scale_std: float = 0.0
    hub_noise_s2: np.ndarray | None = None

    @property
    def std(self) -> np.ndarray:
        """Standard deviations (NaN where not fitted)."""
        s = np.sqrt(np.clip(np.diag(self.cov), 0.0, None))
        return np.where(self.fitted, s, np.nan)

    def correlation(self) -> np.ndarray:
        """Correlation matrix of the fitted parameters (NaN elsewhere)."""
        s = self.std
        with np.errstate(invalid="ignore", divide="ignore"):
            return self.cov / np.outer(s, s)


def weighted_least_squares(a: np.ndarray, b: np.ndarray, group: np.ndarray, tidx: np.ndarray,
                           fitted: np.ndarray, block_samples: int,
                           noise: dict[int, tuple[np.ndarray, np.ndarray]] | None = None,
                           bias_correction: bool = False) -> WlsResult:
    """Solve ``A theta = b`` by weighted least squares with a block-jackknife covariance.

    Parameters
    ----------
    a, b, group, tidx : ndarray
        From :func:`regressors`.
    fitted : ndarray of bool
        Columns to fit (the others are held at 0).
    block_samples : int
        Samples per time block of the jackknife (all three equations of a block together).
    noise : dict group -> (N_AA, N_Ab) or None
        The expected contribution of the sensor noise to each equation group's
        (unweighted) normal equations, ``E[A_n^T A_n]`` (N_PARAMS, N_PARAMS) and
        ``E[A_n^T b_n]`` (N_PARAMS,) (:func:`noise_normal_equations`). The regressors are
        measured with noise (errors in variables), which biases least squares towards
        zero; these are subtracted (bias-compensated least squares).
    bias_correction : bool
        Subtract the jackknife's estimate of the estimator's bias.

    Returns
    -------
    WlsResult
    """
    cols = np.flatnonzero(fitted)
    af = a[:, cols]
    scale = np.linalg.norm(af, axis=0)
    scale[scale == 0] = 1.0
    a_s = af / scale
    def solve(w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        aw, bw = a_s * w[:, None], b * w
        lhs, rhs = aw.T @ aw, aw.T @ bw
        for g, (naa, nab) in (noise or {}).items():
            wg2 = float(w[np.argmax(group == g)]) ** 2
            lhs = lhs - wg2 * naa[np.ix_(cols, cols)] / np.outer(scale, scale)
            rhs = rhs - wg2 * nab[cols] / scale
        return np.linalg.solve(lhs, rhs), lhs

    w = np.ones(b.size)
    th_s, normal = solve(w)
    groups = np.unique(group)
    sigma = np.ones(groups.max() + 1)
    for _ in range(2):  # residuals -> per-equation weights -> WLS (once more with its residuals)
        e = b - a_s @ th_s
        for g in groups:
            m = group == g
            sigma[g] = max(float(np.sqrt(np.mean(e[m] ** 2))), 1e-300)
        w = 1.0 / sigma[group]
        th_s, normal = solve(w)
    aw, bw = a_s * w[:, None], b * w
    rhs_full = aw.T @ bw
    for g, (_, nab) in (noise or {}).items():
        rhs_full = rhs_full - (1.0 / sigma[g]) ** 2 * nab[cols] / scale
    # delete-a-block jackknife: blocks of whole seconds in each drive, all three equations
    block = tidx // max(1, block_samples)  # drives are apart by 1e9 samples
    ub, inv = np.unique(block, return_inverse=True)
    n_g = {g: int(np.sum(group == g)) for g in groups}
    reps = []
    for i in range(ub.size):
        m = inv == i
        lhs_i = normal - aw[m].T @ aw[m]
        rhs_i = rhs_full - aw[m].T @ bw[m]
        for g, (naa, nab) in (noise or {}).items():
            frac = np.sum(m & (group == g)) / n_g[g]
            if frac:
                wg2 = (1.0 / sigma[g]) ** 2
                lhs_i = lhs_i + frac * wg2 * naa[np.ix_(cols, cols)] / np.outer(scale, scale)
                rhs_i = rhs_i + frac * wg2 * nab[cols] / scale
        reps.append(np.linalg.solve(lhs_i, rhs_i))
    reps_a = np.array(reps)
    nb = ub.size
    mean_rep = reps_a.mean(axis=0)
    if bias_correction:
        th_s = th_s - (nb - 1) * (mean_rep - th_s)  # jackknife bias correction
    dev = reps_a - mean_rep
    cov_s = (nb - 1) / nb * dev.T @ dev
    theta = np.full(a.shape[1], np.nan)
    theta[cols] = th_s / scale
    cov = np.zeros((a.shape[1], a.shape[1]))
    cov[np.ix_(cols, cols)] = cov_s / np.outer(scale, scale)
    return WlsResult(theta, cov, np.asarray(fitted, bool), sigma, int(nb))


def _noise_basis(d: DriveRegressors) -> tuple[np.ndarray, np.ndarray]:
    """:func:`equation_rows` of the 24 unit inputs (8 channels x acceleration, velocity,
    displacement filter): ``A`` (3, 24, N_PARAMS) and ``b`` (3, 24), linear maps of each
    channel's filtered noise into the regressors and the right-hand side."""
    nb = 24
    unit = np.eye(nb).reshape(8, 3, nb)  # [channel, filter, basis]
    wheel, body = unit[:4], unit[4:]
    pinv = np.linalg.pinv(d.sensor_matrix)
    cm = np.column_stack([np.ones(4), d.corner_x, d.corner_y])
    basis = DriveRegressors(
        qdd=pinv @ body[:, 0], r=cm @ pinv @ body[:, 2] - wheel[:, 2],
        rd=cm @ pinv @ body[:, 1] - wheel[:, 1], a_long=np.zeros(nb), a_lat=np.zeros(nb),
        body_accel=body[:, 0], corner_x=d.corner_x, corner_y=d.corner_y,
        sensor_matrix=d.sensor_matrix, added_mass_kg=d.added_mass_kg,
        added_mass_at_m=d.added_mass_at_m, rate_hz=d.rate_hz)
    return equation_rows(basis)


def equation_error_transfer(d: DriveRegressors, theta: np.ndarray) -> np.ndarray:
    """How each accelerometer's noise enters each body equation's error ``A theta - b``.

    Returns
    -------
    ndarray (3, 8, 3)
        ``c[e, ch, k]``: equation ``e``'s error per unit of channel ``ch``'s noise through
        the acceleration, velocity and displacement filter ``k``; at angular frequency
        ``w`` the error's transfer from that channel's acceleration noise is
        ``c[e, ch, 0] + c[e, ch, 1] / (j w) + c[e, ch, 2] / (j w)^2``.
    """
    a, b = _noise_basis(d)
    th = np.nan_to_num(np.asarray(theta, float))
    return (a @ th - b).reshape(3, 8, 3)


def noise_gram(d: DriveRegressors, sigma_mps2: Sequence[float], response: np.ndarray,
               car_sigma_mps2: tuple[float, float] = (0.0, 0.0),
               car_response: np.ndarray | None = None,
               channel_cov: np.ndarray | None = None, pairs: bool = False) -> np.ndarray:
    """Expected share of white accelerometer noise in one drive's augmented Gram matrices.

    Every regressor and the right-hand side are linear maps of the eight channels' noise
    through three filters (acceleration, velocity, displacement: the processing's transfer
    functions), so their expected products follow from the filters' lag-0
    cross-correlations ``response``. The maps are found by running :func:`equation_rows`
    on unit inputs.

    Parameters
    ----------
    d : DriveRegressors
        The drive (geometry, added mass, number of samples).
    sigma_mps2 : sequence of 8 float
        Noise std of the hub (fl, fr, rl, rr) and body (fl, fr, rl, rr) channels [m/s^2].
    response : ndarray (3, 3) or (8, 3, 3)
        ``R[f, g] = sum_k h_f[k] h_g[k]`` of the acceleration, velocity and displacement
        filters for unit white noise, for all channels or per channel.
    car_sigma_mps2 : (float, float)
        Noise std of the car's longitudinal and lateral acceleration signals [m/s^2]
        (they are regressors of the pitch and roll moment arms).
    car_response : ndarray (3, 3) or None
        The filters' ``R`` for the car signals; default ``response`` (needed when
        ``response`` is per channel and there is car noise).
    channel_cov : ndarray (8, 8) or None
        Instead of ``sigma_mps2``: the channels' noise covariance [m^2/s^4] (noise common
        to several channels, e.g. what the road puts into the hubs); ``response`` (3, 3).
    pairs : bool
        Also the products of different equations (:data:`EQUATION_PAIRS`).

    Returns
    -------
    ndarray (3 or 6, N_PARAMS + 1, N_PARAMS + 1)
        ``E[[A, b]^T [A, b]]`` of the heave, pitch and roll equations (and their pairs),
        summed over the drive's samples, unweighted.
    """
    a, b = _noise_basis(d)  # (3, 24, P), (3, 24)
    aug = np.concatenate([a, b[..., None]], axis=2)
    resp = np.asarray(response, float)
    if channel_cov is not None:
        s = np.kron(np.asarray(channel_cov, float), resp)
    else:
        resp = np.broadcast_to(resp, (8, 3, 3)) if resp.ndim == 2 else resp
        s = np.zeros((24, 24))
        for ch in range(8):
            idx = slice(3 * ch, 3 * ch + 3)
            s[idx, idx] = float(sigma_mps2[ch]) ** 2 * resp[ch]
    which = EQUATION_PAIRS if pairs else EQUATION_PAIRS[:3]
    left = [g for g, _ in which]
    right = [h for _, h in which]
    out = d.n * np.einsum("eip,ij,ejq->epq", aug[left], s, aug[right])
    if any(car_sigma_mps2):
        if car_response is None:
            if np.ndim(response) == 3:
                raise ValueError("per-channel responses need the car signals' car_response")
            car_response = resp if resp.ndim == 2 else resp[0]
        r_car = float(np.asarray(car_response)[0, 0])
        out[1, 16, 16] += d.n * car_sigma_mps2[0] ** 2 * r_car
        out[2, 17, 17] += d.n * car_sigma_mps2[1] ** 2 * r_car
    return out


def noise_normal_equations(d: DriveRegressors, sigma_mps2: Sequence[float],
                           response: np.ndarray, first_group: int,
                           car_sigma_mps2: tuple[float, float] = (0.0, 0.0),
                           car_response: np.ndarray | None = None
                           ) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Expected share of white accelerometer noise in one drive's normal equations
    (:func:`noise_gram` split as :func:`weighted_least_squares` takes it).

    Parameters
    ----------
    d, sigma_mps2, response, car_sigma_mps2, car_response
        As :func:`noise_gram`.
    first_group : int
        Group id of this drive's heave equation (``3 * drive``).

    Returns
    -------
    dict group -> (E[A^T A], E[A^T b])
        Sums over the drive's samples, unweighted.
    """
    g = noise_gram(d, sigma_mps2, response, car_sigma_mps2, car_response)
    p = N_PARAMS
    return {first_group + e: (g[e, :p, :p], g[e, :p, p]) for e in range(3)}


def band_split_signals(x: np.ndarray, rate_hz: float, band_edges_hz: Sequence[float]
                       ) -> np.ndarray:
    """Signals split into frequency bands along their last (time) axis.

    Parameters
    ----------
    x : ndarray (..., n)
        Signals sampled at ``rate_hz``.
    rate_hz : float
    band_edges_hz : sequence of float
        Increasing edges; band ``j`` is ``[edge_j, edge_j+1)`` (circular FFT over ``n``).

    Returns
    -------
    ndarray (n_bands, ..., n)
        The parts; they sum to ``x`` when the edges span 0 to inf.
    """
    n = x.shape[-1]
    f = np.fft.rfftfreq(n, 1.0 / rate_hz)
    band = np.searchsorted(np.asarray(band_edges_hz, float), f, side="right") - 1
    spec = np.fft.rfft(x, axis=-1)
    return np.stack([np.fft.irfft(np.where(band == j, spec, 0.0), n, axis=-1)
                     for j in range(len(band_edges_hz) - 1)])


def band_split(d: DriveRegressors, band_edges_hz: Sequence[float]) -> list[DriveRegressors]:
    """The drive's regressor signals split into frequency bands (``[edge_j, edge_j+1)``,
    circular FFT over the drive, :func:`band_split_signals`); they sum to the drive. Only
    what :func:`equation_rows` reads is split."""
    names = ("qdd", "r", "rd", "a_long", "a_lat")
    parts = {k: band_split_signals(getattr(d, k), d.rate_hz, band_edges_hz) for k in names}
    return [replace(d, **{k: v[j] for k, v in parts.items()})
            for j in range(len(band_edges_hz) - 1)]


def block_grams(d: DriveRegressors, block_samples: int, pairs: bool = False
                ) -> tuple[np.ndarray, np.ndarray]:
    """Gram matrices ``[A, b]^T [A, b]`` of each equation over consecutive time blocks.

    Parameters
    ----------
    d : DriveRegressors
    block_samples : int
    pairs : bool
        Also the products of different equations' rows (:data:`EQUATION_PAIRS`).

    Returns
    -------
    grams : ndarray (3 or 6, n_blocks, N_PARAMS + 1, N_PARAMS + 1)
    samples : ndarray (n_blocks,)
        Samples in each block.
    """
    a, b = equation_rows(d)
    aug = np.concatenate([a, b[..., None]], axis=2)  # (3, n, P + 1)
    bs = max(1, int(block_samples))
    starts = np.arange(0, d.n, bs)
    which = EQUATION_PAIRS if pairs else EQUATION_PAIRS[:3]
    left = [g for g, _ in which]
    right = [h for _, h in which]
    full = d.n // bs
    blocks = aug[:, : full * bs].reshape(3, full, bs, aug.shape[2])
    out = np.empty((len(which), starts.size, aug.shape[2], aug.shape[2]))
    out[:, :full] = np.matmul(blocks[left].transpose(0, 1, 3, 2), blocks[right])
    if starts.size > full:  # the last, shorter block
        seg = aug[:, full * bs:]
        out[:, full] = np.matmul(seg[left].transpose(0, 2, 1), seg[right])
    return out, np.diff(np.append(starts, d.n))


#: Pairs of equations (heave 0, pitch 1, roll 2) whose products :func:`block_grams` and
#: :func:`noise_gram` give with ``pairs=True``: the three squares, then the cross products.
EQUATION_PAIRS = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))


@dataclass
class DriveNoise:
    """The expected share of the sensors' noise in one drive's Gram matrices, per band.

    Attributes
    ----------
    known : ndarray (3 or 6, n_bands, N_PARAMS + 1, N_PARAMS + 1)
        From the body sensors (noise measured from their redundancy) and the car
        acceleration signals (:func:`noise_gram`), per equation (and pair of equations,
        :data:`EQUATION_PAIRS`).
    hub_unit : ndarray (n_components, 3 or 6, n_bands, N_PARAMS + 1, N_PARAMS + 1)
        From the four hub sensors, per unit of each component of their noise covariance in
        each band: component 0 the variance of each hub (white noise with the same density
        in the band, independent hubs), component 1 (if given) a covariance common to the
        left and right hub of each axle (the road's two tracks are alike, so is what they
        put into the hubs), component 2 (if given) one common to the front and rear hub
        of each side (the rear wheel runs on the front's track).
    hub_s2 : ndarray (n_components, n_bands)
        The hub noise's components [m^2/s^4]: the start of the estimate, or the values used
        when it is not estimated.
    """

    known: np.ndarray
    hub_unit: np.ndarray
    hub_s2: np.ndarray


def compensated_least_squares(grams: Sequence[np.ndarray], samples: Sequence[np.ndarray],
                              fitted: np.ndarray,
                              noise: Sequence[DriveNoise] | None = None,
                              band_grams: Sequence[np.ndarray] | None = None,
                              hub_iterations: int = 0, jackknife: bool = True,
                              bias_correction: bool = False,
                              normal_covariance: bool = False) -> WlsResult:
    """Noise-compensated weighted least squares over drives given as block Gram matrices,
    optionally estimating the hub sensors' noise spectrum from the equation errors, with a
    delete-a-block jackknife covariance that repeats the whole estimate.

    The normal equations are ``sum_g w_g^2 (G_g - N_g)`` over the equation groups (three
    per drive): ``G_g`` the Gram matrix of the rows ``[A, b]``, ``N_g`` the noise's
    expected share in it (errors in variables: subtracted, bias-compensated least
    squares), ``w_g`` one over the group's residual std (two rounds, as
    :func:`weighted_least_squares`).

    Hub noise (``hub_iterations > 0``): the equation errors ``[theta, -1] G [theta, -1]^T``
    of a model that fits hold only noise; in each band ``j`` their energy is the known
    share plus the hub covariance's components (``DriveNoise.hub_unit``: each hub's
    variance, optionally left-right and front-rear covariances) times their unit shares,
    so the components follow per drive by least squares over its three equations (and the
    cross products of equations, if ``band_grams`` has them), relative misfits, variance
    >= 0, |covariance| <= variance; theta and the components are iterated (fixed point).
    Whatever the hub channels carry that is not motion (aliased high-frequency
    acceleration, electronics noise) is compensated so, white or not. The jackknife
    repeats this in every replicate.

    Parameters
    ----------
    grams : sequence of ndarray (3, n_blocks, P + 1, P + 1)
        Per drive, :func:`block_grams`.
    samples : sequence of ndarray (n_blocks,)
        Per drive, the samples in each block.
    fitted : ndarray of bool (P,)
        Columns to fit (the others are held at 0).
    noise : sequence of DriveNoise or None
        Per drive; None: no compensation.
    band_grams : sequence of ndarray (3 or 6, n_blocks, n_bands, P + 1, P + 1) or None
        Per drive, :func:`block_grams` of :func:`band_split` (needed for the hub noise;
        6: with the cross products of equations, then ``DriveNoise`` must have them).
    hub_iterations : int
        Rounds of the hub-noise fixed point (0: ``DriveNoise.hub_s2`` used as given).
    jackknife : bool
        Compute the covariance (else zero, or see ``normal_covariance``).
    bias_correction : bool
        Subtract the jackknife's estimate of the estimator's bias.
    normal_covariance : bool
        Without the jackknife: the inverse of the final weighted, compensated normal
        matrix as the covariance (right for residuals white in time with the groups'
        variances; too small for band-passed residuals: for screening, not reporting).

    Returns
    -------
    WlsResult
        With ``hub_noise_s2`` (drives, components, bands) when there is noise.
    """
    p = fitted.size
    cols = np.flatnonzero(fitted)
    idx = np.append(cols, p)
    tot = sum(g.sum(axis=(0, 1)) for g in grams)
    scale = np.sqrt(np.diag(tot))[cols]
    scale[scale == 0] = 1.0
    dsc = np.append(1.0 / scale, 1.0)
    sc = np.outer(dsc, dsc)

    def sub(m: np.ndarray) -> np.ndarray:
        return m[..., idx[:, None], idx[None, :]] * sc

    gb = [sub(g) for g in grams]
    gfull = [g.sum(axis=1) for g in gb]
    n_tot = [float(np.sum(s)) for s in samples]
    if noise is not None:
        known = [sub(nz.known) for nz in noise]
        hub = [sub(nz.hub_unit) for nz in noise]
        s2_0 = [np.asarray(nz.hub_s2, float).copy() for nz in noise]
    estimate = noise is not None and hub_iterations > 0 and band_grams is not None
    if estimate:
        bgb = [sub(g) for g in band_grams]
        bfull = [g.sum(axis=1) for g in bgb]
    k_dr = len(gb)
    m = cols.size

    def normal(gf: list[np.ndarray], frac: list[float], s2: list[np.ndarray],
               w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        lhs = np.zeros((m, m))
        rhs = np.zeros(m)
        for k in range(k_dr):
            c = gf[k]
            if noise is not None:
                c = c - frac[k] * (known[k][:3].sum(axis=1)
                                   + np.einsum("cj,cejpq->epq", s2[k], hub[k][:, :3]))
            lhs += np.einsum("e,epq->pq", w[k] ** 2, c[:, :m, :m])
            rhs += np.einsum("e,ep->p", w[k] ** 2, c[:, :m, m])
        return lhs, rhs

    def solve(gf: list[np.ndarray], frac: list[float], s2: list[np.ndarray],
              w: np.ndarray) -> np.ndarray:
        return np.linalg.solve(*normal(gf, frac, s2, w))

    def hub_update(th: np.ndarray, bf: list[np.ndarray], frac: list[float]
                   ) -> list[np.ndarray]:
        z = np.append(th, -1.0)
        out = []
        for k in range(k_dr):
            ne = bf[k].shape[0]  # 3 squares, or with the 3 cross products
            e_act = np.einsum("p,ejpq,q->ej", z, bf[k], z)
            e_p = frac[k] * np.einsum("p,ejpq,q->ej", z, known[k][:ne], z)
            e_q = frac[k] * np.einsum("p,cejpq,q->cej", z, hub[k][:, :ne], z)
            sq = np.maximum(e_act[:3], 1e-300)
            # relative misfit of each product: over sqrt(E_gg E_hh)
            wgt = 1.0 / np.sqrt(np.array([sq[g] * sq[h] for g, h in EQUATION_PAIRS[:ne]]))
            coef = np.zeros((e_q.shape[0], e_q.shape[2]))
            for j in range(coef.shape[1]):
                sol = np.linalg.lstsq((e_q[:, :, j] * wgt[:, j]).T,
                                      (e_act[:, j] - e_p[:, j]) * wgt[:, j], rcond=None)[0]
                var = max(float(sol[0]), 0.0)
                coef[0, j] = var
                coef[1:, j] = np.clip(sol[1:], -var, var)  # |correlation| <= 1
            out.append(coef)
        return out

    def estimate_theta(gf: list[np.ndarray], bf: list[np.ndarray] | None, frac: list[float],
                       s2: list[np.ndarray], w: np.ndarray, rounds: int
                       ) -> tuple[np.ndarray, list[np.ndarray]]:
        th = solve(gf, frac, s2, w)
        for _ in range(rounds if estimate else 0):
            s2 = hub_update(th, bf, frac)
            th = solve(gf, frac, s2, w)
        return th, s2

    ones = [1.0] * k_dr
    s2 = s2_0 if noise is not None else [np.zeros(1)] * k_dr
    w = np.ones((k_dr, 3))
    th, s2 = estimate_theta(gfull, bfull if estimate else None, ones, s2, w, hub_iterations)
    sigma = np.ones((k_dr, 3))
    for _ in range(2):  # residuals -> per-equation weights -> fit again
        z = np.append(th, -1.0)
        for k in range(k_dr):
            ms = np.einsum("p,epq,q->e", z, gfull[k], z) / max(n_tot[k], 1.0)
            sigma[k] = np.sqrt(np.maximum(ms, 1e-300))
        w = 1.0 / sigma
        th, s2 = estimate_theta(gfull, bfull if estimate else None, ones, s2, w,
                                hub_iterations)
    reps = []
    if jackknife:
        for k in range(k_dr):
            for i in range(gb[k].shape[1]):
                gf = list(gfull)
                gf[k] = gfull[k] - gb[k][:, i]
                bf = None
                if estimate:
                    bf = list(bfull)
                    bf[k] = bfull[k] - bgb[k][:, i]
                frac = list(ones)
                frac[k] = 1.0 - float(samples[k][i]) / n_tot[k]
                reps.append(estimate_theta(gf, bf, frac, [x.copy() for x in s2], w,
                                           max(1, hub_iterations // 2))[0])
    nb = len(reps)
    cov_s = np.zeros((m, m))
    if nb > 1:
        reps_a = np.array(reps)
        mean_rep = reps_a.mean(axis=0)
        if bias_correction:
            th = th - (nb - 1) * (mean_rep - th)
        dev = reps_a - mean_rep
        cov_s = (nb - 1) / nb * dev.T @ dev
    elif normal_covariance and not jackknife:
        cov_s = np.linalg.pinv(normal(gfull, ones, s2, w)[0])
    theta = np.full(p, np.nan)
    theta[cols] = th / scale
    cov = np.zeros((p, p))
    cov[np.ix_(cols, cols)] = cov_s / np.outer(scale, scale)
    return WlsResult(theta, cov, np.asarray(fitted, bool), sigma.ravel(), int(nb),
                     hub_noise_s2=None if noise is None else np.array(s2))
