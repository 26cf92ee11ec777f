"""Write simulated drives (:mod:`fielddiag.sim`) as sessions, like a recording would be.

Channels: ``wheel_z`` (role wheel) and ``body_z`` (role body) in m/s2, as the sensors read
them (acceleration + g, noise, bias...), on a uniform time base; the vehicle speed as the
signal ``vehicle_speed`` (role speed, m/s, from the simulated CAN); every road event as a
session event. How the drive was made goes into the root attribute ``extra`` under
``simulation`` unless ``include_recipe`` is False (for blind test cases, where the recipe
is kept in a separate file).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from fielddiag.channels import ChannelSpec, Event, SessionMetadata, SignalSpec
from fielddiag.session import write_session
from fielddiag.sim import SimulatedDrive

WHEEL_CHANNEL = ChannelSpec("wheel_z", unit="m/s2", role="wheel", axis="z", sensor="simulated")
BODY_CHANNEL = ChannelSpec("body_z", unit="m/s2", role="body", axis="z", sensor="simulated")
SPEED_SIGNAL = SignalSpec("vehicle_speed", unit="m/s", source="sim", message="SPEED", role="speed")


def drive_to_session(
    drive: SimulatedDrive,
    path: str | os.PathLike,
    *,
    vehicle: str = "simulated car",
    corner: str = "front-left",
    operator: str = "fielddiag simulate",
    notes: str = "",
    include_recipe: bool = True,
    overwrite: bool = False,
) -> Path:
    """Write ``drive`` to a new session file (atomically) and return its path."""
    extra = {"simulation": drive.to_dict()} if include_recipe else {}
    meta = SessionMetadata(
        vehicle=vehicle,
        corner=corner,
        operator=operator,
        added_mass_kg=float(drive.added_mass_kg),
        notes=notes,
        extra=extra,
    )
    events = [Event(float(p.time_s), p.event.kind) for p in drive.events if p.time_s is not None]
    samples = np.column_stack([drive.wheel_accel_mps2, drive.body_accel_mps2])
    return write_session(
        path,
        meta,
        [WHEEL_CHANNEL, BODY_CHANNEL],
        samples,
        sample_rate_hz=drive.sample_rate_hz,
        signals={SPEED_SIGNAL: (drive.vehicle_speed_time_s, drive.vehicle_speed_mps)},
        events=events,
        overwrite=overwrite,
    )
