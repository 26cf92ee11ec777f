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

import importlib

#: Where each public name lives. Loaded on first use (PEP 562): importing one light module
#: of the package (the session reader's role check, the geometry) must not load the
#: identification with scipy and numba, 3 s before a command can even refuse bad input.
_WHERE = {
    "FULL_VEHICLE_ROLES": "recording",
    "CornerParams": "params",
    "Manoeuvre": "manoeuvres",
    "VehicleDrive": "sim",
    "VehicleFileError": "geometry",
    "VehicleGeometry": "geometry",
    "VehicleIdentification": "identify",
    "VehicleIdentifyConfig": "identify",
    "VehicleParams": "params",
    "VehicleRecording": "recording",
    "body_mass_matrix": "sim",
    "braking": "manoeuvres",
    "identify_vehicle": "identify",
    "is_full_vehicle_session": "recording",
    "load_vehicle": "geometry",
    "make_manoeuvre": "manoeuvres",
    "ramp_steer": "manoeuvres",
    "random_vehicle": "params",
    "read_vehicle_recording": "recording",
    "rough_road": "manoeuvres",
    "simulate_vehicle": "sim",
}


def __getattr__(name: str):
    if name in _WHERE:
        value = getattr(importlib.import_module(f"{__name__}.{_WHERE[name]}"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *_WHERE])


__all__ = sorted(_WHERE)
