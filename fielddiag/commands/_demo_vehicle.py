"""``fielddiag demo --full-vehicle``: a whole car end to end with no hardware.

1. Records three drives of a car with a worn rear-left damper (30 % weaker than the
   rear-right one) and dry friction in the front-left strut: rough road as the car is,
   rough road with a known mass added at a known place, and braking (to validate on).
   Each is simulated (:func:`fielddiag.vehicle.simulate_vehicle`) and recorded through
   the virtual devices, all three at once and in real time: an 8-channel virtual DAQ on
   a pseudo-terminal read by the real serial driver, whose channel map gives each channel
   its corner role, and a virtual ECU sending speed and the car's longitudinal and
   lateral accelerations on a python-can virtual bus, read by the real CAN driver
   (:mod:`fielddiag.virtual_drive`).
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


def demo_drives(car, duration_s: float, added_mass_kg: float,
                added_mass_at_m: tuple[float, float], seed: int) -> dict:
    """The demo's three simulated drives of ``car`` (with the friction at the front left).

    Returns
    -------
    dict
        ``before`` (rough road), ``after`` (rough road with the added mass), ``braking``
        (to validate on): :class:`~fielddiag.vehicle.VehicleDrive`.
    """
    from fielddiag.effects import CoulombFriction
    from fielddiag.vehicle import simulate_vehicle

    effects = {FRICTION_CORNER: [CoulombFriction(friction_force_n=FRICTION_N)]}
    runs = {"before": {"seed": seed},
            "after": {"seed": seed + 1, "added_mass_kg": added_mass_kg,
                      "added_mass_at_m": added_mass_at_m},
            "braking": {"seed": seed + 2, "manoeuvre": "braking"}}
    return {label: simulate_vehicle(car, duration_s=duration_s, effects=effects, **kw)
            for label, kw in runs.items()}


def run_full_vehicle(args: argparse.Namespace, run_dir: Path) -> int:
    """Record, identify, diagnose (and serve) the full-vehicle demo car.

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
    from fielddiag.commands.demo import record_drives
    from fielddiag.vehicle import read_vehicle_recording
    from fielddiag.vehicle.diagnose import diagnose_vehicle, format_vehicle_summary
    from fielddiag.vehicle.identify import identify_vehicle

    car = demo_car(args.seed)
    dm = float(args.added_mass)
    at = (ADDED_AT[0] * car.geometry.wheelbase_m, ADDED_AT[1])
    print(f"1/4 recording three {args.duration:g} s drives of a car with eight "
          f"accelerometers (rough road, rough road with {dm:g} kg at ({at[0]:.2f}, "
          f"{at[1]:.2f}) m, braking) at once, through an 8-channel virtual DAQ (pseudo-"
          "terminal) and a virtual ECU (speed and accelerations on CAN)")
    t0 = time.perf_counter()
    drives = demo_drives(car, args.duration + 2.0, dm, at, args.seed)
    paths = record_drives(run_dir, {
        label: {"drive": drive, "vehicle": "demo car (full vehicle)", "corner": "",
                "notes": f"full-vehicle demo drive {label}"}
        for label, drive in drives.items()}, args.duration)
    print(f"    recorded {', '.join(p.name for p in paths)} in "
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
          f"than the rear-right one, its front-left strut has {FRICTION_N:g} N of dry "
          f"friction, and its sprung mass is {car.sprung_mass_kg:.1f} kg: the linear "
          "identification, which leaves the friction out, is biased by it)")
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
