"""``fielddiag vehicle-sim OUTDIR``: a simulated full-vehicle pair (and a validate drive)
as sessions and CSVs, with the vehicle file, so the full-vehicle commands can be tried
without hardware."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from fielddiag.validate import arg_int, arg_number


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "vehicle-sim",
        help="simulate a full-vehicle drive pair (before/after adding a mass) and a "
        "validate drive, as sessions and CSVs",
        description=(
            "Simulate a car with eight accelerometers (hub and body at each corner) over an "
            "ISO 8608 road: a rough-road drive as it is (before.h5), the same with a known "
            "mass added (after.h5), and a drive on another manoeuvre for cross-validation "
            "(validate.h5). Writes also CAR.csv files in the import format, vehicle.json and "
            "truth.json (the simulated parameters). Then: fielddiag identify "
            "OUTDIR/before.h5 OUTDIR/after.h5 --added-mass KG --added-mass-at X,Y "
            "--validate OUTDIR/validate.h5 --json OUT.json"),
    )
    p.add_argument("outdir", help="folder to write into (created if missing)")
    p.add_argument("--duration", type=arg_number("--duration", "sim_duration"), default=180.0,
                   metavar="S", help="length of each drive (s, default 180)")
    p.add_argument("--rate", type=arg_number("--rate", "sample_rate"), default=500.0,
                   metavar="HZ", help="sample rate, 200-1000 Hz (default 500)")
    p.add_argument("--added-mass", type=arg_number("--added-mass", "added_mass"),
                   default=150.0, metavar="KG", help="mass added for the after drive (kg)")
    p.add_argument("--added-mass-at", default=None, metavar="X_M,Y_M",
                   help="where it sits (m behind the front axle, m left of centre; default "
                   "0.7 x wheelbase, 0.3)")
    p.add_argument("--road-class", default="C", help="ISO 8608 road class A..H (default C)")
    p.add_argument("--validate-manoeuvre", default="braking",
                   choices=("braking", "ramp_steer", "rough_road"),
                   help="manoeuvre of the validate drive (default braking)")
    p.add_argument("--random-car", action="store_true",
                   help="a random passenger car from --seed instead of the default car")
    p.add_argument("--seed", type=arg_int("--seed", 0, 2**32 - 1, "a random seed"), default=1,
                   help="random seed (road, noise, car)")
    p.add_argument("--overwrite", action="store_true", help="replace existing files")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from fielddiag.commands.identify import arg_position
    from fielddiag.errors import FieldDiagError, OutputError
    from fielddiag.vehicle import VehicleParams, random_vehicle, simulate_vehicle
    from fielddiag.vehicle.writer import write_vehicle_csv, write_vehicle_session

    out = Path(args.outdir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"cannot create {out} ({exc.strerror}); give a writable folder"
                          ) from None
    car = random_vehicle(args.seed) if args.random_car else VehicleParams()
    if args.added_mass_at is None:
        at = (0.7 * car.geometry.wheelbase_m, 0.3)
    else:
        try:
            at = arg_position(args.added_mass_at)
        except argparse.ArgumentTypeError as exc:
            raise FieldDiagError(str(exc)) from None
    if args.added_mass <= 0:
        raise FieldDiagError("--added-mass must be > 0 kg (the after drive carries it)")
    common = dict(duration_s=args.duration, sample_rate_hz=args.rate, road_class=args.road_class)
    drives = {
        "before": simulate_vehicle(car, manoeuvre="rough_road", seed=args.seed * 3 + 1,
                                   **common),
        "after": simulate_vehicle(car, manoeuvre="rough_road", seed=args.seed * 3 + 2,
                                  added_mass_kg=args.added_mass, added_mass_at_m=at, **common),
        "validate": simulate_vehicle(car, manoeuvre=args.validate_manoeuvre,
                                     seed=args.seed * 3 + 3, **common),
    }
    for name, d in drives.items():
        write_vehicle_session(d, out / f"{name}.h5", vehicle_name="simulated car",
                              overwrite=args.overwrite)
        write_vehicle_csv(d, out / f"{name}.csv")
    (out / "vehicle.json").write_text(car.geometry.to_json() + "\n")
    (out / "truth.json").write_text(json.dumps(car.truth(), indent=2) + "\n")
    print(f"wrote before/after/validate .h5 and .csv, vehicle.json, truth.json in {out}")
    print(f"next: fielddiag identify {out / 'before.h5'} {out / 'after.h5'} --added-mass "
          f"{args.added_mass:g} --added-mass-at {at[0]:.3f},{at[1]:.3f} --validate "
          f"{out / 'validate.h5'} --json {out / 'identified.json'}")
    return 0
