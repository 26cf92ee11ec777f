"""Random validation cases: a before/after pair drawn from a seed, with its truth.

A case is drawn whole from one integer seed (:func:`draw_case`), so a benchmark run is
defined by (first seed, number of cases) and nothing can be tuned on a fixed set: every
run with a fresh seed is a new set. What is drawn (see :data:`METHOD`):

* the car: sprung mass, body frequency, damping ratio, wheel mass, wheel-hop frequency
  (tyre stiffness), tyre damping, sometimes a coupling to the rest of the body;
* the drive: ISO 8608 road class, speed range, speed bumps, sample rate, duration, SNR,
  the added mass (a fraction of the sprung mass) and whether the car levels itself
  (``ride_height_restored``: the ride height is restored after the mass is added);
* the physics: linear, one effect or a pair, drawn from the effect library's registry
  (:data:`fielddiag.effects.EFFECTS`, so a family added later is drawn too), each at a
  strength ``s`` drawn log-uniform over two decades around the noise floor and turned
  into parameters relative to the car by :data:`STRENGTH_RECIPES` (a generic recipe for
  families without one);
* nuisances, each with its own probability: a sensor gain change between the drives on
  one channel, a body/wheel time offset, a bias drift, clipping.

:func:`simulate_case` turns a case into the two :class:`fielddiag.sim.SimulatedDrive`
(deterministic in the seed), :func:`case_drives` into the diagnosis's ``Drive`` objects and
:func:`write_case` into two HDF5 sessions plus a truth JSON.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from fielddiag import sim
from fielddiag.effects import EFFECTS
from fielddiag.units import GRAVITY_MPS2

# ----------------------------------------------------------------------------- ranges
SPRUNG_MASS_KG = (250.0, 600.0)
BODY_FREQ_HZ = (1.0, 1.8)
DAMPING_RATIO = (0.2, 0.45)
SPRUNG_TO_WHEEL_MASS = (6.0, 12.0)
WHEEL_HOP_HZ = (10.0, 15.0)
TYRE_DAMPING_NS_PER_M = (50.0, 300.0)
COUPLING_PROBABILITY = 0.2
COUPLING_FRACTION_OF_K2 = (-0.1, 0.15)
ROAD_CLASSES = ("B", "C", "D")
SAMPLE_RATE_HZ = (200, 1000)
ADDED_MASS_FRACTION = (0.05, 0.15)
DURATION_S = (90.0, 300.0)
SNR_DB = (25.0, 45.0)
MIN_SPEED_MPS = (4.0, 12.0)
SPEED_SPAN_MPS = (5.0, 18.0)
MAX_SPEED_MPS = 33.0
BUMPS_PROBABILITY = 0.5
BUMPS = (2, 8)
SENSOR_BIAS_MPS2 = 0.05
#: Probability of a linear car, one effect, two effects.
PHYSICS_PROBABILITY = {"linear": 0.25, "single": 0.55, "pair": 0.20}
#: Effect strength ``s``: log-uniform; s = 1 is an effect about at the noise floor.
STRENGTH = (0.1, 10.0)
SELF_LEVELLING_PROBABILITY = 0.25
#: Nuisances: probability of each (independently) and the range of its size.
NUISANCE_PROBABILITY = {"gain_change": 0.2, "time_offset": 0.2, "bias_drift": 0.15,
                        "clipping": 0.15}
GAIN_CHANGE = (0.005, 0.05)  # relative, either sign, one channel of the 'after' drive
TIME_OFFSET_S = (0.5e-3, 3e-3)  # one channel late, both drives (DAQ skew)
BIAS_DRIFT_MPS2_PER_S = (3e-4, 5e-3)  # log-uniform, either sign, one channel of one drive
CLIP_FRACTION = (5e-4, 2e-2)  # log-uniform share of the samples beyond full scale
CLIP_ON_WHEEL_PROBABILITY = 0.8

CHANNELS = ("wheel", "body")


# ----------------------------------------------------------------------------- the case
@dataclass(frozen=True)
class Case:
    """One random before/after pair and its truth (JSON-serialisable, :meth:`to_dict`).

    Parameters
    ----------
    seed : int
        The seed it was drawn from (also seeds the roads and the sensor noise).
    params : dict
        :class:`fielddiag.sim.QuarterCarParams` fields.
    body_freq_hz, damping_ratio : float
        What the linear car was drawn from (for people; ``params`` is the truth).
    road_class : str
    speed_range_mps : (float, float)
    bumps : int
        Speed bumps along each drive.
    rate_hz, duration_s, snr_db, added_mass_kg : float
    ride_height_restored : bool
        Self-levelling car (the suspension keeps its unloaded deflection after loading).
    effects : tuple of (name, params)
        Effects present in both drives (``fielddiag.sim.make_effect`` names).
    strengths : tuple of float
        The drawn strength ``s`` of each effect (1: about the noise floor).
    nuisances : tuple of dict
        Each ``{"kind", "channel", "session", "value"}``; kinds ``gain_change`` (value:
        relative gain error of the 'after' drive), ``time_offset`` (s the channel lags),
        ``bias_drift`` (m/s2 per s), ``clipping`` (share of the samples clipped; the full
        scale is set from the signals by :func:`simulate_case`).
    """

    seed: int
    params: dict[str, float]
    body_freq_hz: float
    damping_ratio: float
    road_class: str
    speed_range_mps: tuple[float, float]
    bumps: int
    rate_hz: float
    duration_s: float
    snr_db: float
    added_mass_kg: float
    ride_height_restored: bool
    effects: tuple[tuple[str, dict[str, float]], ...] = ()
    strengths: tuple[float, ...] = ()
    nuisances: tuple[dict[str, Any], ...] = ()
    sensor_bias_mps2: dict[str, float] = field(default_factory=dict)

    @property
    def car(self) -> sim.QuarterCarParams:
        return sim.QuarterCarParams(**self.params)

    @property
    def family(self) -> str:
        """``linear``, an effect name, or two names joined by `` + `` (sorted)."""
        return " + ".join(sorted(n for n, _ in self.effects)) or "linear"

    def nuisance(self, kind: str) -> dict[str, Any] | None:
        """The nuisance of that kind, or None."""
        return next((n for n in self.nuisances if n["kind"] == kind), None)

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-serialisable dict; :meth:`from_dict` inverts it."""
        d = asdict(self)
        d["speed_range_mps"] = list(self.speed_range_mps)
        d["effects"] = [{"effect": n, "parameters": dict(p)} for n, p in self.effects]
        d["strengths"] = list(self.strengths)
        d["nuisances"] = [dict(n) for n in self.nuisances]
        d["family"] = self.family
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Case:
        """Inverse of :meth:`to_dict`."""
        d = {k: v for k, v in d.items() if k != "family"}
        d["speed_range_mps"] = tuple(d["speed_range_mps"])
        d["effects"] = tuple((e["effect"], dict(e["parameters"])) for e in d["effects"])
        d["strengths"] = tuple(d["strengths"])
        d["nuisances"] = tuple(dict(n) for n in d["nuisances"])
        return cls(**d)

    def truth(self) -> dict[str, Any]:
        """What a correct diagnosis reports, in the units of its JSON."""
        car = self.car
        return {
            "seed": self.seed,
            "family": self.family,
            "sprung_mass_kg": car.body_mass_kg,
            "suspension_stiffness_n_per_m": car.suspension_stiffness_n_per_m,
            "suspension_damping_ns_per_m": car.suspension_damping_ns_per_m,
            "coupling_stiffness_n_per_m": car.coupling_stiffness_n_per_m,
            "added_mass_kg": self.added_mass_kg,
            "ride_height_restored": self.ride_height_restored,
            "effects": [{"effect": n, "parameters": dict(p)} for n, p in self.effects],
            "nuisances": [dict(n) for n in self.nuisances],
            "case": self.to_dict(),
        }


# ----------------------------------------------------------------------------- strength
#: ``recipe(s, car, rng) -> parameters`` of an effect at strength ``s`` on this car.
Recipe = Callable[[float, sim.QuarterCarParams, np.random.Generator], dict[str, float]]


def _sag_m(car: sim.QuarterCarParams, added_mass_kg: float) -> float:
    return added_mass_kg * GRAVITY_MPS2 / car.suspension_stiffness_n_per_m


def _friction(s, car, rng):
    return {"friction_force_n": s * 0.007 * car.body_mass_kg * GRAVITY_MPS2,
            "smoothing_velocity_mps": float(rng.uniform(0.005, 0.02))}


def _cubic(s, car, rng):
    return {"cubic_stiffness_n_per_m3": s * 0.075 * car.suspension_stiffness_n_per_m / 0.03**2}


def _asymmetric(s, car, rng):
    a = 0.8 * math.tanh(0.125 * s)  # s = 1: +-10 %; s = 10: rebound 5x compression
    c = car.suspension_damping_ns_per_m
    return {"compression_damping_ns_per_m": c * (1 - a), "rebound_damping_ns_per_m": c * (1 + a)}


def _quadratic(s, car, rng):
    return {"damping_ns2_per_m2": s * 600.0 * car.suspension_damping_ns_per_m / 1800.0}


def _hysteretic(s, car, rng):
    return {"hysteretic_stiffness_n_per_m": s * 0.1 * car.suspension_stiffness_n_per_m,
            "yield_displacement_m": float(rng.uniform(1e-3, 5e-3))}


def _bouc_wen(s, car, rng):
    return {"hysteretic_force_n": s * 0.007 * car.body_mass_kg * GRAVITY_MPS2,
            "yield_displacement_m": float(rng.uniform(5e-4, 3e-3)),
            "yield_exponent": float(rng.uniform(1.0, 3.0))}


def _digressive(s, car, rng):
    a = 0.8 * math.tanh(0.125 * s)  # s = 1: the slope drops 10 % above the knee
    c = car.suspension_damping_ns_per_m
    return {"compression_knee_mps": float(rng.uniform(0.05, 0.3)),
            "compression_drop_ns_per_m": a * c * float(rng.uniform(0.5, 1.0)),
            "rebound_knee_mps": float(rng.uniform(0.05, 0.3)),
            "rebound_drop_ns_per_m": a * c * float(rng.uniform(0.5, 1.0))}


def _top_mount(s, car, rng):
    # the mount's corner k_m / (2 pi C2) falls from ~60 body frequencies (s = 1) to ~6
    return {"suspension_damping_ns_per_m": car.suspension_damping_ns_per_m,
            "mount_stiffness_n_per_m": 60.0 / s * car.suspension_stiffness_n_per_m}


def _travel_damping(s, car, rng):
    # s = 1: damping 10 % higher at 30 mm from the ride height (it grows as travel^2)
    return {"extra_damping_ns_per_m": s * 0.1 * car.suspension_damping_ns_per_m,
            "reference_travel_m": 0.03}


def _generic(name: str) -> Recipe:
    """Force-scaled parameters at ``s`` x typical (scaled to the sprung mass), the others
    at their default or typical value: for a family without a recipe of its own."""

    def recipe(s, car, rng):
        out = {}
        for p in EFFECTS[name].params:
            if p.scales_with_force:
                out[p.name] = s * p.typical * car.body_mass_kg / 380.0
            else:
                out[p.name] = p.default if p.default is not None else p.typical
        return out

    return recipe


#: Per family: parameters at strength s. The bump stop's needs the added mass (its gap
#: is set beyond the loaded car's sag) and is made in :func:`_effect_params`.
STRENGTH_RECIPES: dict[str, Recipe] = {
    "coulomb_friction": _friction,
    "cubic_stiffness": _cubic,
    "asymmetric_damping": _asymmetric,
    "quadratic_damping": _quadratic,
    "hysteretic_spring": _hysteretic,
    "bouc_wen": _bouc_wen,
    "digressive_damping": _digressive,
    "series_top_mount": _top_mount,
    "travel_dependent_damping": _travel_damping,
}


def _effect_params(name: str, s: float, car: sim.QuarterCarParams, added_mass_kg: float,
                   levelled: bool, rng: np.random.Generator) -> dict[str, float]:
    if name == "bump_stop":
        # gap from the unloaded ride height: 8-40 mm beyond where the loaded car rests (the
        # passive car's sag; a self-levelling car rests at the unloaded ride height)
        sag = 0.0 if levelled else _sag_m(car, added_mass_kg)
        gap = sag + float(rng.uniform(0.008, 0.04))
        return {"gap_m": gap, "stiffness_n_per_m": s * car.suspension_stiffness_n_per_m}
    recipe = STRENGTH_RECIPES.get(name) or _generic(name)
    return {k: float(v) for k, v in recipe(s, car, rng).items()}


#: The registry's families when the tests' seeds were last pinned (session 43): tests draw
#: from this list, so that a family added to the library later re-draws none of their
#: cases (``draw_case`` draws from the registry by default, as the benchmarks should).
PINNED_FAMILIES = ("asymmetric_damping", "bouc_wen", "buildup_hysteresis", "bump_stop",
                   "coulomb_friction", "cubic_stiffness", "dahl_friction",
                   "digressive_damping", "hysteretic_spring", "quadratic_damping",
                   "series_top_mount", "travel_dependent_damping")


def effect_families() -> tuple[str, ...]:
    """Every effect of the library's registry (not the linear terms, nor a shape that
    names no physics), at call time."""
    return tuple(sorted(n for n, c in EFFECTS.items() if not c.linear and c.names_physics))


# ----------------------------------------------------------------------------- drawing
def _log_uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


def draw_case(seed: int, *, duration_s: float | None = None,
              families: tuple[str, ...] | None = None) -> Case:
    """Draw one case from ``seed`` (deterministic; see :data:`METHOD`).

    Parameters
    ----------
    seed : int
        Non-negative.
    duration_s : float or None
        Override the drawn duration (short cases for tests); everything else is drawn
        exactly as without it.
    families : tuple of str or None
        Draw the effects from these families only (a run that concentrates on new
        families); None: every family of the registry.

    Returns
    -------
    Case
    """
    car_ss, drive_ss, phys_ss, nuis_ss = np.random.SeedSequence(int(seed)).spawn(4)
    rc = np.random.default_rng(car_ss)
    m2 = float(rc.uniform(*SPRUNG_MASS_KG))
    f_b = float(rc.uniform(*BODY_FREQ_HZ))
    zeta = float(rc.uniform(*DAMPING_RATIO))
    k2 = m2 * (2 * math.pi * f_b) ** 2
    c2 = 2 * zeta * math.sqrt(k2 * m2)
    m1 = m2 / float(rc.uniform(*SPRUNG_TO_WHEEL_MASS))
    k1 = m1 * (2 * math.pi * float(rc.uniform(*WHEEL_HOP_HZ))) ** 2 - k2
    c1 = float(rc.uniform(*TYRE_DAMPING_NS_PER_M))
    k3 = k2 * float(rc.uniform(*COUPLING_FRACTION_OF_K2)) if rc.random() < COUPLING_PROBABILITY \
        else 0.0
    params = {"wheel_mass_kg": m1, "tire_stiffness_n_per_m": k1, "tire_damping_ns_per_m": c1,
              "body_mass_kg": m2, "suspension_stiffness_n_per_m": k2,
              "suspension_damping_ns_per_m": c2, "coupling_stiffness_n_per_m": k3}
    car = sim.QuarterCarParams(**params)

    rd = np.random.default_rng(drive_ss)
    road = str(rd.choice(ROAD_CLASSES))
    v_lo = float(rd.uniform(*MIN_SPEED_MPS))
    v_hi = min(MAX_SPEED_MPS, v_lo + float(rd.uniform(*SPEED_SPAN_MPS)))
    bumps = int(rd.integers(BUMPS[0], BUMPS[1] + 1)) if rd.random() < BUMPS_PROBABILITY else 0
    rate = float(rd.integers(SAMPLE_RATE_HZ[0], SAMPLE_RATE_HZ[1] + 1))
    dur = float(rd.uniform(*DURATION_S))
    snr = float(rd.uniform(*SNR_DB))
    dm = m2 * float(rd.uniform(*ADDED_MASS_FRACTION))
    levelled = bool(rd.random() < SELF_LEVELLING_PROBABILITY)
    bias = {ch: float(rd.uniform(-SENSOR_BIAS_MPS2, SENSOR_BIAS_MPS2)) for ch in CHANNELS}

    rp = np.random.default_rng(phys_ss)
    u = rp.random()
    n_eff = 0 if u < PHYSICS_PROBABILITY["linear"] else (
        1 if u < PHYSICS_PROBABILITY["linear"] + PHYSICS_PROBABILITY["single"] else 2)
    fams = effect_families() if families is None else tuple(sorted(families))
    n_eff = min(n_eff, len(fams))
    names = sorted(str(n) for n in rp.choice(fams, size=n_eff, replace=False))
    effects, strengths = [], []
    for name in names:
        s = _log_uniform(rp, *STRENGTH)
        effects.append((name, _effect_params(name, s, car, dm, levelled, rp)))
        strengths.append(s)

    rn = np.random.default_rng(nuis_ss)
    nuisances = []
    draws = {k: rn.random() < p for k, p in NUISANCE_PROBABILITY.items()}
    if draws["gain_change"]:
        g = float(rn.uniform(*GAIN_CHANGE)) * float(rn.choice([-1.0, 1.0]))
        nuisances.append({"kind": "gain_change", "channel": str(rn.choice(CHANNELS)),
                          "session": "after", "value": g})
    if draws["time_offset"]:
        nuisances.append({"kind": "time_offset", "channel": str(rn.choice(CHANNELS)),
                          "session": "both", "value": float(rn.uniform(*TIME_OFFSET_S))})
    if draws["bias_drift"]:
        b = _log_uniform(rn, *BIAS_DRIFT_MPS2_PER_S) * float(rn.choice([-1.0, 1.0]))
        nuisances.append({"kind": "bias_drift", "channel": str(rn.choice(CHANNELS)),
                          "session": str(rn.choice(["before", "after"])), "value": b})
    if draws["clipping"]:
        ch = "wheel" if rn.random() < CLIP_ON_WHEEL_PROBABILITY else "body"
        nuisances.append({"kind": "clipping", "channel": ch, "session": "both",
                          "value": _log_uniform(rn, *CLIP_FRACTION)})
    return Case(
        seed=int(seed), params=params, body_freq_hz=f_b, damping_ratio=zeta, road_class=road,
        speed_range_mps=(v_lo, v_hi), bumps=bumps, rate_hz=rate,
        duration_s=dur if duration_s is None else float(duration_s), snr_db=snr,
        added_mass_kg=dm, ride_height_restored=levelled, effects=tuple(effects),
        strengths=tuple(strengths), nuisances=tuple(nuisances), sensor_bias_mps2=bias,
    )


# ----------------------------------------------------------------------------- simulation
def _road_events(n: int, length_m: float, rng: np.random.Generator) -> list[sim.RoadEvent]:
    if n <= 0:
        return []
    positions = np.sort(rng.uniform(0.1, 0.9, n)) * length_m
    return [sim.SpeedBump(float(p), height_m=float(rng.uniform(0.04, 0.08)), length_m=0.5)
            for p in positions]


def _sensor(case: Case, channel: str, session: str) -> sim.SensorModel:
    kw: dict[str, Any] = {"output_rate_hz": case.rate_hz, "snr_db": case.snr_db,
                          "bias_mps2": case.sensor_bias_mps2.get(channel, 0.0)}
    for n in case.nuisances:
        if n["channel"] != channel or n["session"] not in (session, "both"):
            continue
        if n["kind"] == "gain_change":
            kw["gain"] = 1.0 + n["value"]
        elif n["kind"] == "time_offset":
            kw["time_offset_s"] = n["value"]
        elif n["kind"] == "bias_drift":
            kw["bias_drift_mps2_per_s"] = n["value"]
    return sim.SensorModel(**kw)


def simulate_case(case: Case) -> tuple[sim.SimulatedDrive, sim.SimulatedDrive]:
    """The before and after drives of a case (deterministic in ``case.seed``).

    Clipping is applied last, as by the sensor model: the full scale of the clipped
    channel is the level that the drawn share of both drives' samples exceed; the
    drives' sensor models then carry it (``clip_mps2``), so :func:`fielddiag.sim.
    simulate_from_dict` reproduces them.
    """
    car = case.car
    effects = [sim.make_effect(n, **p) for n, p in case.effects]
    seeds = np.random.SeedSequence([int(case.seed), 1]).generate_state(4)
    drives = []
    for k, (session, mass) in enumerate((("before", 0.0), ("after", case.added_mass_kg))):
        rng = np.random.default_rng(int(seeds[2 * k]))
        speed = sim.SpeedProfile.random_drive(
            case.duration_s, rng, min_speed_mps=case.speed_range_mps[0],
            max_speed_mps=case.speed_range_mps[1])
        length = float(speed.distance_m(case.duration_s))
        drives.append(sim.simulate(
            car, duration_s=case.duration_s, road_class=case.road_class, speed=speed,
            road_events=_road_events(case.bumps, length, rng), effects=effects,
            added_mass_kg=mass, ride_height_restored=case.ride_height_restored,
            wheel_sensor=_sensor(case, "wheel", session),
            body_sensor=_sensor(case, "body", session), seed=int(seeds[2 * k + 1])))
    clip = case.nuisance("clipping")
    if clip is not None:
        attr = f"{clip['channel']}_accel_mps2"
        both = np.abs(np.concatenate([getattr(d, attr) for d in drives]))
        level = float(np.quantile(both, 1.0 - clip["value"]))
        out = []
        for d in drives:
            sensor_attr = f"{clip['channel']}_sensor"
            clipped = replace(d, **{sensor_attr: replace(getattr(d, sensor_attr),
                                                         clip_mps2=level)})
            setattr(clipped, attr, np.clip(getattr(d, attr), -level, level))
            out.append(clipped)
        drives = out
    return drives[0], drives[1]


def case_drives(case: Case, drives: tuple[sim.SimulatedDrive, sim.SimulatedDrive] | None = None
                ) -> list[Any]:
    """The diagnosis's :class:`fielddiag.diagnose.engine.Drive` pair of a case."""
    from fielddiag.diagnose.engine import Drive

    before, after = simulate_case(case) if drives is None else drives
    name = f"random_{case.seed}"
    return [Drive(wheel_accel_mps2=d.wheel_accel_mps2, body_accel_mps2=d.body_accel_mps2,
                  sample_rate_hz=d.sample_rate_hz, added_mass_kg=d.added_mass_kg, label=label,
                  name=name, start_s=0.0)
            for label, d in (("before", before), ("after", after))]


def write_case(case: Case, folder: str | os.PathLike) -> tuple[Path, Path, Path]:
    """Write ``random_<seed>_before.h5``, ``..._after.h5`` and ``..._truth.json``.

    The sessions do not carry the recipe (a diagnosis run on them cannot peek); the truth
    sits in its own file.
    """
    from fielddiag.simio import drive_to_session

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    name = f"random_{case.seed}"
    paths = [drive_to_session(d, folder / f"{name}_{label}.h5", vehicle="random case",
                              notes=f"random case {case.seed} ({label})",
                              include_recipe=False, overwrite=True)
             for label, d in zip(("before", "after"), simulate_case(case), strict=True)]
    truth = folder / f"{name}_truth.json"
    truth.write_text(json.dumps(case.truth(), indent=2))
    return paths[0], paths[1], truth


METHOD = f"""\
Each case is drawn whole from its own seed (first seed + case index):
  car     sprung mass {SPRUNG_MASS_KG[0]:g}-{SPRUNG_MASS_KG[1]:g} kg, body frequency \
{BODY_FREQ_HZ[0]:g}-{BODY_FREQ_HZ[1]:g} Hz, damping ratio {DAMPING_RATIO[0]:g}-\
{DAMPING_RATIO[1]:g},
          wheel mass = sprung / {SPRUNG_TO_WHEEL_MASS[0]:g}-{SPRUNG_TO_WHEEL_MASS[1]:g}, \
wheel hop {WHEEL_HOP_HZ[0]:g}-{WHEEL_HOP_HZ[1]:g} Hz (tyre stiffness), tyre damping \
{TYRE_DAMPING_NS_PER_M[0]:g}-{TYRE_DAMPING_NS_PER_M[1]:g} N s/m,
          coupling K3 {COUPLING_FRACTION_OF_K2[0]:+g}..{COUPLING_FRACTION_OF_K2[1]:+g} x K2 \
with p = {COUPLING_PROBABILITY:g} (else 0)
  drive   ISO 8608 class {'/'.join(ROAD_CLASSES)}, speed from {MIN_SPEED_MPS[0]:g}-\
{MIN_SPEED_MPS[1]:g} m/s up by {SPEED_SPAN_MPS[0]:g}-{SPEED_SPAN_MPS[1]:g} m/s \
(<= {MAX_SPEED_MPS:g}), {BUMPS[0]}-{BUMPS[1]} speed bumps with p = {BUMPS_PROBABILITY:g},
          {SAMPLE_RATE_HZ[0]}-{SAMPLE_RATE_HZ[1]} Hz, {DURATION_S[0]:g}-{DURATION_S[1]:g} s \
per drive, SNR {SNR_DB[0]:g}-{SNR_DB[1]:g} dB, added mass {100 * ADDED_MASS_FRACTION[0]:g}-\
{100 * ADDED_MASS_FRACTION[1]:g} % of the sprung mass,
          self-levelling (ride height restored after loading) with p = \
{SELF_LEVELLING_PROBABILITY:g}
  physics linear / one effect / a pair with p = {PHYSICS_PROBABILITY['linear']:g} / \
{PHYSICS_PROBABILITY['single']:g} / {PHYSICS_PROBABILITY['pair']:g}, families from the \
effect registry
          ({', '.join(effect_families())}), strength s log-uniform {STRENGTH[0]:g}-\
{STRENGTH[1]:g}
          (friction s x 0.7 % of the sprung weight; cubic s x 0.075 K2 / (30 mm)^2;
          bump stop s x K2, its gap 8-40 mm beyond the loaded car's rest position;
          asymmetric damper C2 (1 -+ a), a = 0.8 tanh(s / 8); quadratic s x 600 N s2/m2 x
          C2 / 1800; Dahl hysteresis s x 0.1 K2; Bouc-Wen s x 0.7 % of the sprung weight,
          yield 0.5-3 mm, exponent 1-3; digressive damper knees 0.05-0.3 m/s, drops
          a x (0.5-1) x C2; top mount in series with C2, k_m = 60 K2 / s; damping growing
          with travel s x 0.1 C2 at 30 mm; a family without a recipe: s x typical values)
  nuisances, each independently: gain change {100 * GAIN_CHANGE[0]:g}-\
{100 * GAIN_CHANGE[1]:g} % on one channel of the 'after' drive (p = \
{NUISANCE_PROBABILITY['gain_change']:g}),
          one channel late by {1e3 * TIME_OFFSET_S[0]:g}-{1e3 * TIME_OFFSET_S[1]:g} ms in both \
drives (p = {NUISANCE_PROBABILITY['time_offset']:g}), bias drift {BIAS_DRIFT_MPS2_PER_S[0]:g}-\
{BIAS_DRIFT_MPS2_PER_S[1]:g} m/s2/s on one
          channel of one drive (p = {NUISANCE_PROBABILITY['bias_drift']:g}), clipping of \
{100 * CLIP_FRACTION[0]:g}-{100 * CLIP_FRACTION[1]:g} % of the samples (wheel channel with \
p = {CLIP_ON_WHEEL_PROBABILITY:g}; p = {NUISANCE_PROBABILITY['clipping']:g})"""
