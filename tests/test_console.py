"""The console status of a recording (fielddiag.console), on hand-written statuses."""

from __future__ import annotations

import io

from fielddiag.console import StatusPrinter, format_status, status_lines


def _status(**over) -> dict:
    st = {
        "state": "recording", "elapsed_s": 12.34, "sample_rate_hz": 500.0,
        "measured_rate_hz": 499.6, "frames_received": 1234, "frames_lost": 3,
        "crc_errors": 2, "gaps": 1, "drift_ppm": -41.6, "buffer_fill": 0.125,
        "file_size_bytes": 2_345_678, "connected": True, "last_error": "",
        "sources": [{"kind": "daq"},
                    {"kind": "can", "frame_rate_hz": 124.4,
                     "last_values": {"WHEEL_SPEED_FL": 9.0, "vehicle_speed": 10.0}}],
    }
    st.update(over)
    return st


def test_one_line_holds_the_rates_counters_speed_and_sizes() -> None:
    line = format_status(_status())
    assert line.split(" | ") == [
        "   12.3 s", "DAQ    500 Hz", "frames 1234 lost 3 crc 2 gaps 1", "drift -42 ppm",
        "CAN   124 fr/s vehicle_speed 36.0 km/h",  # 10 m/s = 36 km/h
        "buf  12%", "2.3 MB"]


def test_nominal_rate_before_a_measurement_and_no_daq_fields_without_a_daq() -> None:
    assert "DAQ 500 Hz" in format_status(_status(measured_rate_hz=None))
    can_only = format_status(_status(sample_rate_hz=None, drift_ppm=None))
    assert "DAQ" not in can_only and "frames" not in can_only and "CAN" in can_only


def test_a_pulled_cable_and_an_error_are_shown_the_error_cut_to_60_characters() -> None:
    err = "the recording stopped: reading serial:///dev/ttyUSB0 failed " + "x" * 40
    line = format_status(_status(connected=False, last_error=err))
    assert "DISCONNECTED" in line and line.endswith(f"[{err[:60]}]")
    # once stopped, a source that is gone is no longer news
    assert "DISCONNECTED" not in format_status(_status(connected=False, state="stopped"))


def test_status_lines_say_why_there_is_no_estimate() -> None:
    assert status_lines(_status()) == [format_status(_status())]
    lines = status_lines(_status(online_error="no DAQ: nothing to estimate from"))
    assert lines[1] == "on-line estimate unavailable: no DAQ: nothing to estimate from"


def test_a_log_gets_one_full_line_per_update() -> None:
    log = io.StringIO()
    printer = StatusPrinter(log)  # a StringIO is no terminal
    assert printer.terminal is False
    st = _status(online_error="the on-line estimator cannot run: " + "y" * 200)
    printer.show(st)
    printer.show(st)
    printer.finish()
    lines = log.getvalue().split("\n")
    assert lines[2] == "" and lines[0] == lines[1] == " | ".join(status_lines(st))
    assert len(lines[0]) > 250  # nothing cut


def test_a_terminal_is_redrawn_in_place_wrapped_to_its_width() -> None:
    term = io.StringIO()
    printer = StatusPrinter(term, terminal=True, width=50)
    st = _status(online_error="z" * 30 + " " + "w" * 30)
    printer.show(st)
    first = term.getvalue()
    rows = first.removeprefix("\r\x1b[J").split("\n")
    assert all(len(r) <= 49 for r in rows) and len(rows) >= 4
    # every word of every line is there, in order: wrapped, never cut
    assert " ".join(rows).split() == " ".join(status_lines(st)).split()
    printer.show(st)
    second = term.getvalue()[len(first):]
    # back up to the first row of the last redraw, clear, redraw the same rows
    assert second == f"\r\x1b[{len(rows) - 1}A\x1b[J" + "\n".join(rows)
    printer.finish()
    assert term.getvalue().endswith("\n")
