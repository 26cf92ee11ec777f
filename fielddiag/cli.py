"""The ``fielddiag`` command line.

Each sub-command lives in its own module under :mod:`fielddiag.commands` and exposes
``register(subparsers)``; this module only discovers them, parses the arguments and turns
errors a user can cause into one readable line and exit status 1.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys
from collections.abc import Sequence

from fielddiag import __version__
from fielddiag.errors import FieldDiagError

#: The order in which commands are listed in ``fielddiag --help``; modules not named here
#: are appended alphabetically.
COMMAND_ORDER = (
    "demo",
    "simulate",
    "import_",
    "info",
    "identify",
    "fit",
    "diagnose",
    "track",
    "record",
    "ports",
    "virtual_daq",
    "virtual_ecu",
    "serve",
    "reprocess",
    "export",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="fielddiag",
        description=(
            "Diagnose vehicle suspensions from field recordings: record test drives, identify "
            "sprung mass, stiffness and damping, and find the physics a linear model leaves out."
        ),
    )
    parser.add_argument("--version", action="version", version=f"fielddiag {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    import fielddiag.commands as pkg

    names = [m.name for m in pkgutil.iter_modules(pkg.__path__) if not m.name.startswith("_")]
    ordered = [n for n in COMMAND_ORDER if n in names] + sorted(set(names) - set(COMMAND_ORDER))
    for name in ordered:
        module = importlib.import_module(f"fielddiag.commands.{name}")
        module.register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 0
    from fielddiag.session_guard import guarded_opens

    try:
        with guarded_opens():  # sessions are probed in a time-limited worker first
            result = args.func(args)
    except FieldDiagError as exc:
        print(f"fielddiag {args.command}: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"fielddiag {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return 0
    return int(result or 0)


if __name__ == "__main__":
    sys.exit(main())
