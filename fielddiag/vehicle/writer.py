"""Write a full-vehicle drive as a session (HDF5) or as a CSV in the import format.

Session: eight DAQ channels named and roled ``wheel_fl`` ... ``body_rr`` (m/s2), the
signals ``vehicle_speed`` (role ``speed``, m/s), ``accel_long`` and ``accel_lat``
(m/s2) on the DAQ time base, and in the metadata the vehicle file
(``extra["vehicle"]``), the added mass (``added_mass_kg``) and where it sits
(``extra["added_mass_at_m"]``); a simulated drive also stores what was simulated
(``extra["simulation"]``: the car, the effects per corner, the manoeuvre, the road, the
seed).

CSV: columns ``time_s``, ``wheel_fl`` ... ``body_rr``, ``speed_mps``,
``accel_long_mps2``, ``accel_lat_mps2``; import it with::

    fielddiag import CAR.csv -o S.h5 --time time_s --vehicle VEHICLE.json \\
        --role wheel_fl=wheel_fl ... --role speed=speed_mps \\
        --role accel_long=accel_long_mps2 --role accel_lat=accel_lat_mps2
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from fielddiag.channels import CORNERS, ChannelSpec, SessionMetadata, SignalSpec
from fielddiag.session import write_session
from fielddiag.vehicle.recording import SIGNAL_NAMES, VehicleRecording, full_vehicle_extra

__all__ = ["CSV_COLUMNS", "csv_role_args", "write_vehicle_csv", "write_vehicle_session"]

#: Columns of the CSV the writer produces, in order (after ``time_s``).
CSV_COLUMNS = (*(f"{k}_{c}" for k in ("wheel", "body") for c in CORNERS),
               "speed_mps", "accel_long_mps2", "accel_lat_mps2")
_CSV_ROLES = {**{f"{k}_{c}": f"{k}_{c}" for k in ("wheel", "body") for c in CORNERS},
              "speed": "speed_mps", "accel_long": "accel_long_mps2",
              "accel_lat": "accel_lat_mps2"}


def csv_role_args() -> list[str]:
    """The ``--role ROLE=COLUMN`` arguments that import a CSV written by
    :func:`write_vehicle_csv` (without the leading ``--role``)."""
    return [f"{r}={c}" for r, c in _CSV_ROLES.items()]


def _metadata(rec: VehicleRecording, vehicle_name: str) -> SessionMetadata:
    extra = full_vehicle_extra(rec.geometry, rec.added_mass_at_m)
    sim = getattr(rec, "simulation_metadata", None)
    notes = ""
    if sim is not None:
        extra["simulation"] = sim()
        notes = "simulated full-vehicle drive (fielddiag.vehicle.simulate_vehicle)"
    return SessionMetadata(vehicle=vehicle_name, added_mass_kg=float(rec.added_mass_kg),
                           notes=notes, extra=extra)


def write_vehicle_session(rec: VehicleRecording, path: str | os.PathLike, *,
                          vehicle_name: str = "", overwrite: bool = False) -> Path:
    """Write a full-vehicle drive as a session.

    Parameters
    ----------
    rec : VehicleRecording or VehicleDrive
        The drive.
    path : str or PathLike
        The ``.h5`` file to create (atomically).
    vehicle_name : str
        Stored as the session's vehicle name.
    overwrite : bool
        Replace an existing file.

    Returns
    -------
    Path

    Raises
    ------
    SessionError
        The file exists (without ``overwrite``) or its folder does not.
    """
    channels = [ChannelSpec(f"{k}_{c}", unit="m/s2", role=f"{k}_{c}", sensor="vehicle")
                for k in ("wheel", "body") for c in CORNERS]
    samples = np.vstack([rec.wheel_accel_mps2, rec.body_accel_mps2]).T
    t = rec.time_s
    signals = {}
    for role, unit in (("speed", "m/s"), ("accel_long", "m/s2"), ("accel_lat", "m/s2")):
        v = getattr(rec, {"speed": "speed_mps", "accel_long": "accel_long_mps2",
                          "accel_lat": "accel_lat_mps2"}[role])
        if v is not None:
            spec = SignalSpec(SIGNAL_NAMES[role], unit=unit, source="vehicle", role=role)
            signals[spec] = (t, np.asarray(v, float))
    return write_session(path, _metadata(rec, vehicle_name), channels, samples,
                         sample_rate_hz=rec.sample_rate_hz, signals=signals,
                         overwrite=overwrite)


def write_vehicle_csv(rec: VehicleRecording, path: str | os.PathLike) -> Path:
    """Write a full-vehicle drive as a CSV (columns: :data:`CSV_COLUMNS` after ``time_s``).

    Missing signals are written as zeros. Values in SI units (m/s2, m/s), 7 significant
    digits.

    Returns
    -------
    Path
    """
    cols = [rec.time_s, *rec.wheel_accel_mps2, *rec.body_accel_mps2,
            rec.signal_or_zero("speed"), rec.signal_or_zero("accel_long"),
            rec.signal_or_zero("accel_lat")]
    p = Path(path)
    np.savetxt(p, np.column_stack(cols), delimiter=",", fmt="%.7g",
               header=",".join(("time_s", *CSV_COLUMNS)), comments="")
    return p
