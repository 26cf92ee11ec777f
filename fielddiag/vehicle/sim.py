"""Full-vehicle simulator: :func:`simulate_vehicle` and its result :class:`VehicleDrive`.

A body with heave, pitch and roll on four corners (unsprung mass on a linear tyre, the
suspension a :class:`~fielddiag.effects.ForceModel` of the effect library, anti-roll bars
per axle), driven by two ISO 8608 road tracks (left and right, partially correlated; the
rear wheels see the front's road ``wheelbase / speed`` later) and by the roll and pitch
moments of the manoeuvre's lateral and longitudinal accelerations through the
centre-of-gravity height. Equations: :mod:`fielddiag.vehicle.dynamics`. Integrated by
fixed-step RK4 (numba) at ``k * sample_rate_hz >= 4000 Hz`` from the static equilibrium
of the loaded car, read by the same accelerometer chain as the quarter car
(:class:`~fielddiag.sim.SensorModel`: + g, anti-alias filter, decimation, noise).

Example::

    from fielddiag.vehicle import VehicleParams, simulate_vehicle
    from fielddiag.effects import CoulombFriction
    car = VehicleParams()
    before = simulate_vehicle(car, manoeuvre="rough_road", duration_s=180, seed=1)
    after = simulate_vehicle(car, manoeuvre="rough_road", duration_s=180, seed=2,
                             added_mass_kg=150, added_mass_at_m=(2.0, 0.3),
                             effects={"fl": [CoulombFriction(friction_force_n=80.0)]})
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from fielddiag.channels import CORNERS
from fielddiag.effects import Effect, ForceModel
from fielddiag.errors import FieldDiagError
from fielddiag.sim._common import G_MPS2, check_number
from fielddiag.sim.road import iso8608_profile
from fielddiag.sim.sensors import SensorModel, _read_sensor
from fielddiag.vehicle.dynamics import (
    corner_models,
    integrate_vehicle,
    internal_rate_factor,
    static_forces,
    union_layout,
)
from fielddiag.vehicle.manoeuvres import Manoeuvre, make_manoeuvre
from fielddiag.vehicle.params import VehicleParams
from fielddiag.vehicle.recording import VehicleRecording

__all__ = ["VehicleDrive", "body_mass_matrix", "simulate_vehicle"]

#: Road sample spacing [m] and the margin of road behind the rear axle at t = 0 [m].
_ROAD_SPACING_M = 0.02
_ROAD_MARGIN_M = 1.0


@dataclass(eq=False)
class VehicleDrive(VehicleRecording):
    """A simulated full-vehicle drive: the readings (:class:`VehicleRecording`) and the truth.

    Attributes (besides the readings)
    ---------------------------------
    vehicle : VehicleParams
        The car simulated.
    manoeuvre : Manoeuvre or None
    effects : dict corner -> list of effect dicts
        The effects simulated at each corner (``Effect.to_dict()``).
    road_class : str or None
    seed : int or None
    body_dofs_m : ndarray (3, n)
        True heave [m], pitch [rad], roll [rad] at the origin, from the unloaded static
        equilibrium.
    wheel_disp_m : ndarray (4, n)
        True hub positions [m].
    suspension_extension_m : ndarray (4, n)
        ``r`` of each corner [m] (body point above the hub minus the hub).
    corner_force_n : ndarray (4, n)
        Force of each corner on the body (suspension + anti-roll bar) [N], up positive.
    road_m : ndarray (4, n)
        Road height under each wheel [m].
    """

    vehicle: VehicleParams | None = None
    manoeuvre: Manoeuvre | None = None
    effects: dict[str, list[dict[str, Any]]] = field(default_factory=dict)
    road_class: str | None = None
    seed: int | None = None
    body_dofs_m: np.ndarray | None = None
    wheel_disp_m: np.ndarray | None = None
    suspension_extension_m: np.ndarray | None = None
    corner_force_n: np.ndarray | None = None
    road_m: np.ndarray | None = None

    def simulation_metadata(self) -> dict[str, Any]:
        """What was simulated (JSON-ready): car, effects, manoeuvre, road, seed."""
        return {
            "vehicle_params": None if self.vehicle is None else self.vehicle.to_dict(),
            "effects": self.effects,
            "manoeuvre": None if self.manoeuvre is None else self.manoeuvre.name,
            "road_class": self.road_class,
            "seed": self.seed,
        }


def body_mass_matrix(vehicle: VehicleParams, added_mass_kg: float = 0.0,
                     added_mass_at_m: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    """Mass matrix of the body for (heave, pitch, roll) at the origin, added mass included.

    ``[[M, Sx, Sy], [Sx, Jp, Jpr], [Sy, Jpr, Jr]]`` with ``Sx = M x_cg``, ``Jp = I_pitch +
    M x_cg^2``, ``Jr = I_roll + M y_cg^2``, ``Jpr = M x_cg y_cg`` plus the point mass's
    ``dM [1, x, y]`` terms.

    Returns
    -------
    numpy.ndarray, shape (3, 3)
    """
    m, xc, yc = vehicle.sprung_mass_kg, vehicle.cog_behind_front_axle_m, \
        vehicle.cog_left_of_centre_m
    xa, ya = added_mass_at_m
    dm = added_mass_kg
    return np.array([
        [m + dm, m * xc + dm * xa, m * yc + dm * ya],
        [m * xc + dm * xa, vehicle.pitch_inertia_kgm2 + m * xc**2 + dm * xa**2,
         m * xc * yc + dm * xa * ya],
        [m * yc + dm * ya, m * xc * yc + dm * xa * ya,
         vehicle.roll_inertia_kgm2 + m * yc**2 + dm * ya**2],
    ])


def _tracks(road_class: str | None, length_m: float, correlation: float,
            rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    if road_class is None:
        n = int(np.ceil(length_m / _ROAD_SPACING_M)) + 4
        return np.zeros(n), np.zeros(n)
    s1, s2 = rng.integers(0, 2**63 - 1, size=2)
    _, h1 = iso8608_profile(road_class, length_m, _ROAD_SPACING_M, seed=int(s1))
    _, h2 = iso8608_profile(road_class, length_m, _ROAD_SPACING_M, seed=int(s2))
    return h1, correlation * h1 + np.sqrt(1.0 - correlation**2) * h2


def _static_state(union: ForceModel, vehicle: VehicleParams, geo: np.ndarray, karb: np.ndarray,
                  theta: np.ndarray, consts: np.ndarray, ext: np.ndarray, u0: np.ndarray,
                  along: float, alat: float) -> np.ndarray:
    """Static equilibrium of the loaded car (7 positions, then 7 zero rates) by Newton."""
    kt = np.array([vehicle.corner(c).tire_stiffness_n_per_m for c in CORNERS])
    ks = np.array([vehicle.corner(c).stiffness_n_per_m for c in CORNERS])

    def resid(x: np.ndarray) -> np.ndarray:
        s = np.concatenate([x, np.zeros(7)])
        f = static_forces(union, s, geo, karb, theta, consts)
        body = np.array([f.sum() + ext[1], geo[0] @ f + ext[2] - ext[0] * along,
                         geo[1] @ f + ext[3] + ext[0] * alat])
        wheels = kt * (u0 - x[3:]) - f
        return np.concatenate([body / (ks.sum()), wheels / kt])

    x = np.concatenate([np.full(1, u0.mean()), np.zeros(2), u0])
    r = resid(x)
    for _ in range(60):  # Newton with a finite-difference Jacobian (piecewise-smooth forces)
        if np.max(np.abs(r)) < 1e-12:
            break
        h = 1e-7
        jac = np.column_stack([(resid(x + h * e) - r) / h for e in np.eye(7)])
        step = np.linalg.lstsq(jac, -r, rcond=None)[0]
        lam = 1.0
        while lam > 1e-4:
            r_new = resid(x + lam * step)
            if np.max(np.abs(r_new)) < np.max(np.abs(r)):
                break
            lam *= 0.5
        x, r = x + lam * step, r_new
    if not np.max(np.abs(r)) < 1e-9:
        raise FieldDiagError(
            "no static equilibrium of the full vehicle: the springs cannot carry the load; "
            "reduce the added mass or check the stiffness parameters.")
    return np.concatenate([x, np.zeros(7)])


def simulate_vehicle(
    vehicle: VehicleParams | None = None,
    *,
    manoeuvre: str | Manoeuvre = "rough_road",
    duration_s: float = 60.0,
    sample_rate_hz: float = 500.0,
    effects: Mapping[str, Sequence[Effect] | ForceModel] | None = None,
    added_mass_kg: float = 0.0,
    added_mass_at_m: tuple[float, float] | None = None,
    road_class: str | None = "C",
    track_correlation: float = 0.3,
    sensor: SensorModel | None = None,
    accel_noise_std_mps2: float = 0.02,
    vehicle_accel_noise_std_mps2: float = 0.05,
    seed: int | None = None,
) -> VehicleDrive:
    """Simulate a full-vehicle drive and read it with eight accelerometers.

    Parameters
    ----------
    vehicle : VehicleParams or None
        The car (default :class:`VehicleParams()`).
    manoeuvre : str or Manoeuvre
        ``rough_road``, ``ramp_steer``, ``braking`` (made for ``duration_s`` from
        ``seed``), or a :class:`~fielddiag.vehicle.manoeuvres.Manoeuvre`.
    duration_s : float
        Length [s].
    sample_rate_hz : float
        Output rate, 200-1000 Hz.
    effects : mapping corner -> sequence of Effect or ForceModel, or None
        Effects (with values) at each corner, added to its linear spring and damper
        (see :func:`~fielddiag.vehicle.dynamics.corner_models`). Effects with internal
        states are refused.
    added_mass_kg : float
        Known mass added on the body (>= 0) [kg].
    added_mass_at_m : (x_m, y_m) or None
        Where it sits; default: above the centre of gravity.
    road_class : str or None
        ISO 8608 class of both tracks; None for a flat road.
    track_correlation : float
        Correlation of the right track with the left one, in [0, 1] (0: independent).
    sensor : SensorModel or None
        The accelerometer chain of all eight channels (its output rate is set to
        ``sample_rate_hz``); default: white noise of ``accel_noise_std_mps2``.
    accel_noise_std_mps2 : float
        Noise of the default sensor [m/s^2].
    vehicle_accel_noise_std_mps2 : float
        Noise of the car's longitudinal and lateral acceleration signals [m/s^2].
    seed : int or None
        Seeds the road, the manoeuvre and the noise.

    Returns
    -------
    VehicleDrive

    Raises
    ------
    FieldDiagError
        A value out of range, an unknown manoeuvre, an effect with internal states, no
        static equilibrium.
    """
    vehicle = vehicle or VehicleParams()
    check_number("simulate_vehicle", "duration_s", duration_s, low=0.0, strict=True)
    check_number("simulate_vehicle", "sample_rate_hz", sample_rate_hz, low=0.0, strict=True)
    if not 200.0 <= sample_rate_hz <= 1000.0:
        raise FieldDiagError(f"simulate_vehicle: sample_rate_hz={sample_rate_hz:g}; give "
                             "200-1000 Hz")
    check_number("simulate_vehicle", "added_mass_kg", added_mass_kg, low=0.0)
    check_number("simulate_vehicle", "track_correlation", track_correlation, low=0.0)
    if track_correlation > 1.0:
        raise FieldDiagError("simulate_vehicle: track_correlation must be in [0, 1]")
    at = (vehicle.cog_behind_front_axle_m, vehicle.cog_left_of_centre_m) \
        if added_mass_at_m is None else (float(added_mass_at_m[0]), float(added_mass_at_m[1]))
    for i, v in enumerate(at):
        check_number("simulate_vehicle", f"added_mass_at_m[{i}]", v)
    ss = np.random.SeedSequence(seed)
    rng_road, rng_man, rng_noise = (np.random.default_rng(s) for s in ss.spawn(3))
    if isinstance(manoeuvre, str):
        manoeuvre = make_manoeuvre(manoeuvre, duration_s, rng_man)
    elif not isinstance(manoeuvre, Manoeuvre):
        raise FieldDiagError("manoeuvre must be a name or a Manoeuvre")

    models = corner_models(vehicle, effects)
    union, theta, consts = union_layout(models)
    k = internal_rate_factor(vehicle, models, sample_rate_hz)
    fs_int = k * sample_rate_hz
    n_out = int(round(duration_s * sample_rate_hz))
    n_int = n_out * k
    dt = 1.0 / fs_int

    g = vehicle.geometry
    wb = g.wheelbase_m
    sp = manoeuvre.speed
    length = float(sp.distance_m(duration_s)) + wb + 2 * _ROAD_MARGIN_M
    road_l, road_r = _tracks(road_class, length, track_correlation, rng_road)
    geo = np.zeros((3, 4))
    geo[0], geo[1] = g.corner_x_m, g.corner_y_m
    geo[2, 0], geo[2, 1] = wb + _ROAD_MARGIN_M, _ROAD_MARGIN_M
    knots = np.array([sp.knot_time_s, sp.knot_speed_mps, sp.knot_distance_m,
                      sp.knot_accel_mps2])
    lat_t, lat_a = manoeuvre.lateral_knots()
    mq = body_mass_matrix(vehicle, added_mass_kg, at)
    minv = np.linalg.inv(mq)
    wheel = np.array([[vehicle.corner(c).wheel_mass_kg for c in CORNERS],
                      [vehicle.corner(c).tire_stiffness_n_per_m for c in CORNERS],
                      [vehicle.corner(c).tire_damping_ns_per_m for c in CORNERS]])
    karb = np.array([vehicle.anti_roll_stiffness_front_n_per_m,
                     vehicle.anti_roll_stiffness_rear_n_per_m])
    wg = added_mass_kg * G_MPS2
    ext = np.array([vehicle.sprung_mass_kg * vehicle.cog_height_m, -wg, -wg * at[0],
                    -wg * at[1]])
    inv_dx = 1.0 / _ROAD_SPACING_M
    u0 = np.array([np.interp(p, np.arange(road_l.size) * _ROAD_SPACING_M, r)
                   for p, r in ((geo[2, 0], road_l), (geo[2, 0], road_r),
                                (geo[2, 1], road_l), (geo[2, 1], road_r))])
    s0 = _static_state(union, vehicle, geo, karb, theta, consts, ext, u0,
                       float(manoeuvre.accel_long_mps2(0.0)), float(manoeuvre.accel_lat_mps2(0.0)))
    acc_b, acc_w, out = integrate_vehicle(union, s0, n_int, dt, k, geo, minv, wheel, karb, ext,
                                          theta, consts, knots, lat_t, lat_a, road_l, road_r,
                                          inv_dx)
    out = out[:, :n_out]

    sensor = sensor or SensorModel(output_rate_hz=sample_rate_hz,
                                   noise_std_mps2=accel_noise_std_mps2)
    if sensor.output_rate_hz != sample_rate_hz:
        sensor = replace(sensor, output_rate_hz=sample_rate_hz)
    sens_pts = g.sensor_matrix()  # (4, 3)
    body_true = sens_pts @ acc_b  # (4, n_int)
    wheel_read = np.array([_read_sensor(acc_w[i], fs_int, k, n_out, sensor, acc_w[i, ::k][:n_out],
                                        rng_noise) for i in range(4)])
    body_read = np.array([_read_sensor(body_true[i], fs_int, k, n_out, sensor,
                                       body_true[i, ::k][:n_out], rng_noise) for i in range(4)])
    t = np.arange(n_out) / sample_rate_hz
    noise = vehicle_accel_noise_std_mps2
    along = out[22] + (rng_noise.normal(0.0, noise, n_out) if noise > 0 else 0.0)
    alat = out[23] + (rng_noise.normal(0.0, noise, n_out) if noise > 0 else 0.0)
    dofs = out[0:3]
    zb = g.corner_matrix() @ dofs
    return VehicleDrive(
        wheel_accel_mps2=wheel_read, body_accel_mps2=body_read, sample_rate_hz=sample_rate_hz,
        geometry=g, speed_mps=sp.speed_mps(t), accel_long_mps2=along, accel_lat_mps2=alat,
        added_mass_kg=float(added_mass_kg), added_mass_at_m=at, label="", name="",
        vehicle=vehicle, manoeuvre=manoeuvre,
        effects={c: [t.to_dict() for t in models[c].terms if not t.linear] for c in CORNERS},
        road_class=road_class, seed=seed, body_dofs_m=dofs, wheel_disp_m=out[3:7],
        suspension_extension_m=zb - out[3:7], corner_force_n=out[14:18], road_m=out[18:22])
