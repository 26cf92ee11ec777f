"""``fielddiag identify BEFORE.h5 AFTER.h5 --added-mass KG [--json OUT.json] [--plots DIR]
[--band LO HI]``: sprung mass, suspension stiffness and damping from two drives.

Full-vehicle sessions (all eight corner roles ``wheel_fl`` ... ``body_rr``) go to the
full-vehicle identification: ``--added-mass-at X_M,Y_M`` says where the mass sits and
``--validate OTHER.h5 ...`` adds cross-validation drives."""

from __future__ import annotations

import argparse
import math

from fielddiag.validate import arg_existing_file, arg_number, band_hz, finite_session


def arg_position(text: str) -> tuple[float, float]:
    """``X_M,Y_M`` -> (x, y) [m], two finite numbers (argparse ``type=``)."""
    parts = text.split(",")
    try:
        if len(parts) != 2:
            raise ValueError
        x, y = float(parts[0]), float(parts[1])
        if not (math.isfinite(x) and math.isfinite(y)):
            raise ValueError
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"--added-mass-at {text!r}: give X_M,Y_M, two numbers in metres (behind the front "
            "axle, left of the centre line), e.g. 1.9,0.3") from None
    return x, y


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "identify",
        help="identify sprung mass, stiffness and damping from a drive before and after "
        "adding a known mass",
        description=(
            "Output-only identification (boundary perturbation): from a drive before and a "
            "drive after adding a known mass on the body, each with a wheel-side and a "
            "body-side accelerometer, find the sprung mass M2, suspension stiffness K2 and "
            "damping C2 (and the coupling stiffness K3 when the data call for it), each with "
            "a standard deviation. Drives that cannot support an answer are refused with "
            "what to record instead."
        ),
    )
    p.add_argument("before", type=arg_existing_file(),
                   help="session of the drive as the car is (.h5)")
    p.add_argument("after", type=arg_existing_file(),
                   help="session of the drive with the added mass (.h5)")
    p.add_argument("--added-mass", type=arg_number("--added-mass", "added_mass"),
                   metavar="KG", default=None,
                   help="mass added on the body for the second drive (kg); default: the "
                   "difference of the sessions' added_mass_kg attributes")
    p.add_argument("--added-mass-at", type=arg_position, metavar="X_M,Y_M", default=None,
                   help="full vehicle: where the added mass sits, metres behind the front axle "
                   "and left of the centre line (default: the after session's record)")
    p.add_argument("--validate", nargs="+", action="extend", metavar="OTHER.h5",
                   type=arg_existing_file(),
                   help="full vehicle: drives of the same car (without the mass, another "
                   "manoeuvre) to cross-validate on")
    p.add_argument("--refine", action="store_true",
                   help="full vehicle: try an output-error refinement after the least squares "
                   "and keep it if it predicts the --validate drives better")
    p.add_argument("--json", metavar="OUT.json", help="write the full result as JSON")
    p.add_argument("--plots", metavar="DIR",
                   help="write PNGs: transmissibility, restoring force, hysteresis loops")
    p.add_argument("--band", nargs=2, type=arg_number("--band", "frequency"),
                   metavar=("LO", "HI"),
                   help="frequency band in Hz (default: chosen from the coherence)")
    p.add_argument("--k3", choices=["auto", "fit", "zero"], default="auto",
                   help="coupling stiffness K3: keep when significant (auto, default), always "
                   "fit, or hold at 0")
    p.add_argument("--loops", nargs="+", type=arg_number("--loops", "frequency"), metavar="HZ",
                   help="frequencies of the hysteresis loops (default: 0.7, 1, 2 and 4 times "
                   "the body natural frequency, where inside the band)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from fielddiag.outputs import check_folder, check_target, write_plots, write_text

    band = band_hz(args.band)
    if args.json:
        check_target(args.json, overwrite=True, flag="--json")
    if args.plots:
        check_folder(args.plots)
    from fielddiag.vehicle.recording import is_full_vehicle_session

    full = [is_full_vehicle_session(p) for p in (args.before, args.after)]
    if any(full):
        if not all(full):
            from fielddiag.errors import FieldDiagError

            raise FieldDiagError(
                f"{args.after if full[0] else args.before} is not a full-vehicle session "
                "(it lacks some of the roles wheel_fl..body_rr) while the other is; give two "
                "full-vehicle drives or two single-corner drives")
        return _run_vehicle(args, band)
    if args.added_mass_at is not None or args.validate or args.refine:
        from fielddiag.errors import FieldDiagError

        raise FieldDiagError("--added-mass-at, --validate and --refine are for full-vehicle "
                             "sessions (roles wheel_fl..body_rr); these are single-corner "
                             "drives")
    for path in (args.before, args.after):
        finite_session(path)
    from fielddiag.pairs import check_pair_before_work

    check_pair_before_work(args.before, args.after, args.added_mass)
    from fielddiag.identify import IdentifyConfig, identify_sessions

    result = identify_sessions(
        args.before, args.after, added_mass_kg=args.added_mass,
        band_hz=band, config=IdentifyConfig(
            k3=args.k3, hysteresis_freqs_hz=tuple(args.loops) if args.loops else None))
    print(result.summary())
    if args.json:
        write_text(args.json, result.to_json() + "\n")
        print(f"JSON written to {args.json}")
    if args.plots:
        from fielddiag.plots import write_identify_plots

        for p in write_plots(write_identify_plots, args.plots, result):
            print(f"plot written to {p}")
    return 0


def _run_vehicle(args: argparse.Namespace, band: tuple[float, float] | None) -> int:
    """The full-vehicle identification of two (or more) full-vehicle sessions."""
    from fielddiag.errors import FieldDiagError
    from fielddiag.outputs import write_text
    from fielddiag.vehicle.identify import VehicleIdentifyConfig, identify_vehicle
    from fielddiag.vehicle.recording import (
        FULL_VEHICLE_ROLES,
        is_full_vehicle_session,
        read_vehicle_recording,
    )

    if args.plots:
        raise FieldDiagError("--plots is not available for full-vehicle sessions yet; leave it "
                             "out")
    for path in (args.before, args.after, *(args.validate or [])):
        finite_session(path, FULL_VEHICLE_ROLES)
    before = read_vehicle_recording(args.before, label="before")
    after = read_vehicle_recording(args.after, label="after")
    validate = []
    for path in args.validate or []:
        if not is_full_vehicle_session(path):
            raise FieldDiagError(f"--validate {path}: not a full-vehicle session (roles "
                                 "wheel_fl..body_rr)")
        validate.append(read_vehicle_recording(path, label="validate"))
    config = VehicleIdentifyConfig(refine=args.refine) if band is None else \
        VehicleIdentifyConfig(band_hz=band, refine=args.refine)
    result = identify_vehicle(before, after, added_mass_kg=args.added_mass,
                              added_mass_at_m=args.added_mass_at, validate=validate,
                              config=config)
    print(result.summary())
    if args.json:
        write_text(args.json, result.to_json() + "\n")
        print(f"JSON written to {args.json}")
    return 0
