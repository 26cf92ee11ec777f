"""Self-levelling cars in the simulator: ``simulate(..., ride_height_restored=True)``.

A passive car sags under the added mass by dM g / K (nearer a bump stop); a self-levelling
one carries the added weight in its levelling system, so the loaded drive moves about the
unloaded static deflection while the body mass is still M + dM.
"""

from __future__ import annotations

import numpy as np
import pytest

from fielddiag.session import SessionReader
from fielddiag.sim import (
    G_MPS2,
    QuarterCarParams,
    levelling_force_n,
    make_effect,
    simulate,
    simulate_from_dict,
    simulate_pair,
    static_state,
)
from fielddiag.simio import drive_to_session

P = QuarterCarParams()
DM = 60.0
GAP = 0.020
KB = 1.0e5
SAG = DM * G_MPS2 / P.suspension_stiffness_n_per_m  # 24.5 mm: past the 20 mm gap


@pytest.mark.parametrize("k3", [0.0, 3000.0, -2000.0])
def test_restored_static_equilibrium_keeps_the_unloaded_deflection(k3: float) -> None:
    car = QuarterCarParams(coupling_stiffness_n_per_m=k3)
    stop = make_effect("bump_stop", gap_m=GAP, stiffness_n_per_m=KB)
    for u in (0.0, 0.01):
        x1u, _, x2u, _, _ = static_state(car, [stop], 0.0, u)
        x1, v1, x2, v2, _ = static_state(car, [stop], DM, u, ride_height_restored=True)
        assert x2 - x1 == pytest.approx(x2u - x1u, abs=1e-12)
        assert v1 == v2 == 0.0
        # the tyre still carries the extra weight: the wheel sinks by L / K1
        lev = levelling_force_n(car, DM, True)
        assert x1 - x1u == pytest.approx(-lev / car.tire_stiffness_n_per_m, rel=1e-9)
    # passive: sagged onto the stop, K2 r + kb (r - gap) = dM g (k3 = 0)
    x1, _, x2, _, _ = static_state(P, [stop], DM)
    assert -(x2 - x1) == pytest.approx(
        (DM * G_MPS2 + KB * GAP) / (P.suspension_stiffness_n_per_m + KB), rel=1e-9
    )
    assert levelling_force_n(P, DM, True) == pytest.approx(DM * G_MPS2, rel=1e-12)
    assert levelling_force_n(P, DM, False) == 0.0


def test_levelled_drive_moves_about_the_unloaded_deflection() -> None:
    stop = make_effect("bump_stop", gap_m=GAP, stiffness_n_per_m=KB)
    kw = dict(duration_s=60.0, road_class="B", effects=[stop], seed=5)  # same road for all
    unloaded = simulate(P, **kw)
    passive = simulate(P, added_mass_kg=DM, **kw)
    levelled = simulate(P, added_mass_kg=DM, ride_height_restored=True, **kw)
    r_u, r_p, r_l = (d.suspension_extension_m for d in (unloaded, passive, levelled))
    # passive: about the sagged equilibrium, about dM g / K nearer the stop; the stop
    # takes part of the load (static 20.9 mm instead of 24.5 mm) and rectifies the ride
    r0_p = (DM * G_MPS2 + KB * GAP) / (P.suspension_stiffness_n_per_m + KB)
    shift = r_l.mean() - r_p.mean()
    assert 0.7 * SAG < shift < 1.05 * SAG
    assert -r_p.mean() == pytest.approx(r0_p, rel=0.2)
    # levelled: the unloaded drive's statistics (same road; the body is 16 % heavier, so
    # the spread may differ by about the change of the response, not by the sag)
    assert abs(r_l.mean() - r_u.mean()) < 0.5e-3
    assert r_l.std() == pytest.approx(r_u.std(), rel=0.15)
    on_u, on_p, on_l = (np.mean(r < -GAP) for r in (r_u, r_p, r_l))
    assert on_l < 0.01 and on_u < 0.01
    # the sagged car rests 0.9 mm past the gap with a 6 mm spread: on the stop about
    # half the time
    assert on_p > 0.3
    # the accelerometers read 1 g at rest in every drive (levelling is internal)
    for d in (unloaded, passive, levelled):
        assert np.mean(d.body_accel_mps2) == pytest.approx(G_MPS2, abs=0.01)
        assert np.mean(d.wheel_accel_mps2) == pytest.approx(G_MPS2, abs=0.01)
        assert np.mean(d.body_acc_true_mps2) == pytest.approx(0.0, abs=0.01)


def test_linear_levelled_car_no_sag_and_truth_recorded(tmp_path) -> None:
    before, after = simulate_pair(
        P, added_mass_kg=DM, seed=3, duration_s=30.0, ride_height_restored=True
    )
    _, passive = simulate_pair(P, added_mass_kg=DM, seed=3, duration_s=30.0)
    assert abs(after.suspension_extension_m.mean()) < 0.5e-3
    assert passive.suspension_extension_m.mean() == pytest.approx(-SAG, abs=0.5e-3)
    assert after.ride_height_restored and not passive.ride_height_restored
    meta = after.to_dict()
    assert meta["ride_height_restored"] is True
    again = simulate_from_dict(meta)
    np.testing.assert_array_equal(again.body_accel_mps2, after.body_accel_mps2)
    path = drive_to_session(after, tmp_path / "after.h5")
    with SessionReader(path) as s:
        assert s.metadata.extra["simulation"]["ride_height_restored"] is True
        assert s.metadata.added_mass_kg == DM
