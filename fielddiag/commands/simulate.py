"""``fielddiag simulate -o SESSION.h5 ...``: a simulated drive as a session, no hardware."""

from __future__ import annotations

import argparse
import dataclasses
import math

from fielddiag.errors import FieldDiagError
from fielddiag.validate import arg_int, arg_number


class _EffectAction(argparse.Action):
    """``--effect NAME`` starts an effect; following ``--param KEY=VALUE`` belong to it."""

    def __call__(self, parser, namespace, values, option_string=None):
        effects = list(getattr(namespace, "effects", None) or [])
        if option_string == "--effect":
            effects.append((values, {}))
        else:
            if not effects:
                raise argparse.ArgumentError(self, "--param must follow an --effect NAME")
            key, sep, value = values.partition("=")
            if not sep:
                raise argparse.ArgumentError(self, f"write --param as KEY=VALUE, not {values!r}")
            try:
                number = float(value)
            except ValueError:
                number = math.nan
            if not math.isfinite(number):
                raise argparse.ArgumentError(
                    self, f"--param {values}: give KEY=VALUE with a finite number, e.g. "
                    "friction_force_n=60") from None
            effects[-1][1][key.strip()] = number
        namespace.effects = effects


def parse_key_values(items: list[str] | None, what: str) -> dict[str, float]:
    out: dict[str, float] = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        try:
            if not sep:
                raise ValueError
            number = float(value)
            if not math.isfinite(number):
                raise ValueError
            out[key.strip()] = number
        except ValueError:
            raise FieldDiagError(f"{what} {item}: write it as KEY=NUMBER with a finite "
                                 "number, e.g. body_mass_kg=400") from None
    return out


def add_drive_arguments(p: argparse.ArgumentParser) -> None:
    """Options describing a simulated drive (shared with ``demo``)."""
    p.add_argument("--duration", type=arg_number("--duration", "sim_duration"),
                   default=120.0, metavar="S", help="drive length (s)")
    p.add_argument("--road-class", default="C", help="ISO 8608 road class A..H (default C)")
    p.add_argument("--seed", type=arg_int("--seed", 0, 2**32 - 1, "a random seed"),
                   default=None, help="random seed (default: random)")
    p.add_argument("--rate", type=arg_number("--rate", "daq_rate"),
                   default=500.0, metavar="HZ", help="DAQ output rate")
    p.add_argument("--snr-db", type=arg_number("--snr-db", "snr"),
                   default=35.0, help="sensor signal-to-noise ratio (dB)")
    p.add_argument(
        "--car",
        action="append",
        metavar="KEY=VALUE",
        help="car parameter, e.g. body_mass_kg=400 (see fielddiag.sim.QuarterCarParams)",
    )
    p.add_argument(
        "--effect",
        action=_EffectAction,
        dest="effects",
        metavar="NAME",
        help="add a suspension effect: coulomb_friction, cubic_stiffness, bump_stop, "
        "asymmetric_damping, quadratic_damping, hysteretic_spring",
    )
    p.add_argument(
        "--param",
        action=_EffectAction,
        dest="effects",
        metavar="KEY=VALUE",
        help="parameter of the preceding --effect, e.g. friction_force_n=60",
    )


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("simulate", help="simulate a drive of one corner into a session")
    p.add_argument("-o", "--output", required=True, help="session file to write (.h5)")
    p.add_argument("--added-mass", type=arg_number("--added-mass", "session_added_mass"),
                   default=0.0, metavar="KG", help="mass on the body")
    p.add_argument("--vehicle", default="simulated car")
    p.add_argument("--corner", default="front-left")
    p.add_argument("--overwrite", action="store_true", help="replace the output if it exists")
    add_drive_arguments(p)
    p.set_defaults(func=run, effects=[])


def drive_from_args(args: argparse.Namespace, added_mass_kg: float, seed: int | None):
    """Run the simulator as the drive options say."""
    car = parse_key_values(args.car, "--car")
    from fielddiag import sim

    fields = {f.name for f in dataclasses.fields(sim.QuarterCarParams)}
    unknown = set(car) - fields
    if unknown:
        raise FieldDiagError(
            f"unknown car parameter {sorted(unknown)[0]!r}; known: {', '.join(sorted(fields))}"
        )
    params = sim.QuarterCarParams(**car)
    effects = [sim.make_effect(name, **kw) for name, kw in args.effects]
    sensor = sim.SensorModel(output_rate_hz=args.rate, snr_db=args.snr_db)
    return sim.simulate(
        params,
        duration_s=args.duration,
        road_class=args.road_class,
        effects=effects,
        added_mass_kg=added_mass_kg,
        sensor=sensor,
        seed=seed,
    )


def run(args: argparse.Namespace) -> int:
    from fielddiag.outputs import atomic_file, check_target

    check_target(args.output, overwrite=args.overwrite)  # before the work
    drive = drive_from_args(args, args.added_mass, args.seed)
    from fielddiag.simio import drive_to_session

    with atomic_file(args.output, overwrite=args.overwrite) as tmp:
        drive_to_session(drive, tmp, vehicle=args.vehicle, corner=args.corner, overwrite=True)
    path = args.output
    eff = ", ".join(e.name for e in drive.effects) or "linear"
    print(
        f"wrote {path}: {drive.duration_s:g} s at {drive.sample_rate_hz:g} Hz, road class "
        f"{drive.road_class}, {eff}, added mass {drive.added_mass_kg:g} kg, seed {drive.seed}"
    )
    return 0
