"""What the virtual devices play: a simulated drive as DAQ channels and ECU series.

:class:`fielddiag.virtual_drive.VirtualDrive` streams one :class:`DriveStream`:

* a quarter car (:func:`quarter_car_stream`, :func:`fielddiag.sim.simulate`): channel 0
  the wheel sensor, 1 the body sensor, the others noise; the ECU sends the speed and the
  wheel speeds;
* a full vehicle (:func:`full_vehicle_stream`, :func:`fielddiag.vehicle.simulate_vehicle`):
  eight channels in the order of :data:`fielddiag.vehicle.corner_map.VIRTUAL_DAQ_MAP` (per
  corner fl, fr, rl, rr: hub, then body), announced by the device as ``wheel``/``body``
  and given their corner roles by the host driver's channel map, as a real DAQ's are
  with ``fielddiag record --role``; a measuring range the hub accelerations do not clip
  (:func:`drivers.virtual.full_scale_for`, 16 g for the default car on a class C road);
  the ECU also sends the car's longitudinal and lateral accelerations (``KINEMATICS``),
  stored as ``accel_long`` and ``accel_lat``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from fielddiag.errors import InvalidValueError

__all__ = ["ECU_SIGNALS", "VEHICLE_ECU_SIGNALS", "DriveStream", "full_vehicle_stream",
           "is_vehicle_drive", "quarter_car_stream"]

#: The DBC signals of the virtual ECU that are decoded and stored (SI: m/s).
ECU_SIGNALS = ["vehicle_speed=SPEED.SPEED"] + [
    f"WHEEL_SPEEDS.WHEEL_SPEED_{w}" for w in ("FL", "FR", "RL", "RR")
]
#: ... and for a full-vehicle drive the car's accelerations, aliased to their roles.
VEHICLE_ECU_SIGNALS = ECU_SIGNALS + ["accel_long=KINEMATICS.ACCEL_X",
                                     "accel_lat=KINEMATICS.ACCEL_Y"]
#: Output rate of a drive simulated for the virtual ECU alone (only its speed is used).
_SPEED_ONLY_RATE_HZ = 100.0
#: Lowest output rate of the full-vehicle simulator (used when only the ECU plays).
_VEHICLE_MIN_RATE_HZ = 200.0


@dataclass
class DriveStream:
    """A simulated drive as the virtual devices play it.

    Attributes
    ----------
    drive : SimulatedDrive or VehicleDrive
        The drive (truth for tests).
    signals_mps2 : ndarray (n, channels) or None
        What the DAQ's sensors read, one column per channel; None: no DAQ.
    daq_roles : list of str or None
        Roles the device announces (None: its defaults, wheel, body, other...).
    role_map : dict or None
        Channel index -> role the host driver applies (the corner map).
    full_scale_mps2 : float or None
        The DAQ's measuring range (None: the device's default, 16 g).
    speed_time_s, speed_mps : ndarray
        The speed the ECU sends.
    accel_mps2 : (ndarray, ndarray) or None
        Longitudinal and lateral acceleration on ``speed_time_s`` (full vehicle).
    ecu_signals : list of str
        The DBC signals the host decodes (``ALIAS=MESSAGE.SIGNAL``).
    extra : dict
        Session metadata ``extra`` the drive contributes (full vehicle: the vehicle file,
        where the added mass sits); ``recipe``: how it was simulated.
    """

    drive: Any
    signals_mps2: np.ndarray | None
    speed_time_s: np.ndarray
    speed_mps: np.ndarray
    ecu_signals: list[str]
    daq_roles: list[str] | None = None
    role_map: dict[int, str] | None = None
    full_scale_mps2: float | None = None
    accel_mps2: tuple[np.ndarray, np.ndarray] | None = None
    extra: dict[str, Any] = field(default_factory=dict)
    recipe: dict[str, Any] = field(default_factory=dict)


def is_vehicle_drive(drive: Any) -> bool:
    """True for a full-vehicle drive (eight readings and a vehicle geometry)."""
    return drive is not None and getattr(drive, "geometry", None) is not None and np.ndim(
        getattr(drive, "body_accel_mps2", None)) == 2


def quarter_car_stream(*, drive_s: float, sample_rate_hz: float, n_channels: int,
                       added_mass_kg: float, seed: int, with_daq: bool, drive: Any = None,
                       params: Any = None, effects: Sequence[Any] = (),
                       road_class: str | None = "C") -> DriveStream:
    """A quarter-car drive (simulated unless ``drive`` is given) for the virtual devices.

    Parameters
    ----------
    drive_s : float
        Length to simulate [s].
    sample_rate_hz : float
        DAQ rate [Hz].
    n_channels : int
        DAQ channels (wheel, body, then noise).
    added_mass_kg : float
        Mass on the body [kg].
    seed : int
        Road, speed profile and noise.
    with_daq : bool
        False: only the speed is needed (simulated at a low rate).
    drive : fielddiag.sim.SimulatedDrive or None
        Stream this drive instead.
    params, effects, road_class : optional
        Passed to the simulator.

    Returns
    -------
    DriveStream
    """
    from drivers.virtual import simulated_accelerations

    options = {"params": params, "effects": tuple(effects), "road_class": road_class}
    signals = None
    if with_daq:
        signals, drive = simulated_accelerations(
            drive_s, sample_rate_hz=sample_rate_hz, n_channels=n_channels,
            added_mass_kg=added_mass_kg, seed=seed, drive=drive, **options)
    elif drive is None:
        _, drive = simulated_accelerations(drive_s, sample_rate_hz=_SPEED_ONLY_RATE_HZ,
                                           added_mass_kg=added_mass_kg, seed=seed, **options)
    return DriveStream(drive=drive, signals_mps2=signals,
                       speed_time_s=drive.vehicle_speed_time_s, speed_mps=drive.vehicle_speed_mps,
                       ecu_signals=list(ECU_SIGNALS), recipe=drive.to_dict())


def full_vehicle_stream(*, drive_s: float, sample_rate_hz: float, added_mass_kg: float,
                        seed: int, with_daq: bool, drive: Any = None,
                        added_mass_at_m: tuple[float, float] | None = None,
                        params: Any = None,
                        effects: Mapping[str, Sequence[Any]] | None = None,
                        road_class: str | None = "C",
                        manoeuvre: str = "rough_road") -> DriveStream:
    """A full-vehicle drive (simulated unless ``drive`` is given) for the virtual devices.

    Parameters
    ----------
    drive_s, sample_rate_hz, added_mass_kg, seed, with_daq
        As :func:`quarter_car_stream`.
    drive : fielddiag.vehicle.VehicleDrive or None
        Stream this drive instead (its rate, added mass and its position are used).
    added_mass_at_m : (x_m, y_m) or None
        Where the added mass sits; required with an added mass.
    params : VehicleParams or None
        The car (default ``VehicleParams()``).
    effects : mapping corner -> effects, or None
        Effects at each corner.
    road_class : str or None
        ISO 8608 class of the road.
    manoeuvre : str
        ``rough_road``, ``ramp_steer`` or ``braking``.

    Returns
    -------
    DriveStream

    Raises
    ------
    InvalidValueError
        An added mass without its position; hub accelerations beyond the largest
        measuring range of the virtual DAQ.
    """
    from drivers.virtual import full_scale_for
    from fielddiag.vehicle.corner_map import VIRTUAL_DAQ_MAP, daq_columns
    from fielddiag.vehicle.recording import full_vehicle_extra

    if drive is None:
        if added_mass_kg > 0 and added_mass_at_m is None:
            raise InvalidValueError(
                f"{added_mass_kg:g} kg added to a full vehicle: say where it sits "
                "(--added-mass-at X_M,Y_M, metres behind the front axle and left of the "
                "centre line)")
        from fielddiag.vehicle import VehicleParams, simulate_vehicle

        drive = simulate_vehicle(
            params if params is not None else VehicleParams(), manoeuvre=manoeuvre,
            duration_s=drive_s,
            sample_rate_hz=sample_rate_hz if with_daq else _VEHICLE_MIN_RATE_HZ,
            effects=effects, added_mass_kg=added_mass_kg,
            added_mass_at_m=added_mass_at_m if added_mass_kg > 0 else None,
            road_class=road_class, seed=seed)
    signals = roles = full_scale = None
    if with_daq:
        signals = daq_columns(drive.wheel_accel_mps2, drive.body_accel_mps2)
        roles = [VIRTUAL_DAQ_MAP[i].split("_")[0] for i in range(signals.shape[1])]
        try:
            full_scale = full_scale_for(signals)
        except ValueError as exc:
            raise InvalidValueError(f"the virtual DAQ cannot record this drive: {exc}; "
                                    "simulate a smoother road or a slower drive") from None
    return DriveStream(
        drive=drive, signals_mps2=signals, daq_roles=roles,
        role_map=dict(VIRTUAL_DAQ_MAP) if with_daq else None, full_scale_mps2=full_scale,
        speed_time_s=drive.time_s, speed_mps=drive.signal_or_zero("speed"),
        accel_mps2=(drive.signal_or_zero("accel_long"), drive.signal_or_zero("accel_lat")),
        ecu_signals=list(VEHICLE_ECU_SIGNALS),
        extra=full_vehicle_extra(drive.geometry, drive.added_mass_at_m),
        recipe=drive.simulation_metadata())
