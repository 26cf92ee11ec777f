"""``fielddiag export SESSION.h5 -o OUT.mf4|OUT.csv``: a session in formats other tools read."""

from __future__ import annotations

import argparse
from pathlib import Path

from fielddiag.errors import FieldDiagError
from fielddiag.validate import arg_existing_file

_HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"

EXPORT_FORMATS = ("mdf4", "csv")
_BY_SUFFIX = {".mf4": "mdf4", ".mdf": "mdf4", ".csv": "csv"}


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "export",
        help="export a session as MDF4 (for asammdf and other MDF tools) or CSV",
        description=(
            "Export a session. MDF4: channels with names, units and comments, each vehicle "
            "signal in its own channel group on its own time base, raw CAN frames as ASAM "
            "bus logging. CSV: OUT.csv holds time_s and the calibrated DAQ channels; every "
            "signal goes to OUT.signal.<name>.csv on its own time stamps, raw CAN frames to "
            "OUT.can_frames.csv, units and roles to OUT.fielddiag.json. `fielddiag import` "
            "reads either back into the same session."
        ),
    )
    p.add_argument("session", type=arg_existing_file(), help="session file (.h5)")
    p.add_argument("-o", "--output", required=True, help="file to write (.mf4 or .csv)")
    p.add_argument(
        "--format",
        choices=EXPORT_FORMATS,
        default=None,
        help="output format (default: from the output file name)",
    )
    p.add_argument("--overwrite", action="store_true", help="replace the output if it exists")
    p.set_defaults(func=run)


def export_format(out: Path, fmt: str | None) -> str:
    """The export format for ``out``: ``fmt`` if given, else from the file suffix."""
    if fmt:
        if fmt not in EXPORT_FORMATS:
            raise FieldDiagError(f"unknown export format {fmt!r}; use {', '.join(EXPORT_FORMATS)}")
        return fmt
    found = _BY_SUFFIX.get(out.suffix.lower())
    if found is None:
        raise FieldDiagError(
            f"cannot tell the export format from {out.name}; name it .mf4 or .csv, or pass "
            f"--format ({', '.join(EXPORT_FORMATS)})"
        )
    return found


def _is_session(path: Path) -> bool:
    """Whether ``path`` is an HDF5 file (a session): exports never replace one."""
    try:
        with open(path, "rb") as fh:
            return fh.read(8) == _HDF5_SIGNATURE
    except OSError:
        return False


def run(args: argparse.Namespace) -> int:
    from fielddiag.outputs import check_target

    out = Path(args.output)
    fmt = export_format(out, args.format)
    if out.exists() and (out.suffix.lower() in (".h5", ".hdf5") or _is_session(out)):
        raise FieldDiagError(f"{out} is a session (HDF5); an export never replaces a session, "
                             "even with --overwrite: name the output .mf4 or .csv")
    check_target(out, overwrite=args.overwrite)
    if fmt == "mdf4":
        from fielddiag.io.mdf import export_mdf

        written = [export_mdf(args.session, out, overwrite=args.overwrite)]
    else:
        from fielddiag.io.csv_export import export_csv

        written = export_csv(args.session, out, overwrite=args.overwrite)
    for path in written:
        print(f"wrote {path}")
    return 0
