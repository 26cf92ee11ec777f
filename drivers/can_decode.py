"""The one CAN decoder: python-can messages -> stored raw frames -> SI signals (cantools).

Live recording (:mod:`drivers.can_vehicle`: a python-can bus or a replayed log) and import
(:mod:`fielddiag.io.canlog`, :mod:`fielddiag.io.mdf`) both go through this module, in the
same two steps, so the same frames give the same stored signals, to the byte, whichever
way they arrived:

1. :func:`messages_to_frames` turns python-can messages into rows of
   :data:`fielddiag.session.CAN_FRAME_DTYPE`, the session's raw frame format (a bus index
   from :class:`BusTable`; ``dlc`` holds the byte count, as python-can does).
2. :meth:`CanDecoder.decode` decodes those rows, never the messages, so a live frame, an
   imported frame and a frame read back from a session are decoded from the same bytes.

Rules, each in one place:

* **Frames decoded**: data frames only (remote and error frames are kept raw, never
  decoded) whose identifier, and standard/extended format, are those of the DBC message,
  on a bus the DBC is bound to (:class:`Dbc`, ``buses``; None means every bus).
* **Payload length** (:func:`payload_lengths`): classic CAN at most 8 bytes; CAN FD the
  byte count rounded up to the next length a CAN FD frame can have (0-8, 12, 16, 20, 24,
  32, 48, 64; :data:`FD_LENGTHS`), at most 64: a CAN FD frame is padded on the wire.
* **Decoding**: cantools, raw values scaled by the DBC, choices (value tables) not
  applied. A frame shorter than its DBC message decodes the signals that fit
  (``allow_truncated``); one in which a requested signal does not fit, or that cantools
  rejects, counts one decode error (:attr:`CanDecoder.errors`). A multiplexed signal
  absent from a frame is no error: it has no sample there.
* **Units** (:func:`fielddiag.units.to_si`): km/h and mph -> m/s, deg -> rad, deg/s and
  rpm -> rad/s, g -> m/s2...; units of no table (``%``, ``Nm``, ``m``) are kept.
* **Names** (:func:`resolve_signals`): ``SIGNAL``, ``MESSAGE.SIGNAL`` or
  ``ALIAS=MESSAGE.SIGNAL``. A signal is stored under its alias, else its own name, else,
  when two chosen signals share that name, ``MESSAGE.SIGNAL``; then made a valid session
  name (:func:`fielddiag.session.safe_name`).
* **Vehicle speed** (role ``speed``): the signal named with ``speed_signal``, else the
  first one aliased ``vehicle_speed`` or with a usual vehicle speed name
  (:data:`VEHICLE_SPEED_NAMES`) and a speed unit.
* **The car's accelerations** (roles ``accel_long``, forward positive, and ``accel_lat``,
  left positive; a full-vehicle session needs them): the signals aliased ``accel_long``
  and ``accel_lat`` (:data:`ROLE_ALIASES`), e.g. ``accel_long=KINEMATICS.ACCEL_X``.
"""

from __future__ import annotations

import difflib
import os
import re
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from fielddiag.channels import SignalSpec
from fielddiag.errors import DbcError
from fielddiag.session import (
    CAN_DATA_BYTES,
    CAN_FLAG_BRS,
    CAN_FLAG_ERROR,
    CAN_FLAG_ESI,
    CAN_FLAG_EXTENDED,
    CAN_FLAG_FD,
    CAN_FLAG_REMOTE,
    CAN_FLAG_RX,
    CAN_FRAME_DTYPE,
    safe_name,
)
from fielddiag.units import SPEED_UNITS, to_si

#: Payload length of each CAN FD DLC code 0..15 (ISO 11898-1; python-can's
#: ``can.util.CAN_FD_DLC``).
FD_LENGTHS = np.array([0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64])
#: Largest payload of a classic CAN frame [bytes].
CLASSIC_MAX_BYTES = 8

#: Normalised names (lower case, letters and digits only) of a vehicle speed signal, in
#: order of preference.
VEHICLE_SPEED_NAMES = (
    "vehiclespeed",
    "speed",
    "vehspeed",
    "vehspd",
    "vspd",
    "vehiclespd",
    "wheelbasedvehiclespeed",
)
#: The alias that makes a signal the vehicle speed whatever its DBC name.
SPEED_ALIAS = "vehicle_speed"
#: Aliases that give a signal a role of the same name: the car's longitudinal and lateral
#: accelerations of a full-vehicle session.
ROLE_ALIASES = ("accel_long", "accel_lat")
_WHEEL_SPEED_RE = re.compile(r"(wheelspeed|wheelspd|whlspd|whlspeed)")


def _norm(name: str) -> str:
    return re.sub(r"[^a-z0-9]", "", name.lower())


# ============================================================================ frames
def frame_flags(msg: Any) -> int:
    """The session's flag bits (``CAN_FLAG_*``) of one python-can message.

    Written out bit by bit: about 0.1 us a message, five times faster than a loop over
    the attributes (the recorder converts every frame of the bus).
    """
    f = 0
    if msg.is_extended_id:
        f |= CAN_FLAG_EXTENDED
    if msg.is_remote_frame:
        f |= CAN_FLAG_REMOTE
    if msg.is_error_frame:
        f |= CAN_FLAG_ERROR
    if msg.is_fd:
        f |= CAN_FLAG_FD
    if msg.bitrate_switch:
        f |= CAN_FLAG_BRS
    if msg.error_state_indicator:
        f |= CAN_FLAG_ESI
    if msg.is_rx:
        f |= CAN_FLAG_RX
    return f


def messages_to_frames(
    msgs: Sequence[Any], time_s: np.ndarray | Sequence[float], bus: np.ndarray | int
) -> np.ndarray:
    """Raw frames of python-can messages, as the session stores them.

    Parameters
    ----------
    msgs : sequence of can.Message
    time_s : array of float
        Time of each frame [s] on the caller's time base (session clock, log time...).
    bus : int or array of int
        Bus index of all frames, or of each.

    Returns
    -------
    numpy.ndarray of CAN_FRAME_DTYPE
        ``dlc`` is python-can's byte count; ``data`` the payload, zero-padded to 64 bytes.
    """
    n = len(msgs)
    out = np.zeros(n, dtype=CAN_FRAME_DTYPE)
    if n == 0:
        return out
    out["time_s"] = time_s
    out["arbitration_id"] = [m.arbitration_id for m in msgs]
    out["bus"] = bus
    out["flags"] = [frame_flags(m) for m in msgs]
    out["dlc"] = [m.dlc for m in msgs]
    width = CAN_DATA_BYTES
    raw = b"".join([m.data[:width].ljust(width, b"\0") for m in msgs])  # bytearray each
    out["data"] = np.frombuffer(raw, dtype="u1").reshape(n, CAN_DATA_BYTES)
    return out


def payload_lengths(frames: np.ndarray) -> np.ndarray:
    """Payload length [bytes] of stored frames: the CAN and CAN FD length rules.

    Parameters
    ----------
    frames : numpy.ndarray of CAN_FRAME_DTYPE

    Returns
    -------
    numpy.ndarray of int
        Classic CAN: ``min(dlc, 8)``. CAN FD: ``min(dlc, 64)`` rounded up to the next
        entry of :data:`FD_LENGTHS` (a 10-byte CAN FD payload travels as 12 bytes).

    Examples
    --------
    >>> f = np.zeros(3, dtype=CAN_FRAME_DTYPE)
    >>> f["dlc"] = [15, 10, 64]
    >>> f["flags"] = [0, CAN_FLAG_FD, CAN_FLAG_FD]
    >>> payload_lengths(f).tolist()
    [8, 12, 64]
    """
    dlc = np.minimum(frames["dlc"].astype(np.int64), CAN_DATA_BYTES)
    fd = (frames["flags"] & CAN_FLAG_FD) != 0
    return np.where(
        fd, FD_LENGTHS[np.searchsorted(FD_LENGTHS, dlc)], np.minimum(dlc, CLASSIC_MAX_BYTES)
    )


def frame_payloads(frames: np.ndarray) -> list[bytes]:
    """Payload bytes of each stored frame (:func:`payload_lengths` of its ``data``)."""
    if len(frames) == 0:
        return []
    raw = np.ascontiguousarray(frames["data"]).tobytes()
    step = CAN_DATA_BYTES
    return [raw[i * step : i * step + n] for i, n in enumerate(payload_lengths(frames).tolist())]


def frame_payload(frame: np.void | np.ndarray) -> bytes:
    """Payload bytes of one stored frame."""
    return frame_payloads(np.atleast_1d(np.asarray(frame, dtype=CAN_FRAME_DTYPE)))[0]


#: How a log's channel names become bus indices (:class:`BusTable`).
BUS_RULE = (
    "bus = the number ending the log's channel name (can0 -> 0, vcan1 -> 1, ASC/BLF channel "
    "2 -> 2); other names get the next free number in order of appearance"
)


@dataclass
class BusTable:
    """Bus index of each channel name of a log, by :data:`BUS_RULE`.

    Examples
    --------
    >>> t = BusTable()
    >>> [t.index(c) for c in ("can1", "can0", "radar", "can1")]
    [1, 0, 2, 1]
    >>> t.names
    {1: 'can1', 0: 'can0', 2: 'radar'}
    """

    names: dict[int, str] = field(default_factory=dict)
    _index: dict[Any, int] = field(default_factory=dict, repr=False)

    def index(self, channel: Any) -> int:
        """Bus index of ``channel`` (a name, a number or None); new ones are numbered."""
        idx = self._index.get(channel)
        if idx is not None:
            return idx
        from can.util import channel2int

        guess = 0 if channel is None else channel2int(channel)
        if guess is None or guess in self.names or not 0 <= guess <= 255:
            guess = next(i for i in range(256) if i not in self.names)
        self._index[channel] = guess
        self.names[guess] = "" if channel is None else str(channel)
        return guess



def buses_named(name: str | int | None, names: Mapping[int, str]) -> frozenset[int] | None:
    """Bus indices a DBC's bus binding stands for.

    Parameters
    ----------
    name : str, int or None
        A bus name as the log writes it (``can1``) or a bus index (``1``); None: no binding.
    names : mapping of int to str
        Bus index -> name (:attr:`BusTable.names`).

    Returns
    -------
    frozenset of int or None
        None (every bus) when ``name`` is None; else the matching indices, maybe none.

    Examples
    --------
    >>> sorted(buses_named("can1", {0: "can0", 1: "can1"})), sorted(buses_named(3, {}))
    ([1], [3])
    """
    if name is None:
        return None
    text = str(name).strip()
    hits = {i for i, n in names.items() if text in (n, str(i))}
    if not hits and text.isdigit() and int(text) < 256:
        hits = {int(text)}
    return frozenset(hits)


# ============================================================================ DBC files
def load_dbc(path: str | os.PathLike | Any) -> Any:
    """Load a DBC (or KCD, SYM, ARXML) file with cantools, leniently (``strict=False``).

    Parameters
    ----------
    path : path or cantools Database
        A Database is returned as it is.

    Returns
    -------
    cantools.database.can.Database

    Raises
    ------
    DbcError
        The file does not exist or is not a CAN database.
    """
    import cantools

    if not isinstance(path, str | os.PathLike):
        return path
    p = os.fspath(path)
    if not os.path.isfile(p):
        raise DbcError(
            f"DBC file {p} not found; pass the database that describes this bus "
            "(--dbc FILE, or ?dbc=FILE in a CAN URL)"
        )
    try:
        return cantools.database.load_file(p, strict=False)
    except Exception as exc:  # cantools raises many kinds of parse errors
        raise DbcError(
            f"{os.path.basename(p)}: not a readable CAN database ({exc}); pass a .dbc, .kcd, "
            ".sym or .arxml file"
        ) from None


@dataclass(frozen=True, eq=False)
class Dbc:
    """A loaded CAN database and the buses it describes.

    Parameters
    ----------
    db : cantools Database
    label : str
        How messages name it (its file name).
    buses : frozenset of int or None
        Bus indices whose frames it decodes; None: every bus.
    """

    db: Any
    label: str = "the DBC"
    buses: frozenset[int] | None = None


def as_dbcs(dbcs: Any) -> list[Dbc]:
    """A :class:`Dbc`, a cantools Database, or a sequence of either -> list of Dbc."""
    if isinstance(dbcs, Dbc) or hasattr(dbcs, "messages"):
        dbcs = [dbcs]
    return [d if isinstance(d, Dbc) else Dbc(d) for d in dbcs]


# ============================================================================ signals
@dataclass(frozen=True, eq=False)
class SignalChoice:
    """One signal to decode: where the DBC defines it and how the session stores it."""

    name: str
    dbc: Dbc
    message: Any  # cantools Message
    signal: Any  # cantools Signal
    role: str = "other"

    @property
    def unit_factor(self) -> float:
        """Factor from the DBC unit to the stored (SI) unit."""
        return to_si(self.signal.unit)[0]

    @property
    def spec(self) -> SignalSpec:
        """How the session stores it: name, SI unit, source ``can``, message, role."""
        return SignalSpec(
            self.name,
            unit=to_si(self.signal.unit)[1],
            source="can",
            message=self.message.name,
            role=self.role,
        )


#: (dbc, message) -> True if the frames at hand carry that message (see :func:`presence`).
Presence = Callable[[Dbc, Any], bool]
_Entry = tuple[Dbc, Any, Any]  # (dbc, message, signal)


def _is_speed(entry: _Entry) -> bool:
    _, _, s = entry
    return _norm(s.name) in VEHICLE_SPEED_NAMES and (s.unit or "").strip().lower() in SPEED_UNITS


def resolve_signals(
    dbcs: Any,
    requests: Iterable[str],
    *,
    present: Presence | None = None,
    speed_signal: str | None = None,
) -> list[SignalChoice]:
    """Find the signals asked for in the DBCs, name them and pick the vehicle speed.

    Parameters
    ----------
    dbcs : Dbc, cantools Database, or a sequence of them
    requests : iterable of str
        ``SIGNAL``, ``MESSAGE.SIGNAL`` or ``ALIAS=MESSAGE.SIGNAL`` (``ALIAS=SIGNAL``).
    present : callable or None
        ``present(dbc, message)``: whether the frames at hand carry the message; a
        signal name found in several messages is then taken from the one that occurs,
        if only one does. None (live recording: frames not known yet) decides nothing.
    speed_signal : str or None
        Stored name of the vehicle speed; None picks it as the module says.

    Returns
    -------
    list of SignalChoice
        In the order asked; a signal asked for twice under one name is kept once.

    Raises
    ------
    DbcError
        A name is in no message (with the closest names), in several, a message has no
        such signal, two signals end up with one name, or ``speed_signal`` is none of them.
    """
    dbcs = as_dbcs(dbcs)
    index: dict[str, list[_Entry]] = {}
    messages: dict[str, Any] = {}
    for d in dbcs:
        for m in d.db.messages:
            messages.setdefault(m.name, m)
            for s in m.signals:
                index.setdefault(s.name, []).append((d, m, s))
                index.setdefault(f"{m.name}.{s.name}", []).append((d, m, s))
    labels = ", ".join(dict.fromkeys(d.label for d in dbcs)) or "the DBC"
    picked: list[tuple[str, _Entry]] = []
    for text in requests:
        alias, _, ref = str(text).rpartition("=")
        alias, ref = alias.strip(), ref.strip()
        hits = index.get(ref)
        if not hits:
            msg_name, dot, sig_name = ref.rpartition(".")
            if dot and msg_name in messages:
                raise DbcError(
                    f"message {msg_name} has no signal {sig_name!r}; it has "
                    f"{', '.join(s.name for s in messages[msg_name].signals)}"
                )
            close = difflib.get_close_matches(ref, list(index), n=5)
            hint = f"; did you mean {', '.join(close)}?" if close else "."
            raise DbcError(
                f"signal {ref!r} is not in {labels}{hint} Name it as SIGNAL or MESSAGE.SIGNAL "
                "as the DBC spells it (`cantools dump FILE.dbc` lists them)"
            )
        if len(hits) > 1 and present is not None:
            live = [h for h in hits if present(h[0], h[1])]
            hits = live if len(live) == 1 else hits
        if len(hits) > 1:
            where = ", ".join(f"{m.name}.{s.name}" for _, m, s in hits)
            raise DbcError(
                f"signal {ref!r} is defined in several messages ({where}); name it as "
                "MESSAGE.SIGNAL"
            )
        picked.append((alias, hits[0]))
    return _name_choices(picked, speed_signal)


def default_signals(dbcs: Any, present: Presence) -> list[SignalChoice]:
    """The vehicle speed and the wheel speeds of the DBCs that occur in the frames at hand.

    Parameters
    ----------
    dbcs : Dbc, cantools Database, or a sequence of them
    present : callable
        ``present(dbc, message)`` (see :func:`presence`).

    Returns
    -------
    list of SignalChoice
        The preferred vehicle speed (order of :data:`VEHICLE_SPEED_NAMES`) first, with
        role ``speed``, then every wheel speed by name; empty if none occurs.
    """
    speed: list[tuple[int, _Entry]] = []
    wheels: list[_Entry] = []
    for d in as_dbcs(dbcs):
        for m in d.db.messages:
            sigs = [s for s in m.signals if (s.unit or "").strip().lower() in SPEED_UNITS]
            if not sigs or not present(d, m):
                continue
            for s in sigs:
                n = _norm(s.name)
                if n in VEHICLE_SPEED_NAMES:
                    speed.append((VEHICLE_SPEED_NAMES.index(n), (d, m, s)))
                elif _WHEEL_SPEED_RE.search(n):
                    wheels.append((d, m, s))
    out: list[_Entry] = [min(speed, key=lambda x: x[0])[1]] if speed else []
    out += sorted(wheels, key=lambda e: e[2].name)
    return _name_choices([("", e) for e in out], None)


def _name_choices(picked: list[tuple[str, _Entry]], speed_signal: str | None) -> list[SignalChoice]:
    short: dict[str, set[tuple[int, str, str]]] = {}
    for alias, (d, m, s) in picked:
        if not alias:
            short.setdefault(s.name, set()).add((id(d), m.name, s.name))
    named: list[tuple[str, _Entry]] = []
    seen: set[tuple[str, int, str, str]] = set()
    for alias, e in picked:
        d, m, s = e
        name = alias or (s.name if len(short[s.name]) == 1 else f"{m.name}.{s.name}")
        name = safe_name(name)
        key = (name, id(d), m.name, s.name)
        if key not in seen:
            seen.add(key)
            named.append((name, e))
    names = [n for n, _ in named]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise DbcError(
            f"signals named twice: {', '.join(dup)}; give them aliases (ALIAS=MESSAGE.SIGNAL)"
        )
    if speed_signal is not None and speed_signal not in names:
        raise DbcError(
            f"speed signal {speed_signal!r} is not among the decoded signals "
            f"({', '.join(names) or 'none'}); name one of them"
        )
    if speed_signal is None:
        speed_signal = next(
            (n for n, e in named if n == SPEED_ALIAS or _is_speed(e)), None
        )
    return [
        SignalChoice(n, d, m, s,
                     "speed" if n == speed_signal else n if n in ROLE_ALIASES else "other")
        for n, (d, m, s) in named
    ]


# ============================================================================ decoding
def frames_of(frames: np.ndarray, message: Any, buses: frozenset[int] | None = None) -> np.ndarray:
    """Indices of the data frames that carry a DBC ``message`` on ``buses`` (None: any).

    Parameters
    ----------
    frames : numpy.ndarray of CAN_FRAME_DTYPE
    message : cantools Message
    buses : frozenset of int or None

    Returns
    -------
    numpy.ndarray of int
        In frame order.
    """
    flags = frames["flags"]
    sel = frames["arbitration_id"] == message.frame_id
    sel &= ((flags & CAN_FLAG_EXTENDED) != 0) == bool(message.is_extended_frame)
    sel &= (flags & (CAN_FLAG_REMOTE | CAN_FLAG_ERROR)) == 0
    if buses is not None:
        sel &= np.isin(frames["bus"], np.fromiter(buses, dtype="u1", count=len(buses)))
    return np.flatnonzero(sel)


def presence(frames: np.ndarray) -> Presence:
    """A ``present(dbc, message)`` for :func:`resolve_signals`: does ``frames`` carry it?"""
    return lambda dbc, message: frames_of(frames, message, dbc.buses).size > 0


class CanDecoder:
    """Decode chosen signals from stored raw frames, to SI units.

    Parameters
    ----------
    choices : sequence of SignalChoice
        From :func:`resolve_signals` or :func:`default_signals`.

    Attributes
    ----------
    specs : list of SignalSpec
        How each signal is stored (SI unit), in the order of ``choices``.
    errors : int
        Frames that failed to decode so far (see the module's rules).
    decoded_frames : int
        Frames decoded so far.

    Examples
    --------
    >>> import cantools
    >>> db = cantools.database.load_string(
    ...     'BO_ 180 SPEED: 8 XXX\\n SG_ SPEED : 47|16@0+ (0.01,0) [0|250] "km/h" XXX\\n',
    ...     strict=False)
    >>> dec = CanDecoder(resolve_signals(db, ["SPEED"]))
    >>> f = np.zeros(1, dtype=CAN_FRAME_DTYPE)
    >>> f["arbitration_id"], f["dlc"] = 180, 8
    >>> f["data"][0, 5:7] = list((3600).to_bytes(2, "big"))  # 36.00 km/h
    >>> t, v = dec.decode(f)["SPEED"]
    >>> round(float(v[0]), 12), dec.specs[0].unit, dec.specs[0].role
    (10.0, 'm/s', 'speed')
    """

    def __init__(self, choices: Sequence[SignalChoice]) -> None:
        self.choices = list(choices)
        self.specs = [c.spec for c in self.choices]
        self.errors = 0
        self.decoded_frames = 0
        groups: dict[tuple[int, str], list[SignalChoice]] = {}
        for c in self.choices:
            groups.setdefault((id(c.dbc), c.message.name), []).append(c)
        self._groups = [(g[0].dbc, g[0].message, g) for g in groups.values()]
        self._ids = np.array(sorted({m.frame_id for _, m, _ in self._groups}), dtype="u4")

    def decode(self, frames: np.ndarray) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Signals carried by ``frames``.

        Parameters
        ----------
        frames : numpy.ndarray of CAN_FRAME_DTYPE
            A batch of stored frames, in time order.

        Returns
        -------
        dict
            ``{name: (time_s, value_si)}`` (float64 arrays, in frame order) for each
            chosen signal with at least one sample in ``frames``.
        """
        out: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        if not self._groups or len(frames) == 0:
            return out
        near = np.flatnonzero(np.isin(frames["arbitration_id"], self._ids))
        if near.size == 0:
            return out
        batch = frames[near]
        for dbc, message, group in self._groups:
            idx = frames_of(batch, message, dbc.buses)
            if idx.size == 0:
                continue
            sel = batch[idx]
            times = sel["time_s"]
            names = [c.signal.name for c in group]
            rows: list[list[int]] = [[] for _ in group]
            vals: list[list[float]] = [[] for _ in group]
            for k, payload in enumerate(frame_payloads(sel)):
                try:
                    decoded = message.decode(
                        payload, decode_choices=False, scaling=True, allow_truncated=True
                    )
                except Exception:  # cantools DecodeError and friends: a frame it rejects
                    self.errors += 1
                    continue
                self.decoded_frames += 1
                short = len(payload) < message.length
                missing = False
                for j, sig in enumerate(names):
                    v = decoded.get(sig)
                    if v is None:  # multiplexed out, or past the end of a short frame
                        missing = True
                        continue
                    rows[j].append(k)
                    vals[j].append(v)
                if short and missing:
                    self.errors += 1
            for c, r, v in zip(group, rows, vals, strict=True):
                if r:
                    out[c.name] = (
                        times[np.asarray(r, dtype=np.intp)].astype("f8"),
                        np.asarray(v, dtype="f8") * c.unit_factor,
                    )
        return out


__all__ = [
    "BUS_RULE",
    "BusTable",
    "CanDecoder",
    "Dbc",
    "FD_LENGTHS",
    "ROLE_ALIASES",
    "SPEED_ALIAS",
    "SignalChoice",
    "VEHICLE_SPEED_NAMES",
    "as_dbcs",
    "buses_named",
    "default_signals",
    "frame_flags",
    "frame_payload",
    "frame_payloads",
    "frames_of",
    "load_dbc",
    "messages_to_frames",
    "payload_lengths",
    "presence",
    "resolve_signals",
]
