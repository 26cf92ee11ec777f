"""``fielddiag virtual-ecu``: publish vehicle speed and wheel speeds on a CAN bus.

The first line printed is the source URL another process records it with, e.g.
``fielddiag record --daq ... --can "THAT_URL" --signal vehicle_speed=SPEED.SPEED``.

Interfaces: ``slcan`` (default) emulates an SLCAN USB-CAN adapter on a pseudo-terminal,
read by python-can's slcan interface from any process; ``udp_multicast`` uses python-can's
UDP multicast bus on loopback (needs the msgpack package); ``virtual`` is python-can's
in-process bus and is only useful from Python. Speeds follow a random drive of the
quarter-car simulator's speed profile generator (looped), or a constant speed.
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import sys
import tempfile
import time

from fielddiag.errors import DeviceError
from fielddiag.validate import arg_int, arg_number


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
                   default=300.0, metavar="S",
                   help="length of the random speed profile, looped (300)")
    p.add_argument("--speed-kmh", type=arg_number("--speed-kmh", "speed_kmh"),
                   default=None, metavar="V",
                   help="constant speed instead of a random drive")
    p.add_argument("--seed", type=arg_int("--seed", 0, 2**32 - 1, "a random seed"),
                   default=0, help="seed of the speed profile")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from drivers.virtual import VIRTUAL_ECU_DBC, SlcanPty, VirtualECU
    from fielddiag.sim import SpeedProfile

    if args.speed_kmh is not None:
        t = np.array([0.0, args.duration])
        v = np.full(2, args.speed_kmh / 3.6)
    else:
        prof = SpeedProfile.random_drive(args.duration, seed=args.seed)
        t = np.arange(0.0, args.duration, 0.01)
        v = prof.speed_mps(t)
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
    ecu = VirtualECU(bus, t, v, dbc=dbc, loop=True, seed=args.seed)
    print(url, flush=True)
    print(
        "# virtual ECU: SPEED at 41 Hz, WHEEL_SPEEDS at 83 Hz; signals vehicle_speed="
        "SPEED.SPEED, WHEEL_SPEED_FL ... (built-in DBC unless --dbc); Ctrl-C to stop",
        file=sys.stderr,
        flush=True,
    )
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
