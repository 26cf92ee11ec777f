"""``fielddiag virtual-daq``: a simulated accelerometer DAQ on a pseudo-terminal.

The first line printed is the serial port to record from (a stable link to the pty);
``fielddiag record --daq serial://THAT_PATH -o drive.h5`` records it. Accelerations come
from the quarter-car simulator (channel 0 wheel, 1 body, further channels noise), streamed
in the binary protocol of drivers/PROTOCOL.md, with optional fault injection. Runs until
Ctrl-C; then prints what it did as one JSON line.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import time

from fielddiag.errors import FieldDiagError
from fielddiag.validate import arg_int, arg_number


def _interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "virtual-daq",
        help="simulated DAQ on a pseudo-terminal (binary protocol, fault injection)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--rate", type=arg_number("--rate", "daq_rate"),
                   default=500.0, metavar="HZ", help="sample rate (500)")
    p.add_argument("--channels", type=arg_int("--channels", 1, 64, "channels"),
                   default=2, metavar="N", help="channels (2)")
    p.add_argument(
        "--format", choices=("int16", "int32", "float32"), default="int32",
        help="sample format on the wire (int32)",
    )
    p.add_argument("--samples-per-frame",
                   type=arg_int("--samples-per-frame", 1, 65535, "samples per frame"),
                   default=None, metavar="N",
                   help="samples per channel per frame (default: 100 frames/s)")
    p.add_argument("--full-scale-g", type=arg_number("--full-scale-g", "full_scale_g"),
                   default=16.0, metavar="G",
                   help="full scale of the integer formats in g (16)")
    p.add_argument("--corrupt", type=arg_number("--corrupt", "corrupt"),
                   default=0.0, metavar="RATE",
                   help="probability that a byte sent is altered (e.g. 1e-3)")
    p.add_argument("--garbage-every", type=arg_number("--garbage-every", "interval"),
                   default=None, metavar="S",
                   help="insert a burst of random bytes every S seconds")
    p.add_argument("--disconnect-at", type=arg_number("--disconnect-at", "time_s"),
                   default=None, metavar="S",
                   help="pull the cable S seconds after streaming started")
    p.add_argument("--disconnect-for", type=arg_number("--disconnect-for", "interval"),
                   default=2.0, metavar="S",
                   help="for this long (2)")
    p.add_argument("--stall-at", type=arg_number("--stall-at", "time_s"), default=None, metavar="S",
                   help="stop sending S seconds after streaming started")
    p.add_argument("--stall-for", type=arg_number("--stall-for", "interval"),
                   default=1.0, metavar="S",
                   help="for this long (1)")
    p.add_argument("--power-cycle", action="store_true",
                   help="reboot when the cable comes back (bus-powered device)")
    p.add_argument("--clock-drift-ppm", type=arg_number("--clock-drift-ppm", "drift_ppm"),
                   default=0.0, metavar="PPM",
                   help="device clock runs fast by this much")
    p.add_argument("--duration", type=arg_number("--duration", "sim_duration"),
                   default=120.0, metavar="S",
                   help="length of the simulated drive, looped (120)")
    p.add_argument("--added-mass", type=arg_number("--added-mass", "session_added_mass"),
                   default=0.0, metavar="KG",
                   help="mass added on the body in the simulation")
    p.add_argument("--seed", type=arg_int("--seed", 0, 2**32 - 1, "a random seed"),
                   default=0, help="seed of road, speed and faults")
    p.add_argument("--serial-number", default="VDAQ-0001", help="serial number it reports")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from drivers.virtual import G_MPS2, VirtualDAQ, simulated_accelerations

    if args.channels < 1 or args.rate <= 0:
        raise FieldDiagError("--channels must be >= 1 and --rate > 0")
    signals, _ = simulated_accelerations(
        args.duration,
        sample_rate_hz=args.rate,
        n_channels=args.channels,
        added_mass_kg=args.added_mass,
        seed=args.seed,
    )
    daq = VirtualDAQ(
        signals,
        sample_rate_hz=args.rate,
        samples_per_frame=args.samples_per_frame,
        sample_format=args.format,
        full_scale_mps2=args.full_scale_g * G_MPS2,
        serial_number=args.serial_number,
        corrupt_rate=args.corrupt,
        garbage_every_s=args.garbage_every,
        disconnect_at_s=args.disconnect_at,
        disconnect_for_s=args.disconnect_for,
        stall_at_s=args.stall_at,
        stall_for_s=args.stall_for,
        power_cycle_on_disconnect=args.power_cycle,
        clock_drift_ppm=args.clock_drift_ppm,
        seed=args.seed,
    )
    print(daq.path, flush=True)
    print(
        f"# virtual DAQ {args.channels} ch at {args.rate:g} Hz ({args.format}); record with: "
        f"fielddiag record --daq serial://{daq.path} -o drive.h5; Ctrl-C to stop",
        file=sys.stderr,
        flush=True,
    )
    signal.signal(signal.SIGTERM, _interrupt)
    signal.signal(signal.SIGINT, _interrupt)  # also when started in the background
    daq.start()
    try:
        while True:
            time.sleep(0.5)
    except KeyboardInterrupt:
        pass
    finally:
        daq.stop()
    st = daq.stats
    print(
        json.dumps(
            {
                "frames_made": st.frames_made,
                "frames_written": st.frames_written,
                "frames_corrupted": st.frames_corrupted,
                "frames_dropped_overflow": st.frames_dropped_overflow,
                "frames_dropped_outage": st.frames_dropped_outage,
                "frames_lost_in_link": st.frames_lost_in_link,
                "garbage_bytes": st.garbage_bytes,
                "bytes_written": st.bytes_written,
                "disconnects": st.disconnects,
            }
        ),
        flush=True,
    )
    return 0
