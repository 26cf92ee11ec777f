"""``fielddiag virtual-ecu``: publish vehicle speed and wheel speeds on a CAN bus.

The first line printed is the source URL another process records it with, e.g.
``fielddiag record --daq ... --can "THAT_URL" --signal vehicle_speed=SPEED.SPEED``.

Interfaces: ``slcan`` (default) emulates an SLCAN USB-CAN adapter on a pseudo-terminal,
read by python-can's slcan interface from any process; ``udp_multicast`` uses python-can's
UDP multicast bus on loopback (needs the msgpack package); ``virtual`` is python-can's
in-process bus and is only useful from Python. Speeds follow a random drive of the
quarter-car simulator's speed profile generator (looped), or a constant speed. Over
``slcan`` the drive starts when a recording first opens the bus.

``--full-vehicle`` sends the speed, wheel speeds and the car's longitudinal and lateral
accelerations (``KINEMATICS``) of a simulated full-vehicle drive, the one ``fielddiag
virtual-daq --full-vehicle`` streams with the same --seed, --duration, --rate and added
mass: one car and one drive. The hint prints the ``--can`` and ``--signal`` arguments
``fielddiag record`` needs (``vehicle_speed``, ``accel_long``, ``accel_lat``).
"""

from __future__ import annotations

import argparse
import os
import shlex
import shutil
import signal
import sys
import tempfile
import time

from fielddiag.commands import _virtual_vehicle as vehicle
from fielddiag.errors import DeviceError, FieldDiagError
from fielddiag.validate import arg_int, arg_number

#: Length of the random speed profile of the quarter-car drive [s].
SPEED_PROFILE_S = 300.0


def _interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "virtual-ecu",
        help="simulated ECU sending speed and wheel speeds on a CAN bus (DBC-encoded)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "--interface", choices=("slcan", "udp_multicast", "virtual"), default="slcan",
        help="how other processes reach the bus (slcan)",
    )
    p.add_argument("--channel", default=None,
                   help="bus channel (udp_multicast group, virtual channel name)")
    p.add_argument("--dbc", default=None, metavar="FILE",
                   help="DBC with SPEED and WHEEL_SPEEDS messages (default: built-in, "
                        "same layout as the Toyota RAV4 DBC)")
    p.add_argument("--duration", type=arg_number("--duration", "sim_duration"),
                   default=None, metavar="S",
                   help="length of the random speed profile, looped (300; full vehicle: "
                   "of the drive, 120)")
    p.add_argument("--speed-kmh", type=arg_number("--speed-kmh", "speed_kmh"),
                   default=None, metavar="V",
                   help="constant speed instead of a random drive")
    p.add_argument("--seed", type=arg_int("--seed", 0, 2**32 - 1, "a random seed"),
                   default=0, help="seed of the speed profile")
    vehicle.add_arguments(p)
    p.add_argument("--added-mass", type=arg_number("--added-mass", "session_added_mass"),
                   default=None, metavar="KG",
                   help="full vehicle: mass added on the body in the simulation (0)")
    p.add_argument("--rate", type=arg_number("--rate", "daq_rate"), default=None,
                   metavar="HZ", help="full vehicle: the virtual DAQ's rate, at which the "
                   "drive is simulated (500)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from drivers.virtual import VIRTUAL_ECU_DBC, SlcanPty, VirtualECU

    _check(args)
    t, v, accel = _series(args)
    if args.interface == "slcan":
        bus = SlcanPty()
        folder = bus.link.dir
    else:
        folder = tempfile.mkdtemp(prefix="fielddiag-vecu-")
    dbc = args.dbc
    if dbc is None:  # write the built-in DBC where the reader can load it
        dbc = os.path.join(folder, "virtual_ecu.dbc")
        with open(dbc, "w") as fh:
            fh.write(VIRTUAL_ECU_DBC)
    dbc_q = f"dbc={os.path.abspath(dbc)}"
    if args.interface == "slcan":
        url = f"can://slcan/{bus.path}?bitrate=500000&sleep_after_open=0&{dbc_q}"
    else:
        import can

        channel = args.channel or (
            "239.74.163.2" if args.interface == "udp_multicast" else "fielddiag"
        )
        try:
            bus = can.Bus(interface=args.interface, channel=channel)
        except Exception as exc:
            raise DeviceError(
                f"cannot open python-can interface {args.interface}: {exc} (udp_multicast "
                "needs `pip install msgpack`; --interface slcan needs nothing)"
            ) from None
        url = f"can://{args.interface}/{channel}?{dbc_q}"
    try:
        ecu = VirtualECU(bus, t, v, dbc=dbc, loop=True, seed=args.seed, accel_mps2=accel,
                         time_fn=bus.time_since_first_open if args.interface == "slcan"
                         else None)
    except KeyError as exc:
        bus.shutdown()
        if args.interface != "slcan":
            shutil.rmtree(folder, ignore_errors=True)
        raise FieldDiagError(f"--dbc {dbc}: no message {exc}; the virtual ECU sends SPEED, "
                             "WHEEL_SPEEDS and (full vehicle) KINEMATICS") from None
    print(url, flush=True)
    print(_hint(args, url), file=sys.stderr, flush=True)
    signal.signal(signal.SIGTERM, _interrupt)
    signal.signal(signal.SIGINT, _interrupt)  # also when started in the background
    ecu.start()
    try:
        while ecu._thread is not None and ecu._thread.is_alive():
            time.sleep(0.5)
        if ecu.error is not None:
            raise DeviceError(f"virtual ECU stopped: {ecu.error}")
    except KeyboardInterrupt:
        pass
    finally:
        ecu.stop()
        bus.shutdown()
        if args.interface != "slcan":
            shutil.rmtree(folder, ignore_errors=True)
    return 0


def _check(args: argparse.Namespace) -> None:
    """Refuse options that do not go together; fill in the defaults of the mode."""
    vehicle.check_arguments(args)
    if args.full_vehicle and args.speed_kmh is not None:
        raise FieldDiagError(
            "--speed-kmh is a constant speed: --full-vehicle sends its "
            "simulated drive (leave --speed-kmh out)"
        )
    if not args.full_vehicle:
        for flag, value in (("--added-mass", args.added_mass), ("--rate", args.rate)):
            if value is not None:
                raise FieldDiagError(
                    f"{flag} is for --full-vehicle (the quarter-car ECU sends a speed profile only)"
                )
    if args.duration is None:
        args.duration = vehicle.DEFAULT_DRIVE_S if args.full_vehicle else SPEED_PROFILE_S
    if args.full_vehicle:
        args.added_mass = args.added_mass or 0.0
        args.rate = args.rate or vehicle.DEFAULT_RATE_HZ


def _series(args: argparse.Namespace) -> tuple:
    """Time [s], speed [m/s] and (full vehicle) the longitudinal and lateral accelerations
    [m/s^2] the ECU sends (None: no accelerations)."""
    import numpy as np

    from fielddiag.sim import SpeedProfile

    if args.full_vehicle:
        stream = vehicle.vehicle_stream(args)
        return stream.speed_time_s, stream.speed_mps, stream.accel_mps2
    if args.speed_kmh is not None:
        return np.array([0.0, args.duration]), np.full(2, args.speed_kmh / 3.6), None
    prof = SpeedProfile.random_drive(args.duration, seed=args.seed)
    t = np.arange(0.0, args.duration, 0.01)
    return t, prof.speed_mps(t), None


def _hint(args: argparse.Namespace, url: str) -> str:
    """The lines for stderr: what is sent, and how to record it."""
    if not args.full_vehicle:
        return (
            "# virtual ECU: SPEED at 41 Hz, WHEEL_SPEEDS at 83 Hz; signals vehicle_speed="
            "SPEED.SPEED, WHEEL_SPEED_FL ... (built-in DBC unless --dbc); Ctrl-C to stop"
        )
    start = (
        "starts when a recording first opens the bus"
        if args.interface == "slcan"
        else "started now"
    )
    return "\n".join(
        [
            "# virtual ECU: a full vehicle (default car, rough road): SPEED at 41 Hz, "
            "WHEEL_SPEEDS at 83 Hz, KINEMATICS (accel_long, accel_lat) at 100 Hz; the drive "
            f"{start}; Ctrl-C to stop",
            "# record it with these arguments (added to the `fielddiag record` command that "
            f"`fielddiag virtual-daq {vehicle.same_drive_args(args)}` prints):",
            shlex.join(vehicle.ecu_record_args(url)),
        ]
    )
