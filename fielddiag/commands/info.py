"""``fielddiag info SESSION.h5 [--json]``: what a session holds."""

from __future__ import annotations

import argparse
import json

from fielddiag.session_guard import untrusted_info
from fielddiag.validate import arg_existing_file


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "info", help="show channels, units, duration, gaps and metadata of a session"
    )
    p.add_argument("session", type=arg_existing_file(), help="session file (.h5)")
    p.add_argument("--json", action="store_true", help="print JSON for scripts")
    p.set_defaults(func=run)


def format_info(info: dict) -> str:
    """Human-readable summary of :meth:`SessionReader.info`."""
    md = info["metadata"]
    lines = [
        f"{info['path']}",
        f"  vehicle {md['vehicle'] or '-'}, corner {md['corner'] or '-'}, "
        f"operator {md['operator'] or '-'}, added mass {md['added_mass_kg']:g} kg",
        f"  created {md['created']} with fielddiag {md['software_version']}"
        + ("" if info["closed_cleanly"] else "  [NOT CLOSED CLEANLY: recording interrupted]"),
        f"  {info['samples']} samples at {info['sample_rate_hz']:g} Hz "
        f"({info['time_base']} time base), duration {info['duration_s']:.3f} s",
        "  channels:",
    ]
    for c in info["channels"]:
        lines.append(
            f"    {c['name']:<16} {c['unit']:<8} role={c['role']:<12} axis={c['axis']:<3} "
            f"{c['sensor']}"
        )
    if info["signals"]:
        lines.append("  signals:")
        for s in info["signals"]:
            rate = f"{s['rate_hz']:.1f} Hz" if s["rate_hz"] else "-"
            lines.append(
                f"    {s['name']:<16} {s['unit']:<8} {s['samples']} samples, {rate}, "
                f"from {s['source'] or '?'} {s['message']}"
            )
    gaps = info["gaps"]
    lines.append(f"  gaps: {len(gaps)}, samples lost: {info['samples_lost']}")
    for g in gaps[:10]:
        lines.append(
            f"    {g['start_s']:.3f}-{g['end_s']:.3f} s: {g['samples_lost']} samples ({g['cause']})"
        )
    if len(gaps) > 10:
        lines.append(f"    ... {len(gaps) - 10} more")
    lines.append(f"  events: {info['events']}, raw CAN frames: {info['can_frames']}")
    nonzero = {k: v for k, v in info["counters"].items() if v}
    if nonzero:
        lines.append("  counters: " + ", ".join(f"{k}={v}" for k, v in nonzero.items()))
    if md["notes"]:
        lines.append(f"  notes: {md['notes']}")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    info = untrusted_info(args.session)
    if args.json:
        print(json.dumps(info, indent=2))
    else:
        print(format_info(info))
    return 0
