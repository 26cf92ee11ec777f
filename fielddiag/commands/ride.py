"""``fielddiag ride SESSION.h5 [--plots DIR] [--json OUT]``: what a body accelerometer
alone says (vertical spectrum, dominant frequencies against speed)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from fielddiag.errors import FieldDiagError
from fielddiag.validate import arg_existing_file


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "ride",
        help="body-only analysis: vertical spectrum and dominant frequencies against speed",
        description=(
            "For drives with only a body accelerometer (no wheel sensor, so no "
            "identification): the spectrum of the vertical body acceleration, its dominant "
            "frequencies, and how they move with vehicle speed."
        ),
    )
    p.add_argument("session", type=arg_existing_file(),
                   help="session file (.h5) with a body channel")
    p.add_argument("--plots", metavar="DIR", help="write ride_spectrum.png and ride_vs_speed.png")
    p.add_argument("--json", metavar="OUT.json", help="write the analysis as JSON")
    p.set_defaults(func=run)


def format_ride(a) -> str:
    """Readable summary of a RideAnalysis."""
    lines = [
        f"body vertical acceleration: {a.duration_s:.0f} s at {a.sample_rate_hz:.1f} Hz, "
        f"rms {a.rms_mps2:.3f} m/s2",
        "dominant frequencies: "
        + (", ".join(f"{p.freq_hz:.2f} Hz" for p in a.peaks) or "none stand out"),
    ]
    for tr in a.tracks:
        kind = (
            f"moves with speed ({tr.slope_hz_per_mps:+.3f} Hz per m/s)"
            if tr.implied_rolling_radius_m
            else "does not move with speed: a resonance of the car"
        )
        lines.append(f"  {tr.mean_freq_hz:.2f} Hz {kind}")
    lines += [f"note: {n}" for n in a.notes]
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from fielddiag.drive import read_accel_channel
    from fielddiag.outputs import check_folder, check_target, write_plots, write_text
    from fielddiag.session import SessionReader

    if args.json:
        check_target(args.json, overwrite=True, flag="--json")
    if args.plots:
        check_folder(args.plots)
    t, a, body = read_accel_channel(args.session, "body", purpose="the ride analysis")
    with SessionReader(args.session) as s:
        speed_t = speed_v = None
        if any(sig.role == "speed" for sig in s.signals):
            speed_t, speed_v = s.signal(s.signal_for_role("speed").name)
    bad = int(a.size - np.count_nonzero(np.isfinite(a)))
    if bad:
        raise FieldDiagError(
            f"{args.session}: the body channel {body.name} holds {bad} of {a.size} samples that "
            "are not finite numbers (NaN or infinite); re-import or re-record the drive")
    from fielddiag.identify.ride import analyse_ride

    analysis = analyse_ride(a, t, speed_time_s=speed_t, speed_mps=speed_v)
    print(format_ride(analysis))
    if args.plots:
        from fielddiag.plots import plot_ride

        for png in write_plots(plot_ride, args.plots, analysis, title=Path(args.session).name):
            print(f"plot written: {png}")
    if args.json:
        write_text(args.json, json.dumps(analysis.to_dict(), indent=2) + "\n")
        print(f"JSON written to {args.json}")
    return 0
