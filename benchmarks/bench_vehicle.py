"""Full-vehicle identification benchmark (not a test: it prints figures).

Method: N randomized linear cars (:func:`fielddiag.vehicle.random_vehicle` from ``--seed``:
mass 1000-1900 kg, wheelbase 2.4-3.0 m, body frequencies 1.1-1.8 Hz, damping ratio
0.2-0.4, anti-roll bars 30-80 % of the corner stiffness, body sensors up to 0.3 m from the
struts). For each: a rough-road drive as it is and one with a random added mass (80-250
kg at a random place: x 30-90 % of the wheelbase, y +-0.4 m), ``--duration`` s each, at a
random rate (``--rates``, default 500/1000 Hz), ISO 8608 road B or C, left/right correlation 0-0.6,
accelerometer noise 0.01-0.05 m/s^2 rms, car-acceleration noise 0.05 m/s^2; and a
validate drive (braking or ramp steer, 60 s). :func:`fielddiag.vehicle.identify_vehicle`
identifies the pair and cross-validates. Printed per quantity: the error distribution
(median and 95th percentile of |error|), the fraction within the issue's budget (mass 3 %,
CoG 2 cm, inertias 10 %, corner K 5 %, C 15 %, anti-roll 20 %) and the coverage: the
fraction of cases where +-2 std (and +-3 std) covers the error (~95 % wanted). Then the wall
time of the identification of two 180 s drives at 500 Hz (reading two session files
included), median of 3.

Usage: ``python benchmarks/bench_vehicle.py [--seed 1] [--n 30] [--duration 180] [--json OUT]``
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from fielddiag.vehicle import random_vehicle, read_vehicle_recording, simulate_vehicle
from fielddiag.vehicle.identify import VehicleIdentifyConfig, identify_vehicle
from fielddiag.vehicle.writer import write_vehicle_session

BUDGET = {"sprung_mass_kg": ("rel", 0.03), "cog_behind_front_axle_m": ("abs", 0.02),
          "cog_left_of_centre_m": ("abs", 0.02), "pitch_inertia_kgm2": ("rel", 0.10),
          "roll_inertia_kgm2": ("rel", 0.10), "stiffness_n_per_m": ("rel", 0.05),
          "damping_ns_per_m": ("rel", 0.15), "anti_roll_stiffness_front_n_per_m": ("rel", 0.20),
          "anti_roll_stiffness_rear_n_per_m": ("rel", 0.20)}


#: Sample rates drawn (``--rates``).
RATES = [500.0, 1000.0]


def _truth_flat(truth: dict) -> dict[str, float]:
    out = {k: v for k, v in truth.items() if k != "corners"}
    for c, d in truth["corners"].items():
        for k, v in d.items():
            out[f"corner_{c}_{k}"] = v
    return out


def _budget(name: str) -> tuple[str, float]:
    for key, b in BUDGET.items():
        if name.endswith(key):
            return b
    raise KeyError(name)


def one_case(seed: int, duration_s: float,
             config: VehicleIdentifyConfig | None = None) -> dict:
    """Simulate and identify one random car; errors and z-scores per quantity."""
    rng = np.random.default_rng(seed)
    car = random_vehicle(rng)
    wb = car.geometry.wheelbase_m
    rate = float(rng.choice(RATES))
    road = str(rng.choice(["B", "C"]))
    noise = float(rng.uniform(0.01, 0.05))
    corr = float(rng.uniform(0.0, 0.6))
    dm = float(rng.uniform(80.0, 250.0))
    at = (float(rng.uniform(0.3, 0.9) * wb), float(rng.uniform(-0.4, 0.4)))
    common = dict(sample_rate_hz=rate, road_class=road, accel_noise_std_mps2=noise,
                  track_correlation=corr)
    seeds = rng.integers(0, 2**31, 3)
    before = simulate_vehicle(car, duration_s=duration_s, seed=int(seeds[0]), **common)
    after = simulate_vehicle(car, duration_s=duration_s, seed=int(seeds[1]), added_mass_kg=dm,
                             added_mass_at_m=at, **common)
    man = "braking" if seed % 2 else "ramp_steer"
    val = simulate_vehicle(car, duration_s=60.0, seed=int(seeds[2]), manoeuvre=man, **common)
    val.name = man
    t0 = time.perf_counter()
    res = identify_vehicle(before, after, dm, at, validate=[val],
                           config=config or VehicleIdentifyConfig())
    elapsed = time.perf_counter() - t0
    truth = _truth_flat(car.truth())
    rows = {}
    for name, est in res.flat().items():
        kind, _ = _budget(name)
        t = truth[name]
        err = est.value - t
        rows[name] = {"err": err / t if kind == "rel" else err, "z": err / est.std,
                      "std": est.std / abs(t) if kind == "rel" else est.std}
    hub = res.noise.get("hub_noise_std_mps2")
    return {"seed": seed, "rate_hz": rate, "road": road, "noise": noise, "added_mass_kg": dm,
            "rows": rows, "cv_nrmse": res.cross_validation[0]["nrmse"],
            "fit_nrmse": res.fit_nrmse, "identify_s": elapsed,
            "refined": bool(res.refinement.get("applied")),
            "hub_noise_mps2": None if hub is None else float(np.median(hub)),
            "warnings": list(res.warnings)}


def timing(duration_s: float = 180.0, repeats: int = 3) -> list[float]:
    """Wall time of read + identify of two session files of ``duration_s`` at 500 Hz."""
    car = random_vehicle(7)
    out = []
    with tempfile.TemporaryDirectory() as tmp:
        b = simulate_vehicle(car, duration_s=duration_s, seed=71)
        a = simulate_vehicle(car, duration_s=duration_s, seed=72, added_mass_kg=150.0,
                             added_mass_at_m=(2.0, 0.3))
        pb = write_vehicle_session(b, Path(tmp) / "b.h5")
        pa = write_vehicle_session(a, Path(tmp) / "a.h5")
        for _ in range(repeats):
            t0 = time.perf_counter()
            identify_vehicle(read_vehicle_recording(pb), read_vehicle_recording(pa))
            out.append(time.perf_counter() - t0)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--n", type=int, default=30)
    ap.add_argument("--duration", type=float, default=180.0)
    ap.add_argument("--json", default=None)
    ap.add_argument("--refine", action="store_true", help="try the output-error refinement")
    ap.add_argument("--doubt", type=float, default=VehicleIdentifyConfig.compensation_doubt,
                    help="compensation_doubt of the identification")
    ap.add_argument("--rates", default="500,1000",
                    help="sample rates to draw from, Hz (comma-separated)")
    args = ap.parse_args()
    RATES[:] = [float(x) for x in args.rates.split(",")]
    print(__doc__.split("Usage:")[0].strip())
    print(f"\nseed {args.seed}, {args.n} cases, {args.duration:g} s drives\n")
    config = VehicleIdentifyConfig(refine=args.refine, compensation_doubt=args.doubt)
    print(f"identification settings: {config}")
    simulate_vehicle(duration_s=1.0)  # compile once
    cases = []
    t_all = time.perf_counter()
    for i in range(args.n):
        cases.append(one_case(args.seed * 100003 + i, args.duration, config))
        c = cases[-1]
        worst = max(c["rows"].items(), key=lambda kv: abs(kv[1]["z"]))
        print(f"case {i:3d}: {c['rate_hz']:5.0f} Hz road {c['road']} noise {c['noise']:.3f} "
              f"dM {c['added_mass_kg']:5.1f} kg  mass err "
              f"{100 * c['rows']['sprung_mass_kg']['err']:+.2f} %"
              f"  cv NRMSE {c['cv_nrmse']:.3f}  worst z {worst[0]} {worst[1]['z']:+.1f}  "
              f"identify {c['identify_s']:.1f} s{' (OE)' if c['refined'] else ''}"
              + (f"  hub noise {c['hub_noise_mps2']:.3f}" if c["hub_noise_mps2"] else "")
              + (f"  {len(c['warnings'])} warning(s)" if c["warnings"] else ""), flush=True)
    print(f"\n{'quantity':36s} {'median|err|':>11s} {'p95|err|':>9s} {'in budget':>9s} "
          f"{'2std cov':>8s} {'3std cov':>8s} {'med std':>8s}")
    names = list(cases[0]["rows"])
    summary = {}
    for name in names:
        kind, budget = _budget(name)
        err = np.array([abs(c["rows"][name]["err"]) for c in cases])
        z = np.array([abs(c["rows"][name]["z"]) for c in cases])
        std = np.array([c["rows"][name]["std"] for c in cases])
        unit = "%" if kind == "rel" else "cm"
        f = 100.0
        summary[name] = {"median_abs_err": float(np.median(err)),
                         "p95_abs_err": float(np.percentile(err, 95)),
                         "in_budget": float(np.mean(err <= budget)),
                         "cover_2std": float(np.mean(z <= 2)), "cover_3std": float(np.mean(z <= 3))}
        print(f"{name:36s} {f * np.median(err):9.2f}{unit:>2s} {f * np.percentile(err, 95):7.2f}"
              f"{unit:>2s} {100 * np.mean(err <= budget):8.0f}% {100 * np.mean(z <= 2):7.0f}% "
              f"{100 * np.mean(z <= 3):7.0f}% {f * np.median(std):6.2f}{unit:>2s}")
    print(f"\noutput-error refinement applied in {sum(c['refined'] for c in cases)} of "
          f"{len(cases)} cases")
    cv = np.array([c["cv_nrmse"] for c in cases])
    print(f"\ncross-validation NRMSE of the body accelerations: median {np.median(cv):.3f}, "
          f"max {cv.max():.3f}")
    med = np.median([c["identify_s"] for c in cases])
    print(f"identify per case (in memory, incl. validate drive): median {med:.1f} s; all "
          f"cases {time.perf_counter() - t_all:.0f} s")
    t = timing()
    times = ", ".join(f"{x:.2f}" for x in t)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"identify of two 180 s drives at 500 Hz from session files: {times} s "
          f"(median {np.median(t):.2f} s; load average {load:.1f})")
    if args.json:
        Path(args.json).write_text(json.dumps({"seed": args.seed, "n": args.n,
                                               "duration_s": args.duration, "summary": summary,
                                               "timing_s": t, "cases": cases}, indent=1))


if __name__ == "__main__":
    main()
