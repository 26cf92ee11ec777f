"""Which DAQ channel is which sensor: the channel map of a recording (``--role ROLE=CHANNEL``).

A DAQ tells how many channels it has, not where their sensors are: its INFO frame knows
``wheel`` and ``body`` but no corner. A full-vehicle recording therefore says which
channel is which corner's sensor, as ``fielddiag import`` maps CSV columns::

    fielddiag record --daq serial:///dev/ttyUSB0 --role wheel_fl=0 --role body_fl=1 \\
        --role wheel_fr=2 --role body_fr=3 --role wheel_rl=4 --role body_rl=5 \\
        --role wheel_rr=6 --role body_rr=7 --vehicle-file car.json ...

``CHANNEL`` is the DAQ channel number, counted from 0 (``ch3``, the name ``fielddiag info``
gives a channel without a role, is accepted too). Channels not mapped are kept with role
``other``. A map with any corner role (``wheel_fl``...) is a full-vehicle map and must give
all eight. The car's speed and accelerations come from CAN, named by their alias
(``--signal vehicle_speed=...``, ``accel_long=...``, ``accel_lat=...``), not by ``--role``.
"""

from __future__ import annotations

import difflib
import re
from collections.abc import Iterable, Mapping

import numpy as np

from fielddiag.channels import CORNERS
from fielddiag.errors import FieldDiagError
from fielddiag.vehicle.recording import FULL_VEHICLE_ROLES, VEHICLE_SIGNAL_ROLES

__all__ = ["MAP_ROLES", "VIRTUAL_DAQ_MAP", "CornerMapError", "daq_columns", "is_full_vehicle",
           "parse_channel_map"]

#: Roles a DAQ channel can be given with ``--role``.
MAP_ROLES = ("wheel", "body", "acceleration", "force", "displacement", *FULL_VEHICLE_ROLES)
#: The channel order of the virtual DAQ in full-vehicle mode: per corner (fl, fr, rl, rr)
#: the hub sensor, then the body sensor.
VIRTUAL_DAQ_MAP = {2 * k + j: f"{kind}_{c}" for k, c in enumerate(CORNERS)
                   for j, kind in enumerate(("wheel", "body"))}
#: The CAN alias of each vehicle signal role.
_SIGNAL_ALIASES = {"speed": "vehicle_speed", "accel_long": "accel_long",
                   "accel_lat": "accel_lat"}
_CHANNEL_RE = re.compile(r"(?:ch)?(\d+)", re.IGNORECASE)


class CornerMapError(FieldDiagError):
    """A channel map (``--role ROLE=CHANNEL``) is malformed, ambiguous or incomplete."""


def parse_channel_map(items: Iterable[str] | None) -> dict[int, str]:
    """``ROLE=CHANNEL`` items -> {channel index: role}, checked.

    Parameters
    ----------
    items : iterable of str or None
        e.g. ``["wheel_fl=0", "body_fl=ch1"]``.

    Returns
    -------
    dict
        Channel index -> role; empty for no items.

    Raises
    ------
    CornerMapError
        An item not ``ROLE=CHANNEL``, an unknown role (a vehicle signal role says how to
        give it), a role or a channel given twice, a full-vehicle map without all eight
        corner sensors.
    """
    by_channel: dict[int, str] = {}
    by_role: dict[str, int] = {}
    for item in items or ():
        role, sep, chan = (p.strip() for p in str(item).partition("="))
        if not sep or not role or not chan:
            raise CornerMapError(f"--role {item!r}: write it as ROLE=CHANNEL, e.g. wheel_fl=0")
        _check_role(role)
        m = _CHANNEL_RE.fullmatch(chan)
        if m is None:
            raise CornerMapError(f"--role {role}={chan}: the channel is the DAQ channel number "
                                 "counted from 0 (e.g. 3 or ch3)")
        index = int(m.group(1))
        if role in by_role:
            raise CornerMapError(f"--role {role} is given twice (channels {by_role[role]} and "
                                 f"{index}); give each role once")
        if index in by_channel:
            raise CornerMapError(f"channel {index} is mapped twice ({by_channel[index]} and "
                                 f"{role}); one sensor per channel")
        by_role[role] = index
        by_channel[index] = role
    if is_full_vehicle(by_channel):
        missing = [r for r in FULL_VEHICLE_ROLES if r not in by_role]
        plain = [r for r in by_role if r in ("wheel", "body")]
        if missing:
            raise CornerMapError(
                f"a full-vehicle recording needs all eight corner sensors; missing "
                f"{', '.join(missing)} (give --role {missing[0]}=CHANNEL ...)")
        if plain:
            raise CornerMapError(
                f"--role {plain[0]} is a single-corner role; a full-vehicle map names the "
                "corner (wheel_fl ... body_rr)")
    return dict(sorted(by_channel.items()))


def _check_role(role: str) -> None:
    if role in MAP_ROLES:
        return
    if role in VEHICLE_SIGNAL_ROLES:
        raise CornerMapError(
            f"--role {role}: {role} is a CAN signal, not a DAQ channel; give it with "
            f"--signal {_SIGNAL_ALIASES[role]}=MESSAGE.SIGNAL (and --can URL)")
    close = difflib.get_close_matches(role, MAP_ROLES, n=1, cutoff=0.6)
    hint = f"did you mean {close[0]}? " if close else ""
    raise CornerMapError(f"--role {role}: unknown role; {hint}the roles are "
                         f"{', '.join(MAP_ROLES)}")


def is_full_vehicle(channel_map: Mapping[int, str]) -> bool:
    """True when the map gives any corner role (``wheel_fl`` ... ``body_rr``)."""
    return any(r in FULL_VEHICLE_ROLES for r in channel_map.values())


def daq_columns(wheel_accel: np.ndarray, body_accel: np.ndarray,
                channel_map: Mapping[int, str] = VIRTUAL_DAQ_MAP) -> np.ndarray:
    """A full-vehicle drive's eight readings as DAQ channels, in the order of a map.

    Parameters
    ----------
    wheel_accel, body_accel : ndarray, shape (4, n)
        Hub and body readings, corners fl, fr, rl, rr.
    channel_map : mapping
        Channel index -> corner role, channels 0 to 7 (default :data:`VIRTUAL_DAQ_MAP`).

    Returns
    -------
    ndarray, shape (n, 8)
        Column ``i`` is the reading of the sensor mapped to channel ``i``.
    """
    rows = {f"{kind}_{c}": arr[k] for kind, arr in (("wheel", wheel_accel),
                                                    ("body", body_accel))
            for k, c in enumerate(CORNERS)}
    return np.column_stack([rows[channel_map[i]] for i in range(len(FULL_VEHICLE_ROLES))])
