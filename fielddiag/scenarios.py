"""Named test drives: before/after pairs with known (and often concealed) physics.

A scenario is a recipe for a pair of simulated drives of one car corner (before, and after
adding a mass to the body) plus what a correct diagnosis must say about it. The demo, the
tests, the benchmarks and ``sample_data/concealed/make_concealed.py`` all draw from here,
so every claim about the diagnosis is checked on the same, reproducible cases.

"Concealed" means the effect hides in a linear fit: the linear model alone tracks the body
acceleration well by eye (NRMSE under 0.25) and partly absorbs the effect (friction looks
like extra damping, a progressive spring like extra stiffness, a bump stop acts only in a
few events). "Small" cases go further: the effect lifts the linear model's held-out error
only 1.3-2x above the noise floor (the true model's held-out error on the same data).
"""

from __future__ import annotations

import json
import os
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from fielddiag import sim
from fielddiag.errors import FieldDiagError
from fielddiag.units import GRAVITY_MPS2


@dataclass(frozen=True)
class Scenario:
    """A before/after pair of simulated drives and the diagnosis it calls for.

    Parameters
    ----------
    name : str
        Unique, file-name safe.
    description : str
        One line for people.
    effects : tuple of (name, params)
        Suspension effects present in both drives (``fielddiag.sim.make_effect`` names).
    params : dict
        Overrides of :class:`fielddiag.sim.QuarterCarParams`.
    added_mass_kg : float
        Mass added on the body for the second drive.
    ride_height_restored : bool
        Self-levelling car: the ride height is restored after the mass is added (see
        :func:`fielddiag.sim.simulate`); False: passive sag.
    duration_s, rate_hz, road_class, snr_db : drive settings.
    speed_range_mps : (min, max) of the random speed profile.
    bumps : int
        Speed bumps along each drive (where a bump stop shows itself).
    wheel_sensor, body_sensor, after_body_sensor : dict
        Overrides of :class:`fielddiag.sim.SensorModel` (``after_body_sensor`` applies to the
        body sensor of the second drive only, e.g. a remounted sensor with another gain).
    expected_verdict : {"adequate", "missing_physics"}
    expected_effects : tuple of str
        Effects a correct diagnosis names (``unexplained`` for physics outside the library).
    expected_warnings : tuple of str
        Data-warning kinds a correct diagnosis raises.
    small : bool
        The effect lifts the linear model's held-out error only 1.3-2x above the noise
        floor (the held-out NRMSE of the true model on the same data; measured by
        benchmarks/bench_diagnose.py): it must still be named and sized, but the augmented
        model cannot be much better than the linear one.
    seed : int
    """

    name: str
    description: str
    effects: tuple[tuple[str, dict[str, float]], ...] = ()
    params: dict[str, float] = field(default_factory=dict)
    added_mass_kg: float = 60.0
    ride_height_restored: bool = False
    duration_s: float = 150.0
    rate_hz: float = 500.0
    road_class: str = "C"
    snr_db: float = 35.0
    speed_range_mps: tuple[float, float] = (6.0, 22.0)
    bumps: int = 0
    wheel_sensor: dict[str, Any] = field(default_factory=dict)
    body_sensor: dict[str, Any] = field(default_factory=dict)
    after_body_sensor: dict[str, Any] = field(default_factory=dict)
    expected_verdict: str = "adequate"
    expected_effects: tuple[str, ...] = ()
    expected_warnings: tuple[str, ...] = ()
    small: bool = False
    seed: int = 0

    @property
    def car(self) -> sim.QuarterCarParams:
        return sim.QuarterCarParams(**self.params)

    def truth(self) -> dict[str, Any]:
        """What a correct answer contains (JSON-serialisable)."""
        car = self.car
        return {
            "scenario": self.name,
            "description": self.description,
            "sprung_mass_kg": car.body_mass_kg,
            "suspension_stiffness_n_per_m": car.suspension_stiffness_n_per_m,
            "suspension_damping_ns_per_m": car.suspension_damping_ns_per_m,
            "coupling_stiffness_n_per_m": car.coupling_stiffness_n_per_m,
            "added_mass_kg": self.added_mass_kg,
            "ride_height_restored": self.ride_height_restored,
            "effects": [{"effect": n, "parameters": dict(p)} for n, p in self.effects],
            "expected_verdict": self.expected_verdict,
            "expected_effects": list(self.expected_effects),
            "expected_warnings": list(self.expected_warnings),
            "recipe": asdict(self),
        }


def _sensor(base: dict[str, Any], rate_hz: float, snr_db: float) -> sim.SensorModel:
    kw = {"output_rate_hz": rate_hz, "snr_db": snr_db, "bias_mps2": 0.03, **base}
    return sim.SensorModel(**kw)


def _road_events(n: int, length_m: float, rng: np.random.Generator) -> list[sim.RoadEvent]:
    if n <= 0:
        return []
    positions = np.sort(rng.uniform(0.1, 0.9, n)) * length_m
    return [
        sim.SpeedBump(float(p), height_m=float(rng.uniform(0.05, 0.08)), length_m=0.5)
        for p in positions
    ]


def simulate_scenario(sc: Scenario) -> tuple[sim.SimulatedDrive, sim.SimulatedDrive]:
    """Simulate the before and after drives of a scenario (deterministic in its seed)."""
    car = sc.car
    effects = [sim.make_effect(n, **p) for n, p in sc.effects]
    drives = []
    for k, mass in enumerate((0.0, sc.added_mass_kg)):
        seed = sc.seed * 2 + k + 1000
        rng = np.random.default_rng(seed)
        speed = sim.SpeedProfile.random_drive(
            sc.duration_s,
            rng,
            min_speed_mps=sc.speed_range_mps[0],
            max_speed_mps=sc.speed_range_mps[1],
        )
        length = float(speed.distance_m(sc.duration_s))
        body = dict(sc.body_sensor)
        if k == 1:
            body.update(sc.after_body_sensor)
        drives.append(
            sim.simulate(
                car,
                duration_s=sc.duration_s,
                road_class=sc.road_class,
                speed=speed,
                road_events=_road_events(sc.bumps, length, rng),
                effects=effects,
                added_mass_kg=mass,
                ride_height_restored=sc.ride_height_restored,
                wheel_sensor=_sensor(sc.wheel_sensor, sc.rate_hz, sc.snr_db),
                body_sensor=_sensor(body, sc.rate_hz, sc.snr_db),
                seed=seed,
            )
        )
    return drives[0], drives[1]


def diagnose_scenario(sc: Scenario | str, **overrides: Any) -> dict[str, Any]:
    """Simulate a scenario's before/after pair and diagnose it (for tests and benchmarks).

    A plain module-level function, so that a process pool can run the catalogue in
    parallel.

    Parameters
    ----------
    sc : Scenario or str
        The scenario or its name.
    **overrides
        Fields to replace (e.g. ``duration_s=90``), as in :func:`get_scenario`.

    Returns
    -------
    dict
        ``name``; ``out``: the diagnosis's JSON (``Diagnosis.to_dict()``); ``warnings``:
        every data warning with its ``kind``, ``value``, ``session`` and ``channel``;
        ``wall_s``: the time the diagnosis took (simulation excluded).
    """
    import time

    from fielddiag.diagnose.engine import Drive, diagnose_drives

    if isinstance(sc, str):
        sc = get_scenario(sc, **overrides)
    elif overrides:
        sc = replace(sc, **overrides)
    before, after = simulate_scenario(sc)
    drives = [
        Drive(
            d.wheel_accel_mps2,
            d.body_accel_mps2,
            d.sample_rate_hz,
            added_mass_kg=d.added_mass_kg,
            label=label,
            name=sc.name,
        )
        for label, d in (("before", before), ("after", after))
    ]
    t0 = time.perf_counter()
    diag = diagnose_drives(drives)
    wall = time.perf_counter() - t0
    return {
        "name": sc.name,
        "out": diag.to_dict(),
        "warnings": [
            {"kind": w.kind, "value": w.value, "session": w.session, "channel": w.channel}
            for w in diag.warnings
        ],
        "wall_s": wall,
    }


def write_scenario(
    sc: Scenario, folder: str | os.PathLike, *, include_recipe: bool = False
) -> tuple[Path, Path, Path]:
    """Write ``<name>_before.h5``, ``<name>_after.h5`` and ``<name>_truth.json``.

    The sessions do not carry the recipe unless asked: the truth sits in its own file, so
    a diagnosis run on the sessions cannot peek at it.
    """
    from fielddiag.simio import drive_to_session

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    before, after = simulate_scenario(sc)
    paths = []
    for label, drive in (("before", before), ("after", after)):
        paths.append(
            drive_to_session(
                drive,
                folder / f"{sc.name}_{label}.h5",
                vehicle="scenario car",
                corner="front-left",
                notes=f"scenario {sc.name} ({label})",
                include_recipe=include_recipe,
                overwrite=True,
            )
        )
    truth_path = folder / f"{sc.name}_truth.json"
    truth_path.write_text(json.dumps(sc.truth(), indent=2))
    return paths[0], paths[1], truth_path


# ----------------------------------------------------------------------------- catalogue
def _cases() -> list[Scenario]:
    cases: list[Scenario] = []
    add = cases.append
    # Linear cars: the diagnosis must say "adequate" (no false alarm), including hard ones.
    add(Scenario("linear_plain", "linear car, class C road, 500 Hz", seed=1))
    add(
        Scenario(
            "linear_noisy_200hz",
            "linear car, noisy 200 Hz recording, class B road",
            rate_hz=200.0,
            snr_db=25.0,
            road_class="B",
            seed=2,
        )
    )
    add(
        Scenario(
            "linear_short",
            "linear car, only 60 s per drive",
            duration_s=60.0,
            seed=3,
            params={"coupling_stiffness_n_per_m": 3000.0},
        )
    )
    add(
        Scenario(
            "linear_bias_drift",
            "linear car, body sensor bias drifting",
            body_sensor={"bias_drift_mps2_per_s": 0.002},
            seed=4,
            expected_warnings=("bias_drift",),
        )
    )
    # Dry friction, three sizes.
    for i, (f_n, road, snr) in enumerate(
        ((35.0, "C", 35.0), (60.0, "B", 30.0), (110.0, "C", 40.0))
    ):
        add(
            Scenario(
                f"friction_{i + 1}",
                f"dry friction {f_n:g} N in the strut",
                effects=(("coulomb_friction", {"friction_force_n": f_n}),),
                road_class=road,
                snr_db=snr,
                seed=10 + i,
                expected_verdict="missing_physics",
                expected_effects=("coulomb_friction",),
            )
        )
    # Progressive spring.
    for i, (k3, road) in enumerate(((4e6, "C"), (1.0e7, "C"), (4e7, "B"))):
        add(
            Scenario(
                f"cubic_{i + 1}",
                f"progressive spring k3 = {k3:.3g} N/m3",
                effects=(("cubic_stiffness", {"cubic_stiffness_n_per_m3": k3}),),
                road_class=road,
                seed=20 + i,
                expected_verdict="missing_physics",
                expected_effects=("cubic_stiffness",),
            )
        )
    # Bump stop reached only over a few speed bumps / big compressions.
    for i, (gap, k, bumps) in enumerate(((0.045, 1.5e5, 6), (0.05, 2.5e5, 8), (0.04, 1.0e5, 4))):
        add(
            Scenario(
                f"bump_stop_{i + 1}",
                f"bump stop {gap * 1000:g} mm gap, {k:.3g} N/m",
                effects=(("bump_stop", {"gap_m": gap, "stiffness_n_per_m": k}),),
                bumps=bumps,
                seed=30 + i,
                expected_verdict="missing_physics",
                expected_effects=("bump_stop",),
            )
        )
    # Asymmetric damper.
    for i, (cc, cr) in enumerate(((1300.0, 2300.0), (1000.0, 2600.0), (1500.0, 2100.0))):
        add(
            Scenario(
                f"asymmetric_{i + 1}",
                f"damper {cc:g} N s/m in compression, {cr:g} in rebound",
                effects=(
                    (
                        "asymmetric_damping",
                        {"compression_damping_ns_per_m": cc, "rebound_damping_ns_per_m": cr},
                    ),
                ),
                seed=40 + i,
                expected_verdict="missing_physics",
                expected_effects=("asymmetric_damping",),
            )
        )
    # Small effects: the linear model's held-out NRMSE only 1.3-2x the noise floor. Other
    # roads, speeds, noise levels and added masses than the cases above.
    add(
        Scenario(
            "small_friction",
            "dry friction 25 N, smooth class B road at low speed, noisier sensors, 80 kg added",
            effects=(("coulomb_friction", {"friction_force_n": 25.0}),),
            road_class="B",
            snr_db=30.0,
            speed_range_mps=(5.0, 15.0),
            added_mass_kg=80.0,
            seed=80,
            small=True,
            expected_verdict="missing_physics",
            expected_effects=("coulomb_friction",),
        )
    )
    add(
        Scenario(
            "small_cubic",
            "progressive spring k3 = 1.8e6 N/m3, fast drive, 50 kg added",
            effects=(("cubic_stiffness", {"cubic_stiffness_n_per_m3": 1.8e6}),),
            speed_range_mps=(10.0, 27.0),
            added_mass_kg=50.0,
            seed=81,
            small=True,
            expected_verdict="missing_physics",
            expected_effects=("cubic_stiffness",),
        )
    )
    add(
        Scenario(
            "small_bump_stop",
            "soft bump stop 45 mm gap, 2.5e4 N/m, six speed bumps, 70 kg added",
            effects=(("bump_stop", {"gap_m": 0.045, "stiffness_n_per_m": 2.5e4}),),
            bumps=6,
            added_mass_kg=70.0,
            seed=82,
            small=True,
            expected_verdict="missing_physics",
            expected_effects=("bump_stop",),
        )
    )
    add(
        Scenario(
            "small_asymmetric",
            "damper 1600 N s/m in compression, 2000 in rebound, 200 Hz recording",
            effects=(
                (
                    "asymmetric_damping",
                    {"compression_damping_ns_per_m": 1600.0, "rebound_damping_ns_per_m": 2000.0},
                ),
            ),
            rate_hz=200.0,
            speed_range_mps=(6.0, 18.0),
            seed=83,
            small=True,
            expected_verdict="missing_physics",
            expected_effects=("asymmetric_damping",),
        )
    )
    # Two effects at once.
    add(
        Scenario(
            "friction_and_asymmetric",
            "dry friction with an asymmetric damper",
            effects=(
                ("coulomb_friction", {"friction_force_n": 70.0}),
                (
                    "asymmetric_damping",
                    {"compression_damping_ns_per_m": 1200.0, "rebound_damping_ns_per_m": 2400.0},
                ),
            ),
            seed=50,
            expected_verdict="missing_physics",
            expected_effects=("coulomb_friction", "asymmetric_damping"),
        )
    )
    add(
        Scenario(
            "cubic_and_bump_stop",
            "progressive spring with a bump stop",
            effects=(
                ("cubic_stiffness", {"cubic_stiffness_n_per_m3": 1.0e7}),
                ("bump_stop", {"gap_m": 0.045, "stiffness_n_per_m": 2.0e5}),
            ),
            bumps=6,
            seed=51,
            expected_verdict="missing_physics",
            expected_effects=("cubic_stiffness", "bump_stop"),
        )
    )
    add(
        Scenario(
            "quadratic_damping",
            "velocity-squared (orifice) damping",
            effects=(("quadratic_damping", {"damping_ns2_per_m2": 3000.0}),),
            seed=60,
            expected_verdict="missing_physics",
            expected_effects=("quadratic_damping",),
        )
    )
    # Physics outside the library.
    add(
        Scenario(
            "travel_dependent_damping",
            "damping growing with travel, a position-sensitive damper (outside the library)",
            effects=(("travel_dependent_damping", {"extra_damping_ns_per_m": 1800.0,
                                                   "reference_travel_m": 0.03}),),
            bumps=6,
            seed=61,
            expected_verdict="missing_physics",
            expected_effects=("unexplained",),
        )
    )
    # Problems of the measurement, not of the suspension.
    add(
        Scenario(
            "sensor_gain_changed",
            "body sensor remounted with 8 % more gain for 'after'",
            after_body_sensor={"gain": 1.08},
            seed=70,
            expected_warnings=("sensor_gain_changed",),
        )
    )
    add(
        Scenario(
            "channel_time_offset",
            "body channel 4 ms late against the wheel channel",
            body_sensor={"time_offset_s": 0.004},
            seed=71,
            expected_warnings=("channel_time_offset",),
        )
    )
    add(
        Scenario(
            "clipping",
            "wheel accelerometer saturating at +-4 g",
            wheel_sensor={"clip_mps2": 4 * GRAVITY_MPS2},
            road_class="D",
            seed=72,
            speed_range_mps=(8.0, 20.0),
            expected_warnings=("clipping",),
        )
    )
    return cases


SCENARIOS: dict[str, Scenario] = {sc.name: sc for sc in _cases()}


def get_scenario(name: str, **overrides: Any) -> Scenario:
    """A scenario by name, optionally with fields replaced (e.g. ``seed=5``)."""
    try:
        sc = SCENARIOS[name]
    except KeyError:
        raise FieldDiagError(f"unknown scenario {name!r}; known: {', '.join(SCENARIOS)}") from None
    return replace(sc, **overrides) if overrides else sc
