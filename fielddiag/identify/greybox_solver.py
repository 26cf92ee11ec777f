"""The optimiser of the grey-box fit and the covariance of its estimate.

Levenberg-Marquardt with bounds on residuals and Jacobian computed together (the
sensitivity equations give both in one simulation), and the sandwich covariance for
coloured residuals (HAC).

Why a hand-written LM and not ``scipy.optimize.least_squares`` (measured by
``benchmarks/bench_greybox_solver.py``, 2026-11-25, shared 2-core machine at load ~9): on
the 18 fits a diagnosis makes for six catalogue scenarios (linear and true-effect models,
before/after pairs, continuation as in the diagnosis), with the *same* analytic Jacobian,
both reach the same minimum (least_squares' final cost within 1.2e-9 relative of ours,
held-out NRMSE equal to 4 digits), but least_squares(trf) needs more simulations (median
16 vs 13; 12-14 vs 7-9 on every linear fit) and more time (median 3.5-3.7 s vs 2.7-2.9 s
per fit, total 67.8 s vs 62.6 s). The LM therefore stays the default of
:func:`fielddiag.identify.greybox.fit_greybox`; :func:`scipy_trf` runs the same problem
through scipy (``fit_greybox(..., solver="trf")``) for comparison.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from scipy import linalg, optimize, signal

__all__ = ["LMOutcome", "hac_covariance", "levenberg_marquardt", "scipy_trf", "solve"]




@dataclass
class LMOutcome:
    """What :func:`levenberg_marquardt` returns.

    Parameters
    ----------
    x : ndarray
        The solution (the fitted vector, in its own units).
    residual : ndarray
        Residuals at ``x``.
    jacobian : ndarray
        Jacobian of the residuals at ``x``.
    cost : float
        ``0.5 |residual|^2``.
    iterations, evaluations : int
        Iterations and evaluations of ``fun``.
    converged : bool
        A tolerance was met (rather than the iteration limit).
    message : str
        Why it stopped.
    cost_history : list of float
        Cost after each accepted step (the start first).
    active : ndarray of bool
        Parameters held at a bound by the gradient.
    """

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

    Parameters
    ----------
    fun : callable
        ``fun(x) -> (r, J)``: residuals ``(m,)`` and Jacobian ``(m, n)``.
    x0 : ndarray
        Start ``(n,)`` (clipped into the bounds).
    lower, upper : ndarray
        Bounds ``(n,)`` (``-inf``/``inf`` for none).
    max_iterations : int
        Largest number of accepted or rejected iterations.
    xtol, ftol, gtol : float
        Relative step, relative cost decrease and scaled gradient tolerances.
    callback : callable or None
        ``callback(iteration, x, cost)`` after each accepted step.

    Returns
    -------
    LMOutcome
        The solution, its residuals, Jacobian and cost, the counts, whether it converged
        (and why it stopped), the cost history and the parameters held at a bound.
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
        if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
            # an overflowing Jacobian or damping: LAPACK's least squares would loop on the
            # non-finite values (numpy's lstsq never returns), so the fit ends here
            message = ("stopped: the step could not be computed (the Jacobian or its "
                       "damping overflowed)")
            it -= 1
            break
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
        # a trial point whose residual or Jacobian overflows is rejected like a worse one
        finite = bool(np.all(np.isfinite(r_new)) and np.all(np.isfinite(jac_new)))
        cost_new = 0.5 * float(r_new @ r_new) if finite else math.inf
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


def scipy_trf(
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
    """The same problem as :func:`levenberg_marquardt` solved by
    ``scipy.optimize.least_squares(method="trf")`` with the analytic Jacobian.

    ``fun(x) -> (r, J)`` gives both at once; the Jacobian of the last evaluated point is
    kept for scipy's ``jac`` call. ``max_iterations`` bounds the evaluations of ``fun``.

    Parameters
    ----------
    fun : callable
        ``fun(x) -> (r, J)``.
    x0 : ndarray
        Start (clipped into the bounds).
    lower, upper : ndarray
        Bounds (``-inf``/``inf`` for none).
    max_iterations : int
        Largest number of evaluations of ``fun`` (scipy's ``max_nfev``).
    xtol, ftol, gtol : float
        scipy's tolerances.
    callback : callable or None
        ``callback(iteration, x, cost)`` at each Jacobian evaluation.

    Returns
    -------
    LMOutcome
    """
    last: dict[str, Any] = {}
    history: list[float] = []
    count = [0]

    def evaluate(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if "x" not in last or not np.array_equal(last["x"], x):
            r, j = fun(x)
            count[0] += 1
            last.update(x=np.array(x, copy=True), r=r, j=j)
        return last["r"], last["j"]

    def f(x: np.ndarray) -> np.ndarray:
        r = evaluate(x)[0]
        return r if np.all(np.isfinite(r)) else np.full_like(r, np.inf)

    def jac(x: np.ndarray) -> np.ndarray:
        j = evaluate(x)[1]
        c = 0.5 * float(last["r"] @ last["r"])
        history.append(c)
        if callback is not None:
            callback(len(history) - 1, np.array(x, copy=True), c)
        return j

    x0 = np.clip(np.asarray(x0, float), lower, upper)
    bounds = (lower, upper) if (np.any(np.isfinite(lower)) or np.any(np.isfinite(upper))) \
        else (-np.inf, np.inf)
    sol = optimize.least_squares(f, x0, jac=jac, bounds=bounds, method="trf", x_scale=1.0,
                                 xtol=xtol, ftol=ftol, gtol=gtol, max_nfev=max_iterations)
    r, j = evaluate(sol.x)
    g = j.T @ r
    active = ((sol.x <= lower) & (g > 0)) | ((sol.x >= upper) & (g < 0))
    return LMOutcome(sol.x, r, j, 0.5 * float(r @ r), max(len(history) - 1, 0), count[0],
                     bool(sol.status > 0), str(sol.message), history, active)


def solve(method: str, fun: Any, x0: np.ndarray, lower: np.ndarray, upper: np.ndarray,
          **kw: Any) -> LMOutcome:
    """Run the named optimiser (``"lm"``: :func:`levenberg_marquardt`; ``"trf"``:
    :func:`scipy_trf`) with the arguments of :func:`levenberg_marquardt`.

    A parameter whose bounds meet (``lower >= upper``: the data resolve no range of it) is
    held at its lower bound and the optimiser runs on the others (both need a strictly
    open box); it is reported ``active`` and keeps its column of the Jacobian.

    Parameters
    ----------
    method : str
        ``"lm"`` or ``"trf"``.
    fun, x0, lower, upper
        As :func:`levenberg_marquardt`.
    **kw
        Its options, passed on.

    Returns
    -------
    LMOutcome

    Raises
    ------
    ValueError
        Unknown ``method`` (the callers check the user's choice first).
    """
    solvers = {"lm": levenberg_marquardt, "trf": scipy_trf}
    if method not in solvers:
        raise ValueError(f"unknown solver {method!r}; use 'lm' or 'trf'")
    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    held = ~(lower < upper)
    if not held.any():
        return solvers[method](fun, x0, lower, upper, **kw)
    x_held = np.where(held, lower, np.clip(np.asarray(x0, float), lower, upper))
    free = ~held
    # the full Jacobians of the last few points evaluated: the outcome keeps every column
    jacobians: OrderedDict[bytes, np.ndarray] = OrderedDict()

    def expand(q: np.ndarray) -> np.ndarray:
        x = x_held.copy()
        x[free] = q
        return x

    def fun_free(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r, j = fun(expand(q))
        jacobians[np.asarray(q, float).tobytes()] = j
        while len(jacobians) > 4:
            jacobians.popitem(last=False)
        return r, j[:, free]

    if not free.any():
        r, j = fun(x_held)
        cost = 0.5 * float(r @ r)
        return LMOutcome(x_held, r, j, cost, 0, 1, True,
                         "every parameter held where its bounds meet", [cost], held.copy())
    if kw.get("callback") is not None:
        user_callback = kw["callback"]
        kw["callback"] = lambda it, q, cost: user_callback(it, expand(q), cost)
    out = solvers[method](fun_free, x_held[free], lower[free], upper[free], **kw)
    jac = jacobians.get(np.asarray(out.x, float).tobytes())
    if jac is None:
        _, jac = fun(expand(out.x))
    active = held.copy()
    active[free] = out.active
    return replace(out, x=expand(out.x), jacobian=jac, active=active)


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


