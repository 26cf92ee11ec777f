"""Force-term library: composition, derivatives, agreement with the simulator."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numba import njit

from fielddiag.errors import FieldDiagError
from fielddiag.identify.terms import (
    TERMS,
    AsymmetricDamping,
    BumpStop,
    CoulombFriction,
    CouplingSpring,
    CubicStiffness,
    ForceModel,
    LinearDamper,
    LinearSpring,
    ParamSpec,
    Term,
    make_term,
    model_from_sim,
)
from fielddiag.sim import QuarterCarParams, make_effect, suspension_force_n

ALL = LinearSpring() + LinearDamper() + CouplingSpring() + CoulombFriction() + CubicStiffness() \
    + BumpStop() + AsymmetricDamping()


@njit(cache=True)
def _quadratic_damping(r, rd, x2, p, c, dp):  # pragma: no cover - compiled
    dp[0] = -rd * abs(rd)
    return -p[0] * rd * abs(rd), 0.0, -2.0 * p[0] * abs(rd), 0.0


class QuadraticDamping(Term):
    """A new effect defined outside the library: one small class."""

    name = "quadratic_damping"
    params = (ParamSpec("damping_ns2_per_m2", "N s^2/m^2", 0.0, math.inf, 500.0, True,
                        "quadratic damping", "drive over sharp bumps"),)
    kernel = _quadratic_damping


def _states(rng: np.random.Generator, n: int = 200) -> tuple[np.ndarray, ...]:
    # travel within +-8 cm (bump stop gap 6 cm is crossed), rates within +-0.8 m/s
    return rng.uniform(-0.08, 0.08, n), rng.uniform(-0.8, 0.8, n), rng.uniform(-0.05, 0.05, n)


def test_composition_like_a_feature_library() -> None:
    m = LinearSpring() + LinearDamper() + CoulombFriction()
    assert isinstance(m, ForceModel)
    assert m.param_keys == ("linear_spring.suspension_stiffness_n_per_m",
                            "linear_damper.suspension_damping_ns_per_m",
                            "coulomb_friction.friction_force_n",
                            "coulomb_friction.smoothing_velocity_mps")
    assert sum([LinearSpring(), LinearDamper()]) == LinearSpring() + LinearDamper()
    # asymmetric damping replaces the linear damper, in either order
    for m2 in (LinearSpring() + LinearDamper() + AsymmetricDamping(),
               AsymmetricDamping() + LinearSpring() + LinearDamper()):
        assert "linear_damper" not in m2 and "asymmetric_damping" in m2
    with pytest.raises(FieldDiagError, match="twice"):
        LinearSpring() + LinearSpring()
    with pytest.raises(FieldDiagError, match="unknown model term"):
        make_term("magic_spring")
    with pytest.raises(FieldDiagError, match="no setting"):
        CoulombFriction(smoothing_speed=0.1)
    assert m.index("friction_force_n") == 2
    assert m.index("friction_force_n_per_kg") == 2
    with pytest.raises(FieldDiagError, match="no parameter"):
        m.index("gap_m")
    assert ForceModel.from_dict(ALL.to_dict()) == ALL
    assert set(TERMS) >= {"coulomb_friction", "cubic_stiffness", "bump_stop",
                          "asymmetric_damping"}


def test_parameter_names_units_and_bounds() -> None:
    names = {p.name: p for p in ALL.specs}
    for name in ("friction_force_n", "cubic_stiffness_n_per_m3", "gap_m", "stiffness_n_per_m",
                 "compression_damping_ns_per_m", "rebound_damping_ns_per_m",
                 "suspension_stiffness_n_per_m", "coupling_stiffness_n_per_m"):
        assert name in names
    assert names["friction_force_n"].lower == 0 and names["gap_m"].lower == 0
    assert names["suspension_stiffness_n_per_m"].lower == 0
    assert names["coupling_stiffness_n_per_m"].lower == -math.inf  # may be negative
    assert not names["gap_m"].scales_with_force
    assert names["friction_force_n"].per_unit_mass_name() == "friction_force_n_per_kg"


def test_derivatives_match_central_differences(rng: np.random.Generator) -> None:
    model = ALL + QuadraticDamping()
    theta = model.vector()
    r, rd, x2 = _states(rng)
    # keep away from the kink of the asymmetric damper at rdot = 0
    rd = np.where(np.abs(rd) < 1e-3, 1e-3, rd)
    f, ds, dp = model.force(r, rd, x2, theta)
    for k, arr in enumerate((r, rd, x2)):
        h = 1e-7
        args_p = [r, rd, x2]
        args_m = [r, rd, x2]
        args_p[k] = arr + h
        args_m[k] = arr - h
        fd = (model.force(*args_p, theta)[0] - model.force(*args_m, theta)[0]) / (2 * h)
        scale = np.abs(ds[:, k]) + 1e-3 * np.max(np.abs(ds[:, k])) + 1e-9
        assert np.all(np.abs(fd - ds[:, k]) / scale < 1e-4), k
    for j in range(model.n_params):
        h = 1e-6 * max(abs(theta[j]), 1e-3)
        tp, tm = theta.copy(), theta.copy()
        tp[j] += h
        tm[j] -= h
        fd = (model.force(r, rd, x2, tp)[0] - model.force(r, rd, x2, tm)[0]) / (2 * h)
        # plus the round-off of the difference quotient (forces of ~1e3 N over a small h)
        roundoff = 1e4 * np.finfo(float).eps * (np.abs(f) + 1.0) / h
        scale = np.abs(dp[:, j]) + 1e-6 * np.max(np.abs(dp[:, j])) + 1e-12 + roundoff
        assert np.all(np.abs(fd - dp[:, j]) / scale < 1e-4), model.param_keys[j]


def test_force_equals_simulator_force(rng: np.random.Generator) -> None:
    p = QuarterCarParams()
    effects = [make_effect("coulomb_friction", friction_force_n=90.0),
               make_effect("cubic_stiffness", cubic_stiffness_n_per_m3=2e6),
               make_effect("asymmetric_damping", compression_damping_ns_per_m=1100,
                           rebound_damping_ns_per_m=2500)]
    model, values = model_from_sim(p, effects)
    r, rd, _ = _states(rng)
    ours = model.force(r, rd, np.zeros_like(r), values)[0]
    theirs = suspension_force_n(r, rd, p, effects)
    np.testing.assert_allclose(ours, theirs, rtol=1e-12, atol=1e-9)
    # bump stop: the model rounds the hinge by a softplus of width w; the difference is
    # at most kb * w * ln 2 (at the hinge) and vanishes away from it
    bump = [make_effect("bump_stop", gap_m=0.03, stiffness_n_per_m=2e5)]
    model, values = model_from_sim(p, bump)
    ours = model.force(r, rd, 0.0, values)[0]
    theirs = suspension_force_n(r, rd, p, bump)
    w = BumpStop().settings["width_m"]
    assert np.max(np.abs(ours - theirs)) <= 2e5 * w * math.log(2) * (1 + 1e-9)
    far = np.abs(-r - 0.03) > 20 * w
    np.testing.assert_allclose(ours[far], theirs[far], rtol=1e-9, atol=1e-6)


def test_per_unit_mass_homogeneity(rng: np.random.Generator) -> None:
    """Scaling every force-scaled parameter by c scales the force by c (per-unit-mass fit)."""
    theta = ALL.vector()
    r, rd, x2 = _states(rng)
    c = 1.0 / 380.0
    scaled = np.where(ALL.force_scaled, theta * c, theta)
    np.testing.assert_allclose(ALL.force(r, rd, x2, scaled)[0],
                               c * ALL.force(r, rd, x2, theta)[0], rtol=1e-12, atol=1e-12)


def test_new_effect_is_one_small_class(rng: np.random.Generator) -> None:
    model = LinearSpring() + LinearDamper() + QuadraticDamping()
    r, rd, x2 = _states(rng)
    f = model.force(r, rd, x2, {"damping_ns2_per_m2": 300.0})[0]
    expected = -24e3 * r - 1.8e3 * rd - 300.0 * rd * np.abs(rd)
    np.testing.assert_allclose(f, expected, rtol=1e-12, atol=1e-9)


def test_kernels_compile_in_memory_without_a_cache_directory(monkeypatch,
                                                             rng: np.random.Generator) -> None:
    """FIELDDIAG_KERNEL_CACHE="" (or an unwritable cache) compiles per process instead."""
    from fielddiag.effects import compose as terms

    monkeypatch.setenv("FIELDDIAG_KERNEL_CACHE", "")
    monkeypatch.setattr(terms, "_BOUND_CACHE", {})
    model = QuadraticDamping() + LinearSpring()
    r, rd, x2 = _states(rng, 20)
    f = model.force(r, rd, x2, {"damping_ns2_per_m2": 300.0})[0]
    np.testing.assert_allclose(f, -24e3 * r - 300.0 * rd * np.abs(rd), rtol=1e-12, atol=1e-9)
    assert not type(terms._BOUND_CACHE[next(iter(terms._BOUND_CACHE))]).__name__ == "module"
