"""``fielddiag import FILE -o SESSION.h5 ...``: bring a recording made elsewhere into a session."""

from __future__ import annotations

import argparse
from pathlib import Path

from fielddiag.channels import SessionMetadata
from fielddiag.errors import ImportFormatError

FORMATS = ("csv",)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "import",
        help="import a CSV (or other) recording into a session",
        description=(
            "Import a recording into a session file. CSV: one row per sample with a header; "
            "map columns to roles with --role ROLE=COLUMN (roles: wheel, body, speed, and for "
            "rig tests force, displacement, acceleration; any other ROLE keeps the column "
            "under that name)."
        ),
    )
    p.add_argument("file", help="file to import")
    p.add_argument("-o", "--output", required=True, help="session file to write (.h5)")
    p.add_argument(
        "--format",
        default=None,
        help=f"file format (default: from the file name; {', '.join(FORMATS)})",
    )
    p.add_argument("--role", action="append", metavar="ROLE=COLUMN", help="map a column to a role")
    p.add_argument("--time", dest="time_column", metavar="COLUMN", help="column holding time")
    p.add_argument("--time-unit", default="s", help="unit of the time column: s, ms, us")
    p.add_argument("--accel-unit", default="m/s2", help="unit of acceleration columns: m/s2 or g")
    p.add_argument("--speed-unit", default="m/s", help="unit of the speed column: m/s, km/h, mph")
    p.add_argument(
        "--added-mass",
        type=float,
        default=0.0,
        metavar="KG",
        help="mass added to the body for this drive",
    )
    p.add_argument("--vehicle", default="", help="vehicle name")
    p.add_argument("--corner", default="", help="corner, e.g. front-left")
    p.add_argument("--operator", default="", help="who recorded it")
    p.add_argument("--notes", default="", help="free text")
    p.add_argument("--overwrite", action="store_true", help="replace the output if it exists")
    p.set_defaults(func=run)


def _detect_format(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix in (".csv", ".txt", ".tsv"):
        return "csv"
    raise ImportFormatError(
        f"cannot tell the format of {path.name} from its name; pass --format ({', '.join(FORMATS)})"
    )


def run(args: argparse.Namespace) -> int:
    from fielddiag.io.csv_import import CsvImportOptions, import_csv, parse_role_args

    src = Path(args.file)
    fmt = args.format or _detect_format(src)
    if fmt not in FORMATS:
        raise ImportFormatError(f"unknown format {fmt!r}; known: {', '.join(FORMATS)}")
    meta = SessionMetadata(
        vehicle=args.vehicle,
        corner=args.corner,
        operator=args.operator,
        added_mass_kg=args.added_mass,
        notes=args.notes,
    )
    if not args.time_column:
        raise ImportFormatError("say which column holds the time with --time COLUMN")
    options = CsvImportOptions(
        roles=parse_role_args(args.role),
        time_column=args.time_column,
        time_unit=args.time_unit,
        accel_unit=args.accel_unit,
        speed_unit=args.speed_unit,
    )
    out = import_csv(src, args.output, options, meta, overwrite=args.overwrite)
    print(f"wrote {out}")
    return 0
