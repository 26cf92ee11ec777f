"""``fielddiag ports [--json]``: serial ports a DAQ may be plugged into."""

from __future__ import annotations

import argparse
import json


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "ports",
        help="list serial ports (and running virtual DAQs/ECUs) to record from",
        description=(
            "List the serial ports a DAQ may be plugged into (pyserial's list_ports), and "
            "the links of running `fielddiag virtual-daq` / `virtual-ecu` devices. Record "
            "from one with `fielddiag record --daq serial://PORT -o drive.h5`."
        ),
    )
    p.add_argument("--json", action="store_true", help="print JSON for scripts")
    p.add_argument(
        "--no-virtual", action="store_true", help="do not list virtual devices"
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from drivers.serial_daq import list_ports

    ports = list_ports(include_virtual=not args.no_virtual)
    if args.json:
        print(json.dumps(ports, indent=2))
        return 0
    if not ports:
        print(
            "no serial ports found: plug the DAQ in (USB), check `dmesg` for the device, "
            "and on Linux that you are in the 'dialout' group"
        )
        return 0
    for p in ports:
        ids = ""
        if p["vid"] is not None:
            ids = f" [{p['vid']:04x}:{p['pid']:04x}]"
        sn = f" serial {p['serial_number']}" if p.get("serial_number") else ""
        print(f"{p['device']:<40} {p['description']}{ids}{sn}")
        if p["manufacturer"] == "fielddiag":
            scheme = "serial://" if "VDAQ" in p["device"] else "can://slcan/"
            print(f"{'':<40} use {scheme}{p['device']}")
    return 0
