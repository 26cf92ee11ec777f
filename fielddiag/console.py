"""The live status of a recording on a console: one line of counters, the on-line estimate.

:func:`format_status` turns :meth:`fielddiag.recorder.Recorder.status` into one line,
:func:`status_lines` adds the on-line estimate and the advice for the technician, and
:class:`StatusPrinter` shows them on a terminal (redrawn in place, wrapped, never cut) or
in a log (one full line per update). Nothing here records or computes anything.
"""

from __future__ import annotations

import shutil
import sys
import textwrap
from collections.abc import Mapping
from typing import Any, TextIO

__all__ = ["StatusPrinter", "format_status", "status_lines"]


def format_status(st: Mapping[str, Any]) -> str:
    """One console line of a recorder's status.

    Parameters
    ----------
    st : mapping
        :meth:`fielddiag.recorder.Recorder.status`: ``elapsed_s`` [s], ``sample_rate_hz``
        and ``measured_rate_hz`` [Hz], the frame counters, ``drift_ppm`` [ppm],
        ``buffer_fill`` (0..1), ``file_size_bytes`` [bytes], ``sources`` (each CAN source
        with ``frame_rate_hz`` [frames/s] and ``last_values``, speeds in m/s).

    Returns
    -------
    str
        The fields joined by `` | ``: elapsed time [s], DAQ rate [Hz] and counters, clock
        drift [ppm], per CAN source the frame rate and the vehicle speed [km/h], buffer
        fill [%], file size [MB], ``DISCONNECTED`` while a source is unplugged, and the
        start of the last error.
    """
    parts = [f"{st.get('elapsed_s', 0.0):7.1f} s"]
    if st.get("sample_rate_hz"):
        rate = st.get("measured_rate_hz")
        parts.append(
            f"DAQ {rate:6.0f} Hz" if rate is not None else f"DAQ {st['sample_rate_hz']:g} Hz"
        )
        parts.append(
            f"frames {st['frames_received']} lost {st['frames_lost']} crc {st['crc_errors']} "
            f"gaps {st['gaps']}"
        )
        if st.get("drift_ppm") is not None:
            parts.append(f"drift {st['drift_ppm']:+.0f} ppm")
    for s in st.get("sources", []):
        if s.get("kind") == "can":
            fr = s.get("frame_rate_hz")
            txt = f"CAN {fr:5.0f} fr/s" if fr is not None else "CAN -"
            for k, v in s.get("last_values", {}).items():
                if k == "vehicle_speed" or "SPEED" == k.upper():
                    txt += f" {k} {v * 3.6:.1f} km/h"
                    break
            parts.append(txt)
    parts.append(f"buf {100 * st.get('buffer_fill', 0.0):3.0f}%")
    parts.append(f"{st.get('file_size_bytes', 0) / 1e6:.1f} MB")
    if not st.get("connected", True) and st.get("state") == "recording":
        parts.append("DISCONNECTED")
    if st.get("last_error"):
        parts.append(f"[{st['last_error'][:60]}]")
    return " | ".join(parts)


def status_lines(st: Mapping[str, Any]) -> list[str]:
    """The live status as lines: recorder counters, then the on-line estimate and its advice.

    Parameters
    ----------
    st : mapping
        :meth:`fielddiag.recorder.Recorder.status`; its ``online`` entry (the on-line
        estimator's status) or ``online_error`` entry, if any, adds lines.

    Returns
    -------
    list of str
        :func:`format_status`, then (with an estimate) the estimate per parameter and
        ``advice: ...``, or the reason there is no estimate. Nothing is cut: the advice
        for the technician is a line of its own, whole.
    """
    lines = [format_status(st)]
    online = st.get("online")
    if online:  # the estimator is running, so its module is imported already
        from fielddiag.identify.online import format_estimate

        lines.append(format_estimate(online))
        lines.append("advice: " + online.get("advice", ""))
    elif st.get("online_error"):
        lines.append("on-line estimate unavailable: " + st["online_error"])
    return lines


class StatusPrinter:
    """Show :meth:`fielddiag.recorder.Recorder.status` on a console, the on-line estimate
    included.

    On a terminal the status lines are redrawn in place, wrapped to the terminal width
    (never cut). Otherwise (a log file, a pipe) each update is one full line appended.

    Parameters
    ----------
    stream : text stream or None
        Default ``sys.stderr``.
    terminal : bool or None
        Redraw in place; default: whether ``stream`` is a terminal.
    width : int or None
        Terminal width [columns]; default: the terminal's size.
    """

    def __init__(self, stream: TextIO | None = None, *, terminal: bool | None = None,
                 width: int | None = None) -> None:
        self.stream = stream or sys.stderr
        if terminal is None:
            isatty = getattr(self.stream, "isatty", None)
            terminal = bool(isatty()) if isatty is not None else False
        self.terminal = terminal
        self.width = width
        self._rows_shown = 0  # terminal rows of the last redraw

    def _rows(self, lines: list[str]) -> list[str]:
        width = self.width or shutil.get_terminal_size((120, 24)).columns
        room = max(20, width - 1)  # a full last column would make the terminal wrap itself
        rows: list[str] = []
        for line in lines:
            if len(line) <= room:
                rows.append(line)
            else:
                rows.extend(textwrap.wrap(line, room, subsequent_indent="    ",
                                          break_on_hyphens=False))
        return rows

    def show(self, st: Mapping[str, Any]) -> None:
        """Print one status.

        Parameters
        ----------
        st : mapping
            :meth:`fielddiag.recorder.Recorder.status`.
        """
        lines = status_lines(st)
        if not self.terminal:
            self.stream.write(" | ".join(lines) + "\n")
        else:
            rows = self._rows(lines)
            up = f"\x1b[{self._rows_shown - 1}A" if self._rows_shown > 1 else ""
            # back to the first row of the last redraw, clear to the end of the screen
            self.stream.write("\r" + up + "\x1b[J" + "\n".join(rows))
            self._rows_shown = len(rows)
        self.stream.flush()

    def finish(self) -> None:
        """End the live display: what follows is printed below it."""
        if self.terminal and self._rows_shown:
            self.stream.write("\n")
            self.stream.flush()
        self._rows_shown = 0
