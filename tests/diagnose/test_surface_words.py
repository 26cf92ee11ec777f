"""The force surface's shape in words (fielddiag.diagnose.surface_words)."""

from __future__ import annotations

import numpy as np
import pytest

from fielddiag.diagnose.surface_words import describe_force_surface, describe_memory_surface
from fielddiag.effects.force_surface import ForceSurface

R = np.linspace(-0.03, 0.03, 201)
V = np.linspace(-0.4, 0.4, 201)[::-1]


@pytest.mark.parametrize("term, a, words", [
    ("travel3", 50.0, "the spring stiffens away from the ride height at both ends (by 7.5e+03 "
                      "N/m at 20 mm of travel)"),
    ("travel3", -50.0, "the spring softens away"),
    ("speed3", 40.0, "the damping rises with speed in both directions (by 600 N s/m at 0.2"),
    ("speed2", -30.0, "the damping is stronger in compression"),
    ("travel2_speed", 160.0, "the damping grows with travel away from the ride height, in "
                             "both directions (by 800 N s/m at 20 mm of travel)"),
    ("travel2", 20.0, "the spring is stiffer toward rebound (extension)"),
    ("travel_speed", -10.0, "stronger on the compression side"),
    ("travel_speed2", 10.0, "the spring force depends on speed"),
])
def test_each_term_is_told_with_its_size(term, a, words):
    told = describe_force_surface({f"surface_{term}_n": a}, R, V)
    assert len(told) == 1 and words in told[0], told


def test_the_terms_that_carry_the_force_are_told_strongest_first():
    told = describe_force_surface({"surface_travel2_speed_n": 160.0, "surface_speed3_n": 200.0,
                                   "surface_travel2_n": 0.5}, R, V, unit="N/kg")
    assert len(told) == 2  # the 0.5 N term carries < 25 % of the strongest's force
    assert told[0].startswith("the damping rises with speed")  # larger over these speeds
    assert "N/kg s/m" in told[0] and "damping grows with travel" in told[1]


def test_a_flat_surface_says_nothing():
    assert describe_force_surface({p.name: 0.0 for p in ForceSurface.params}, R, V) == []


def test_the_surface_force_is_the_sum_of_its_terms():
    e = ForceSurface(*np.arange(1.0, 8.0))
    r, v = np.array([0.01, -0.02]), np.array([0.1, 0.3])
    q, w = r / 0.02, v / 0.2
    expect = -(1 * q**2 + 2 * q * w + 3 * w**2 + 4 * q**3 + 5 * q**2 * w + 6 * q * w**2
               + 7 * w**3)
    np.testing.assert_allclose(e.force(r, v, np.zeros(2), e.value_vector())[0], expect,
                               rtol=1e-12)
    assert not ForceSurface.names_physics and not ForceSurface.diagnosable


@pytest.mark.parametrize("coefficients, damping, words", [
    # a_speed 300 N at 0.2 m/s: +-1500 N s/m about the mean damping 2000 -> 500 just after a
    # reversal, 3500 later: 86 % weaker; lost in sum over the first memory travel, 2 mm
    ({"memory_loop_speed_n": 300.0, "memory_travel_m": 2e-3}, 2000.0,
     "the damping is 86 % weaker for about the first 2 mm after each reversal of the motion "
     "(500 against 3.5e+03 N s/m later in the stroke): as free play in the damper's "
     "mounting"),
    # more than the mean damping: none left after a reversal
    ({"memory_loop_speed_n": 500.0, "memory_travel_m": 1e-3}, 2000.0,
     "the damping all but vanishes for about the first 1 mm after each reversal of the "
     "motion (4.5e+03 N s/m later in the stroke)"),
    ({"memory_loop_speed_n": -100.0, "memory_travel_m": 2e-3}, None,
     "the damping is 1e+03 N s/m stronger for about the first 2 mm"),
    # a loop 2 x 40 N high; travel amplitude sqrt(2) x std(R) = 24.62 mm: 4 x 40 N x 24.62 mm
    ({"memory_loop_n": 40.0, "memory_travel_m": 1e-3}, None,
     "a hysteresis loop 80 N high that closes over about 1 mm after each reversal (3.94 J "
     "per cycle of +-25 mm)"),
    ({"memory_loop_travel_n": -25.0, "memory_travel_m": 1e-3}, None,
     "50 N higher per 20 mm toward compression"),
])
def test_a_force_with_memory_is_told_by_its_terms(coefficients, damping, words):
    told = describe_memory_surface(coefficients, R, V, damping=damping)
    assert len(told) == 1 and words in told[0], told


def test_a_memory_with_no_force_says_nothing():
    assert describe_memory_surface({"memory_travel_m": 2e-3}, R, V) == []
