"""Batch reprocessing on dask.distributed: speed-up from 1 to 2 workers, scheduler overhead.

Method
------
1. Write N simulated before/after session pairs (default 100) to a temporary folder: cars
   drawn at random (sprung mass 300-480 kg, stiffness 18-32 kN/m, damping 1200-2600 Ns/m,
   added mass 40-80 kg), ISO class C road, 500 Hz, D s per drive (default 40), one vehicle
   per pair so pairing goes by metadata.
2. ``fielddiag reprocess`` (the library calls behind it: plan, then reprocess with a fresh
   LocalCluster of process workers, 1 thread each) over all pairs with the steps asked
   (default identify and diagnose), once with 1 worker and once with 2 (``force``, so the
   second run redoes everything). Wall time is measured from the start of the cluster to
   the last result recorded in the catalog, cluster start-up included; the start-up alone
   is printed too. Speed-up = wall(1 worker) / wall(2 workers). Goal: at least 1.7 on 2
   cores.
3. Scheduler overhead per pair: M no-op tasks (default 1000) that take a PairJob and return
   a PairOutcome, through the same ``run_jobs`` path (map, as_completed, result transfer,
   the on-done callback writing the catalog row is NOT included) on 2 workers, after the
   cluster is up; overhead = wall / M. Writing one catalog row is timed separately.

Usage: python benchmarks/bench_reprocess.py [--pairs 100] [--duration 40]
                                            [--steps identify,diagnose] [--noop 1000]
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from fielddiag.batch.reprocess import plan, reprocess
from fielddiag.batch.runner import ClusterInfo, run_jobs
from fielddiag.batch.store import BatchCatalog
from fielddiag.batch.task import PairJob, PairOutcome, StepOutcome
from fielddiag.sim import QuarterCarParams, SensorModel, simulate_pair
from fielddiag.simio import drive_to_session


def write_fleet(folder: Path, n_pairs: int, duration_s: float, seed: int = 2026) -> None:
    rng = np.random.default_rng(seed)
    for i in range(n_pairs):
        car = QuarterCarParams(
            body_mass_kg=float(rng.uniform(300, 480)),
            suspension_stiffness_n_per_m=float(rng.uniform(18e3, 32e3)),
            suspension_damping_ns_per_m=float(rng.uniform(1200, 2600)),
        )
        before, after = simulate_pair(
            car, added_mass_kg=float(rng.uniform(40, 80)), seed=int(rng.integers(1 << 30)),
            duration_s=duration_s, sensor=SensorModel(output_rate_hz=500.0, snr_db=35.0))
        sub = folder / f"car-{i:03d}"
        sub.mkdir(parents=True)
        drive_to_session(before, sub / "before.h5", vehicle=f"car-{i:03d}")
        drive_to_session(after, sub / "after.h5", vehicle=f"car-{i:03d}")


def timed_batch(folder: Path, workers: int, steps: list[str]) -> dict:
    batch = plan([folder], steps=steps, force=True)
    marks: dict[str, float] = {"t0": time.perf_counter()}
    failed = []
    finished = 0

    def started(info: ClusterInfo) -> None:
        marks["up"] = time.perf_counter()

    def done(outcome: PairOutcome) -> None:
        nonlocal finished
        marks["last"] = time.perf_counter()
        finished += 1
        if outcome.status == "failed":
            failed.append(outcome.message)
        if finished % 10 == 0:
            print(f"    {finished}/{len(batch.jobs)} pairs", file=sys.stderr, flush=True)

    reprocess(batch, workers=workers, on_done=done, on_start=started)
    return {
        "pairs": len(batch.jobs),
        "wall_s": marks["last"] - marks["t0"],
        "startup_s": marks["up"] - marks["t0"],
        "work_s": marks["last"] - marks["up"],
        "failed": failed,
    }


def _noop(job: PairJob) -> PairOutcome:
    return PairOutcome(job.before, job.after, job.added_mass_kg, job.vehicle, job.corner,
                       [StepOutcome("identify", "done")])


def scheduler_overhead(n_tasks: int) -> tuple[float, float]:
    jobs = [PairJob(f"/fleet/car-{i}/before.h5", f"/fleet/car-{i}/after.h5", 50.0,
                    ("identify",), {"identify": ""}, {"identify": f"{i:08x}"})
            for i in range(n_tasks)]
    marks: dict[str, float] = {}
    run_jobs(jobs, workers=2, task=_noop,
             on_start=lambda info: marks.__setitem__("up", time.perf_counter()),
             on_done=lambda o: marks.__setitem__("last", time.perf_counter()))
    return (marks["last"] - marks["up"]) / n_tasks, marks["up"]


def catalog_row_cost(folder: Path, n: int = 200) -> float:
    db = BatchCatalog(folder / "bench-catalog.sqlite")
    t0 = time.perf_counter()
    for i in range(n):
        db.record(PairOutcome(str(folder / f"b{i}.h5"), str(folder / f"a{i}.h5"), 50.0, "v",
                              "fl", [StepOutcome("identify", "done", summary={"x": 1.0})]))
    return (time.perf_counter() - t0) / n


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--pairs", type=int, default=100)
    ap.add_argument("--duration", type=float, default=40.0, help="seconds per drive")
    ap.add_argument("--steps", default="identify,diagnose")
    ap.add_argument("--noop", type=int, default=1000, help="no-op tasks for the overhead")
    args = ap.parse_args()
    steps = [s for s in args.steps.split(",") if s]
    print(__doc__.split("Usage")[0].strip())
    print(f"\nmachine: {os.cpu_count()} cores; {args.pairs} pairs x 2 drives x "
          f"{args.duration:g} s at 500 Hz; steps {'+'.join(steps)}\n")
    folder = Path(tempfile.mkdtemp(prefix="fielddiag-bench-reprocess-"))
    try:
        t0 = time.perf_counter()
        write_fleet(folder, args.pairs, args.duration)
        print(f"wrote {2 * args.pairs} sessions in {time.perf_counter() - t0:.1f} s")
        runs = {}
        for workers in (1, 2):
            print(f"  running with {workers} worker(s)...", file=sys.stderr, flush=True)
            runs[workers] = r = timed_batch(folder, workers, steps)
            load = os.getloadavg()[0]
            print(f"{workers} worker(s): {r['pairs']} pairs in {r['wall_s']:.1f} s "
                  f"(cluster start-up {r['startup_s']:.1f} s, then {r['work_s']:.1f} s = "
                  f"{r['work_s'] / r['pairs']:.2f} s per pair); failed: {len(r['failed'])}; "
                  f"1-min load average at the end {load:.2f} (other work on the machine "
                  "inflates it beyond the workers)")
            for msg in r["failed"][:3]:
                print(f"   failed: {msg}")
        speedup = runs[1]["wall_s"] / runs[2]["wall_s"]
        speedup_work = runs[1]["work_s"] / runs[2]["work_s"]
        print(f"\nspeed-up 1 -> 2 workers: {speedup:.2f}x wall (start-up included), "
              f"{speedup_work:.2f}x after start-up; goal >= 1.7x: "
              f"{'met' if speedup >= 1.7 else 'NOT met'}")
        per_task, _ = scheduler_overhead(args.noop)
        row = catalog_row_cost(folder)
        per_pair = runs[2]["work_s"] / runs[2]["pairs"]
        print(f"scheduler overhead per pair (no-op task, 2 workers, {args.noop} tasks): "
              f"{per_task * 1e3:.2f} ms; catalog row write: {row * 1e3:.2f} ms; together "
              f"{(per_task + row) / per_pair * 100:.2f} % of a pair's work "
              f"({per_pair:.2f} s per pair on 2 workers)")
    finally:
        shutil.rmtree(folder, ignore_errors=True)


if __name__ == "__main__":
    main()
