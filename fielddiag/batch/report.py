"""Text output of a batch: a progress bar while it runs and the final table."""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TextIO

from fielddiag.batch.summary import diagnose_text, suspension_text
from fielddiag.batch.task import PairOutcome

__all__ = ["Progress", "format_table", "short_path"]


def short_path(path: str | os.PathLike, root: Path) -> str:
    """``path`` relative to ``root`` when it lies under it."""
    p = Path(path)
    try:
        return p.relative_to(root).as_posix()
    except ValueError:
        return str(p)


def _fmt_duration(seconds: float) -> str:
    seconds = max(0.0, seconds)
    if seconds < 60:
        return f"{seconds:.0f}s"
    m, s = divmod(int(round(seconds)), 60)
    if m < 60:
        return f"{m}m{s:02d}s"
    h, m = divmod(m, 60)
    return f"{h}h{m:02d}m"


class Progress:
    """A progress bar on a terminal (redrawn in place), one line per pair otherwise.

    Parameters
    ----------
    total : int
        Pairs to run.
    root : Path
        Paths are printed relative to it.
    stream : text stream
        Where to draw (stderr by default, so stdout stays the table).
    """

    def __init__(self, total: int, root: Path, stream: TextIO | None = None) -> None:
        self.total = total
        self.root = root
        self.stream = stream or sys.stderr
        self.done = 0
        self.failed = 0
        self.t0 = time.monotonic()
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())

    def _bar(self, width: int = 30) -> str:
        filled = int(width * self.done / self.total) if self.total else width
        elapsed = time.monotonic() - self.t0
        eta = elapsed / self.done * (self.total - self.done) if self.done else float("nan")
        eta_text = _fmt_duration(eta) if self.done else "?"
        return (f"[{'#' * filled}{'.' * (width - filled)}] {self.done}/{self.total} pairs, "
                f"{self.failed} failed, {_fmt_duration(elapsed)} elapsed, ETA {eta_text}")

    def start(self, message: str) -> None:
        print(message, file=self.stream, flush=True)
        if self.tty:
            print(self._bar(), end="\r", file=self.stream, flush=True)

    def update(self, outcome: PairOutcome) -> None:
        self.done += 1
        self.failed += outcome.status == "failed"
        if self.tty:
            print(f"\x1b[2K{self._bar()}", end="\r", file=self.stream, flush=True)
            if outcome.status == "failed":
                print(f"\x1b[2Kfailed: {short_path(outcome.before, self.root)}: "
                      f"{outcome.message}", file=self.stream, flush=True)
                print(self._bar(), end="\r", file=self.stream, flush=True)
        else:
            status = f"{outcome.status:<6}"
            line = (f"[{self.done:>{len(str(self.total))}}/{self.total}] {status} "
                    f"{short_path(outcome.before, self.root)} + "
                    f"{short_path(outcome.after, self.root)} ({outcome.wall_s:.1f} s)")
            if outcome.status == "failed":
                line += f": {outcome.message}"
            print(line, file=self.stream, flush=True)

    def finish(self) -> None:
        if self.tty:
            print(f"\x1b[2K{self._bar()}", file=self.stream, flush=True)


def _step_summary(o: PairOutcome, step: str) -> dict:
    st = next((s for s in o.steps if s.step == step), None)
    return st.summary if st is not None and st.status != "failed" else {}


def format_table(
    outcomes: Sequence[PairOutcome],
    root: Path,
    unpaired: Sequence[tuple[Path, str]] = (),
    unreadable: Sequence[tuple[Path, str]] = (),
) -> str:
    """The final table: one line per pair (status, result or reason), then the sessions
    left out."""
    rows = [("status", "before", "after", "+kg", "suspension", "diagnosis", "time")]
    for o in outcomes:
        status = o.status if o.status != "skipped" else "up to date"
        rows.append((status, short_path(o.before, root), short_path(o.after, root),
                     f"{o.added_mass_kg:g}", suspension_text(_step_summary(o, "identify"),
                                     _step_summary(o, "diagnose")),
                     diagnose_text(_step_summary(o, "diagnose")),
                     "-" if o.status == "skipped" else f"{o.wall_s:.1f} s"))
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    lines = ["  ".join(cell.ljust(w) for cell, w in zip(r, widths, strict=True)).rstrip()
             for r in rows]
    lines.insert(1, "  ".join("-" * w for w in widths))
    failed = [o for o in outcomes if o.status == "failed"]
    if failed:
        lines.append("")
        lines.append("Failed:")
        for o in failed:
            lines.append(f"  {short_path(o.before, root)} + {short_path(o.after, root)}: "
                         f"{o.message}")
    if unreadable:
        lines.append("")
        lines.append("Unreadable sessions (left out):")
        lines.extend(f"  {short_path(p, root)}: {why}" for p, why in unreadable)
    if unpaired:
        lines.append("")
        lines.append("Not paired (left out):")
        lines.extend(f"  {short_path(p, root)}: {why}" for p, why in unpaired)
    return "\n".join(lines)
