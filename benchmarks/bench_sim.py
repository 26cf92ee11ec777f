"""Benchmark of the quarter-car simulator (fielddiag.sim).

Run with ``python benchmarks/bench_sim.py``. Prints the method, the numba compile time of
the first call (cold, in a fresh process with an empty cache, and warm, loading the
on-disk cache), and simulated seconds per wall-clock second for a 300 s random drive on
an ISO 8608 class C road at 500 Hz and 2000 Hz output, linear and with two effects
(median of 3 runs after a warm-up). Goal: >= 50x real time at 500 Hz.
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

from fielddiag.sim import (
    AsymmetricDamping,
    CoulombFriction,
    QuarterCarParams,
    SensorModel,
    SpeedProfile,
    internal_rate_factor,
    iso8608_profile,
    simulate,
)

DURATION_S = 300.0
REPEATS = 3

_FIRST_CALL = """
import json, time
t0 = time.perf_counter()
from fielddiag.sim import simulate
t1 = time.perf_counter()
simulate(duration_s=1.0, seed=0)
t2 = time.perf_counter()
simulate(duration_s=1.0, seed=0)
t3 = time.perf_counter()
print(json.dumps({"import_s": t1 - t0, "first_call_s": t2 - t1, "second_call_s": t3 - t2}))
"""


def first_call_times(cache_dir: str) -> dict[str, float]:
    """Time import and the first two 1 s simulations in a fresh interpreter."""
    env = {**os.environ, "NUMBA_CACHE_DIR": cache_dir}
    out = subprocess.run(
        [sys.executable, "-c", _FIRST_CALL], env=env, check=True, capture_output=True, text=True
    ).stdout
    return json.loads(out.strip().splitlines()[-1])


def throughput(output_rate_hz: float, effects: tuple) -> tuple[float, float]:
    """(median wall seconds, simulated seconds per wall second) for a DURATION_S drive."""
    sensor = SensorModel(output_rate_hz=output_rate_hz)
    simulate(duration_s=10.0, seed=0, sensor=sensor, effects=effects)  # warm-up
    walls = []
    for i in range(REPEATS):
        t0 = time.perf_counter()
        simulate(
            duration_s=DURATION_S, seed=100 + i, road_class="C", sensor=sensor, effects=effects
        )
        walls.append(time.perf_counter() - t0)
    wall = statistics.median(walls)
    return wall, DURATION_S / wall


def main() -> None:
    params = QuarterCarParams()
    print("fielddiag.sim benchmark")
    print(
        "method: 2-DOF quarter car, fixed-step RK4 in a numba kernel (njit, cache=True) at "
        "k x output rate >= 4000 Hz; ISO 8608 road by inverse FFT, Catmull-Rom between "
        "samples; sensors: Butterworth-4 anti-alias (sosfilt) at the internal rate, "
        "decimate by k, noise/quantise/clip."
    )
    print(f"python {sys.version.split()[0]}, {os.cpu_count()} CPU(s)")

    with tempfile.TemporaryDirectory() as empty:
        cold = first_call_times(empty)
        warm = first_call_times(empty)  # same directory: now holds the cache
    compile_cold = cold["first_call_s"] - cold["second_call_s"]
    compile_warm = warm["first_call_s"] - warm["second_call_s"]
    print(
        f"numba first call, empty cache : {cold['first_call_s']:.2f} s "
        f"(compile ~ {compile_cold:.2f} s; import {cold['import_s']:.2f} s)"
    )
    print(
        f"numba first call, disk cache  : {warm['first_call_s']:.2f} s "
        f"(cache load ~ {compile_warm:.2f} s)"
    )

    speed = SpeedProfile.random_drive(DURATION_S, seed=1)
    length_m = float(speed.distance_m(DURATION_S))
    t0 = time.perf_counter()
    iso8608_profile("C", length_m, seed=1)
    print(
        f"road generation alone        : {time.perf_counter() - t0:.3f} s "
        f"({length_m / 1000:.1f} km at 0.02 m)"
    )

    two = (CoulombFriction(friction_force_n=80.0), AsymmetricDamping(1200.0, 2600.0))
    print(
        f"\n{DURATION_S:.0f} s drive, median of {REPEATS} after warm-up (simulated s per wall s):"
    )
    print(f"{'output':>8} {'internal':>9} {'effects':>26} {'wall s':>8} {'x real time':>12}")
    for rate_hz in (500.0, 2000.0):
        for label, effects in (("none (linear)", ()), ("friction + asym. damping", two)):
            k = internal_rate_factor(rate_hz, params, effects)
            wall, speedup = throughput(rate_hz, effects)
            print(
                f"{rate_hz:>6.0f}Hz {k * rate_hz:>7.0f}Hz {label:>26} {wall:>8.3f} "
                f"{speedup:>11.0f}x"
            )
    print("\ngoal: >= 50x real time at 500 Hz output")


if __name__ == "__main__":
    main()
