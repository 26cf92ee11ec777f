"""Full-vehicle per-corner diagnosis benchmark (not a test: it prints figures).

Method: ``--n`` random cars of each kind from ``--seed``
(:func:`fielddiag.vehicle.random_vehicle`: mass 1000-1900 kg, corner stiffness and
damping within +-8 % of their axle's, body sensors up to 0.3 m from the struts), each
driven twice on an ISO 8608 class C rough road (``--duration`` s at a rate drawn per car
from ``--rates``, default 500 Hz; the simulator's anti-alias filter, a 4-pole Butterworth
at 0.4 fs; accelerometer noise 0.01-0.05 m/s^2 rms), the second time with 80-250 kg added
at a random place (x 30-90 % of the wheelbase, y +-0.4 m). The rate is drawn from its own
stream, so a seed gives the same cars, roads and noise at any ``--rates``. Three kinds of
car:

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

The random cars' corners are within +-8 % of their axle's, so an axle's two dampers can
differ by up to ~27 % (damping also scales with the square root of the stiffness): a
``left_right_mismatch`` at a corner whose true ratio to its partner lies beyond the
diagnosis's tolerance (``mismatch_tolerance``, 20 %) is what the rule asks for; such
findings are counted apart ("true spread"), not as false.

:func:`fielddiag.vehicle.diagnose.diagnose_vehicle` with its defaults. Printed per kind:
the errors of the diagnosis's parameters against the truth (the linear model's on linear
and worn-damper cars, where it is the true model; the chosen model's on all), sprung mass
(median and largest |error|, and |error| / std), corner stiffness and damping (largest
|error| over the corners the model has). Then the wall time of :func:`identify_vehicle`
+ :func:`diagnose_vehicle` of two 180 s drives at 500 Hz read from session files (median
of ``--repeat``) with the load average (``--n 0``: the timing only).

Usage: ``python benchmarks/bench_vehicle_diagnose.py [--seed 1] [--n 10] [--duration 90]
[--rates 200]``
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from fielddiag.channels import CORNERS
from fielddiag.effects import make_effect
from fielddiag.vehicle import random_vehicle, read_vehicle_recording, simulate_vehicle
from fielddiag.vehicle.diagnose import VehicleDiagnoseConfig, _static_sag_m, diagnose_vehicle
from fielddiag.vehicle.identify import identify_vehicle
from fielddiag.vehicle.regression import DriveRegressors

PARTNER = {"fl": "fr", "fr": "fl", "rl": "rr", "rr": "rl"}
KINDS = {"worn": 0, "effect": 1, "linear": 2}
#: Sample rates drawn (``--rates``).
RATES = [500.0]
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


def _errors(model: dict, car) -> dict:
    """Relative errors of a diagnosis model (``linear_model`` / ``augmented_model``)."""
    truth = car.truth()
    mass = model["sprung_mass_kg"]
    out = {"mass_err": mass["value"] / truth["sprung_mass_kg"] - 1.0,
           "mass_z": (mass["value"] - truth["sprung_mass_kg"]) / max(mass["std"], 1e-300)}
    for q, key in (("stiffness_n_per_m", "k_err"), ("damping_ns_per_m", "c_err")):
        errs = [model["corners"][c][q]["value"] / truth["corners"][c][q] - 1.0
                for c in CORNERS if q in model["corners"][c]]
        out[key] = max(errs, key=abs) if errs else float("nan")
    return out


def simulate_case(kind: str, i: int, seed: int, duration: float) -> tuple:
    """One random case: ``(car, before, after, added_mass_kg, at_m, truth, rate_hz)``."""
    rng = np.random.default_rng([seed, i, KINDS[kind]])
    # the rate from its own stream: the same cars, roads and noise at any --rates
    rate = float(np.random.default_rng([seed, i, KINDS[kind], 1]).choice(RATES))
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
                              accel_noise_std_mps2=noise, sample_rate_hz=rate)
    after = simulate_vehicle(car, duration_s=duration, seed=s2, effects=effects,
                             accel_noise_std_mps2=noise, added_mass_kg=dm, added_mass_at_m=at,
                             sample_rate_hz=rate)
    return car, before, after, dm, at, truth, rate


def true_spread(car, tolerance: float = VehicleDiagnoseConfig.mismatch_tolerance
                ) -> set[tuple[str, str]]:
    """(corner, quantity) whose true value is below its axle partner's by more than the
    tolerance (ratio < 1 / (1 + tolerance))."""
    out = set()
    for left in ("fl", "rl"):
        right = PARTNER[left]
        for q, attr in (("damping", "damping_ns_per_m"), ("stiffness", "stiffness_n_per_m")):
            a, b = getattr(car.corner(left), attr), getattr(car.corner(right), attr)
            if min(a, b) / max(a, b) < 1.0 / (1.0 + tolerance):
                out.add((left if a < b else right, q))
    return out


def _case(kind: str, i: int, seed: int, duration: float) -> dict:
    car, before, after, dm, at, truth, rate = simulate_case(kind, i, seed, duration)
    corner = truth.get("corner")
    spread = true_spread(car) - ({(corner, "damping")} if kind == "worn" else set())
    t0 = time.perf_counter()
    out = diagnose_vehicle(before, after, dm, at).to_dict()
    wall = time.perf_counter() - t0
    found = [(f["effect"], f.get("corner") or f.get("axle"), f["parameters"])
             for f in out["findings"]]
    real = [f for f in found if f[0] == "left_right_mismatch"
            and (f[1], f[2]["quantity"]) in spread]
    found = [f for f in found if f not in real]
    row = {"kind": kind, "case": i, "rate_hz": rate, "truth": truth, "wall_s": wall,
           "findings": [(e, p) for e, p, _ in found],
           "true_spread": sorted(spread),
           "true_spread_found": [(e, p, f["quantity"], f["ratio"]) for e, p, f in real],
           "linear": _errors(out["linear_model"], car),
           "chosen": _errors(out["augmented_model"], car)}
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


def _pct(x: float) -> str:
    return f"{100 * x:+.2f} %"


def _error_lines(rows: list[dict], label: str) -> list[str]:
    """Median and largest |error| of the mass, |error| / std, the corners' largest."""
    out = []
    for model in ("linear", "chosen"):
        if model == "linear" and label == "effect":
            continue  # the linear model leaves the effect out: biased by design
        m = np.array([r[model]["mass_err"] for r in rows])
        z = np.array([r[model]["mass_z"] for r in rows])
        k = np.array([r[model]["k_err"] for r in rows])
        c = np.array([r[model]["c_err"] for r in rows])
        out.append(
            f"    {label:6s} {model:6s} model: mass error median {_pct(np.median(m))}, "
            f"|err| median {100 * np.median(np.abs(m)):.2f} % max {100 * np.max(np.abs(m)):.2f}"
            f" %, |err|/std max {np.max(np.abs(z)):.1f}; corner K |err| max "
            f"{100 * np.nanmax(np.abs(k)):.2f} %, C |err| max {100 * np.nanmax(np.abs(c)):.2f} %")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--n", type=int, default=10, help="cars of each kind (0: timing only)")
    ap.add_argument("--duration", type=float, default=90.0, help="drive length [s]")
    ap.add_argument("--rates", default="500",
                    help="sample rates to draw from per car, Hz (comma-separated)")
    ap.add_argument("--timing-duration", type=float, default=180.0)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--json", help="write the rows")
    args = ap.parse_args()
    RATES[:] = [float(x) for x in args.rates.split(",")]
    print(__doc__.split("Usage:")[0])
    print(f"seed {args.seed}, {args.n} cars of each kind, {args.duration:g} s drives at "
          f"{'/'.join(f'{r:g}' for r in RATES)} Hz\n")
    rows = []
    for kind in KINDS:
        for i in range(args.n):
            r = _case(kind, i, args.seed, args.duration)
            rows.append(r)
            e = r["chosen"]
            print(f"  {kind:6s} {i:2d} {r['rate_hz']:5.0f} Hz truth "
                  f"{r['truth'].get('effect', '')}@{r['truth'].get('corner', '-')}: found "
                  f"{r['findings']} {'OK' if r['right'] else 'WRONG'} ({r['wall_s']:.1f} s)"
                  + (f" + true spread {r['true_spread_found']}" if r["true_spread_found"]
                     else "")
                  + f"  mass {_pct(e['mass_err'])} ({e['mass_z']:+.1f} std), K {_pct(e['k_err'])}"
                  f", C {_pct(e['c_err'])}"
                  + (f" (linear model's mass {_pct(r['linear']['mass_err'])})"
                     if kind == "effect" else ""), flush=True)
    if rows:
        worn = [r for r in rows if r["kind"] == "worn"]
        eff = [r for r in rows if r["kind"] == "effect"]
        lin = [r for r in rows if r["kind"] == "linear"]
        ratios = [r["ratio"] for r in worn if r["ratio"] is not None]
        print("\nresults")
        print(f"  worn damper (30 % weaker) attributed to the right corner: "
              f"{100 * np.mean([r['right'] for r in worn]):.0f} % "
              f"({sum(r['right'] for r in worn)}/{len(worn)}); ratio median "
              f"{np.median(ratios) if ratios else float('nan'):.3f} (range "
              f"{min(ratios, default=float('nan')):.3f}-{max(ratios, default=float('nan')):.3f})"
              f"; other findings on these cars: {sum(r['false'] for r in worn)}")
        print(f"  effect and corner both right: {100 * np.mean([r['right'] for r in eff]):.0f} %"
              f" ({sum(r['right'] for r in eff)}/{len(eff)}); corner right: "
              f"{100 * np.mean([r['corner_right'] for r in eff]):.0f} %; extra findings: "
              f"{sum(r['false'] for r in eff)}")
        for name in EFFECTS:
            sub = [r for r in eff if r["truth"]["effect"] == name]
            if sub:
                print(f"    {name:20s} {sum(r['right'] for r in sub)}/{len(sub)}")
        print(f"  false alarms on linear cars: {sum(not r['right'] for r in lin)}/{len(lin)} "
              f"cars ({sum(r['false'] for r in lin)} findings)")
        spread = [(r["kind"], r["case"], f) for r in rows for f in r["true_spread_found"]]
        n_spread = sum(bool(r["true_spread"]) for r in rows)
        print(f"  cars with a true left/right spread beyond the tolerance: {n_spread}; found "
              f"as left_right_mismatch (not counted above): "
              + (", ".join(f"{k} {i} {f[1]} {f[2]} ratio {f[3]:.3f}" for k, i, f in spread)
                 or "none"))
        print("  parameter errors of the diagnosis (relative to the truth):")
        for label, sub in (("worn", worn), ("effect", eff), ("linear", lin)):
            for line in _error_lines(sub, label):
                print(line)
        print(f"  diagnosis wall time per pair of {args.duration:g} s drives: median "
              f"{np.median([r['wall_s'] for r in rows]):.1f} s")
    times = _timing(args.timing_duration, args.repeat)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"  identify + diagnose of two {args.timing_duration:g} s drives at 500 Hz (sessions "
          f"read from disk): median {np.median(times):.1f} s, runs "
          + ", ".join(f"{t:.1f}" for t in times) + f" s (target < 30 s; load average "
          f"{load:.1f})")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1, default=str))


if __name__ == "__main__":
    main()
