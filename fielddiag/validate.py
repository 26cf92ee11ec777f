"""One validation layer for the numbers and paths a user gives.

The command line (as argparse ``type=`` helpers), the dashboard's forms and the batch
manifest all check their input here, so a value is refused the same way wherever it comes
from: finite, within a physical range a technician can defend, and with the unit and what
to give instead in the one-line message, e.g.::

    --added-mass nan: give the mass added to the body in kg, a finite number between 0 and 2000

The ranges (:data:`RANGES`) are deliberately wide: they catch typos and nonsense (a mass
of 1e12 kg, a negative duration, NaN) without second-guessing an unusual but real test.
"""

from __future__ import annotations

import argparse
import math
import os
import stat
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from fielddiag.errors import FieldDiagError, InvalidValueError

__all__ = [
    "RANGES",
    "Range",
    "arg_int",
    "arg_number",
    "band_hz",
    "check_number",
    "existing_file",
    "integer",
    "number",
]


@dataclass(frozen=True)
class Range:
    """A physical quantity's accepted range.

    Attributes
    ----------
    what : str
        What the value is, as the message names it ("the mass added to the body").
    unit : str
        Its unit ("kg"), or "" for a pure number.
    lo, hi : float
        The bounds.
    lo_open, hi_open : bool
        Whether the bound itself is refused (``lo_open``: the value must exceed ``lo``).
    why : str
        The reason for the range, for the documentation (not printed).
    """

    what: str
    unit: str
    lo: float
    hi: float
    lo_open: bool = False
    hi_open: bool = False
    why: str = ""

    def describe(self) -> str:
        """``"a finite number between 0 and 2000"``, plus ", more than 0" (or ", less
        than ...") where the bound itself is refused."""
        text = f"a finite number between {self.lo:g} and {self.hi:g}"
        if self.lo_open:
            text += f", more than {self.lo:g}"
        if self.hi_open:
            text += f", less than {self.hi:g}"
        return text

    def contains(self, value: float) -> bool:
        if not math.isfinite(value):
            return False
        above = value > self.lo if self.lo_open else value >= self.lo
        below = value < self.hi if self.hi_open else value <= self.hi
        return above and below


#: The ranges every entry point uses, by name. Each states why it is what it is.
RANGES: dict[str, Range] = {
    # a test mass is sandbags or weights a technician lifts onto one corner's body: a
    # tonne is already a truck's worth; 2000 kg leaves room for heavy vehicles
    "added_mass": Range("the mass added to the body", "kg", 0.0, 2000.0, lo_open=True,
                        why="identification needs a known, positive test mass; 2 t bounds any "
                            "mass a person loads onto one corner"),
    # the drive as the car is has 0 kg added: session metadata may say 0
    "session_added_mass": Range("the mass added to the body for this drive (0 as the car is)",
                                "kg", 0.0, 2000.0,
                                why="0 for the drive as the car is, else as added_mass"),
    # sprung mass of one corner: a small car about 200 kg, a loaded truck axle end a few t
    "body_mass": Range("the sprung mass of the corner", "kg", 0.0, 10000.0, lo_open=True,
                       why="one corner of a car or truck carries well under 10 t"),
    "record_duration": Range("how long to record", "s", 0.0, 86400.0, lo_open=True,
                             why="a positive time; one day is longer than any test drive"),
    "sim_duration": Range("the length of the simulated drive", "s", 0.0, 3600.0,
                          lo_open=True, why="an hour of simulation already takes minutes"),
    "daq_rate": Range("the DAQ sample rate", "Hz", 1.0, 50000.0,
                      why="suspension content lies below 100 Hz; the DAQ samples up to 2 kHz "
                          "per channel, 50 kHz bounds any accelerometer DAQ"),
    "frequency": Range("a frequency", "Hz", 0.0, 1000.0, lo_open=True,
                       why="suspension motion lies between 0.1 and 100 Hz; 1 kHz bounds a "
                           "band a 2 kHz DAQ can resolve"),
    "snr": Range("the sensor signal-to-noise ratio", "dB", -20.0, 200.0,
                 why="from noise dominating the signal to a perfect sensor"),
    "time_s": Range("a time in the session", "s", 0.0, 1e6,
                    why="session time starts at 0; 1e6 s is longer than any drive"),
    "interval": Range("an interval", "s", 0.0, 3600.0, lo_open=True,
                      why="a positive time up to an hour"),
    "holdout": Range("the fraction held out for validation", "", 0.0, 0.9, hi_open=True,
                     why="some data must remain for the fit"),
    "percent": Range("a relative standard deviation", "%", 0.0, 100.0, lo_open=True,
                     why="a positive percentage"),
    "max_apart": Range("how far apart two drives of a pair may be", "h", 0.0, 8760.0,
                       lo_open=True, why="a positive time up to a year"),
    "upload_mb": Range("the largest upload", "MB", 0.0, 100000.0, lo_open=True,
                       why="a positive size up to 100 GB"),
    "speed_kmh": Range("the vehicle speed", "km/h", 0.0, 400.0,
                       why="from standstill to faster than any road car"),
    "full_scale_g": Range("the accelerometer full scale", "g", 0.0, 1000.0, lo_open=True,
                          why="positive; 1000 g bounds shock accelerometers"),
    "corrupt": Range("the fraction of corrupted frames", "", 0.0, 1.0,
                     why="a probability"),
    "drift_ppm": Range("the clock drift", "ppm", -10000.0, 10000.0,
                       why="crystal oscillators drift tens of ppm; 1 % is broken hardware"),
}


def number(
    value: object, name: str, spec: Range | str, *, source: str = ""
) -> float:
    """``value`` as a float within ``spec``, or :class:`InvalidValueError` saying what to give.

    Parameters
    ----------
    value : object
        The text or number the user gave.
    name : str
        How the user gave it: an option (``--added-mass``), a form field or a column.
    spec : Range or str
        The accepted range, or its key in :data:`RANGES`.
    source : str
        Where the value came from when that is not the command line (``"manifest.csv
        line 3"``), put before the name.

    Returns
    -------
    float
    """
    rng = RANGES[spec] if isinstance(spec, str) else spec
    text = str(value).strip()
    try:
        x = float(text)
    except (TypeError, ValueError):
        x = math.nan
    if rng.contains(x):
        return x
    unit = f" in {rng.unit}" if rng.unit else ""
    where = f"{source}: " if source else ""
    shown = text if len(text) <= 40 else text[:37] + "..."
    raise InvalidValueError(f"{where}{name} {shown}: give {rng.what}{unit}, {rng.describe()}")


def check_number(value: float | None, name: str, spec: Range | str) -> float | None:
    """Like :func:`number` for a value already parsed (None passes through)."""
    return None if value is None else number(value, name, spec)


def integer(value: object, name: str, lo: int, hi: int, what: str) -> int:
    """``value`` as an int in ``[lo, hi]``, or :class:`InvalidValueError`."""
    text = str(value).strip()
    try:
        n = int(text)
    except (TypeError, ValueError):
        n = None
    if n is None or not lo <= n <= hi:
        shown = text if len(text) <= 40 else text[:37] + "..."
        raise InvalidValueError(f"{name} {shown}: give {what}, a whole number from {lo} to {hi}")
    return n


def arg_number(name: str, spec: Range | str) -> Callable[[str], float]:
    """An argparse ``type=`` that checks a number with :func:`number`."""

    def parse(text: str) -> float:
        try:
            return number(text, name, spec)
        except InvalidValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None

    parse.__name__ = name.lstrip("-").replace("-", "_")
    return parse


def arg_int(name: str, lo: int, hi: int, what: str) -> Callable[[str], int]:
    """An argparse ``type=`` that checks a whole number with :func:`integer`."""

    def parse(text: str) -> int:
        try:
            return integer(text, name, lo, hi, what)
        except InvalidValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None

    parse.__name__ = name.lstrip("-").replace("-", "_")
    return parse


def band_hz(band: tuple[float, float] | list[float] | None, name: str = "--band"
            ) -> tuple[float, float] | None:
    """A frequency band ``(low, high)`` in Hz: both in the ``frequency`` range, low < high."""
    if band is None:
        return None
    lo, hi = (number(b, name, "frequency") for b in band)
    if not lo < hi:
        raise InvalidValueError(f"{name} {lo:g} {hi:g}: give the low edge first, below the high "
                                "edge, both in Hz, e.g. --band 0.5 30")
    return lo, hi


def existing_file(path: str | os.PathLike, what: str = "session file") -> Path:
    """``path`` if it is an existing regular file the user can read.

    Refuses a missing path, a folder, a device node or a FIFO (reading ``/dev/zero`` as a
    session would never end) with a line saying what to give.
    """
    p = Path(path)
    try:
        st = p.stat()
    except FileNotFoundError:
        raise FieldDiagError(f"{p} does not exist; give an existing {what}") from None
    except OSError as exc:
        raise FieldDiagError(f"cannot read {p} ({exc.strerror}); give an existing {what}"
                             ) from None
    if stat.S_ISDIR(st.st_mode):
        raise FieldDiagError(f"{p} is a folder; give a {what}, not a folder")
    if not stat.S_ISREG(st.st_mode):
        raise FieldDiagError(f"{p} is not a regular file (a device or a pipe); give a {what}")
    if not os.access(p, os.R_OK):
        raise FieldDiagError(f"cannot read {p} (permission denied); give a {what} you can read")
    return p


def arg_existing_file(what: str = "session file") -> Callable[[str], str]:
    """An argparse ``type=`` that checks with :func:`existing_file` (returns the text)."""

    def parse(text: str) -> str:
        try:
            existing_file(text, what)
        except FieldDiagError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None
        return text

    parse.__name__ = "file"
    return parse


def finite_session(path: str | os.PathLike, roles: tuple[str, ...] = ("wheel", "body")) -> None:
    """Refuse a session whose channels of ``roles`` hold NaN or infinite samples.

    The numerics cannot use such samples; the message names the file, the channel and how
    many samples are bad, instead of the internal step that would trip over them. Roles
    the session does not have are left to the command to report.
    """
    import numpy as np

    from fielddiag.session import SessionReader

    with SessionReader(path) as s:
        for role in roles:
            for ch in s.channels_for_role(role):
                values = s.read(ch.name)
                bad = int(values.size - np.count_nonzero(np.isfinite(values)))
                if bad:
                    raise FieldDiagError(
                        f"{path}: channel {ch.name} ({role}) holds {bad} of {values.size} "
                        "samples that are not finite numbers (NaN or infinite); re-import or "
                        "re-record the drive")
