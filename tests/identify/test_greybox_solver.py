"""fielddiag.identify.greybox_solver: the bounded Levenberg-Marquardt and the HAC covariance.

* Rosenbrock as least squares, r = [10 (x2 - x1^2), 1 - x1]: minimum 0 at (1, 1); with
  x1 <= 0.5 the constrained minimum is (0.5, 0.25) (x2 = x1^2 zeroes the first residual,
  the second falls as x1 grows).
* y = A exp(-t / tau): noise-free data give the parameters back; with tau bounded below
  its true value the fit stops at the bound, flagged active.
* For a linear model y = X beta + e the least-squares covariance is sigma^2 (X^T X)^-1
  with white e; with AR(1) e (coefficient phi) the variance of a mean is the white one
  times (1 + phi) / (1 - phi), which HAC must find.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import optimize

from fielddiag.identify.greybox_solver import (
    hac_covariance,
    levenberg_marquardt,
    scipy_trf,
    solve,
)

INF = np.array([np.inf, np.inf])


def _rosenbrock(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    r = np.array([10 * (x[1] - x[0] ** 2), 1 - x[0]])
    j = np.array([[-20 * x[0], 10.0], [-1.0, 0.0]])
    return r, j


def test_rosenbrock_unbounded_reaches_the_minimum():
    out = levenberg_marquardt(_rosenbrock, np.array([-1.2, 1.0]), -INF, INF,
                              max_iterations=200, xtol=1e-12, ftol=1e-14)
    assert out.converged, out.message
    np.testing.assert_allclose(out.x, [1.0, 1.0], atol=1e-6)
    assert out.cost < 1e-12
    assert not out.active.any()
    # accepted steps only lower the cost
    assert all(b <= a for a, b in zip(out.cost_history, out.cost_history[1:], strict=False))
    assert out.cost_history[0] == pytest.approx(0.5 * (4.4**2 + 2.2**2))  # at (-1.2, 1)


def test_rosenbrock_bounded_stops_at_the_bound():
    lower = np.array([-2.0, -2.0])
    upper = np.array([0.5, 2.0])
    out = levenberg_marquardt(_rosenbrock, np.array([-1.2, 1.0]), lower, upper,
                              max_iterations=200, xtol=1e-12, ftol=1e-14)
    np.testing.assert_allclose(out.x, [0.5, 0.25], atol=1e-6)
    assert out.cost == pytest.approx(0.5 * 0.25, rel=1e-6)  # r = [0, 0.5]
    assert out.active.tolist() == [True, False]
    assert np.all(out.x <= upper) and np.all(out.x >= lower)


def _exp_problem(a_true: float, tau_true: float, noise: float, seed: int):
    t = np.linspace(0.0, 5.0, 200)
    y = a_true * np.exp(-t / tau_true)
    y = y + noise * np.random.default_rng(seed).standard_normal(t.size)

    def fun(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        a, tau = p
        e = np.exp(-t / tau)
        r = a * e - y
        j = np.column_stack([e, a * e * t / tau**2])
        return r, j

    return t, y, fun


def test_exponential_fit_recovers_parameters_and_respects_bounds():
    _, _, fun = _exp_problem(2.0, 0.8, 0.0, 0)
    lower, upper = np.array([0.0, 0.05]), np.array([10.0, 10.0])
    out = levenberg_marquardt(fun, np.array([1.0, 3.0]), lower, upper, max_iterations=100)
    np.testing.assert_allclose(out.x, [2.0, 0.8], rtol=1e-6)
    assert out.converged
    # tau held below its true value: the fit sits on the bound and says so
    upper2 = np.array([10.0, 0.5])
    out2 = levenberg_marquardt(fun, np.array([1.0, 0.3]), lower, upper2, max_iterations=100)
    assert out2.x[1] == pytest.approx(0.5, abs=1e-12)
    assert out2.active.tolist() == [False, True]
    # the amplitude is then the least-squares one for tau = 0.5 (a linear problem)
    t = np.linspace(0.0, 5.0, 200)
    e = np.exp(-t / 0.5)
    y = 2.0 * np.exp(-t / 0.8)
    assert out2.x[0] == pytest.approx(float(e @ y / (e @ e)), rel=1e-6)


def test_noisy_exponential_fit_matches_scipy():
    """Same minimum as scipy.optimize.least_squares (the estimate of a noisy problem), to
    1e-6 relative with tight tolerances (with the default ftol = 1e-8 the two differ by a
    few 1e-6, far below the estimate's own sd of ~0.5 %)."""
    t, y, fun = _exp_problem(2.0, 0.8, 0.05, 1)
    lower, upper = np.array([0.0, 0.05]), np.array([10.0, 10.0])
    ours = levenberg_marquardt(fun, np.array([1.0, 3.0]), lower, upper, max_iterations=100,
                               xtol=1e-12, ftol=1e-12)
    ref = optimize.least_squares(lambda p: fun(p)[0], [1.0, 3.0], jac=lambda p: fun(p)[1],
                                 bounds=(lower, upper), xtol=1e-12, ftol=1e-12)
    np.testing.assert_allclose(ours.x, ref.x, rtol=1e-6)
    via_trf = solve("trf", fun, np.array([1.0, 3.0]), lower, upper, max_iterations=100)
    np.testing.assert_allclose(via_trf.x, ref.x, rtol=1e-5)
    assert scipy_trf(fun, np.array([1.0, 3.0]), lower, upper).cost == pytest.approx(
        ours.cost, rel=1e-6)
    with pytest.raises(ValueError, match="unknown solver"):
        solve("newton", fun, np.array([1.0, 3.0]), lower, upper)


def test_diverging_model_stops_with_a_message():
    def fun(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return np.array([np.nan]), np.array([[1.0]])

    out = levenberg_marquardt(fun, np.array([1.0]), -np.inf * np.ones(1), np.inf * np.ones(1))
    assert not out.converged
    assert "diverged" in out.message


def test_a_point_every_step_from_which_diverges_stops_within_a_few_evaluations():
    """Finite at the start, non-finite at every other point (a model that blows up as soon
    as it moves): each trial is rejected and the damping grows until the step vanishes;
    the solver stops there, at the start, with no step tolerance, bounded or not, rather
    than running to its iteration limit."""
    x0 = np.array([1.0, 2.0])

    def fun(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r = np.array([1.0, -0.5]) if np.array_equal(x, x0) else np.array([np.inf, 0.0])
        return r, np.array([[1.0, 0.2], [0.1, 1.0]])

    for lower, upper in ((-INF, INF), (np.zeros(2), np.full(2, 10.0))):
        out = levenberg_marquardt(fun, x0, lower, upper, max_iterations=200, xtol=0.0)
        np.testing.assert_array_equal(out.x, x0)
        assert out.cost == pytest.approx(0.625)
        assert out.evaluations <= 14
        assert out.message == "no further reduction possible"


def test_hac_equals_the_ols_covariance_for_white_residuals():
    """Regressors [1, t, sin]; white residuals of sd 0.5: HAC and the white formula both
    estimate sigma^2 (X^T X)^-1. The white formula uses the sample variance exactly; HAC
    adds a few lags of sample autocovariance, each with sd ~sigma^2/sqrt(n): with n = 8000
    and L <= ~10 lags, within 15 %."""
    n, sigma = 8000, 0.5
    t = np.linspace(0.0, 1.0, n)
    x = np.column_stack([np.ones(n), t, np.sin(2 * np.pi * 7 * t)])
    e = sigma * np.random.default_rng(2).standard_normal(n)
    cov, info = hac_covariance(x, e)
    analytic = sigma**2 * np.linalg.inv(x.T @ x)
    white = info["white_covariance"]
    np.testing.assert_allclose(white, np.var(e) * np.linalg.inv(x.T @ x), rtol=1e-9)
    np.testing.assert_allclose(np.diag(white), np.diag(analytic), rtol=0.05)  # sd 1.6 %
    np.testing.assert_allclose(np.diag(cov), np.diag(analytic), rtol=0.15)
    assert info["lag_window_samples"] <= 10


def test_hac_finds_the_long_run_variance_of_ar1_residuals():
    """AR(1) with phi = 0.6: var(mean) = sigma_e^2 / n * (1 + phi) / (1 - phi) = 4 x the
    white value. Sampling error of a lag-window estimate with L ~ 20 of n = 40000: ~5 %."""
    n, phi = 40000, 0.6
    rng = np.random.default_rng(3)
    e = np.zeros(n)
    w = rng.standard_normal(n)
    for i in range(1, n):
        e[i] = phi * e[i - 1] + w[i]
    jac = np.ones((n, 1))
    cov, info = hac_covariance(jac, e)
    ratio = cov[0, 0] / info["white_covariance"][0, 0]
    assert ratio == pytest.approx((1 + phi) / (1 - phi), rel=0.15)
    assert info["lag_window_samples"] >= 5  # rho^L falls under 2 sqrt(log10(n)/n) at L ~ 8


@pytest.mark.parametrize("method", ["lm", "trf"])
def test_a_parameter_whose_bounds_meet_is_held_and_the_rest_fitted(method):
    # the data may resolve no range of a parameter (its resolved upper bound at its lower
    # one): both optimisers need an open box, and one such parameter raised "Each lower
    # bound must be strictly less than each upper bound" out of a whole diagnosis (seed
    # 1795936923 of the randomized benchmark)
    _, _, fun = _exp_problem(2.0, 0.8, 0.0, 0)
    lower, upper = np.array([0.0, 0.5]), np.array([10.0, 0.5])
    out = solve(method, fun, np.array([1.0, 0.3]), lower, upper, max_iterations=100)
    assert out.x[1] == 0.5 and out.active.tolist() == [False, True]
    # the amplitude is the least-squares one for tau = 0.5, as with tau held by the gradient
    t = np.linspace(0.0, 5.0, 200)
    e = np.exp(-t / 0.5)
    y = 2.0 * np.exp(-t / 0.8)
    assert out.x[0] == pytest.approx(float(e @ y / (e @ e)), rel=1e-5)
    # the Jacobian keeps both columns (the covariance needs them)
    assert out.jacobian.shape == (200, 2)
    np.testing.assert_allclose(out.jacobian, fun(out.x)[1])
    # every parameter held: one evaluation, nothing to fit
    both = solve(method, fun, np.array([1.0, 0.3]), np.array([2.0, 0.5]),
                 np.array([2.0, 0.5]))
    assert both.x.tolist() == [2.0, 0.5] and both.evaluations == 1 and both.active.all()


def test_a_trial_point_whose_jacobian_overflows_is_rejected():
    """Residuals finite and lower everywhere past x = 2, but the Jacobian there overflows
    (a bump stop's exponential far beyond its gap): LAPACK's least squares and SVD loop
    for ever on such values (seed 1795948194 hung the diagnosis for 20 minutes), so the
    trial must be rejected like a worse point, and the solver end at a finite Jacobian."""

    def fun(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r = np.array([3.0 - x[0]])
        j = np.array([[-1.0]]) if x[0] <= 2.0 else np.array([[np.inf]])
        return r, j

    out = levenberg_marquardt(fun, np.array([0.0]), np.array([-10.0]), np.array([10.0]),
                              max_iterations=200)
    assert np.all(np.isfinite(out.jacobian))
    assert out.x[0] <= 2.0
    assert out.cost >= 0.5 - 1e-9
