"""``fielddiag demo``: the main job end to end with no hardware.

1. Records two drives of a simulated car through the virtual devices: the virtual DAQ on
   a pseudo-terminal read by the real serial driver, the virtual ECU on a python-can bus
   read by the real CAN driver. One drive is the car as it is, one with a mass added to
   the body. (Both are recorded at once to save your time; a technician records them one
   after the other.) The demo car hides dry friction in its strut.
2. Identifies sprung mass, stiffness and damping from the pair.
3. Diagnoses the pair: locates the mismatch and names the physics the linear model missed.
4. Serves the dashboard over the demo's sessions (``--no-serve`` to skip).

Every run writes into a new folder, so nothing from an earlier run is ever overwritten.
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time
from pathlib import Path

from fielddiag.validate import arg_int, arg_number

DEFAULT_ADDED_MASS_KG = 60.0
#: Shortest drive the demo records: the identification needs 30 s of data, and a drive
#: recorded for 30 s holds slightly less (the first frames arrive after the start).
MIN_DURATION_S = 32.0
DEFAULT_DURATION_S = 120.0
#: The full vehicle's: its identification needs 40 s of each drive
#: (``VehicleIdentifyConfig.min_duration_s``), plus the same margin.
FULL_VEHICLE_MIN_DURATION_S = 42.0
FULL_VEHICLE_DURATION_S = 60.0
#: The demo car's hidden physics: dry friction in the strut (concealed: the linear model
#: alone fits its body acceleration well by eye).
DEMO_EFFECTS = (("coulomb_friction", {"friction_force_n": 70.0}),)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "demo", help="record, identify and diagnose a simulated car, no hardware needed"
    )
    p.add_argument("--out", default="fielddiag-demo", help="folder for the demo's runs")
    p.add_argument("--duration", type=arg_number("--duration", "sim_duration"),
                   default=None, metavar="S",
                   help=f"length of each recorded drive (real time, the drives are recorded "
                        f"at once; default {DEFAULT_DURATION_S:g}, at least {MIN_DURATION_S:g}; "
                        f"with --full-vehicle default {FULL_VEHICLE_DURATION_S:g}, at least "
                        f"{FULL_VEHICLE_MIN_DURATION_S:g})")
    p.add_argument("--added-mass", type=arg_number("--added-mass", "added_mass"),
                   default=None, metavar="KG",
                   help=f"mass added on the body for the second drive (default "
                        f"{DEFAULT_ADDED_MASS_KG:g} kg, 150 kg with --full-vehicle)")
    p.add_argument("--full-vehicle", action="store_true",
                   help="a whole car (eight accelerometers) with a worn rear-left damper and "
                        "friction in the front-left strut: identify the body and the corners, "
                        "diagnose each corner")
    p.add_argument("--seed", type=arg_int("--seed", 0, 2**32 - 1, "a random seed"),
                   default=1, help="random seed of the demo car's roads")
    p.add_argument("--no-serve", action="store_true", help="do not start the dashboard at the end")
    p.add_argument("--port", type=arg_int("--port", 1, 65535, "a TCP port"),
                   default=8080, help="dashboard port (default 8080)")
    p.set_defaults(func=run)


def _new_run_dir(root: Path) -> Path:
    root.mkdir(parents=True, exist_ok=True)
    stamp = time.strftime("%Y%m%d-%H%M%S")
    run = root / f"run-{stamp}"
    k = 1
    while run.exists():
        k += 1
        run = root / f"run-{stamp}-{k}"
    run.mkdir()
    return run


#: Transmit buffer of the demo's virtual DAQs [bytes]: about a minute of an 8-channel
#: drive. The virtual devices run in the recording process, so when a busy machine starves
#: that process for seconds, a device catches up in one burst that a 64 kB buffer (the
#: fault-injection default) would drop; a demo shows the analysis, not that overload.
DEMO_TX_BUFFER_BYTES = 1 << 20


def record_drives(run_dir: Path, drives: dict[str, dict], duration_s: float) -> list[Path]:
    """Record drives at once through the virtual devices, showing their progress.

    Parameters
    ----------
    run_dir : Path
        Folder of the sessions (``<label>.h5``).
    drives : dict
        Label -> keyword arguments of :func:`fielddiag.virtual_drive.record_virtual_drive`
        (each drive on its own pseudo-terminal and CAN bus); the DAQs buffer
        :data:`DEMO_TX_BUFFER_BYTES` unless the drive's ``faults`` say otherwise.
    duration_s : float
        Length of each recording [s] (real time).

    Returns
    -------
    list of Path
        The sessions, in the order of ``drives``.

    Raises
    ------
    FieldDiagError
        The first recording that failed (the others are finished first).
    """
    from fielddiag.virtual_drive import record_virtual_drive

    status: dict[str, dict] = {}
    results: dict[str, Path] = {}
    errors: list[BaseException] = []

    def worker(label: str) -> None:
        kwargs = dict(drives[label])
        kwargs["faults"] = {"tx_buffer_bytes": DEMO_TX_BUFFER_BYTES, **(kwargs.get("faults") or {})}
        try:
            results[label] = record_virtual_drive(
                run_dir / f"{label}.h5", duration_s=duration_s,
                progress=lambda st: status.__setitem__(label, st), **kwargs)
        except BaseException as exc:  # reported by the main thread
            errors.append(exc)

    threads = [threading.Thread(target=worker, args=(label,), daemon=True) for label in drives]
    for t in threads:
        t.start()
    tty = sys.stdout.isatty()
    last = 0.0
    while any(t.is_alive() for t in threads):
        time.sleep(0.25)
        if time.monotonic() - last < (0.5 if tty else 10.0):
            continue
        last = time.monotonic()
        parts = []
        for label in drives:
            st = status.get(label, {})
            parts.append(
                f"{label}: {st.get('elapsed_s', 0.0):5.1f}/{duration_s:g} s, "
                f"{st.get('frames_received', 0)} frames, {st.get('frames_lost', 0)} lost"
            )
        line = "  recording  " + " | ".join(parts)
        print(("\r" + line) if tty else line, end="" if tty else "\n", flush=True)
    if tty:
        print()
    for t in threads:
        t.join()
    if errors:
        raise errors[0]
    return [results[label] for label in drives]


def _record_pair(run_dir: Path, args: argparse.Namespace) -> list[Path]:
    """Record before and after concurrently through the virtual devices, with progress."""
    from fielddiag import sim

    effects = [sim.make_effect(n, **p) for n, p in DEMO_EFFECTS]
    common = {"vehicle": "demo car", "corner": "front-left", "effects": effects,
              "include_recipe": False}
    return record_drives(run_dir, {
        label: {"added_mass_kg": mass, "seed": seed, **common,
                "notes": f"demo drive {label}, {args.added_mass:g} kg added for 'after'"}
        for label, mass, seed in (("before", 0.0, args.seed),
                                  ("after", args.added_mass, args.seed + 1))
    }, args.duration)


def _store_beside_sessions(result: dict, kind: str, sessions: list[Path]) -> None:
    """Write a result where the dashboard finds it: ``<stem>.<kind>.json`` beside each
    session of the pair (the catalog then lists both drives as processed, and the
    identification and diagnosis pages show it for either)."""
    from fielddiag.catalog import result_path

    text = json.dumps(result, indent=1)
    for session in sessions:
        result_path(session, kind).write_text(text, encoding="utf-8")


def run(args: argparse.Namespace) -> int:
    from fielddiag.errors import FieldDiagError

    shortest = FULL_VEHICLE_MIN_DURATION_S if args.full_vehicle else MIN_DURATION_S
    if args.duration is None:
        args.duration = FULL_VEHICLE_DURATION_S if args.full_vehicle else DEFAULT_DURATION_S
    if args.duration < shortest:
        raise FieldDiagError(
            f"--duration {args.duration:g}: give at least {shortest:g} s; the "
            f"identification needs {shortest - 2:g} s of each drive, and a recording holds a "
            "little less than it ran for")
    if args.full_vehicle:
        from fielddiag.commands._demo_vehicle import DEFAULT_ADDED_MASS_KG as full_kg
        from fielddiag.commands._demo_vehicle import run_full_vehicle

        if args.added_mass is None:
            args.added_mass = full_kg
        run_dir = _new_run_dir(Path(args.out))
        print(f"fielddiag demo --full-vehicle: writing into {run_dir}")
        return run_full_vehicle(args, run_dir)
    if args.added_mass is None:
        args.added_mass = DEFAULT_ADDED_MASS_KG
    from fielddiag.identify import identify_sessions
    from fielddiag.plots import write_identify_plots

    run_dir = _new_run_dir(Path(args.out))
    print(f"fielddiag demo: writing into {run_dir}")
    print(
        f"1/4 recording two {args.duration:g} s drives through the virtual DAQ (pseudo-"
        f"terminal) and virtual ECU (CAN): as the car is, and with {args.added_mass:g} kg "
        "on the body"
    )
    t0 = time.perf_counter()
    before, after = _record_pair(run_dir, args)
    print(f"    recorded {before.name} and {after.name} in {time.perf_counter() - t0:.0f} s")

    print("2/4 identifying sprung mass, stiffness and damping")
    ident = identify_sessions(before, after, added_mass_kg=args.added_mass)
    print("    " + ident.summary().replace("\n", "\n    "))
    _store_beside_sessions(ident.to_dict(), "identify", [before, after])
    write_identify_plots(ident, run_dir / "plots")

    print("3/4 diagnosing: where does the linear model miss, and why?")
    from fielddiag.diagnose.engine import diagnose_sessions
    from fielddiag.diagnose.report import format_summary
    from fielddiag.plots.diagnose import write_diagnosis_plots

    diag = diagnose_sessions([before, after], added_mass_kg=args.added_mass)
    out = diag.to_dict()
    _store_beside_sessions({"session_paths": [before.name, after.name], **out}, "diagnose",
                           [before, after])
    write_diagnosis_plots(diag, run_dir / "plots")
    print("    " + format_summary(out).replace("\n", "\n    "))
    print(
        "    (the demo car has dry friction of "
        f"{DEMO_EFFECTS[0][1]['friction_force_n']:g} N in its strut)"
    )
    print(f"    results beside each drive in {run_dir} (before.identify.json, "
          f"before.diagnose.json...), plots in {run_dir / 'plots'}")
    if args.no_serve:
        print("4/4 dashboard skipped (--no-serve); start it with "
              f"`fielddiag serve --root {Path(args.out)}`")
        return 0
    from fielddiag.web.app import serve

    print("4/4 serving the dashboard over the demo's runs (Ctrl-C to stop)", flush=True)
    serve(Path(args.out), host="127.0.0.1", port=args.port,
          print_address=lambda line: print(line, flush=True))
    return 0
