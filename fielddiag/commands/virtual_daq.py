"""``fielddiag virtual-daq``: a simulated accelerometer DAQ on a pseudo-terminal.

The first line printed is the serial port to record from (a stable link to the pty);
``fielddiag record --daq serial://THAT_PATH -o drive.h5`` records it. Accelerations come
from the quarter-car simulator (channel 0 wheel, 1 body, further channels noise), streamed
in the binary protocol of drivers/PROTOCOL.md, with optional fault injection. Runs until
Ctrl-C; then prints what it did as one JSON line.

``--full-vehicle`` streams the eight accelerometers of a simulated full vehicle instead
(per corner fl, fr, rl, rr: hub, then body), the drive ``fielddiag record --virtual
--full-vehicle`` records; it writes the car's vehicle file (beside the pty, or to
--write-vehicle-file) and prints the whole ``fielddiag record`` command, channel map
included. ``fielddiag virtual-ecu --full-vehicle`` with the same --seed, --duration, --rate
and added mass sends the same drive's speed and accelerations.
"""

from __future__ import annotations

import argparse
import json
import shlex
import signal
import sys
import time

from fielddiag.commands import _virtual_vehicle as vehicle
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
                   default=vehicle.DEFAULT_RATE_HZ, metavar="HZ", help="sample rate (500)")
    p.add_argument("--channels", type=arg_int("--channels", 1, 64, "channels"),
                   default=None, metavar="N", help="channels (2; not with --full-vehicle)")
    p.add_argument(
        "--format", choices=("int16", "int32", "float32"), default="int32",
        help="sample format on the wire (int32)",
    )
    p.add_argument("--samples-per-frame",
                   type=arg_int("--samples-per-frame", 1, 65535, "samples per frame"),
                   default=None, metavar="N",
                   help="samples per channel per frame (default: 100 frames/s)")
    p.add_argument("--full-scale-g", type=arg_number("--full-scale-g", "full_scale_g"),
                   default=None, metavar="G",
                   help="full scale of the integer formats in g (16; full vehicle: the "
                   "smallest range the hub accelerations do not clip)")
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
                   default=vehicle.DEFAULT_DRIVE_S, metavar="S",
                   help="length of the simulated drive, looped (120)")
    p.add_argument("--added-mass", type=arg_number("--added-mass", "session_added_mass"),
                   default=0.0, metavar="KG",
                   help="mass added on the body in the simulation")
    p.add_argument("--seed", type=arg_int("--seed", 0, 2**32 - 1, "a random seed"),
                   default=0, help="seed of road, speed and faults")
    p.add_argument("--serial-number", default="VDAQ-0001", help="serial number it reports")
    vehicle.add_arguments(p)
    p.add_argument("--write-vehicle-file", default=None, metavar="PATH",
                   help="full vehicle: write the car's vehicle file here (default: beside the "
                   "pty, removed at exit)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from drivers.virtual import G_MPS2, VirtualDAQ

    _check(args)
    signals, roles, needed_mps2, geometry = _signals(args)
    full_scale_mps2 = _full_scale(args.full_scale_g, needed_mps2)
    daq = VirtualDAQ(
        signals,
        sample_rate_hz=args.rate,
        samples_per_frame=args.samples_per_frame,
        sample_format=args.format,
        full_scale_mps2=full_scale_mps2,
        roles=roles,
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
    vehicle_file = None
    if geometry is not None:
        try:
            vehicle_file = vehicle.write_vehicle_file(geometry, args.write_vehicle_file,
                                                      daq.link.dir)
        except BaseException:
            daq.stop()
            raise
    print(daq.path, flush=True)
    print(_hint(args, daq.path, vehicle_file, full_scale_mps2 / G_MPS2), file=sys.stderr,
          flush=True)
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


def _check(args: argparse.Namespace) -> None:
    """Refuse options that do not go together."""
    vehicle.check_arguments(args)
    if args.full_vehicle and args.channels is not None:
        raise FieldDiagError(
            "--channels is for the quarter car: --full-vehicle streams its "
            "eight accelerometers (leave --channels out)"
        )
    if args.write_vehicle_file and not args.full_vehicle:
        raise FieldDiagError("--write-vehicle-file is for --full-vehicle")


def _signals(args: argparse.Namespace) -> tuple:
    """What the sensors read (n, channels), their roles (None: the device's defaults), the
    measuring range they need [m/s^2] and the car's geometry (None, None: quarter car)."""
    from drivers.virtual import simulated_accelerations

    if args.full_vehicle:
        stream = vehicle.vehicle_stream(args)
        return (
            stream.signals_mps2,
            stream.daq_roles,
            stream.full_scale_mps2,
            stream.drive.geometry,
        )
    signals, _ = simulated_accelerations(
        args.duration,
        sample_rate_hz=args.rate,
        n_channels=args.channels or 2,
        added_mass_kg=args.added_mass,
        seed=args.seed,
    )
    return signals, None, None, None


def _full_scale(chosen_g: float | None, needed_mps2: float | None) -> float:
    """The measuring range [m/s^2]: --full-scale-g (default 16 g), or for a full vehicle
    the range its readings need (a smaller --full-scale-g is refused: it would clip)."""
    from drivers.virtual import G_MPS2

    if chosen_g is None:
        return 16.0 * G_MPS2 if needed_mps2 is None else needed_mps2
    if needed_mps2 is not None and chosen_g * G_MPS2 < needed_mps2 * (1 - 1e-12):
        raise FieldDiagError(
            f"--full-scale-g {chosen_g:g}: the simulated hub accelerations "
            f"need {needed_mps2 / G_MPS2:g} g or more (leave it out to get "
            "that range)"
        )
    return chosen_g * G_MPS2


def _hint(args: argparse.Namespace, port: str, vehicle_file: object, full_scale_g: float) -> str:
    """The lines for stderr: what streams, and how to record it."""
    if vehicle_file is None:
        return (
            f"# virtual DAQ {args.channels or 2} ch at {args.rate:g} Hz ({args.format}); "
            f"record with: fielddiag record --daq serial://{port} -o drive.h5; Ctrl-C to "
            "stop"
        )
    record = [
        "fielddiag",
        "record",
        *vehicle.daq_record_args(port, vehicle_file, args),
        "-o",
        "drive.h5",
    ]
    return "\n".join(
        [
            f"# virtual DAQ: a full vehicle (default car, rough road), 8 ch (per corner hub, "
            f"body) at {args.rate:g} Hz ({args.format}, {full_scale_g:g} g); vehicle file "
            f"{vehicle_file}; Ctrl-C to stop",
            "# record with (add the --can/--signal arguments of `fielddiag virtual-ecu "
            f"{vehicle.same_drive_args(args)}` for the speed and accelerations of this drive):",
            shlex.join(record),
        ]
    )
