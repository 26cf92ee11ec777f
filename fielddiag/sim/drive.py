"""Simulated drives: :func:`simulate`, :func:`simulate_pair` and their result."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from fielddiag.errors import FieldDiagError
from fielddiag.sim._common import check_number
from fielddiag.sim.dynamics import (
    _phys_array,
    integrate,
    internal_rate_factor,
    static_state,
    suspension_model,
)
from fielddiag.sim.effects import Effect, effects_from_dicts
from fielddiag.sim.road import (
    RoadEvent,
    SpeedProfile,
    iso8608_profile,
    road_event_from_dict,
)
from fielddiag.sim.sensors import DEFAULT_SENSOR, SensorModel, _read_sensor
from fielddiag.sim.vehicle import DEFAULT_PARAMS, QuarterCarParams


@dataclass(frozen=True)
class InitialOffset:
    """Deviation of the initial state from the loaded static equilibrium (free responses)."""

    wheel_disp_m: float = 0.0
    wheel_vel_mps: float = 0.0
    body_disp_m: float = 0.0
    body_vel_mps: float = 0.0


@dataclass(frozen=True)
class EventPassage:
    """A road event and the time the wheel passes its centre (None: not reached)."""

    event: RoadEvent
    time_s: float | None

    def to_dict(self) -> dict[str, Any]:
        """Event fields plus ``time_s``."""
        return {**self.event.to_dict(), "time_s": self.time_s}


@dataclass(eq=False)
class SimulatedDrive:
    """A simulated drive: sensor readings, CAN speed, and the truth at the output rate.

    Displacements are from the static equilibrium of the car without added mass (so the
    suspension extension is ``body_disp_m - wheel_disp_m``); accelerometer readings include
    g and the sensor model; ``*_true_*`` arrays do not include g. ``suspension_force_n`` is
    the force of the springs, dampers and effects, without the static force of a levelling
    system (``ride_height_restored``).
    """

    sample_rate_hz: float
    time_s: np.ndarray
    wheel_accel_mps2: np.ndarray
    body_accel_mps2: np.ndarray
    vehicle_speed_time_s: np.ndarray
    vehicle_speed_mps: np.ndarray
    wheel_disp_m: np.ndarray
    body_disp_m: np.ndarray
    wheel_vel_mps: np.ndarray
    body_vel_mps: np.ndarray
    wheel_acc_true_mps2: np.ndarray
    body_acc_true_mps2: np.ndarray
    road_m: np.ndarray
    suspension_force_n: np.ndarray
    hysteretic_state_m: np.ndarray
    params: QuarterCarParams
    effects: tuple[Effect, ...]
    added_mass_kg: float
    seed: int
    road_class: str | None
    road_waviness: float
    events: tuple[EventPassage, ...]
    speed: SpeedProfile
    wheel_sensor: SensorModel
    body_sensor: SensorModel
    internal_rate_hz: float
    duration_s: float
    can_speed_rate_hz: float
    road_spacing_m: float = 0.02
    initial_offset: InitialOffset | None = None
    ride_height_restored: bool = False

    @property
    def metadata(self) -> dict[str, Any]:
        """Same as :meth:`to_dict`."""
        return self.to_dict()

    @property
    def suspension_extension_m(self) -> np.ndarray:
        """r = body - wheel displacement [m]."""
        return self.body_disp_m - self.wheel_disp_m

    def to_dict(self) -> dict[str, Any]:
        """How the drive was made (no arrays), JSON-serialisable; see :func:`simulate_from_dict`."""
        from fielddiag import __version__

        return {
            "generator": "fielddiag.sim.simulate",
            "fielddiag_version": __version__,
            "method": (
                f"2-DOF quarter car, fixed-step RK4 at {self.internal_rate_hz:g} Hz from the "
                "loaded static equilibrium; ISO 8608 road (random phases, Catmull-Rom "
                "between samples); accelerometers through a Butterworth-4 anti-alias filter, "
                f"decimated to {self.sample_rate_hz:g} Hz"
            ),
            "params": self.params.to_dict(),
            "duration_s": self.duration_s,
            "road_class": self.road_class,
            "road_waviness": self.road_waviness,
            "road_spacing_m": self.road_spacing_m,
            "speed": self.speed.to_dict(),
            "road_events": [e.to_dict() for e in self.events],
            "effects": [e.to_dict() for e in self.effects],
            "added_mass_kg": self.added_mass_kg,
            "ride_height_restored": self.ride_height_restored,
            "wheel_sensor": self.wheel_sensor.to_dict(),
            "body_sensor": self.body_sensor.to_dict(),
            "seed": self.seed,
            "can_speed_rate_hz": self.can_speed_rate_hz,
            "sample_rate_hz": self.sample_rate_hz,
            "internal_rate_hz": self.internal_rate_hz,
            "initial_offset": None if self.initial_offset is None else asdict(self.initial_offset),
        }


def simulate_from_dict(meta: dict[str, Any]) -> SimulatedDrive:
    """Re-run the drive described by ``SimulatedDrive.to_dict()`` (bit-identical)."""
    try:
        events = []
        for e in meta.get("road_events", []):
            events.append(road_event_from_dict(e))
        off = meta.get("initial_offset")
        return simulate(
            QuarterCarParams(**meta["params"]),
            duration_s=meta["duration_s"],
            road_class=meta["road_class"],
            road_waviness=meta.get("road_waviness", 2.0),
            road_spacing_m=meta.get("road_spacing_m", 0.02),
            speed=SpeedProfile.from_dict(meta["speed"]),
            road_events=tuple(events),
            effects=effects_from_dicts(meta.get("effects", [])),
            added_mass_kg=meta.get("added_mass_kg", 0.0),
            ride_height_restored=bool(meta.get("ride_height_restored", False)),
            wheel_sensor=SensorModel(**meta["wheel_sensor"]),
            body_sensor=SensorModel(**meta["body_sensor"]),
            seed=meta["seed"],
            can_speed_rate_hz=meta.get("can_speed_rate_hz", 50.0),
            initial_offset=None if off is None else InitialOffset(**off),
        )
    except (KeyError, TypeError) as exc:
        raise FieldDiagError(
            f"simulation metadata is incomplete or malformed ({exc}); "
            "pass a dict made by SimulatedDrive.to_dict()."
        ) from None


def _make_road(
    road_class: str | None,
    length_m: float,
    spacing_m: float,
    waviness: float,
    rng: np.random.Generator,
    events: Sequence[RoadEvent],
) -> np.ndarray:
    if road_class is None:
        n = int(math.ceil(length_m / spacing_m)) + 2
        dist, h = np.arange(n) * spacing_m, np.zeros(n)
    else:
        dist, h = iso8608_profile(road_class, length_m, spacing_m, rng, waviness)
        h = h - h[0]
    for ev in events:
        h = h + ev.height_profile_m(dist)
    return h


def simulate(
    params: QuarterCarParams = DEFAULT_PARAMS,
    *,
    duration_s: float = 120.0,
    road_class: str | None = "C",
    speed: SpeedProfile | None = None,
    road_events: Sequence[RoadEvent] = (),
    effects: Sequence[Effect] = (),
    added_mass_kg: float = 0.0,
    ride_height_restored: bool = False,
    sensor: SensorModel = DEFAULT_SENSOR,
    wheel_sensor: SensorModel | None = None,
    body_sensor: SensorModel | None = None,
    seed: int | None = None,
    can_speed_rate_hz: float = 50.0,
    road_waviness: float = 2.0,
    road_spacing_m: float = 0.02,
    initial_offset: InitialOffset | None = None,
) -> SimulatedDrive:
    """Simulate a drive of one corner over a random road and read it with two accelerometers.

    Parameters
    ----------
    params : QuarterCarParams
        The car (linear part).
    duration_s : float
        Length of the drive [s].
    road_class : str or None
        ISO 8608 class 'A'..'H'; None for a flat road.
    speed : SpeedProfile or None
        Vehicle speed; default ``SpeedProfile.random_drive(duration_s, seed)``.
    road_events : sequence of RoadEvent
        Discrete events added to the profile (positions in m from the start).
    effects : sequence of Effect
        Nonlinear suspension effects (at most one of each kind).
    added_mass_kg : float
        Mass added on the body; the drive starts from the loaded static equilibrium.
    ride_height_restored : bool
        False (passive car): the suspension sags under the added mass, so the loaded drive
        moves about a deflection ``dM g / K`` further into compression (nearer a bump
        stop). True (self-levelling suspension, or the ride height re-set after loading):
        a levelling system between wheel and body carries the added weight
        (:func:`~fielddiag.sim.dynamics.levelling_force_n`), so the suspension moves about
        the same static deflection as without the mass, while the body mass is still
        ``M2 + dM`` (the tyre still deflects under the extra weight; the accelerometers
        still read 1 g at rest).
    sensor, wheel_sensor, body_sensor : SensorModel
        ``sensor`` is used for any channel not given its own. Output rates must agree.
    seed : int or None
        Seeds the road, the random drive and the noise; None draws one (stored in the result).
    can_speed_rate_hz : float
        Rate of the CAN speed signal (quantised to 0.01 km/h).
    road_waviness : float
        ISO 8608 exponent w.
    road_spacing_m : float
        Road sample spacing; between samples the height is a Catmull-Rom cubic (C1).
    initial_offset : InitialOffset or None
        Deviation from the static equilibrium at t = 0 (free-response studies).

    Returns
    -------
    SimulatedDrive
    """
    if not isinstance(params, QuarterCarParams):
        raise FieldDiagError(f"params must be a QuarterCarParams, got {params!r}.")
    wheel_sensor = sensor if wheel_sensor is None else wheel_sensor
    body_sensor = sensor if body_sensor is None else body_sensor
    rate_hz = wheel_sensor.output_rate_hz
    if body_sensor.output_rate_hz != rate_hz:
        raise FieldDiagError(
            "wheel and body sensors must share output_rate_hz "
            f"({rate_hz:g} != {body_sensor.output_rate_hz:g} Hz)."
        )
    check_number("simulate", "duration_s", duration_s, low=0.0, strict=True)
    check_number("simulate", "added_mass_kg", added_mass_kg, low=-params.body_mass_kg, strict=True)
    check_number("simulate", "can_speed_rate_hz", can_speed_rate_hz, low=0.0, strict=True)
    check_number("simulate", "road_spacing_m", road_spacing_m, low=0.0, strict=True)
    if duration_s * rate_hz < 2:
        raise FieldDiagError(
            f"duration_s={duration_s:g} is shorter than two samples at "
            f"{rate_hz:g} Hz; simulate a longer drive."
        )
    if seed is not None and (not isinstance(seed, int | np.integer) or seed < 0):
        raise FieldDiagError(f"seed={seed!r} must be a non-negative integer or None.")
    if speed is not None and not isinstance(speed, SpeedProfile):
        raise FieldDiagError(f"speed must be a SpeedProfile or None, got {speed!r}.")
    effects = tuple(effects)
    model, theta = suspension_model(params, effects)
    if seed is None:
        seed = int(np.random.SeedSequence().generate_state(1)[0])
    road_ss, speed_ss, wheel_ss, body_ss = np.random.SeedSequence(seed).spawn(4)
    if speed is None:
        speed = SpeedProfile.random_drive(duration_s, np.random.default_rng(speed_ss))
    events = tuple(road_events)
    for ev in events:
        if not isinstance(ev, RoadEvent):
            raise FieldDiagError(f"road_events must be SpeedBump or Pothole, got {ev!r}.")

    k = internal_rate_factor(rate_hz, params, effects, added_mass_kg)
    internal_hz = k * rate_hz
    n_out = int(round(duration_s * rate_hz))
    n_int = n_out * k
    dt = 1.0 / internal_hz
    length_m = float(speed.distance_m(n_int * dt)) + 10.0
    road_h = _make_road(
        road_class, length_m, road_spacing_m, road_waviness, np.random.default_rng(road_ss), events
    )

    restored = bool(ride_height_restored)
    phys = _phys_array(params, added_mass_kg, restored)
    state0 = static_state(params, effects, added_mass_kg, float(road_h[0]), restored)
    if initial_offset is not None:
        o = initial_offset
        state0[:4] += [o.wheel_disp_m, o.wheel_vel_mps, o.body_disp_m, o.body_vel_mps]
    v_k = np.ascontiguousarray(speed.knot_speed_mps)
    acc1, acc2, out = integrate(
        model,
        np.ascontiguousarray(state0[:4]),
        np.ascontiguousarray(state0[4 : 4 + model.n_states]),
        n_int,
        dt,
        k,
        phys,
        theta,
        model.constant_values(),
        np.ascontiguousarray(speed.knot_time_s),
        v_k,
        np.ascontiguousarray(speed.knot_distance_m),
        np.ascontiguousarray(speed.knot_accel_mps2),
        road_h,
        1.0 / road_spacing_m,
    )

    a1_out, a2_out = acc1[::k].copy(), acc2[::k].copy()
    wheel = _read_sensor(
        acc1, internal_hz, k, n_out, wheel_sensor, a1_out, np.random.default_rng(wheel_ss)
    )
    body = _read_sensor(
        acc2, internal_hz, k, n_out, body_sensor, a2_out, np.random.default_rng(body_ss)
    )
    del acc1, acc2

    can_t = np.arange(int(round(duration_s * can_speed_rate_hz))) / can_speed_rate_hz
    can_v = np.round(speed.speed_mps(can_t) * 3.6 / 0.01) * 0.01 / 3.6
    passages = tuple(
        EventPassage(ev, _passage_time(speed, ev.position_m, duration_s)) for ev in events
    )
    return SimulatedDrive(
        sample_rate_hz=float(rate_hz),
        time_s=np.arange(n_out) / rate_hz,
        wheel_accel_mps2=wheel,
        body_accel_mps2=body,
        vehicle_speed_time_s=can_t,
        vehicle_speed_mps=can_v,
        wheel_disp_m=out[0],
        body_disp_m=out[2],
        wheel_vel_mps=out[1],
        body_vel_mps=out[3],
        wheel_acc_true_mps2=a1_out,
        body_acc_true_mps2=a2_out,
        road_m=out[4],
        suspension_force_n=out[5],
        hysteretic_state_m=out[6],
        params=params,
        effects=effects,
        added_mass_kg=float(added_mass_kg),
        seed=int(seed),
        road_class=None if road_class is None else str(road_class).upper(),
        road_waviness=float(road_waviness),
        events=passages,
        speed=speed,
        wheel_sensor=wheel_sensor,
        body_sensor=body_sensor,
        internal_rate_hz=float(internal_hz),
        duration_s=float(duration_s),
        can_speed_rate_hz=float(can_speed_rate_hz),
        road_spacing_m=float(road_spacing_m),
        initial_offset=initial_offset,
        ride_height_restored=restored,
    )


def _passage_time(speed: SpeedProfile, position_m: float, duration_s: float) -> float | None:
    t = speed.time_at_distance_s(position_m)
    return None if t is None or t > duration_s else t


def simulate_pair(
    params: QuarterCarParams = DEFAULT_PARAMS,
    *,
    added_mass_kg: float,
    seed: int | None = None,
    **kw: Any,
) -> tuple[SimulatedDrive, SimulatedDrive]:
    """Two drives of the same car over different road realisations, the second with added mass.

    The two drive seeds are derived from ``seed``; ``kw`` goes to :func:`simulate`
    (``ride_height_restored=True`` for a self-levelling car: it acts on the second drive).

    Returns
    -------
    (before, after) : tuple of SimulatedDrive
    """
    s_before, s_after = (int(s) for s in np.random.SeedSequence(seed).generate_state(2))
    if s_after == s_before:  # pragma: no cover - 1 in 2**32
        s_after += 1
    before = simulate(params, added_mass_kg=0.0, seed=s_before, **kw)
    after = simulate(params, added_mass_kg=added_mass_kg, seed=s_after, **kw)
    return before, after
