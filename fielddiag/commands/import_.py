"""``fielddiag import FILE -o SESSION.h5 ...``: bring a recording made elsewhere into a session."""

from __future__ import annotations

import argparse
from pathlib import Path

from fielddiag.channels import SessionMetadata
from fielddiag.errors import ImportFormatError
from fielddiag.io.formats import FORMATS, detect_format, get_format, import_file, options_from_args
from fielddiag.validate import arg_number


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "import",
        help="import a recording (CSV, PVS, CAN log, MDF4...) into a session",
        description=(
            "Import a recording into a session file. The format is detected from the file "
            "(--format overrides): "
            + "; ".join(f"{f.name}: {f.description}" for f in FORMATS.values())
            + ". CSV: map columns to roles with --role ROLE=COLUMN (roles: wheel, body, "
            "speed, and for rig tests force, displacement, acceleration; --role other=COLUMN, "
            "or any other name, keeps the column as a channel named after the column; a name "
            "close to a role, such as whel, is refused as a typo). CAN logs and MDF4 bus "
            "logging: --dbc FILE and --signal NAME."
        ),
    )
    p.add_argument("file", help="file (or PVS folder) to import")
    p.add_argument("-o", "--output", required=True, help="session file to write (.h5)")
    p.add_argument(
        "--format",
        default=None,
        help=f"file format (default: detected from the file; {', '.join(FORMATS)})",
    )
    p.add_argument("--role", action="append", metavar="ROLE=COLUMN",
                   help="CSV/MDF4: map a column or channel to a role")
    p.add_argument("--time", dest="time_column", metavar="COLUMN", help="CSV: column holding time")
    p.add_argument("--time-unit", default=None,
                   help="CSV: unit of the time column: s (default), ms, us")
    p.add_argument("--accel-unit", default=None,
                   help="CSV: unit of acceleration columns: m/s2 (default) or g")
    p.add_argument("--speed-unit", default=None,
                   help="CSV: unit of the speed column: m/s (default), km/h, mph")
    p.add_argument("--dbc", action="append", metavar="[BUS=]FILE",
                   help="CAN log/MDF4: DBC to decode CAN frames (repeatable; BUS=FILE binds it "
                        "to one bus, e.g. can1=radar.dbc)")
    p.add_argument("--signal", action="append", metavar="NAME",
                   help="CAN log/MDF4: signal to decode, SIGNAL, MESSAGE.SIGNAL or "
                        "ALIAS=MESSAGE.SIGNAL (repeatable; "
                        "default: vehicle speed and wheel speeds)")
    p.add_argument("--channel", action="append", metavar="NAME",
                   help="MDF4: channel to import (repeatable; default: all numeric channels)")
    p.add_argument("--side", choices=("left", "right"), default=None,
                   help="PVS: sensor network to import (default: from the file name, or left)")
    p.add_argument("--vertical-axis", choices=("x", "y", "z", "auto"), default=None,
                   help="PVS: accelerometer axis that is vertical (default: auto, from gravity)")
    p.add_argument(
        "--added-mass",
        type=arg_number("--added-mass", "session_added_mass"),
        default=0.0,
        metavar="KG",
        help="mass added to the body for this drive",
    )
    p.add_argument("--vehicle", default="",
                   help="vehicle name, or a vehicle file VEHICLE.json (wheelbase, tracks, "
                   "body-sensor positions) for a full-vehicle import with all eight roles "
                   "wheel_fl..body_rr, and speed, accel_long, accel_lat")
    p.add_argument("--corner", default="", help="corner, e.g. front-left")
    p.add_argument("--operator", default="", help="who recorded it")
    p.add_argument("--notes", default="", help="free text")
    p.add_argument("--overwrite", action="store_true", help="replace the output if it exists")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from fielddiag.outputs import atomic_file

    src = Path(args.file)
    if not src.exists():
        raise ImportFormatError(f"{src} does not exist; give the file (or PVS folder) to import")
    try:
        fmt = get_format(args.format).name if args.format else detect_format(src)
    except ImportFormatError as exc:
        if not args.format:
            raise
        raise ImportFormatError(f"{exc}; give one of them with --format, or leave --format "
                                "out to detect the format from the file") from None
    vehicle_name, extra = args.vehicle, {}
    if args.vehicle.lower().endswith(".json"):
        vehicle_name, extra = _full_vehicle(args, fmt)
    meta = SessionMetadata(
        vehicle=vehicle_name,
        corner=args.corner,
        operator=args.operator,
        added_mass_kg=args.added_mass,
        notes=args.notes,
        extra=extra,
    )
    # the session is written under a temporary name beside the output and moved into place
    # only when complete: a failed import (bad row, full disk) leaves nothing behind
    with atomic_file(args.output, overwrite=args.overwrite) as tmp:
        import_file(src, tmp, format=fmt, metadata=meta, overwrite=True,
                    **options_from_args(fmt, args))
    print(f"wrote {args.output}")
    return 0


def _full_vehicle(args: argparse.Namespace, fmt: str) -> tuple[str, dict]:
    """(vehicle name, metadata extra) of a full-vehicle import from ``--vehicle FILE.json``."""
    from fielddiag.io.csv_import import parse_role_args
    from fielddiag.vehicle.geometry import load_vehicle
    from fielddiag.vehicle.recording import FULL_VEHICLE_ROLES

    geometry = load_vehicle(args.vehicle)
    if fmt == "csv":
        roles = parse_role_args(args.role)
        missing = [r for r in FULL_VEHICLE_ROLES if r not in roles]
        if missing:
            raise ImportFormatError(
                f"a full-vehicle import (--vehicle {Path(args.vehicle).name}) needs all eight "
                f"accelerometer roles; missing {', '.join(missing)} (give --role "
                f"{missing[0]}=COLUMN ...)")
    return Path(args.vehicle).stem, {"vehicle": geometry.to_dict(), "full_vehicle": True}
