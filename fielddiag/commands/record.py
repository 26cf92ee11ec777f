"""``fielddiag record``: record a DAQ and CAN sources into one session.

    fielddiag record --daq serial:///dev/ttyUSB0 \\
        --can "can://socketcan/can0?bitrate=500000&dbc=car.dbc" \\
        --signal vehicle_speed=SPEED.SPEED -o drive.h5 \\
        --added-mass 0 --vehicle "RAV4 2018" --corner front-left

    fielddiag record --virtual -o drive.h5 --duration 60 --added-mass 40

A full vehicle (eight accelerometers on one DAQ, the car's speed and accelerations on CAN):
say which channel is which sensor with --role ROLE=CHANNEL (channel numbers from 0), give
the vehicle file, and name the CAN signals by their roles' aliases::

    fielddiag record --daq serial:///dev/ttyUSB0 --role wheel_fl=0 --role body_fl=1 \\
        --role wheel_fr=2 --role body_fr=3 --role wheel_rl=4 --role body_rl=5 \\
        --role wheel_rr=6 --role body_rr=7 --vehicle-file car.json \\
        --can "can://socketcan/can0?dbc=car.dbc" --signal vehicle_speed=SPEED.SPEED \\
        --signal accel_long=KINEMATICS.ACCEL_X --signal accel_lat=KINEMATICS.ACCEL_Y \\
        --added-mass 150 --added-mass-at 1.9,0.3 -o after.h5

``--virtual`` records a simulated car instead: the virtual DAQ on a pseudo-terminal read
by the real serial driver and the virtual ECU on python-can's virtual bus read by the real
CAN driver (:mod:`fielddiag.virtual_drive`, as ``fielddiag demo`` and the dashboard do);
the drive is simulated with the added mass on the body and streamed once for --duration,
or in a loop until Ctrl-C. ``--virtual --full-vehicle`` records the default full vehicle
(``VehicleParams()``) the same way: eight channels, speed and accelerations.

A status line shows rates, frames lost, CRC errors, buffer fill and elapsed time; with a
wheel and a body channel, two more lines show the on-line estimate (value ± relative
standard deviation and information in bits per parameter) and the advice for the driver,
whole. On a terminal the lines are redrawn every 0.5 s; in a log, one line every 5 s. Ctrl-C
(or SIGTERM, or --duration) stops cleanly. The file is flushed every 0.5 s, can be read
while it grows, and a killed recorder loses at most the last second. If the disk fills
up, the recording stops with a message and everything written before is kept.
"""

from __future__ import annotations

import argparse
import signal
import sys
import time
from pathlib import Path

from fielddiag.commands.identify import arg_position
from fielddiag.errors import FieldDiagError
from fielddiag.validate import arg_int, arg_number


class _StopRequests:
    """Ctrl-C and SIGTERM while recording: requests to stop, answered by the recording
    loop, which then closes the session. The handler raises nothing: an exception raised
    wherever the main thread happens to be (starting a thread, writing the status line)
    is not a clean stop, and a later Ctrl-C while the session closes is only counted."""

    def __init__(self) -> None:
        self.count = 0
        self._saved: dict[int, object] = {}

    def __call__(self, signum: int, frame: object) -> None:
        self.count += 1

    def install(self) -> None:
        for sig in (signal.SIGINT, signal.SIGTERM):  # SIGINT also when in the background
            self._saved[sig] = signal.signal(sig, self)

    def restore(self) -> None:
        for sig, handler in self._saved.items():
            signal.signal(sig, handler)
        self._saved.clear()


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "record",
        help="record a DAQ (serial) and CAN sources into a session file",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "--daq",
        metavar="URL",
        help="DAQ source: serial://PORT?baud=921600 or serial+ascii://PORT?baud=115200",
    )
    p.add_argument(
        "--can",
        metavar="URL",
        action="append",
        default=[],
        help="CAN source: can://INTERFACE/CHANNEL?dbc=FILE or canlog://FILE?dbc=FILE "
        "(repeatable; the n-th is stored as bus n)",
    )
    p.add_argument(
        "--signal",
        metavar="NAME",
        action="append",
        default=[],
        help="DBC signal to decode and store: SIGNAL, MESSAGE.SIGNAL or "
        "ALIAS=MESSAGE.SIGNAL (repeatable; stored in SI: km/h -> m/s, deg -> rad, rpm -> "
        "rad/s...); the aliases vehicle_speed, accel_long (forward positive) and accel_lat (left "
        "positive) give the signal that role",
    )
    p.add_argument(
        "--role",
        metavar="ROLE=CHANNEL",
        action="append",
        default=[],
        help="which DAQ channel (number from 0) is which sensor, e.g. wheel_fl=0 "
        "(repeatable; unmapped channels are kept as other). A full vehicle maps all eight: "
        "wheel_fl, body_fl, wheel_fr, body_fr, wheel_rl, body_rl, wheel_rr, body_rr",
    )
    p.add_argument(
        "--vehicle-file",
        metavar="VEHICLE.json",
        default=None,
        help="full vehicle: wheelbase_m, track_front_m, track_rear_m and body_sensors "
        "positions (see docs/full-vehicle.md)",
    )
    p.add_argument(
        "--added-mass-at",
        type=arg_position,
        metavar="X_M,Y_M",
        default=None,
        help="full vehicle: where the added mass sits, metres behind the front axle and "
        "left of the centre line",
    )
    p.add_argument(
        "--full-vehicle",
        action="store_true",
        help="with --virtual: a simulated full vehicle (eight accelerometers, speed and "
        "accelerations on CAN)",
    )
    p.add_argument(
        "--speed-signal",
        metavar="NAME",
        default=None,
        help="which decoded signal is the vehicle speed (default: found by name)",
    )
    p.add_argument(
        "--virtual",
        action="store_true",
        help="record a simulated car through the virtual DAQ and ECU (no --daq/--can)",
    )
    p.add_argument(
        "--seed",
        type=arg_int("--seed", 0, 2**32 - 1, "a random seed"),
        default=0,
        help="with --virtual: seed of the simulated road, speed and noise",
    )
    p.add_argument("-o", "--output", required=True, metavar="SESSION.h5", help="file to create")
    p.add_argument(
        "--duration",
        type=arg_number("--duration", "record_duration"),
        default=None,
        metavar="S",
        help="stop after S seconds (default: Ctrl-C)",
    )
    p.add_argument(
        "--added-mass",
        type=arg_number("--added-mass", "session_added_mass"),
        default=0.0,
        metavar="KG",
        help="mass added on the body for this drive (0 = as the car is)",
    )
    p.add_argument("--vehicle", default="", metavar="NAME")
    p.add_argument("--corner", default="", metavar="NAME", help="e.g. front-left")
    p.add_argument("--operator", default="", metavar="NAME")
    p.add_argument("--notes", default="", metavar="TEXT")
    p.add_argument("--overwrite", action="store_true", help="replace an existing file")
    p.add_argument("--quiet", action="store_true", help="no status line")
    p.add_argument(
        "--no-online",
        action="store_true",
        help="do not estimate stiffness and damping on-line while recording",
    )
    p.add_argument(
        "--status-interval",
        type=arg_number("--status-interval", "interval"),
        default=None,
        metavar="S",
        help="seconds between status lines (0.5 on a terminal, else 5)",
    )
    p.set_defaults(func=run)


def full_vehicle_options(args: argparse.Namespace) -> tuple[dict[int, str], dict]:
    """The channel map (``--role``) and the full-vehicle metadata ``extra``, checked.

    Returns
    -------
    channel_map : dict
        Channel index -> role (empty: the DAQ's own roles).
    extra : dict
        The vehicle file and where the added mass sits (empty: not a full vehicle).

    Raises
    ------
    FieldDiagError
        A bad map, a full-vehicle map without a vehicle file (or the reverse), a bad
        vehicle file, an added mass on a full vehicle without its position, a position
        without a full vehicle or without a mass.
    """
    channel_map: dict[int, str] = {}
    full = False
    if args.role or args.vehicle_file:
        if args.virtual:
            raise FieldDiagError("--virtual records the virtual DAQ with its own channels and "
                                 "car: leave out --role and --vehicle-file")
        if not args.daq:
            raise FieldDiagError("--role and --vehicle-file describe a DAQ's channels: give "
                                 "--daq URL")
    if args.full_vehicle and not args.virtual:
        raise FieldDiagError("--full-vehicle is for --virtual; a real DAQ records the full "
                             "vehicle with its channel map (--role wheel_fl=CHANNEL ... "
                             "--vehicle-file VEHICLE.json)")
    if args.role:
        from fielddiag.vehicle.corner_map import is_full_vehicle, parse_channel_map

        channel_map = parse_channel_map(args.role)
        full = is_full_vehicle(channel_map)
        if full and not args.vehicle_file:
            raise FieldDiagError("a full-vehicle recording needs the vehicle file: give "
                                 "--vehicle-file VEHICLE.json (wheelbase, tracks, body-sensor "
                                 "positions)")
    if args.vehicle_file and not full:
        raise FieldDiagError("--vehicle-file is for a full-vehicle recording: map the eight "
                             "sensors with --role wheel_fl=CHANNEL ... --role body_rr=CHANNEL")
    full = full or args.full_vehicle
    if full and args.added_mass > 0 and args.added_mass_at is None:
        raise FieldDiagError(f"--added-mass {args.added_mass:g} on a full vehicle: say where "
                             "it sits with --added-mass-at X_M,Y_M (metres behind the front "
                             "axle, left of the centre line)")
    if args.added_mass_at is not None and not full:
        raise FieldDiagError("--added-mass-at is for a full-vehicle recording (--role "
                             "wheel_fl=CHANNEL ... --vehicle-file, or --virtual --full-vehicle)")
    if args.added_mass_at is not None and args.added_mass <= 0:
        raise FieldDiagError("--added-mass-at says where the added mass sits: give "
                             "--added-mass KG too (or leave --added-mass-at out for the drive "
                             "as the car is)")
    extra: dict = {}
    if full and not args.virtual:
        from fielddiag.vehicle.geometry import load_vehicle
        from fielddiag.vehicle.recording import full_vehicle_extra

        extra = full_vehicle_extra(load_vehicle(args.vehicle_file), args.added_mass_at)
    return channel_map, extra


def build_sources(args: argparse.Namespace, channel_map: dict[int, str] | None = None
                  ) -> list:
    """The sources named on the command line, configured (not opened).

    ``channel_map`` (channel index -> role, from ``--role``) is given to the DAQ source,
    which applies it once the device has said how many channels it has.
    """
    from drivers.base import open_source, parse_source_url
    from drivers.can_vehicle import CanBusSource, _CanSource

    if not args.daq and not args.can:
        raise FieldDiagError("nothing to record: give --daq URL and/or --can URL")
    sources = []
    if args.daq:
        src = open_source(args.daq)
        if src.kind != "daq":
            raise FieldDiagError(f"--daq {args.daq} is not a DAQ source; use --can for CAN")
        if channel_map:
            if not hasattr(src, "role_map"):
                raise FieldDiagError(f"--daq {args.daq}: this source takes no channel map "
                                     "(--role); use the device's own roles")
            src.role_map = dict(channel_map)
        sources.append(src)
    for i, url in enumerate(args.can):
        src = open_source(url)
        if not isinstance(src, _CanSource):
            raise FieldDiagError(f"--can {url} is not a CAN source (can:// or canlog://)")
        src.add_signals(args.signal)
        if args.speed_signal:
            src.speed_signal = args.speed_signal
        if isinstance(src, CanBusSource) and "bus" not in parse_source_url(url).params:
            src.bus_index = i
        sources.append(src)
    if args.signal and not args.can:
        raise FieldDiagError("--signal needs a --can source with a DBC")
    return sources


def run(args: argparse.Namespace) -> int:
    from fielddiag.channels import SessionMetadata
    from fielddiag.outputs import check_target
    from fielddiag.recorder import Recorder

    check_target(args.output, overwrite=args.overwrite)
    channel_map, extra = full_vehicle_options(args)
    vehicle = args.vehicle
    if extra and not vehicle:
        vehicle = Path(args.vehicle_file).stem
    meta = SessionMetadata(
        vehicle=vehicle,
        corner=args.corner,
        operator=args.operator,
        added_mass_kg=args.added_mass,
        notes=args.notes,
        extra=extra,
    )
    rec, run_ = None, None
    if args.virtual:
        run_ = virtual_drive(args, meta)
    else:
        rec = Recorder(args.output, build_sources(args, channel_map), metadata=meta,
                       overwrite=args.overwrite)
    requests = _StopRequests()
    if threading_main():
        requests.install()
    try:
        return _record(args, rec, run_, requests, full_vehicle=bool(extra))
    finally:
        requests.restore()


def _load_online_estimator() -> None:
    """Import and compile the on-line estimator (about 3 s the first time in a process).

    A failure is left for :meth:`Recorder.attach_online_estimator` to report."""
    try:
        from fielddiag.identify.online import OnlineEstimator

        OnlineEstimator(200.0).warm_up()
    except Exception:
        pass


def _record(args: argparse.Namespace, rec, run_, requests: _StopRequests, *,
            full_vehicle: bool = False) -> int:
    """Start, record until the end or a stop request, close; print the summary."""
    from fielddiag.console import StatusPrinter, status_lines

    # the virtual drive attaches its own; a full vehicle has no single corner to estimate
    online = run_ is None and not args.no_online and not full_vehicle
    if run_ is not None:
        rec = run_.start().recorder  # the on-line estimator is attached already
        stop = run_.stop_or_raise
    else:
        if online and not requests.count:
            # compiled before the sources start: loading it (imports, numba) beside a
            # running source thread held the reader up by up to 0.2 s a block
            if sys.stderr.isatty():
                print("loading the on-line estimator...", file=sys.stderr, flush=True)
            _load_online_estimator()
        rec.start()
        stop = rec.stop
    tty = sys.stderr.isatty()
    interval = args.status_interval or (0.5 if tty else 5.0)
    printer = StatusPrinter(sys.stderr, terminal=tty)
    try:  # from here on, Ctrl-C stops the recording cleanly
        if online:
            rec.attach_online_estimator()  # compiled already: attached at once
        chans = ", ".join(f"{c.name} ({c.role})" for c in rec.channels) or "none"
        sigs = ", ".join(s.name for s in rec.signals) or "none"
        print(
            f"recording to {args.output}\n  channels: {chans}\n  signals: {sigs}\n"
            + "".join(f"  warning: {w}\n" for w in missing_vehicle_signals(rec))
            + "  Ctrl-C to stop",
            file=sys.stderr,
            flush=True,
        )
        next_status = time.monotonic() + interval
        while rec.running and not requests.count:
            if args.duration is not None and rec.clock.now() >= args.duration:
                break
            time.sleep(0.1)
            if not args.quiet and time.monotonic() >= next_status:
                printer.show(rec.status())
                next_status += interval
    except KeyboardInterrupt:  # Ctrl-C where no handler could be installed
        pass
    finally:
        try:
            final = stop()
        finally:
            printer.finish()
    if "online" in final:
        print("\n".join(status_lines(final)[1:]), file=sys.stderr)
    print(
        f"stopped after {final['elapsed_s']:.1f} s: {final['samples']} samples, "
        f"{final['frames_received']} frames, {final['frames_lost']} lost, "
        f"{final['crc_errors']} CRC errors, {final['gaps']} gaps, "
        f"{final['can_frames_received']} CAN frames -> {args.output}",
        file=sys.stderr,
    )
    return 0


def missing_vehicle_signals(rec: object) -> list[str]:
    """Warnings for a full-vehicle recording without the speed or the car's accelerations."""
    if not any(c.role.startswith(("wheel_", "body_")) for c in rec.channels):
        return []  # not a full vehicle (and fielddiag.vehicle is not worth importing)
    from fielddiag.vehicle.recording import VEHICLE_SIGNAL_ROLES

    have = {s.role for s in rec.signals}
    alias = {"speed": "vehicle_speed"}
    return [f"no CAN signal with role {r}: the full-vehicle identification takes it as 0; "
            f"record it with --signal {alias.get(r, r)}=MESSAGE.SIGNAL"
            for r in VEHICLE_SIGNAL_ROLES if r not in have]


def virtual_drive(args: argparse.Namespace, meta: object):
    """The :class:`fielddiag.virtual_drive.VirtualDrive` of ``--virtual`` (not started)."""
    from fielddiag.virtual_drive import LOOP_DRIVE_S, VirtualDrive

    if args.daq or args.can or args.signal or args.speed_signal:
        raise FieldDiagError("--virtual records the virtual DAQ and ECU: give it without "
                             "--daq, --can, --signal and --speed-signal")
    once = args.duration is not None
    return VirtualDrive(
        args.output, drive_s=args.duration + 2.0 if once else LOOP_DRIVE_S, loop=not once,
        metadata=meta, seed=args.seed, online=not (args.no_online or args.full_vehicle),
        full_vehicle=args.full_vehicle, added_mass_at_m=args.added_mass_at,
        overwrite=args.overwrite)


def threading_main() -> bool:
    import threading

    return threading.current_thread() is threading.main_thread()
