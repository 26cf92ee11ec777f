"""Output-error refinement of the full-vehicle parameters (after the least-squares fit).

The body (heave, pitch, roll) is *simulated*, driven by the measured hub motion and the
car's accelerations, and the parameters are adjusted (scipy ``least_squares``, trust region)
so that the simulated body accelerations match the measured ones. Unlike the equation-error
least squares, the regressors are then not measured (noise in them does not bias the
estimate), but the fit is nonlinear and needs the least-squares start.

The model is the linear one of :mod:`fielddiag.vehicle.regression`; for each drive it is a
linear state-space system (states ``q, q'``; inputs the four hub displacements and
velocities, ``a_long``, ``a_lat``), discretised with a first-order hold at the analysis
rate (the inputs are linear between samples) and run by a small numba loop. The covariance
is the block sandwich of the Gauss-Newton Jacobian.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy import optimize, signal

from fielddiag.vehicle.regression import N_PARAMS, DriveRegressors, WlsResult, mass_matrix

__all__ = ["OutputErrorResult", "refine_output_error", "simulate_body_accel"]

#: Seconds dropped at the start of each simulated drive (the start from rest).
SETTLE_S = 3.0


@njit(cache=True, nogil=True)
def _dsim(ad, bd, cd, dd, u):  # pragma: no cover - compiled
    n = u.shape[0]
    nx = ad.shape[0]
    ny = cd.shape[0]
    x = np.zeros(nx)
    xn = np.empty(nx)
    y = np.empty((n, ny))
    for k in range(n):
        for i in range(ny):
            s = 0.0
            for j in range(nx):
                s += cd[i, j] * x[j]
            for j in range(u.shape[1]):
                s += dd[i, j] * u[k, j]
            y[k, i] = s
        for i in range(nx):
            s = 0.0
            for j in range(nx):
                s += ad[i, j] * x[j]
            for j in range(u.shape[1]):
                s += bd[i, j] * u[k, j]
            xn[i] = s
        for i in range(nx):
            x[i] = xn[i]
    return y


def _state_space(theta: np.ndarray, d: DriveRegressors):
    th = np.nan_to_num(theta)
    lev = np.column_stack([np.ones(4), d.corner_x, d.corner_y])  # (4, 3)
    k, c = th[6:10], th[10:14]
    kq = (lev.T * k) @ lev
    cq = (lev.T * c) @ lev
    kw = lev.T * k  # (3, 4)
    cw = lev.T * c
    for kb, (a, b) in ((th[14], (0, 1)), (th[15], (2, 3))):
        dv = lev[a] - lev[b]
        kq = kq + kb * np.outer(dv, dv)
        kw[:, a] += kb * dv
        kw[:, b] -= kb * dv
    e = np.zeros((3, 2))
    e[1, 0], e[2, 1] = -th[16], th[17]
    minv = np.linalg.inv(mass_matrix(th, d.added_mass_kg, d.added_mass_at_m))
    a = np.block([[np.zeros((3, 3)), np.eye(3)], [-minv @ kq, -minv @ cq]])
    b = np.vstack([np.zeros((3, 10)), minv @ np.hstack([kw, cw, e])])
    cm = d.sensor_matrix @ np.hstack([-minv @ kq, -minv @ cq])
    dm = d.sensor_matrix @ minv @ np.hstack([kw, cw, e])
    return a, b, cm, dm


def simulate_body_accel(theta: np.ndarray, d: DriveRegressors) -> np.ndarray:
    """The body sensors' accelerations simulated from the hub motion (4, n) [m/s^2]."""
    a, b, cm, dm = _state_space(theta, d)
    ad, bd, cd, dd, _ = signal.cont2discrete((a, b, cm, dm), 1.0 / d.rate_hz, method="foh")
    u = np.column_stack([d.wheel_disp.T, d.wheel_vel.T, d.a_long, d.a_lat])
    return _dsim(ad, bd, cd, dd, np.ascontiguousarray(u)).T


@dataclass
class OutputErrorResult:
    """The refined estimate and how well each start simulates."""

    wls: WlsResult
    nrmse: float
    nrmse_start: float
    success: bool


def _residuals(theta_free, theta0, free, drives, skip, scale):
    th = theta0.copy()
    th[free] = theta_free * scale
    out = []
    for d in drives:
        y = simulate_body_accel(th, d)[:, skip:]
        m = d.body_accel[:, skip:]
        out.append(((y - m) / np.sqrt(np.mean(m * m))).ravel())
    return np.concatenate(out)


def refine_output_error(start: WlsResult, drives: Sequence[DriveRegressors],
                        block_s: float = 2.0) -> OutputErrorResult:
    """Refine a least-squares estimate by output error on the same drives.

    Parameters
    ----------
    start : WlsResult
        The least-squares estimate (start values; unfitted parameters stay out).
    drives : sequence of DriveRegressors
        The identification drives (with their added masses).
    block_s : float
        Time block of the sandwich covariance [s].

    Returns
    -------
    OutputErrorResult
        The refined estimate (theta, covariance) and the simulation NRMSE before/after.
    """
    free = np.flatnonzero(start.fitted)
    theta0 = np.nan_to_num(start.theta)
    scale = np.where(np.abs(theta0[free]) > 0, np.abs(theta0[free]), 1.0)
    skip = int(round(SETTLE_S * drives[0].rate_hz))
    r0 = _residuals(theta0[free] / scale, theta0, free, drives, skip, scale)
    sol = optimize.least_squares(_residuals, theta0[free] / scale, method="trf", x_scale=1.0,
                                 args=(theta0, free, drives, skip, scale), max_nfev=8,
                                 diff_step=1e-4)
    theta = theta0.copy()
    theta[free] = sol.x * scale
    jac = sol.jac / scale  # d residual / d theta
    e = sol.fun
    # residual rows: drive, sensor, sample; blocks of block_s within each drive
    block_ids = []
    base = 0
    for d in drives:
        n = d.n - skip
        per = max(1, int(round(block_s * d.rate_hz)))
        t_blk = np.arange(n) // per
        block_ids.append(np.tile(t_blk, 4) + base)
        base += int(t_blk.max()) + 1
    blocks = np.concatenate(block_ids)
    gsum = np.zeros((base, free.size))
    np.add.at(gsum, blocks, jac * e[:, None])
    meat = gsum.T @ gsum * base / max(base - 1, 1)
    bread = np.linalg.pinv(jac.T @ jac)
    cov = np.zeros((N_PARAMS, N_PARAMS))
    cov[np.ix_(free, free)] = bread @ meat @ bread
    th_full = np.full(N_PARAMS, np.nan)
    th_full[free] = theta[free]
    nrmse = float(np.sqrt(np.mean(e**2)))
    return OutputErrorResult(
        WlsResult(th_full, cov, start.fitted.copy(), start.group_sigma, int(base)),
        nrmse=nrmse, nrmse_start=float(np.sqrt(np.mean(r0**2))), success=bool(sol.success))
