"""Identification benchmarks (not tests: they print figures).

Three measurements, each selectable with ``--only``:

``speed``
    Wall time and peak memory of ``identify`` (both routes, jackknife, restoring force,
    loops; everything the command computes except plotting) on session files: 2 x 300 s at
    500 Hz (goal < 5 s) and 2 x 1 h at 2 kHz (goal < 60 s and < 2 GB), and how the time
    grows with duration (60 s to 1 h at 500 Hz). Each case runs in a fresh Python process
    so that the peak resident set size (``VmHWM`` of /proc/self/status) is that of one
    identification (reading the two session files included; the interpreter and imports
    too, printed separately).
``coverage``
    Monte Carlo calibration: N simulated drive pairs (default 100) with the cars, roads,
    rates, noise and added masses drawn at random from the ranges of the issue (M2 250-550
    kg, K2 15-40 kN/m, damping ratio 0.15-0.45, ISO road B or C, 120-300 s, 200/500/1000 Hz,
    SNR 25-40 dB, bias +-0.5 m/s2 with drift, added mass 8-30 % of M2). Prints the error
    distribution of M2, K2, C2, how often each is within its budget (2 %, 3 %, 10 %), and
    the coverage: how often the truth lies within 3 (and 2, 1) standard deviations.
``small-mass``
    The std must say so when the data cannot resolve the mass: 3 % added mass, and noisy
    200 Hz recordings; prints the std and the error over 10 seeds each.

Usage: ``python benchmarks/bench_identify.py [--only speed|coverage|small-mass] [--n 100]``
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from fielddiag.errors import InsufficientDataError
from fielddiag.identify import Recording, identify_recordings
from fielddiag.identify.pipeline import PAIR_INCONSISTENT
from fielddiag.sim import QuarterCarParams, SensorModel, simulate, simulate_pair

BUDGET = {"sprung_mass_kg": 0.02, "suspension_stiffness_n_per_m": 0.03,
          "suspension_damping_ns_per_m": 0.10}
ROUTES = ("reported", "frequency", "time")
TRUTH_KEY = {"sprung_mass_kg": "body_mass_kg",
             "suspension_stiffness_n_per_m": "suspension_stiffness_n_per_m",
             "suspension_damping_ns_per_m": "suspension_damping_ns_per_m"}


# ---------------------------------------------------------------------------------------
# speed
# ---------------------------------------------------------------------------------------

_CHILD = r"""
import json, sys, time
def hwm_mb():  # peak resident set of this address space (ru_maxrss survives exec on Linux)
    for line in open("/proc/self/status"):
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
t0 = time.perf_counter()
from fielddiag.identify import identify_sessions
rss_imp = hwm_mb()
t0 = time.perf_counter()
res = identify_sessions(sys.argv[1], sys.argv[2], added_mass_kg=float(sys.argv[3]))
dt = time.perf_counter() - t0
rss = hwm_mb()
print(json.dumps({"wall_s": dt, "peak_rss_mb": rss, "import_rss_mb": rss_imp,
                  "m2": res.sprung_mass_kg.value, "m2_std": res.sprung_mass_kg.std}))
"""


def _make_pair(folder: Path, duration_s: float, rate_hz: float, dm: float, seed: int
               ) -> tuple[Path, Path]:
    from fielddiag.simio import drive_to_session

    paths = []
    for i, mass in enumerate((0.0, dm)):
        d = simulate(QuarterCarParams(), duration_s=duration_s, road_class="C",
                     added_mass_kg=mass, seed=seed + i,
                     sensor=SensorModel(output_rate_hz=rate_hz, snr_db=30, bias_mps2=0.2))
        p = folder / f"d{duration_s:g}_{rate_hz:g}_{i}.h5"
        drive_to_session(d, p, include_recipe=False)
        paths.append(p)
        del d
    return paths[0], paths[1]


def _run_child(before: Path, after: Path, dm: float) -> dict:
    out = subprocess.run([sys.executable, "-c", _CHILD, str(before), str(after), str(dm)],
                         capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def bench_speed() -> None:
    print("== speed: identify on session files (fresh process per case)")
    dm = 60.0
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        cases = [(300, 500, "goal < 5 s"), (3600, 2000, "goal < 60 s, < 2 GB")]
        for dur, rate, goal in cases:
            b, a = _make_pair(folder, dur, rate, dm, seed=11)
            size = (b.stat().st_size + a.stat().st_size) / 1e6
            r = _run_child(b, a, dm)
            print(f"2 x {dur:>5g} s at {rate:>5g} Hz ({size:6.0f} MB of sessions): "
                  f"{r['wall_s']:6.2f} s wall, peak RSS {r['peak_rss_mb']:6.0f} MB "
                  f"(after imports {r['import_rss_mb']:.0f} MB)   [{goal}]  "
                  f"M2 = {r['m2']:.2f} +- {r['m2_std']:.2f} kg (truth 380)")
            b.unlink()
            a.unlink()
        print("scaling with duration at 500 Hz:")
        rows = []
        for dur in (60, 120, 300, 900, 1800, 3600):
            b, a = _make_pair(folder, dur, 500, dm, seed=21)
            r = _run_child(b, a, dm)
            rows.append((dur, r["wall_s"]))
            print(f"  2 x {dur:>5g} s: {r['wall_s']:6.2f} s wall, peak RSS "
                  f"{r['peak_rss_mb']:6.0f} MB, {r['wall_s'] / dur * 1000:5.2f} ms per s of drive")
            b.unlink()
            a.unlink()
        d = np.log([r[0] for r in rows[2:]])
        t = np.log([r[1] for r in rows[2:]])
        print(f"  time ~ duration^{np.polyfit(d, t, 1)[0]:.2f} (fit over 300 s - 1 h)")


# ---------------------------------------------------------------------------------------
# coverage
# ---------------------------------------------------------------------------------------


def draw_case(rng: np.random.Generator) -> dict:
    """One random scenario within the ranges of the issue."""
    m2 = rng.uniform(250, 550)
    k2 = rng.uniform(15e3, 40e3)
    zeta = rng.uniform(0.15, 0.45)
    params = QuarterCarParams(
        wheel_mass_kg=rng.uniform(30, 55), tire_stiffness_n_per_m=rng.uniform(180e3, 280e3),
        tire_damping_ns_per_m=rng.uniform(50, 300), body_mass_kg=m2,
        suspension_stiffness_n_per_m=k2,
        suspension_damping_ns_per_m=2 * zeta * math.sqrt(k2 * m2))
    rate = float(rng.choice([200.0, 500.0, 1000.0]))
    sensor = SensorModel(output_rate_hz=rate, snr_db=rng.uniform(25, 40),
                         bias_mps2=rng.uniform(-0.5, 0.5),
                         bias_drift_mps2_per_s=rng.uniform(-1e-3, 1e-3))
    return dict(params=params, sensor=sensor, road=str(rng.choice(["B", "C"])),
                duration_s=float(rng.uniform(120, 300)), dm=m2 * rng.uniform(0.08, 0.30),
                seed=int(rng.integers(2**31)))


def run_case(case: dict) -> dict:
    """Simulate one pair, identify, and return errors and z-scores."""
    b, a = simulate_pair(case["params"], added_mass_kg=case["dm"], seed=case["seed"],
                         duration_s=case["duration_s"], road_class=case["road"],
                         sensor=case["sensor"])
    fs = b.sample_rate_hz
    t0 = time.perf_counter()
    res = identify_recordings(Recording(b.wheel_accel_mps2, b.body_accel_mps2, fs),
                              Recording(a.wheel_accel_mps2, a.body_accel_mps2, fs), case["dm"])
    out = {"wall_s": time.perf_counter() - t0, "k3": res.k3_included,
           "misfit": res.routes["time"].cost / res.routes["time"].n_residuals,
           "flagged_nonlinear": any("times the sensor noise" in w for w in res.warnings),
           "flagged_pair": any(w.startswith(PAIR_INCONSISTENT) for w in res.warnings)}
    truth = case["params"].to_dict()
    for key, tkey in TRUTH_KEY.items():
        for route in ROUTES:
            e = getattr(res.routes[route] if route in res.routes else res, key)
            out[f"{route}:{key}:rel"] = e.value / truth[tkey] - 1
            out[f"{route}:{key}:z"] = (e.value - truth[tkey]) / e.std
    return out


def bench_coverage(n: int, seed: int = 2024) -> None:
    print(f"== coverage: {n} simulated drive pairs (random cars, roads, rates, SNR, masses)")
    rng = np.random.default_rng(seed)
    rows, refused = [], 0
    t0 = time.perf_counter()
    for i in range(n):
        case = draw_case(rng)
        try:
            rows.append(run_case(case))
        except InsufficientDataError as exc:
            refused += 1
            print(f"  case {i} refused: {exc}")
        if (i + 1) % 10 == 0:
            print(f"  {i + 1}/{n} done, {time.perf_counter() - t0:.0f} s", flush=True)
    print(f"{len(rows)} identified, {refused} refused; mean identify time "
          f"{np.mean([r['wall_s'] for r in rows]):.2f} s")
    for route in ROUTES:
        print(f"route {route}:" if route in ("frequency", "time")
              else "reported (what identify prints and writes):")
        for key, budget in BUDGET.items():
            rel = np.array([r[f"{route}:{key}:rel"] for r in rows])
            z = np.abs([r[f"{route}:{key}:z"] for r in rows])
            rms = 100 * np.sqrt(np.mean(rel**2))
            print(f"  {key:<30} error mean {100 * rel.mean():+6.2f} %, rms {rms:5.2f} %,"
                  f" max |err| {100 * np.abs(rel).max():5.2f} %; within {100 * budget:g} %: "
                  f"{100 * np.mean(np.abs(rel) <= budget):5.1f} %;  truth within 1/2/3 std: "
                  f"{100 * np.mean(z <= 1):4.0f} / {100 * np.mean(z <= 2):4.0f} / "
                  f"{100 * np.mean(z <= 3):4.0f} %  (Gaussian 68/95/99.7)")
    print(f"K3 kept (false alarm, truth K3 = 0): {sum(r['k3'] for r in rows)} of {len(rows)}")
    mis = np.array([r["misfit"] for r in rows])
    print(f"time-route residual / sensor noise (linear cars): median {np.median(mis):.2f}, "
          f"max {mis.max():.2f}; flagged 'not linear' (false alarm): "
          f"{sum(r['flagged_nonlinear'] for r in rows)} of {len(rows)}")
    print("flagged 'the two drives do not behave like one corner' (false alarm: each pair is "
          f"one car): {sum(r['flagged_pair'] for r in rows)} of {len(rows)}")


# ---------------------------------------------------------------------------------------
# small added mass and noisy 200 Hz
# ---------------------------------------------------------------------------------------


def bench_small_mass(n: int = 10) -> None:
    print("== honest std when the data cannot resolve the mass (default car, M2 = 380 kg)")
    p = QuarterCarParams()
    cases = [("10 % mass, 500 Hz, 35 dB, 300 s", 38.0, 500.0, 35.0),
             ("3 % mass, 500 Hz, 35 dB, 300 s", 11.4, 500.0, 35.0),
             ("10 % mass, 200 Hz, 25 dB, 300 s", 38.0, 200.0, 25.0),
             ("3 % mass, 200 Hz, 25 dB, 300 s", 11.4, 200.0, 25.0),
             ("3 % mass, 200 Hz, 20 dB, 120 s", 11.4, 200.0, 20.0)]
    for label, dm, rate, snr in cases:
        errs, stds, refused = [], [], 0
        dur = 120.0 if "120 s" in label else 300.0
        for s in range(n):
            b, a = simulate_pair(p, added_mass_kg=dm, seed=500 + s, duration_s=dur,
                                 road_class="C", sensor=SensorModel(output_rate_hz=rate,
                                                                    snr_db=snr, bias_mps2=0.2))
            try:
                res = identify_recordings(
                    Recording(b.wheel_accel_mps2, b.body_accel_mps2, rate),
                    Recording(a.wheel_accel_mps2, a.body_accel_mps2, rate), dm)
            except InsufficientDataError:
                refused += 1
                continue
            errs.append(res.sprung_mass_kg.value / 380 - 1)
            stds.append(res.sprung_mass_kg.relative_std)
        if errs:
            e, s_ = np.array(errs), np.array(stds)
            print(f"  {label:<34} median std {100 * np.median(s_):5.2f} %, rms error "
                  f"{100 * np.sqrt(np.mean(e**2)):5.2f} %, |err| <= 3 std in "
                  f"{np.sum(np.abs(e) <= 3 * s_)}/{e.size}, refused {refused}/{n}")
        else:
            print(f"  {label:<34} refused {refused}/{n}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", choices=["speed", "coverage", "small-mass"])
    ap.add_argument("--n", type=int, default=100, help="drive pairs for coverage")
    ap.add_argument("--seed", type=int, default=2024)
    args = ap.parse_args()
    print(__doc__)
    print(f"machine: {os.cpu_count()} cores; numpy {np.__version__}")
    if args.only in (None, "speed"):
        bench_speed()
    if args.only in (None, "small-mass"):
        bench_small_mass()
    if args.only in (None, "coverage"):
        bench_coverage(args.n, args.seed)
    print(f"peak RSS of this process: "
          f"{resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB")


if __name__ == "__main__":
    main()
