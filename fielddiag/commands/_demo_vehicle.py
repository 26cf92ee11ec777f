"""``fielddiag demo --full-vehicle``: a whole car end to end with no hardware.

1. Simulates three drives of a car with a worn rear-left damper (30 % weaker than the
   rear-right one) and dry friction in the front-left strut
   (:func:`fielddiag.vehicle.simulate_vehicle`, eight accelerometers, speed and the car's
   accelerations) and writes them as full-vehicle sessions: rough road as the car is,
   rough road with a known mass added at a known place, and braking (to validate on).
   The 8-channel virtual DAQ/ECU recording path does not exist yet; the sessions are
   written by the simulator's writer.
2. Identifies the body (mass, centre of gravity, inertias), the four corners and the
   anti-roll bars, cross-validated on the braking drive.
3. Diagnoses per corner and prints the findings.
4. Serves the dashboard over the runs (``--no-serve`` to skip).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

#: The demo car's faults.
WORN_CORNER, WORN_RATIO = "rl", 0.7
FRICTION_CORNER, FRICTION_N = "fl", 80.0
#: Default added mass of the full-vehicle demo [kg] and where it sits (fractions of the
#: wheelbase behind the front axle, metres left of centre).
DEFAULT_ADDED_MASS_KG = 150.0
ADDED_AT = (0.75, 0.3)


def demo_car(seed: int = 1):
    """The demo car: a random plausible car (from ``seed``) whose rear-left damper is 30 %
    weaker than the rear-right one.

    Returns
    -------
    VehicleParams
    """
    from fielddiag.vehicle import random_vehicle

    car = random_vehicle(1000 + seed)
    partner = car.corner("rr").damping_ns_per_m
    return car.with_corner(WORN_CORNER, damping_ns_per_m=WORN_RATIO * partner)


def run_full_vehicle(args: argparse.Namespace, run_dir: Path) -> int:
    """Simulate, identify, diagnose (and serve) the full-vehicle demo car.

    Parameters
    ----------
    args : argparse.Namespace
        The demo's arguments (``duration``, ``added_mass``, ``seed``, ``no_serve``,
        ``port``, ``out``).
    run_dir : Path
        New folder of this run.

    Returns
    -------
    int
        0.
    """
    from fielddiag.catalog import result_path
    from fielddiag.effects import CoulombFriction
    from fielddiag.vehicle import read_vehicle_recording, simulate_vehicle
    from fielddiag.vehicle.diagnose import diagnose_vehicle, format_vehicle_summary
    from fielddiag.vehicle.identify import identify_vehicle
    from fielddiag.vehicle.writer import write_vehicle_session

    car = demo_car(args.seed)
    dm = float(args.added_mass)
    at = (ADDED_AT[0] * car.geometry.wheelbase_m, ADDED_AT[1])
    effects = {FRICTION_CORNER: [CoulombFriction(friction_force_n=FRICTION_N)]}
    print(f"1/4 simulating three {args.duration:g} s drives of a car with eight "
          f"accelerometers: rough road, rough road with {dm:g} kg at ({at[0]:.2f}, "
          f"{at[1]:.2f}) m, braking")
    t0 = time.perf_counter()
    paths = []
    for label, kw in (("before", {"seed": args.seed}),
                      ("after", {"seed": args.seed + 1, "added_mass_kg": dm,
                                 "added_mass_at_m": at}),
                      ("braking", {"seed": args.seed + 2, "manoeuvre": "braking"})):
        drive = simulate_vehicle(car, duration_s=args.duration, effects=effects, **kw)
        paths.append(write_vehicle_session(drive, run_dir / f"{label}.h5",
                                           vehicle_name="demo car (full vehicle)"))
    print(f"    written {', '.join(p.name for p in paths)} in "
          f"{time.perf_counter() - t0:.0f} s")
    before = read_vehicle_recording(paths[0], label="before")
    after = read_vehicle_recording(paths[1], label="after")
    braking = read_vehicle_recording(paths[2], label="validate")

    print("2/4 identifying body mass, centre of gravity, inertias, corners, anti-roll bars")
    ident = identify_vehicle(before, after, dm, at, validate=[braking])
    print("    " + ident.summary().replace("\n", "\n    "))
    ident_json = {"mode": "full_vehicle", "session_paths": [p.name for p in paths[:2]],
                  **ident.to_dict()}
    print("3/4 diagnosing each corner: which corner, which effect, left/right balance")
    diag = diagnose_vehicle(before, after, dm, at, validate=[braking],
                            progress=lambda m: print(f"    {m}", flush=True))
    out = {"session_paths": [p.name for p in paths[:2]], **diag.to_dict(),
           "identification": ident.to_dict()}
    for p in paths[:2]:
        result_path(p, "identify").write_text(json.dumps(ident_json, indent=1),
                                              encoding="utf-8")
        result_path(p, "diagnose").write_text(json.dumps(out, indent=1), encoding="utf-8")
    print("    " + format_vehicle_summary(out).replace("\n", "\n    "))
    print(f"    (the demo car's rear-left damper is {100 * (1 - WORN_RATIO):.0f} % weaker "
          f"than the rear-right one, and its front-left strut has {FRICTION_N:g} N of dry "
          "friction)")
    print(f"    results beside each drive in {run_dir} (before.identify.json, "
          "before.diagnose.json...)")
    if args.no_serve:
        print("4/4 dashboard skipped (--no-serve); start it with "
              f"`fielddiag serve --root {Path(args.out)}`")
        return 0
    from fielddiag.web.app import serve

    print("4/4 serving the dashboard over the demo's runs (Ctrl-C to stop)", flush=True)
    serve(Path(args.out), host="127.0.0.1", port=args.port,
          print_address=lambda line: print(line, flush=True))
    return 0
