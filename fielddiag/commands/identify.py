"""``fielddiag identify BEFORE.h5 AFTER.h5 --added-mass KG [--json OUT.json] [--plots DIR]
[--band LO HI]``: sprung mass, suspension stiffness and damping from two drives."""

from __future__ import annotations

import argparse
from pathlib import Path

from fielddiag.errors import FieldDiagError


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
    p.add_argument("before", help="session of the drive as the car is (.h5)")
    p.add_argument("after", help="session of the drive with the added mass (.h5)")
    p.add_argument("--added-mass", type=float, metavar="KG", default=None,
                   help="mass added on the body for the second drive (kg); default: the "
                   "difference of the sessions' added_mass_kg attributes")
    p.add_argument("--json", metavar="OUT.json", help="write the full result as JSON")
    p.add_argument("--plots", metavar="DIR",
                   help="write PNGs: transmissibility, restoring force, hysteresis loops")
    p.add_argument("--band", nargs=2, type=float, metavar=("LO", "HI"),
                   help="frequency band in Hz (default: chosen from the coherence)")
    p.add_argument("--k3", choices=["auto", "fit", "zero"], default="auto",
                   help="coupling stiffness K3: keep when significant (auto, default), always "
                   "fit, or hold at 0")
    p.add_argument("--loops", nargs="+", type=float, metavar="HZ",
                   help="frequencies of the hysteresis loops (default: 0.7, 1, 2 and 4 times "
                   "the body natural frequency, where inside the band)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from fielddiag.identify import IdentifyConfig, identify_sessions

    for path in (args.before, args.after):
        if not Path(path).is_file():
            raise FieldDiagError(f"{path} does not exist; give two session files (.h5)")
    if args.loops and not all(0 < f < 1e4 for f in args.loops):
        raise FieldDiagError("--loops: give frequencies in Hz above 0, e.g. --loops 1.2 5")
    if args.json and not Path(args.json).resolve().parent.is_dir():
        raise FieldDiagError(f"folder of {args.json} does not exist; create it first")
    result = identify_sessions(
        args.before, args.after, added_mass_kg=args.added_mass,
        band_hz=tuple(args.band) if args.band else None, config=IdentifyConfig(
            k3=args.k3, hysteresis_freqs_hz=tuple(args.loops) if args.loops else None))
    print(result.summary())
    if args.json:
        result.to_json(args.json)
        print(f"JSON written to {args.json}")
    if args.plots:
        from fielddiag.plots import write_identify_plots

        for p in write_identify_plots(result, args.plots):
            print(f"plot written to {p}")
    return 0
