"""``fielddiag diagnose``: where the linear model and the recording disagree, and why.

* ``fielddiag diagnose BEFORE.h5 AFTER.h5 --added-mass KG`` : a car corner, two drives.
* ``fielddiag diagnose SESSION.h5`` : one drive (parameters per unit sprung mass), or a rig
  test (a session with a ``force`` channel and a ``displacement``/``acceleration`` one).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from fielddiag.errors import FieldDiagError
from fielddiag.validate import arg_existing_file, arg_number, finite_session


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "diagnose",
        help="locate the mismatch between model and recording and name the missing physics",
        description=(
            "Fit the linear model, locate where it and the recording differ (time windows, "
            "frequency band, region of suspension travel and speed), test the effects a linear "
            "model leaves out (coulomb_friction, cubic_stiffness, bump_stop, "
            "asymmetric_damping, and pairs of them) on data held out from the fit, and report "
            "the physics found, or that the linear model is adequate, plus warnings about "
            "the data itself. One session with a force channel is diagnosed as a rig test."
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
    is_rig = False
    if len(paths) == 1:
        with SessionReader(paths[0]) as s:
            is_rig = bool(s.channels_for_role("force"))
    if not is_rig:
        for p in paths:
            finite_session(p)
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
