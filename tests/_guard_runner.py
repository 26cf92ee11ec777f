"""A child process that opens damaged session files for the guard's fuzz test.

One JSON request per line on stdin: ``{"path": ..., "mode": "guarded" | "direct"}``;
one JSON answer per line on stdout: ``{"status": "ok" | "fielddiag" | "other", ...}``.
``guarded`` opens through :func:`fielddiag.session_guard.open_untrusted`, ``direct`` with
:class:`fielddiag.session.SessionReader`; both then read everything the session holds.
The parent enforces the per-case time limit and sees a crash as the pipe closing.
"""

import json
import sys
import traceback

from fielddiag.errors import FieldDiagError
from fielddiag.session import SessionReader
from fielddiag.session_guard import open_untrusted


def read_all(path: str, mode: str) -> dict:
    reader = open_untrusted(path) if mode == "guarded" else SessionReader(path)
    with reader as s:
        info = s.info()
        n = sum(len(s.read(c.name)) for c in s.channels)
        for sig in s.signals:
            s.signal(sig.name)
        s.can_frames()
        s.events  # noqa: B018
    return {"samples": info["samples"], "values": n}


def main() -> None:
    print(json.dumps({"ready": True}), flush=True)
    for line in sys.stdin:
        req = json.loads(line)
        try:
            answer = {"status": "ok", **read_all(req["path"], req.get("mode", "guarded"))}
        except FieldDiagError as exc:
            answer = {"status": "fielddiag", "message": str(exc)}
        except Exception as exc:  # noqa: BLE001 (reported to the parent, which fails)
            answer = {"status": "other", "message": f"{type(exc).__name__}: {exc}",
                      "traceback": traceback.format_exc()}
        print(json.dumps(answer), flush=True)


if __name__ == "__main__":
    main()
