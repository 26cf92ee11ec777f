"""``fielddiag diagnose``: where the linear model and the recording disagree, and why.

* ``fielddiag diagnose BEFORE.h5 AFTER.h5 --added-mass KG`` : a car corner, two drives.
* ``fielddiag diagnose SESSION.h5`` : one drive (parameters per unit sprung mass), or a rig
  test (a session with a ``force`` channel and a ``displacement``/``acceleration`` one).
* ``fielddiag diagnose BEFORE.h5 AFTER.h5 --added-mass KG --added-mass-at X_M,Y_M`` with
  full-vehicle sessions (roles ``wheel_fl`` .. ``body_rr``): per-corner findings
  (:mod:`fielddiag.vehicle.diagnose`).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from fielddiag.effects import diagnosis_effects
from fielddiag.errors import FieldDiagError
from fielddiag.validate import arg_existing_file, arg_number, finite_session


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "diagnose",
        help="locate the mismatch between model and recording and name the missing physics",
        description=(
            "Fit the linear model, locate where it and the recording differ (time windows, "
            "frequency band, region of suspension travel and speed), test the effects a linear "
            f"model leaves out ({', '.join(diagnosis_effects())}, and pairs of them) and a "
            "smooth force surface that names no physics, on data held out from the fit, with "
            "the data problems (a late channel, a gain change, clipping) as competing "
            "explanations, and report the physics found (or 'unexplained' with its shape), "
            "or that the linear model is adequate. One session with a force channel is "
            "diagnosed as a rig test."
        ),
    )
    p.add_argument(
        "sessions",
        nargs="+",
        type=arg_existing_file(),
        metavar="SESSION.h5",
        help="BEFORE.h5 AFTER.h5, or one session (drive or rig test)",
    )
    p.add_argument(
        "--added-mass",
        type=arg_number("--added-mass", "added_mass"),
        metavar="KG",
        default=None,
        help="mass added on the body for the second drive (default: from the "
        "sessions' added_mass_kg)",
    )
    from fielddiag.commands.identify import arg_position

    p.add_argument("--added-mass-at", type=arg_position, metavar="X_M,Y_M", default=None,
                   help="full vehicle: where the added mass sits, metres behind the front axle "
                   "and left of the centre line (default: from the after session)")
    p.add_argument("--validate", nargs="+", type=arg_existing_file(), metavar="OTHER.h5",
                   default=None, help="full vehicle: drives of the same car on another "
                   "manoeuvre to score the linear and the chosen model on")
    p.add_argument("--json", metavar="OUT.json", help="write the diagnosis as JSON")
    p.add_argument("--plots", metavar="DIR", help="write PNGs of the mismatch and the fits")
    p.set_defaults(func=run)


def _print_summary(out: dict) -> None:
    from fielddiag.diagnose.report import format_summary

    print(format_summary(out))


def run(args: argparse.Namespace) -> int:
    from fielddiag.outputs import check_folder, check_target, write_plots, write_text
    from fielddiag.session import SessionReader

    paths = [Path(p) for p in args.sessions]
    if len(paths) > 2:
        raise FieldDiagError("give one session (a drive or a rig test) or two (before, after)")
    if args.json:
        check_target(args.json, overwrite=True, flag="--json")
    if args.plots:
        check_folder(args.plots)
    from fielddiag.vehicle.recording import is_full_vehicle_session

    full = [is_full_vehicle_session(p) for p in paths]
    if any(full):
        return _run_vehicle(args, paths, full)
    if args.added_mass_at is not None or args.validate:
        raise FieldDiagError("--added-mass-at and --validate are for full-vehicle sessions "
                             "(roles wheel_fl..body_rr); these are single-corner drives")
    is_rig = False
    if len(paths) == 1:
        with SessionReader(paths[0]) as s:
            is_rig = bool(s.channels_for_role("force"))
    if not is_rig:
        for p in paths:
            finite_session(p)
        if len(paths) == 2:
            from fielddiag.pairs import check_pair_before_work

            check_pair_before_work(paths[0], paths[1], args.added_mass)
    if is_rig:
        from fielddiag.diagnose.rig import diagnose_rig, rig_data_from_session
        from fielddiag.plots.diagnose import write_rig_plots as write_plots_into

        with SessionReader(paths[0]) as s:
            result = diagnose_rig(rig_data_from_session(s))
    else:
        from fielddiag.diagnose.engine import diagnose_sessions
        from fielddiag.plots.diagnose import write_diagnosis_plots as write_plots_into

        result = diagnose_sessions(
            paths,
            added_mass_kg=args.added_mass,
            progress=lambda msg: print(f"  {msg}", flush=True),  # stderr: errors only
        )
    out = result.to_dict()
    if args.plots:
        for png in write_plots(write_plots_into, args.plots, result):
            print(f"plot written: {png}")
    _print_summary(out)
    if args.json:
        write_text(args.json, json.dumps(out, indent=2) + "\n")
        print(f"JSON written to {args.json}")
    return 0


def _run_vehicle(args: argparse.Namespace, paths: list[Path], full: list[bool]) -> int:
    """The per-corner diagnosis of two full-vehicle sessions."""
    from fielddiag.outputs import write_text
    from fielddiag.vehicle.diagnose import diagnose_vehicle, format_vehicle_summary
    from fielddiag.vehicle.recording import FULL_VEHICLE_ROLES, read_vehicle_recording

    if len(paths) != 2 or not all(full):
        raise FieldDiagError("a full-vehicle diagnosis needs two full-vehicle sessions (roles "
                             "wheel_fl..body_rr): BEFORE.h5 AFTER.h5 --added-mass KG "
                             "--added-mass-at X_M,Y_M")
    if args.plots:
        raise FieldDiagError("--plots is not available for full-vehicle sessions yet; leave it "
                             "out")
    validate_paths = [Path(p) for p in args.validate or []]
    for p in (*paths, *validate_paths):
        finite_session(p, FULL_VEHICLE_ROLES)
    before = read_vehicle_recording(paths[0], label="before")
    after = read_vehicle_recording(paths[1], label="after")
    validate = [read_vehicle_recording(p, label="validate") for p in validate_paths]
    result = diagnose_vehicle(before, after, added_mass_kg=args.added_mass,
                              added_mass_at_m=args.added_mass_at, validate=validate,
                              progress=lambda msg: print(f"  {msg}", flush=True))
    out = result.to_dict()
    print(format_vehicle_summary(out))
    if args.json:
        write_text(args.json, json.dumps(out, indent=2) + "\n")
        print(f"JSON written to {args.json}")
    return 0
