"""Full-vehicle per-corner diagnosis benchmark (not a test: it prints figures).

Method: ``--n`` random cars of each kind from ``--seed``
(:func:`fielddiag.vehicle.random_vehicle`: mass 1000-1900 kg, corner stiffness and
damping within +-8 % of their axle's, body sensors up to 0.3 m from the struts), each
driven twice on an ISO 8608 class C rough road (``--duration`` s at 500 Hz, accelerometer
noise 0.01-0.05 m/s^2 rms), the second time with 80-250 kg added at a random place
(x 30-90 % of the wheelbase, y +-0.4 m). Three kinds of car:

* worn damper: one random corner's damping set to 0.7 x its axle partner's (30 % weaker);
  right when a ``left_right_mismatch`` finding names that corner with ``quantity`` damping
  (its ratio is printed);
* effect: one random corner gets one effect of the library: dry friction 50-150 N
  (smoothing 5-20 mm/s), a progressive spring (cubic term adding 10-30 % stiffness at
  3 cm), a bump stop (gap 8-15 mm beyond the loaded car's sag at that corner, stiffness
  1.5-3 x the spring's) or an asymmetric damper (compression 0.5-0.7 x, rebound 1.3-1.5 x
  the corner's damping); right when the first effect finding names that effect at that
  corner (a finding at another corner, or a mismatch, is counted as a false finding);
* linear: no change; a false alarm is any finding.

:func:`fielddiag.vehicle.diagnose.diagnose_vehicle` with its defaults. Then the wall time
of :func:`identify_vehicle` + :func:`diagnose_vehicle` of two 180 s drives at 500 Hz read
from session files (median of ``--repeat``).

Usage: ``python benchmarks/bench_vehicle_diagnose.py [--seed 1] [--n 10] [--duration 90]``
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from fielddiag.channels import CORNERS
from fielddiag.effects import make_effect
from fielddiag.vehicle import random_vehicle, read_vehicle_recording, simulate_vehicle
from fielddiag.vehicle.diagnose import _static_sag_m, diagnose_vehicle
from fielddiag.vehicle.identify import identify_vehicle
from fielddiag.vehicle.regression import DriveRegressors

PARTNER = {"fl": "fr", "fr": "fl", "rl": "rr", "rr": "rl"}
EFFECTS = ("coulomb_friction", "cubic_stiffness", "bump_stop", "asymmetric_damping")


def _sag(car, dm: float, at: tuple[float, float]) -> np.ndarray:
    g = car.geometry
    d = DriveRegressors(np.zeros((3, 1)), np.zeros((4, 1)), np.zeros((4, 1)), np.zeros(1),
                        np.zeros(1), np.zeros((4, 1)), g.corner_x_m, g.corner_y_m,
                        g.sensor_matrix(), dm, at, 100.0)
    th = np.zeros(18)
    th[6:10] = [car.corner(c).stiffness_n_per_m for c in CORNERS]
    th[14], th[15] = car.anti_roll_stiffness_front_n_per_m, car.anti_roll_stiffness_rear_n_per_m
    return _static_sag_m(th, d)


def _effect(name: str, car, corner: str, sag_m: float, rng: np.random.Generator):
    k = car.corner(corner).stiffness_n_per_m
    c = car.corner(corner).damping_ns_per_m
    u = rng.uniform
    if name == "coulomb_friction":
        return make_effect(name, friction_force_n=u(50, 150), smoothing_velocity_mps=u(0.005, 0.02))
    if name == "cubic_stiffness":
        return make_effect(name, cubic_stiffness_n_per_m3=u(0.1, 0.3) * k / 0.03**2)
    if name == "bump_stop":
        return make_effect(name, gap_m=abs(sag_m) + u(0.008, 0.015),
                           stiffness_n_per_m=u(1.5, 3) * k)
    return make_effect(name, compression_damping_ns_per_m=u(0.5, 0.7) * c,
                       rebound_damping_ns_per_m=u(1.3, 1.5) * c)


def _case(kind: str, i: int, seed: int, duration: float) -> dict:
    rng = np.random.default_rng([seed, i, {"worn": 0, "effect": 1, "linear": 2}[kind]])
    car = random_vehicle(rng)
    wb = car.geometry.wheelbase_m
    dm = float(rng.uniform(80, 250))
    at = (float(rng.uniform(0.3, 0.9) * wb), float(rng.uniform(-0.4, 0.4)))
    noise = float(rng.uniform(0.01, 0.05))
    corner = str(rng.choice(CORNERS))
    effects, truth = None, {}
    if kind == "worn":
        car = car.with_corner(corner, damping_ns_per_m=0.7 * car.corner(
            PARTNER[corner]).damping_ns_per_m)
        truth = {"corner": corner}
    elif kind == "effect":
        name = str(rng.choice(EFFECTS))
        sag = _sag(car, dm, at)[CORNERS.index(corner)]
        eff = _effect(name, car, corner, sag, rng)
        effects = {corner: [eff]}
        truth = {"corner": corner, "effect": name, "parameters": eff.to_dict()}
    s1, s2 = (int(v) for v in rng.integers(0, 2**31, 2))
    before = simulate_vehicle(car, duration_s=duration, seed=s1, effects=effects,
                              accel_noise_std_mps2=noise)
    after = simulate_vehicle(car, duration_s=duration, seed=s2, effects=effects,
                             accel_noise_std_mps2=noise, added_mass_kg=dm, added_mass_at_m=at)
    t0 = time.perf_counter()
    out = diagnose_vehicle(before, after, dm, at).to_dict()
    wall = time.perf_counter() - t0
    found = [(f["effect"], f.get("corner") or f.get("axle"), f["parameters"])
             for f in out["findings"]]
    row = {"kind": kind, "case": i, "truth": truth, "wall_s": wall,
           "findings": [(e, p) for e, p, _ in found]}
    if kind == "worn":
        mm = [f for f in found if f[0] == "left_right_mismatch"
              and f[2]["quantity"] == "damping" and f[1] == corner]
        row["right"] = bool(mm)
        row["ratio"] = mm[0][2]["ratio"] if mm else None
        row["false"] = len(found) - len(mm)
    elif kind == "effect":
        eff_found = [f for f in found if f[0] != "left_right_mismatch"]
        row["right"] = bool(eff_found) and eff_found[0][:2] == (truth["effect"], corner)
        row["corner_right"] = bool(eff_found) and eff_found[0][1] == corner
        row["false"] = len(found) - int(row["right"])
        if row["right"]:
            row["fitted"] = eff_found[0][2]
    else:
        row["right"] = not found
        row["false"] = len(found)
    return row


def _timing(duration: float, repeat: int) -> list[float]:
    car = random_vehicle(2024)
    at = (0.7 * car.geometry.wheelbase_m, 0.2)
    from fielddiag.vehicle.writer import write_vehicle_session

    times = []
    with tempfile.TemporaryDirectory() as tmp:
        b = write_vehicle_session(simulate_vehicle(car, duration_s=duration, seed=1),
                                  Path(tmp) / "b.h5")
        a = write_vehicle_session(simulate_vehicle(car, duration_s=duration, seed=2,
                                                   added_mass_kg=150.0, added_mass_at_m=at),
                                  Path(tmp) / "a.h5")
        for _ in range(repeat):
            t0 = time.perf_counter()
            rb = read_vehicle_recording(b, label="before")
            ra = read_vehicle_recording(a, label="after")
            identify_vehicle(rb, ra, 150.0, at)
            diagnose_vehicle(rb, ra, 150.0, at)
            times.append(time.perf_counter() - t0)
    return times


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--n", type=int, default=10, help="cars of each kind")
    ap.add_argument("--duration", type=float, default=90.0, help="drive length [s]")
    ap.add_argument("--timing-duration", type=float, default=180.0)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--json", help="write the rows")
    args = ap.parse_args()
    print(__doc__.split("Usage:")[0])
    print(f"seed {args.seed}, {args.n} cars of each kind, {args.duration:g} s drives\n")
    rows = []
    for kind in ("worn", "effect", "linear"):
        for i in range(args.n):
            r = _case(kind, i, args.seed, args.duration)
            rows.append(r)
            print(f"  {kind:6s} {i:2d} truth {r['truth'].get('effect', '')}"
                  f"@{r['truth'].get('corner', '-')}: found {r['findings']} "
                  f"{'OK' if r['right'] else 'WRONG'} ({r['wall_s']:.1f} s)", flush=True)
    worn = [r for r in rows if r["kind"] == "worn"]
    eff = [r for r in rows if r["kind"] == "effect"]
    lin = [r for r in rows if r["kind"] == "linear"]
    ratios = [r["ratio"] for r in worn if r["ratio"] is not None]
    print("\nresults")
    print(f"  worn damper (30 % weaker) attributed to the right corner: "
          f"{100 * np.mean([r['right'] for r in worn]):.0f} % ({sum(r['right'] for r in worn)}"
          f"/{len(worn)}); ratio median {np.median(ratios) if ratios else float('nan'):.3f}"
          f" (range {min(ratios, default=float('nan')):.3f}-"
          f"{max(ratios, default=float('nan')):.3f}); other findings on these cars: "
          f"{sum(r['false'] for r in worn)}")
    print(f"  effect and corner both right: {100 * np.mean([r['right'] for r in eff]):.0f} % "
          f"({sum(r['right'] for r in eff)}/{len(eff)}); corner right: "
          f"{100 * np.mean([r['corner_right'] for r in eff]):.0f} %; extra findings: "
          f"{sum(r['false'] for r in eff)}")
    for name in EFFECTS:
        sub = [r for r in eff if r["truth"]["effect"] == name]
        if sub:
            print(f"    {name:20s} {sum(r['right'] for r in sub)}/{len(sub)}")
    print(f"  false alarms on linear cars: {sum(not r['right'] for r in lin)}/{len(lin)} cars "
          f"({sum(r['false'] for r in lin)} findings)")
    print(f"  diagnosis wall time per pair of {args.duration:g} s drives: median "
          f"{np.median([r['wall_s'] for r in rows]):.1f} s")
    times = _timing(args.timing_duration, args.repeat)
    print(f"  identify + diagnose of two {args.timing_duration:g} s drives at 500 Hz (sessions "
          f"read from disk): median {np.median(times):.1f} s, runs "
          + ", ".join(f"{t:.1f}" for t in times) + " s (target < 30 s)")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1, default=str))


if __name__ == "__main__":
    main()
