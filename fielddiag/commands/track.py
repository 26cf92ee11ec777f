"""``fielddiag track``: replay a session through the on-line parameter estimator.

    fielddiag track drive.h5 --every 5
    fielddiag track drive.h5 --compare --json track.json

The recording is fed in blocks, in time order, to the same estimator that runs during
``fielddiag record`` (a Kalman filter on the parameters per unit sprung mass, equation
error on causally integrated accelerations). Every ``--every`` seconds of data it prints
the estimates with their relative standard deviation, the information gathered per
parameter in bits, and the advice line the technician would see. ``--compare`` also runs
the off-line grey-box fit on the same session and reports when the on-line estimate came
within 5 % of it.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

from fielddiag.validate import arg_existing_file, arg_number, finite_session


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "track",
        help="replay a session through the on-line estimator (estimates, bits, advice)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("session", metavar="SESSION.h5", type=arg_existing_file())
    p.add_argument("--every", type=arg_number("--every", "interval"), default=5.0, metavar="S",
                   help="print a line every S seconds of data (default 5)")
    p.add_argument("--block", type=arg_number("--block", "interval"), default=0.1, metavar="S",
                   help="block length fed at once, as the recorder does (default 0.1 s)")
    p.add_argument("--terms", metavar="NAME[,NAME...]", default="",
                   help="effect terms added to the linear spring and damper")
    p.add_argument("--cutoff", type=arg_number("--cutoff", "frequency"), default=0.5, metavar="HZ",
                   help="high-pass corner of the causal integration (default 0.5 Hz)")
    p.add_argument("--target", type=arg_number("--target", "percent"), default=5.0, metavar="PCT",
                   help="relative standard deviation counted as enough (default 5 %%)")
    p.add_argument("--body-mass", type=arg_number("--body-mass", "body_mass"),
                   default=None, metavar="KG",
                   help="known sprung mass: report absolute values too")
    p.add_argument("--compare", action="store_true",
                   help="also fit off-line and report the time to come within 5 %% of it")
    p.add_argument("--json", nargs="?", const="-", default=None, metavar="OUT",
                   help="write the snapshots (and the comparison) as JSON to OUT "
                        "(default: standard output)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from fielddiag.outputs import check_target, write_text

    if args.json and args.json != "-":
        check_target(args.json, overwrite=True, flag="--json")
    finite_session(args.session)
    from fielddiag.commands.fit import build_model
    from fielddiag.drive import read_corner_drive
    from fielddiag.identify.online import (
        OnlineEstimator,
        convergence_time,
        format_status,
        replay,
    )

    model = build_model(args.terms)
    drive = read_corner_drive(args.session, purpose="the on-line estimate")
    t, aw, ab = drive.time_s, drive.wheel_accel_mps2, drive.body_accel_mps2
    fs, dm = drive.sample_rate_hz, drive.added_mass_kg
    est = OnlineEstimator(fs, model, cutoff_hz=args.cutoff, target_rel_std=args.target / 100,
                          body_mass_kg=args.body_mass, added_mass_kg=dm).warm_up()
    out = sys.stderr if args.json == "-" else sys.stdout
    t0 = time.perf_counter()
    snaps = replay(est, t, aw, ab, block_s=args.block, every_s=args.every,
                   callback=lambda st: print(format_status(st), file=out))
    wall = time.perf_counter() - t0
    final = snaps[-1]
    data_s = t.size / fs
    print(f"advice: {final['advice']}", file=out)
    print(f"replayed {data_s:.1f} s of data in {wall:.2f} s ({data_s / wall:.0f}x real time; "
          f"estimator alone {final['realtime_factor'] or 0:.0f}x)", file=out)
    report: dict = {"session": str(args.session), "snapshots": snaps}
    if args.compare:
        from fielddiag.identify.greybox import GreyBoxData, fit_greybox

        fit = fit_greybox(GreyBoxData.from_session(args.session), model)
        conv = convergence_time(snaps, fit.per_unit_mass, 0.05)
        report["offline"] = fit.to_dict()
        report["time_to_converge_s"] = conv
        for p in final["parameters"]:
            off = fit.per_unit_mass[p["key"]]
            print(f"  {p['name']:<40} on-line {p['value']:.5g}  off-line {off:.5g}  "
                  f"({100 * (p['value'] / off - 1):+.2f} %)", file=out)
        print("within 5 % of the off-line fit after "
              + (f"{conv:.1f} s of data" if conv is not None else "never (not yet)"), file=out)
    if args.json:
        text = json.dumps(report, indent=2)
        if args.json == "-":
            print(text)
        else:
            write_text(args.json, text + "\n")
    return 0

