"""The ``fielddiag`` command line.

Each sub-command lives in its own module under :mod:`fielddiag.commands` and exposes
``register(subparsers)``; this module only discovers them, parses the arguments and turns
errors a user can cause into one readable line and exit status 1.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import re
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


class OneLineParser(argparse.ArgumentParser):
    """An argument parser whose usage errors are one line and exit status 1, like every
    other error a user can fix (argparse's default prints the usage and exits 2)."""

    def error(self, message: str) -> None:  # type: ignore[override]
        # "argument --added-mass: --added-mass nan: give ..." -> the validator's own line
        m = re.match(r"argument ([^:]+): (.*)$", message, re.S)
        if m and any(m.group(2).startswith(name) for name in m.group(1).split("/")):
            message = m.group(2)
        message = " ".join(message.split())
        self.exit(1, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _command_name(module: str) -> str:
    """The command a module registers: ``import_`` -> ``import``, ``virtual_daq`` ->
    ``virtual-daq``."""
    return module.rstrip("_").replace("_", "-")


def build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The parser of every command, or, when ``argv`` names a command, of that one only:
    a command's module imports only what it needs, so ``fielddiag info`` does not pay for
    importing the numerics of ``fit``."""
    parser = OneLineParser(
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
    wanted = next((a for a in (argv or []) if not a.startswith("-")), None)
    chosen = [n for n in ordered if _command_name(n) == wanted]
    for name in chosen or ordered:
        module = importlib.import_module(f"fielddiag.commands.{name}")
        module.register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser(argv)
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help, --version (0) or a usage error (1, one line)
        return exc.code if isinstance(exc.code, int) else 1
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
