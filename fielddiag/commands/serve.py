"""``fielddiag serve [--root DIR] [--host 127.0.0.1] [--port 8080]``: the web dashboard."""

from __future__ import annotations

import argparse
from pathlib import Path

from fielddiag.errors import FieldDiagError
from fielddiag.validate import arg_int, arg_number


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "serve",
        help="web dashboard: sessions, live recording, identification, diagnosis",
        description=(
            "Serve the dashboard for the sessions under a folder. It listens on 127.0.0.1 "
            "(this computer only) by default; any other address requires an access token, "
            "generated and printed unless given with --token."
        ),
    )
    p.add_argument("--root", default=".", help="folder holding the sessions (default: here)")
    p.add_argument("--host", default="127.0.0.1",
                   help="address to listen on (0.0.0.0: every interface; needs a token)")
    p.add_argument("--port", type=arg_int("--port", 1, 65535, "a TCP port"),
                   default=8080, help="port (default 8080)")
    p.add_argument("--token", default=None,
                   help="access token (default: generated when --host is not loopback)")
    p.add_argument("--max-upload-mb", type=arg_number("--max-upload-mb", "upload_mb"),
                   default=200.0, metavar="MB",
                   help="largest file accepted by upload (default 200 MB)")
    p.add_argument("--show", action="store_true", help="open a browser tab")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from fielddiag.web.app import serve

    if not 0 < args.port < 65536:
        raise FieldDiagError(f"--port must be between 1 and 65535, not {args.port}")
    if args.max_upload_mb <= 0:
        raise FieldDiagError("--max-upload-mb must be positive")
    serve(
        Path(args.root),
        host=args.host,
        port=args.port,
        token=args.token,
        show=args.show,
        max_upload_bytes=int(args.max_upload_mb * 1e6),
        print_address=lambda line: print(line, flush=True),
    )
    return 0
