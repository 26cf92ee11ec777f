"""``--full-vehicle`` of ``fielddiag virtual-daq`` and ``fielddiag virtual-ecu``.

Both devices play one simulated car and drive: :func:`fielddiag.virtual_streams.
full_vehicle_stream` (the default car, ``VehicleParams()``, on a rough road), the drive
``fielddiag record --virtual --full-vehicle`` records in-process. Two devices started with
the same ``--seed``, ``--duration``, ``--rate`` and added mass simulate the same drive: the
DAQ streams its eight accelerometers, the ECU its speed, wheel speeds and accelerations.
Their hints print the ``fielddiag record`` arguments that record them.
"""

from __future__ import annotations

import argparse
import shlex
from pathlib import Path
from typing import Any

from fielddiag.commands.identify import arg_position
from fielddiag.errors import FieldDiagError

#: Length of the simulated drive both devices loop, unless --duration says otherwise [s].
DEFAULT_DRIVE_S = 120.0
#: Sample rate of the virtual DAQ, at which the drive is simulated [Hz].
DEFAULT_RATE_HZ = 500.0
#: Name of the vehicle file the virtual DAQ writes beside its pseudo-terminal.
VEHICLE_FILE_NAME = "virtual_car.json"


def add_arguments(p: argparse.ArgumentParser) -> None:
    """``--full-vehicle`` and ``--added-mass-at``."""
    p.add_argument(
        "--full-vehicle",
        action="store_true",
        help="play a simulated full vehicle (the default car on a rough road): the same car "
        "and drive in a virtual-daq and a virtual-ecu given the same --seed, --duration, "
        "--rate and added mass",
    )
    p.add_argument(
        "--added-mass-at",
        type=arg_position,
        default=None,
        metavar="X_M,Y_M",
        help="full vehicle: where the added mass sits, metres behind the front axle and "
        "left of the centre line",
    )


def check_arguments(args: argparse.Namespace) -> None:
    """Refuse ``--added-mass-at`` without ``--full-vehicle`` or without an added mass.

    Raises
    ------
    FieldDiagError
    """
    if args.added_mass_at is None:
        return
    if not args.full_vehicle:
        raise FieldDiagError(
            "--added-mass-at is for --full-vehicle (where the added mass sits on the car)"
        )
    if not args.added_mass:
        raise FieldDiagError(
            "--added-mass-at says where the added mass sits: give --added-mass KG too"
        )


def vehicle_stream(args: argparse.Namespace) -> Any:
    """The drive of ``--full-vehicle``, as the virtual DAQ streams it.

    The virtual ECU takes it too, simulated at the DAQ's rate (``with_daq``): the speed is
    the same at any rate, the accelerations' noise is not.

    Returns
    -------
    fielddiag.virtual_streams.DriveStream

    Raises
    ------
    FieldDiagError
        An added mass without its position, hub accelerations beyond the DAQ's range.
    """
    from fielddiag.virtual_streams import full_vehicle_stream

    return full_vehicle_stream(
        drive_s=args.duration,
        sample_rate_hz=args.rate,
        added_mass_kg=args.added_mass,
        seed=args.seed,
        with_daq=True,
        added_mass_at_m=args.added_mass_at,
    )


def write_vehicle_file(geometry: Any, path: str | None, folder: str) -> Path:
    """Write the car's vehicle file to ``path``, or into ``folder`` when ``path`` is None.

    An existing file is left alone when it holds this car, and refused otherwise.

    Returns
    -------
    Path

    Raises
    ------
    FieldDiagError
        ``path`` holds something else, or cannot be written.
    """
    from fielddiag.outputs import write_text

    target = Path(path) if path else Path(folder) / VEHICLE_FILE_NAME
    text = geometry.to_json() + "\n"
    if target.is_file():
        if target.read_text(encoding="utf-8", errors="replace") == text:
            return target
        raise FieldDiagError(
            f"--write-vehicle-file {target}: the file exists and holds something else; "
            "give a new path (it is not replaced)"
        )
    return write_text(target, text, overwrite=False, flag="--write-vehicle-file")


def daq_record_args(port: str, vehicle_file: Path, args: argparse.Namespace) -> list[str]:
    """The ``fielddiag record`` arguments for the full-vehicle virtual DAQ on ``port``:
    the channel map in the order the stream uses, the vehicle file, the added mass."""
    from fielddiag.vehicle.corner_map import VIRTUAL_DAQ_MAP

    words = ["--daq", f"serial://{port}"]
    for channel, role in VIRTUAL_DAQ_MAP.items():
        words += ["--role", f"{role}={channel}"]
    words += ["--vehicle-file", str(vehicle_file)]
    words += added_mass_args(args)
    return words


def added_mass_args(args: argparse.Namespace) -> list[str]:
    """``--added-mass KG --added-mass-at X_M,Y_M`` as given (none without an added mass)."""
    if not args.added_mass:
        return []
    x_m, y_m = args.added_mass_at
    return [
        "--added-mass",
        _number(args.added_mass),
        "--added-mass-at",
        f"{_number(x_m)},{_number(y_m)}",
    ]


def _number(value: float) -> str:
    """Shortest text that reads back as ``value``."""
    short = f"{value:g}"
    return short if float(short) == value else repr(float(value))


def ecu_record_args(url: str) -> list[str]:
    """The ``fielddiag record`` arguments for the full-vehicle virtual ECU at ``url``: the
    bus and the signals, the car's by their roles' aliases (vehicle_speed, accel_long,
    accel_lat)."""
    from fielddiag.virtual_streams import VEHICLE_ECU_SIGNALS

    return ["--can", url, *[w for s in VEHICLE_ECU_SIGNALS for w in ("--signal", s)]]


def same_drive_args(args: argparse.Namespace) -> str:
    """The options that make the other virtual device play the same drive."""
    words = [
        "--full-vehicle",
        "--seed",
        str(args.seed),
        "--duration",
        _number(args.duration),
        "--rate",
        _number(args.rate),
    ]
    words += added_mass_args(args)
    return shlex.join(words)
