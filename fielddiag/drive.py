"""One reader of a recorded drive: a session -> SI arrays of one car corner with metadata.

Every consumer of a drive (identification, diagnosis, the grey-box fit, the on-line
replay, the ride analysis) reads it here, so that the wheel and body channels are found
by role, converted from their unit to m/s^2 (:mod:`fielddiag.units`) and checked for
irregular time stamps and gaps in one place.

A single-corner session names its accelerometers with the roles ``wheel`` (below the
spring) and ``body`` (above it); a full-vehicle session with ``wheel_fl``, ``body_fl``...
(:data:`fielddiag.channels.CORNERS`), read one corner at a time with ``corner=``.

Examples
--------
>>> from fielddiag.drive import read_corner_drive
>>> d = read_corner_drive("before.h5", label="before")
>>> d.sample_rate_hz, d.duration_s, d.wheel_accel_mps2.mean()   # doctest: +SKIP
(500.0, 180.0, 9.80...)
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fielddiag.channels import CORNERS, ChannelSpec, SessionMetadata
from fielddiag.errors import (
    ChannelNotFoundError,
    FieldDiagError,
    InsufficientDataError,
    SessionError,
)
from fielddiag.units import ACCEL_UNITS, factor_to_si

__all__ = [
    "CornerDrive",
    "accel_unit_factor",
    "corner_role",
    "find_channel",
    "read_accel_channel",
    "read_corner_drive",
]

#: Where each accelerometer goes (said when it is missing).
_MOUNT = {
    "wheel": "on the wheel carrier or hub, below the spring",
    "body": "on the body at the strut top, above the spring",
}
#: Relative jitter of the time steps (std / median, gaps left out) above which a recording
#: is not treated as uniformly sampled.
MAX_JITTER = 0.01
#: A time step longer than ``(1 + GAP_TOLERANCE)`` sample periods is a gap.
GAP_TOLERANCE = 0.5


# ------------------------------------------------------------------------------- data
@dataclass
class CornerDrive:
    """The wheel and body accelerometer readings of one car corner during one drive.

    The readings are as the accelerometers give them: gravity, bias and drift included,
    converted to m/s^2. The field order lets ``CornerDrive(wheel, body, rate)`` build one
    from arrays (simulated or synthetic data).

    Attributes
    ----------
    wheel_accel_mps2, body_accel_mps2 : ndarray
        Vertical acceleration of the wheel (unsprung) and of the body (sprung) side, up
        positive, gravity included [m/s^2].
    sample_rate_hz : float
        Sample rate [Hz] (with time stamps: samples per second over the gap-free
        pieces).
    added_mass_kg : float
        Mass added on the body for this drive [kg].
    label : str
        The drive's part in an analysis (``before``, ``after``, ``drive``).
    path : str
        The session file ("" for arrays not read from a file).
    pieces : list of (int, int) or None
        Contiguous index ranges [i0, i1) when the time base has gaps; None: one piece.
    start_s : float
        Session time of the first sample [s].
    name : str
        The session's file name ("" for arrays).
    corner : {None, "fl", "fr", "rl", "rr"}
        The corner read from a full-vehicle session; None for a single-corner session.
    metadata : SessionMetadata or None
        The session header (vehicle, corner as written, operator...); None for arrays.
    wheel_channel, body_channel : str
        Names of the channels read.
    timestamps_s : ndarray or None
        The recorded sample times [s] when the session has a time-stamp base (they show
        the gaps); None for a uniform time base.
    """

    wheel_accel_mps2: np.ndarray
    body_accel_mps2: np.ndarray
    sample_rate_hz: float
    added_mass_kg: float = 0.0
    label: str = ""
    path: str = ""
    pieces: list[tuple[int, int]] | None = None
    start_s: float = 0.0
    name: str = ""
    corner: str | None = None
    metadata: SessionMetadata | None = None
    wheel_channel: str = ""
    body_channel: str = ""
    timestamps_s: np.ndarray | None = None

    @property
    def n(self) -> int:
        """Number of samples (of the shorter channel)."""
        return int(min(np.shape(self.wheel_accel_mps2)[0], np.shape(self.body_accel_mps2)[0]))

    @property
    def duration_s(self) -> float:
        """Recorded time [s]: samples / rate (gaps not counted)."""
        return self.n / self.sample_rate_hz

    @property
    def time_s(self) -> np.ndarray:
        """Sample times [s]: the recorded time stamps, or ``start_s + i / rate``."""
        if self.timestamps_s is not None:
            return np.asarray(self.timestamps_s)[: self.n]
        return self.start_s + np.arange(self.n) / self.sample_rate_hz

    @property
    def vehicle(self) -> str:
        """The vehicle named in the session header ("" when unknown)."""
        return "" if self.metadata is None else str(self.metadata.vehicle)

    def piece_list(self) -> list[tuple[int, int]]:
        """Contiguous index ranges [i0, i1): ``[(0, n)]`` without gaps.

        Returns
        -------
        list of (int, int)
        """
        return [(0, self.n)] if self.pieces is None else list(self.pieces)


# --------------------------------------------------------------------------- channels
def corner_role(kind: str, corner: str | None = None) -> str:
    """The channel role of a wheel or body accelerometer, at one corner or alone.

    Parameters
    ----------
    kind : {"wheel", "body"}
    corner : {None, "fl", "fr", "rl", "rr"}
        None for a single-corner session.

    Returns
    -------
    str
        ``kind`` alone, or ``f"{kind}_{corner}"``.

    Raises
    ------
    FieldDiagError
        ``corner`` is not one of :data:`fielddiag.channels.CORNERS`.

    Examples
    --------
    >>> corner_role("wheel"), corner_role("body", "rl")
    ('wheel', 'body_rl')
    """
    if corner is None:
        return kind
    if corner not in CORNERS:
        raise FieldDiagError(f"corner {corner!r} is not a corner; give one of {', '.join(CORNERS)}")
    return f"{kind}_{corner}"


def find_channel(
    channels: Sequence[ChannelSpec],
    kind: str,
    *,
    corner: str | None = None,
    source: str = "the session",
    purpose: str = "the analysis",
) -> ChannelSpec:
    """The one wheel or body accelerometer channel among ``channels``, found by its role.

    Parameters
    ----------
    channels : sequence of ChannelSpec
        A session's (or a live recorder's) DAQ channels.
    kind : {"wheel", "body"}
    corner : {None, "fl", "fr", "rl", "rr"}
        Look for ``wheel_fl``... instead of ``wheel``.
    source : str
        What holds the channels, for the message (a file name).
    purpose : str
        Who needs the channel, for the message (``identify``, ``diagnose``).

    Returns
    -------
    ChannelSpec

    Raises
    ------
    ChannelNotFoundError
        No channel or several channels have the role; the message lists the channels and
        says where to mount the accelerometer.

    Examples
    --------
    >>> chans = [ChannelSpec("w", role="wheel"), ChannelSpec("b", unit="g", role="body")]
    >>> find_channel(chans, "body").name
    'b'
    """
    role = corner_role(kind, corner)
    found = [c for c in channels if c.role == role]
    if len(found) == 1:
        return found[0]
    have = ", ".join(f"{c.name} ({c.role})" for c in channels) or "none"
    what = "no" if not found else "several"
    where = _MOUNT[kind] + ("" if corner is None else f" of the {corner} corner")
    hint = ""
    if corner is None and not found and any(c.role.startswith(f"{kind}_") for c in channels):
        hint = f"; this is a full-vehicle session: give the corner ({', '.join(CORNERS)})"
    raise ChannelNotFoundError(
        f"{source} has {what} {role} channel (role '{role}'; channels: {have}). "
        f"{purpose} needs exactly one wheel-side and one body-side vertical "
        f"accelerometer in each drive: record with an accelerometer {where}, "
        f"vertical axis, channel role '{role}'{hint}")


def accel_unit_factor(unit: str, channel: str = "") -> float:
    """Factor from a channel's acceleration unit to m/s^2 (``g`` -> standard gravity).

    Parameters
    ----------
    unit : str
        The channel's unit as stored (``m/s2``, ``g``, ``mg``...); case and blanks ignored.
    channel : str
        The channel's name, for the message.

    Returns
    -------
    float
        ``value_mps2 = value * factor``.

    Raises
    ------
    FieldDiagError
        The unit is not an acceleration.

    Examples
    --------
    >>> from fielddiag.units import GRAVITY_MPS2
    >>> accel_unit_factor("g") == accel_unit_factor(" G ") == GRAVITY_MPS2
    True
    """
    try:
        return factor_to_si(unit, "acceleration")
    except KeyError:
        raise FieldDiagError(
            f"channel {channel!r} is in {unit!r}, not an acceleration; the fit needs "
            f"accelerometers in one of {', '.join(ACCEL_UNITS)} (fix the unit on import)"
        ) from None


# ------------------------------------------------------------------------- time base
def _time_base(
    s, i0: int, i1: int, purpose: str
) -> tuple[np.ndarray | None, float, list[tuple[int, int]]]:
    """(time stamps or None, rate, pieces) of samples [i0, i1) of an open session."""
    from fielddiag.dsp import contiguous_pieces

    n = i1 - i0
    if s.time_base != "timestamps":
        cuts = sorted({s.index_range(g.start_s, None)[0] - i0 for g in s.gaps})
        edges = [0] + [i for i in cuts if 0 < i < n] + [n]
        return None, s.sample_rate_hz, [(a, b) for a, b in zip(edges[:-1], edges[1:],
                                                               strict=True) if b > a]
    t = s.time_at(i0, i1)
    dt = np.diff(t)
    med = float(np.median(dt))
    if not med > 0:
        raise SessionError(f"{s.path.name} has time stamps that do not increase; re-import "
                           "or re-record the drive")
    inside = dt[dt < (1 + GAP_TOLERANCE) * med]
    if inside.size and float(np.std(inside)) > MAX_JITTER * med:
        raise SessionError(
            f"{s.path.name} has irregular time stamps (jitter "
            f"{100 * np.std(inside) / med:.0f} % of the sample period); {purpose} "
            "needs a uniformly sampled DAQ recording")
    pieces = contiguous_pieces(t, n, 1.0 / med, GAP_TOLERANCE)
    # the rate: samples per second over the gap-free pieces. Not 1 / median step: a
    # recorder's host clock mapping slews by up to a few 1e-3 while it steers towards its
    # fit (drivers.clock_fit), and a busy host steers for long stretches, so the median
    # step can be that far off; over a piece the steering averages out.
    steps = sum(b - a - 1 for a, b in pieces)
    span_s = sum(float(t[b - 1] - t[a]) for a, b in pieces)
    fs = steps / span_s if steps > 0 and span_s > 0 else 1.0 / med
    return t, fs, pieces


# ---------------------------------------------------------------------------- readers
def read_corner_drive(
    path: str | os.PathLike,
    *,
    label: str = "",
    corner: str | None = None,
    start_s: float | None = None,
    end_s: float | None = None,
    added_mass_kg: float | None = None,
    require_continuous: bool = False,
    purpose: str = "the analysis",
    gap_advice: str = "export the longest gap-free stretch",
) -> CornerDrive:
    """Read the wheel and body accelerometers of one corner from a session, in m/s^2.

    Parameters
    ----------
    path : str or PathLike
        The session file.
    label : str
        The drive's part in the analysis (``before``, ``after``).
    corner : {None, "fl", "fr", "rl", "rr"}
        None reads the channels with roles ``wheel`` and ``body``; a corner reads
        ``wheel_<corner>`` and ``body_<corner>`` of a full-vehicle session.
    start_s, end_s : float or None
        Read only the samples with ``start_s <= t < end_s`` (session time [s]).
    added_mass_kg : float or None
        Overrides the session's ``added_mass_kg`` attribute [kg].
    require_continuous : bool
        Refuse a drive whose time base has gaps (instead of listing them in ``pieces``).
    purpose : str
        Who reads the drive (``identify``, ``diagnose``), for the messages.
    gap_advice : str
        What to do about gaps, for the message of ``require_continuous``.

    Returns
    -------
    CornerDrive
        Readings in m/s^2 (gravity included), the rate [Hz], the start time [s], the
        added mass [kg], the contiguous pieces and the session header.

    Raises
    ------
    ChannelNotFoundError
        No or several wheel or body channels (the message says where to mount one).
    FieldDiagError
        A channel's unit is not an acceleration, or ``corner`` is not a corner.
    InsufficientDataError
        Fewer than two samples in the stretch read, or gaps with ``require_continuous``.
    SessionError
        The file is not a readable session, or its time stamps are irregular.

    Examples
    --------
    >>> d = read_corner_drive("after.h5", label="after", start_s=10, end_s=130)  # doctest: +SKIP
    >>> d.added_mass_kg, d.piece_list()                                           # doctest: +SKIP
    (60.0, [(0, 60000)])
    """
    from fielddiag.session import SessionReader

    path = Path(path)
    with SessionReader(path) as s:
        name = s.path.name
        wch = find_channel(s.channels, "wheel", corner=corner, source=name, purpose=purpose)
        bch = find_channel(s.channels, "body", corner=corner, source=name, purpose=purpose)
        fw, fb = accel_unit_factor(wch.unit, wch.name), accel_unit_factor(bch.unit, bch.name)
        i0, i1 = s.index_range(start_s, end_s)
        if i1 - i0 < 2:
            span = "" if start_s is None and end_s is None else f" between {start_s} and {end_s} s"
            raise InsufficientDataError(f"{name} holds no samples{span}; record or choose a "
                                        "longer stretch")
        stamps, fs, pieces = _time_base(s, i0, i1, purpose)
        if require_continuous and len(pieces) > 1:
            ta, tb = s.time_at(i0 + pieces[0][1] - 1, i0 + pieces[0][1] + 1)
            raise InsufficientDataError(
                f"{name} has gaps in its time base (the first between {ta:.2f} and {tb:.2f} s); "
                f"{purpose} needs a continuous recording ({gap_advice})")
        wheel = s.read(wch.name, start_s, end_s) * fw
        body = s.read(bch.name, start_s, end_s) * fb
        return CornerDrive(
            wheel_accel_mps2=wheel,
            body_accel_mps2=body,
            sample_rate_hz=fs,
            added_mass_kg=float(s.metadata.added_mass_kg if added_mass_kg is None
                                else added_mass_kg),
            label=label,
            path=str(path),
            pieces=None if len(pieces) == 1 else pieces,
            start_s=float(s.time_at(i0, i0 + 1)[0]),
            name=name,
            corner=corner,
            metadata=s.metadata,
            wheel_channel=wch.name,
            body_channel=bch.name,
            timestamps_s=stamps,
        )


def read_accel_channel(
    path: str | os.PathLike,
    kind: str,
    *,
    corner: str | None = None,
    start_s: float | None = None,
    end_s: float | None = None,
    purpose: str = "the analysis",
) -> tuple[np.ndarray, np.ndarray, ChannelSpec]:
    """One accelerometer of a corner (the body's alone, for the ride analysis), in m/s^2.

    Unlike :func:`read_corner_drive` it needs only the one channel and keeps any time
    base (irregular steps included) as recorded.

    Parameters
    ----------
    path : str or PathLike
        The session file.
    kind : {"wheel", "body"}
    corner : {None, "fl", "fr", "rl", "rr"}
    start_s, end_s : float or None
        Session time limits [s].
    purpose : str
        Who reads it, for the messages.

    Returns
    -------
    time_s : ndarray
        Sample times [s].
    accel_mps2 : ndarray
        The readings converted to m/s^2 (gravity included).
    channel : ChannelSpec
        The channel read.

    Raises
    ------
    ChannelNotFoundError
        No or several channels with the role.
    FieldDiagError
        The channel's unit is not an acceleration.

    Examples
    --------
    >>> t, a, ch = read_accel_channel("drive.h5", "body")  # doctest: +SKIP
    """
    from fielddiag.session import SessionReader

    with SessionReader(path) as s:
        ch = find_channel(s.channels, kind, corner=corner, source=s.path.name, purpose=purpose)
        factor = accel_unit_factor(ch.unit, ch.name)
        t, a = s.read_with_time(ch.name, start_s, end_s)
        return t, a * factor, ch
