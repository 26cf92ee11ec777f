"""On-line estimator: convergence to the off-line fit, speed, information, advice, plumbing."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

from drivers.base import Block
from fielddiag.channels import ChannelSpec
from fielddiag.cli import main
from fielddiag.errors import ChannelNotFoundError
from fielddiag.identify.greybox import GreyBoxData, fit_greybox
from fielddiag.identify.online import (
    OnlineEstimator,
    advice_line,
    convergence_time,
    replay,
)
from fielddiag.identify.terms import linear_model
from fielddiag.sim import QuarterCarParams, SensorModel, simulate
from fielddiag.simio import drive_to_session

# a car unlike the prior (typical values of a 380 kg corner): 60 % stiffer per kg
CAR = QuarterCarParams(body_mass_kg=300.0, suspension_stiffness_n_per_m=30e3,
                       suspension_damping_ns_per_m=2500.0)
TRUTH = {"linear_spring.suspension_stiffness_n_per_m": 100.0,
         "linear_damper.suspension_damping_ns_per_m": 2500.0 / 300.0}


@pytest.fixture(scope="module")
def drive():
    return simulate(CAR, duration_s=60.0, road_class="C", seed=3,
                    sensor=SensorModel(noise_std_mps2=0.05))


def test_converges_to_the_offline_fit_faster_than_real_time(drive) -> None:
    offline = fit_greybox(GreyBoxData.from_drive(drive), linear_model())
    est = OnlineEstimator(drive.sample_rate_hz).warm_up()
    t0 = time.perf_counter()
    snaps = replay(est, drive.time_s, drive.wheel_accel_mps2, drive.body_accel_mps2,
                   block_s=0.1, every_s=1.0)
    wall = time.perf_counter() - t0
    data_s = drive.time_s.size / drive.sample_rate_hz
    assert data_s / wall >= 20.0  # whole replay, Python overhead per 0.1 s block included
    final = {p["key"]: p["value"] for p in snaps[-1]["parameters"]}
    for k, v in offline.per_unit_mass.items():
        assert final[k] == pytest.approx(v, rel=0.05)
        assert final[k] == pytest.approx(TRUTH[k], rel=0.02)
    t_conv = convergence_time(snaps, offline.per_unit_mass, 0.05)
    assert t_conv is not None and t_conv <= 15.0
    assert snaps[-1]["enough_data"]
    assert snaps[-1]["advice"].startswith("enough data: stiffness ±")
    # the information grows as the drive goes on
    bits = np.array([[p["information_bits"] for p in s["parameters"]] for s in snaps[2:]])
    assert np.all(bits[-1] > bits[0]) and np.all(bits[-1] > 5.0)
    json.dumps(snaps[-1])  # JSON-ready


def test_standard_deviations_cover_the_truth() -> None:
    z = []
    for seed in range(6):
        d = simulate(CAR, duration_s=25.0, road_class="C", seed=40 + seed,
                     sensor=SensorModel(noise_std_mps2=0.05))
        st = replay(OnlineEstimator(d.sample_rate_hz), d.time_s, d.wheel_accel_mps2,
                    d.body_accel_mps2, every_s=100.0)[-1]
        for p in st["parameters"]:
            z.append((p["value"] - TRUTH[p["key"]]) / p["std"])
    assert np.max(np.abs(z)) < 3.5, z


def test_no_excitation_is_not_observable_then_a_rough_road_is() -> None:
    """Standing still (noise only) gives no usable information, whatever the filter's
    covariance says; a rough road afterwards gives enough."""
    still = simulate(CAR, duration_s=15.0, road_class=None, seed=5,
                     sensor=SensorModel(noise_std_mps2=0.05))
    rough = simulate(CAR, duration_s=30.0, road_class="C", seed=6,
                     sensor=SensorModel(noise_std_mps2=0.05))
    est = OnlineEstimator(still.sample_rate_hz)
    st = replay(est, still.time_s, still.wheel_accel_mps2, still.body_accel_mps2,
                every_s=100.0)[-1]
    assert st["explained_fraction"] < 0.2
    assert all(p["state"] == "not observable" for p in st["parameters"])
    assert not st["enough_data"]
    assert "not enough road excitation" in st["advice"]
    t = rough.time_s + still.time_s[-1] + 1.0 / rough.sample_rate_hz
    st = replay(est, t, rough.wheel_accel_mps2, rough.body_accel_mps2, every_s=100.0)[-1]
    assert st["explained_fraction"] > 0.9
    assert st["enough_data"] and st["advice"].startswith("enough data")
    vals = {p["key"]: p["value"] for p in st["parameters"]}
    for k, v in TRUTH.items():
        assert vals[k] == pytest.approx(v, rel=0.05)


def test_advice_line_names_the_parameter_and_the_manoeuvre() -> None:
    def entry(label: str, rel: float, state: str, advice: str) -> dict:
        return {"label": label, "rel_std_pct": rel, "target_rel_std_pct": 5.0, "state": state,
                "advice": advice}

    stiff = entry("stiffness", 2.0, "ok", "drive over undulations")
    damp = entry("damping", 60.0, "not observable", "drive over sharper bumps")
    assert advice_line([stiff, damp], enough=False) == (
        "damping is not yet observable: drive over sharper bumps")
    damp = entry("damping", 8.0, "converging", "drive over sharper bumps")
    assert advice_line([stiff, damp], enough=False).startswith("damping ±8.0 % (goal ±5.0 %)")
    damp = entry("damping", 4.6, "ok", "drive over sharper bumps")
    assert advice_line([stiff, damp], enough=True) == (
        "enough data: stiffness ±2.0 %, damping ±4.6 %")
    assert advice_line([stiff], enough=False, started=False).startswith("waiting")


def test_block_listener_matches_update_and_survives_gaps(drive) -> None:
    n = drive.time_s.size
    cut = slice(10000, 10500)  # 1 s of samples lost
    keep = np.ones(n, bool)
    keep[cut] = False
    t = drive.time_s[keep]
    aw = drive.wheel_accel_mps2[keep]
    ab = drive.body_accel_mps2[keep]
    channels = [ChannelSpec("body_z", role="body"), ChannelSpec("speed", role="other"),
                ChannelSpec("wheel_z", role="wheel")]
    a = OnlineEstimator(drive.sample_rate_hz)
    listener = a.block_listener(channels)
    b = OnlineEstimator(drive.sample_rate_hz)
    for i in range(0, t.size, 64):
        j = min(t.size, i + 64)
        samples = np.column_stack([ab[i:j], np.zeros(j - i), aw[i:j]])
        listener(Block(time_s=t[i:j], samples=samples))
        b.update(t[i:j], aw[i:j], ab[i:j])
    assert a.estimates() == b.estimates()
    for k, v in a.estimates().items():
        assert np.isfinite(v) and v == pytest.approx(TRUTH[k], rel=0.02)
    with pytest.raises(ChannelNotFoundError, match="role 'wheel'"):
        a.block_listener([ChannelSpec("body_z", role="body")])


def test_cli_track(tmp_path, capsys, drive) -> None:
    path = drive_to_session(drive, tmp_path / "drive.h5")
    out = tmp_path / "track.json"
    assert main(["track", str(path), "--every", "10", "--compare", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "advice: enough data" in text and "x real time" in text
    assert "within 5 % of the off-line fit after" in text
    report = json.loads(out.read_text())
    assert len(report["snapshots"]) == 6
    assert report["time_to_converge_s"] is not None and report["time_to_converge_s"] <= 20.0
    assert main(["track", str(tmp_path / "nope.h5")]) == 1
