"""The full vehicle: a body with heave, pitch and roll on four corners.

Modules (one concern each):

* :mod:`~fielddiag.vehicle.geometry`: the vehicle file (JSON), corner and body-sensor
  positions, rigid-body kinematics (body points from heave/pitch/roll and back);
* :mod:`~fielddiag.vehicle.params`: the car's parameters (:class:`VehicleParams`) and a
  random car;
* :mod:`~fielddiag.vehicle.manoeuvres`: rough road, ramp steer, braking;
* :mod:`~fielddiag.vehicle.dynamics`: equations of motion and the numba RK4 loop;
* :mod:`~fielddiag.vehicle.sim`: :func:`simulate_vehicle` -> :class:`VehicleDrive`;
* :mod:`~fielddiag.vehicle.recording`: a measured drive (:class:`VehicleRecording`) and
  its reader from a session;
* :mod:`~fielddiag.vehicle.writer`: a drive to a session (HDF5) or a CSV in the import
  format;
* :mod:`~fielddiag.vehicle.identify`: :func:`identify_vehicle` ->
  :class:`VehicleIdentification` (mass, centre of gravity, inertias, corner stiffness
  and damping, anti-roll bars, with standard deviations).
"""

from fielddiag.vehicle.geometry import VehicleFileError, VehicleGeometry, load_vehicle
from fielddiag.vehicle.identify import (
    VehicleIdentification,
    VehicleIdentifyConfig,
    identify_vehicle,
)
from fielddiag.vehicle.manoeuvres import Manoeuvre, braking, make_manoeuvre, ramp_steer, rough_road
from fielddiag.vehicle.params import CornerParams, VehicleParams, random_vehicle
from fielddiag.vehicle.recording import (
    FULL_VEHICLE_ROLES,
    VehicleRecording,
    is_full_vehicle_session,
    read_vehicle_recording,
)
from fielddiag.vehicle.sim import VehicleDrive, body_mass_matrix, simulate_vehicle

__all__ = [
    "FULL_VEHICLE_ROLES",
    "CornerParams",
    "Manoeuvre",
    "VehicleDrive",
    "VehicleFileError",
    "VehicleGeometry",
    "VehicleIdentification",
    "VehicleIdentifyConfig",
    "VehicleParams",
    "VehicleRecording",
    "body_mass_matrix",
    "braking",
    "identify_vehicle",
    "is_full_vehicle_session",
    "load_vehicle",
    "make_manoeuvre",
    "ramp_steer",
    "random_vehicle",
    "read_vehicle_recording",
    "rough_road",
    "simulate_vehicle",
]
