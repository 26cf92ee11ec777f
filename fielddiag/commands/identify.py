"""``fielddiag identify BEFORE.h5 AFTER.h5 --added-mass KG [--json OUT.json] [--plots DIR]
[--band LO HI]``: sprung mass, suspension stiffness and damping from two drives."""

from __future__ import annotations

import argparse

from fielddiag.validate import arg_existing_file, arg_number, band_hz, finite_session


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
    for path in (args.before, args.after):
        finite_session(path)
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
