"""Full-vehicle sessions as a recorder with trouble leaves them (shared by the vehicle
and dashboard tests)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fielddiag.channels import Gap
from fielddiag.session import SessionReader, write_session
from fielddiag.vehicle.writer import write_vehicle_session


def write_with_a_gap(drive, path: Path, gap_s: tuple[float, float], vehicle_name: str = ""
                     ) -> Path:
    """The drive as a session whose DAQ lost the samples in ``gap_s`` [s] (a recorder's
    gap): written whole by the writer, then again without them."""
    tmp = write_vehicle_session(drive, path.with_name(path.stem + ".whole.h5"),
                                vehicle_name=vehicle_name)
    with SessionReader(tmp) as s:
        meta, channels, signals = s.metadata, s.channels, s.signals
        cols = np.column_stack([s.read(c.name) for c in channels])
        sig = {spec: s.signal(spec.name) for spec in signals}
    tmp.unlink()
    keep = (drive.time_s < gap_s[0]) | (drive.time_s >= gap_s[1])
    gap = Gap(gap_s[0], gap_s[1], int((~keep).sum()), "frames lost")
    return write_session(path, meta, channels, cols[keep], sample_rate_hz=drive.sample_rate_hz,
                         time_s=drive.time_s[keep], signals=sig, gaps=[gap])
