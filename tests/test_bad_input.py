"""Bad input and faults, each as a real ``fielddiag`` subprocess (issue 14).

Every case must exit with status 1 and print exactly one line on stderr that names the value
or file and says what to do, with no traceback; nothing may be left behind in the output
folder (no temporary, ``.partial`` or 0-byte file, no empty plot folder), and the input files
must be unchanged (hashed before and after).

Real faults, not mocks: a read-only file system is a read-only tmpfs, a full disk is a tmpfs
of a few kB (one per case, so that cases cannot fill each other's disk), unwritable paths
are under /proc, and the device node is a /dev/full made with mknod in the case's folder
(never the machine's own: a faulty ``--overwrite`` would replace it). Mounting and mknod
need root; without it those cases are skipped and say so.

The cases run concurrently (three at a time) once per module, so that 140 subprocesses take
about a minute; each test then checks one case's recorded outcome.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import re
import shutil
import stat
import subprocess
import sys
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest

from fielddiag import sim
from fielddiag.channels import ChannelSpec, SessionMetadata
from fielddiag.cli import main
from fielddiag.session import SessionReader, write_session
from fielddiag.simio import drive_to_session

#: A tiny tmpfs: any result file or plot fills it (a probe file of 0 bytes still fits).
FULL_DISK_SIZE = "8k"
#: Longest a case may take: a hang is a failure, not a stuck test run.
CASE_TIMEOUT_S = 120.0
#: The line says what to do: a verb of instruction.
SAYS_WHAT_TO_DO = re.compile(
    r"\b(give|choose|pass|create|free|use|write|name|record|re-import|re-record|fix|remove|"
    r"export|check|cut|fill|sort|say|map|delete|install|see|save)\b", re.I)


@dataclasses.dataclass(frozen=True)
class Case:
    """One bad input: the arguments (``{B}``, ``{A}``, ``{OUT}``... are filled in), the
    fragments the error line must contain, and an optional set-up of the output folder."""

    id: str
    args: tuple[str, ...]
    expect: tuple[str, ...] = ()
    setup: Callable[[Path, dict], None] | None = None
    #: fill the tiny tmpfs before the run (results smaller than its few kB must fail too)
    fill: bool = False

    @property
    def needs_full(self) -> bool:
        return any("{FULL}" in a for a in self.args)

    @property
    def needs_mounts(self) -> bool:
        return self.needs_full or any("{RO}" in a for a in self.args)


def C(id_: str, *args: str, expect: tuple[str, ...] | str = (), setup=None,
      fill: bool = False) -> Case:
    return Case(id_, tuple(args), (expect,) if isinstance(expect, str) else tuple(expect),
                setup, fill)


# ------------------------------------------------------------------ set-ups of output folders
def _existing_csv(out: Path, ws: dict) -> None:
    (out / "x.csv").write_text("keep me\n")


def _existing_session(out: Path, ws: dict) -> None:
    shutil.copy(ws["B"], out / "old.h5")


def _existing_output_session(out: Path, ws: dict) -> None:
    shutil.copy(ws["B"], out / "s.h5")


def _link_to_device(out: Path, ws: dict) -> None:
    (out / "link.csv").symlink_to("full_dev")  # made by the run, as for {DEV}


def _folder_named_csv(out: Path, ws: dict) -> None:
    (out / "dir.csv").mkdir()


def _file_named_plots(out: Path, ws: dict) -> None:
    (out / "plots").write_text("a file, not a folder\n")


# ----------------------------------------------------------------------------- the cases
BA = ("{B}", "{A}")
MASS_VALUES = [("nan", "nan"), ("inf", "inf"), ("neginf", "-inf"), ("1e12", "1e12"),
               ("negative", "-5"), ("zero", "0"), ("text", "abc"), ("over2000", "2001")]
CSV_ROLES = ("--time", "time_s", "--role", "wheel=wheel", "--role", "body=body")

CASES: list[Case] = []
for cmd in ("identify", "diagnose", "fit"):
    for name, value in MASS_VALUES:
        CASES.append(C(f"{cmd}-added-mass-{name}", cmd, *BA, f"--added-mass={value}",
                       expect=(f"--added-mass {value}", "kg", "between 0 and 2000")
                       if name != "zero" else ("--added-mass 0", "kg")))
CASES += [
    # ---------------------------------------------------------- numbers given as options
    C("import-added-mass-nan", "import", "{CSV}", "-o", "{OUT}/s.h5", *CSV_ROLES,
      "--added-mass", "nan", expect=("--added-mass nan", "kg")),
    C("import-added-mass-negative", "import", "{CSV}", "-o", "{OUT}/s.h5", *CSV_ROLES,
      "--added-mass=-1", expect=("--added-mass -1", "kg")),
    C("import-added-mass-1e12", "import", "{CSV}", "-o", "{OUT}/s.h5", *CSV_ROLES,
      "--added-mass", "1e12", expect=("--added-mass 1e12", "kg")),
    C("import-added-mass-inf", "import", "{CSV}", "-o", "{OUT}/s.h5", *CSV_ROLES,
      "--added-mass", "inf", expect=("--added-mass inf", "kg")),
    C("record-duration-zero", "record", "--daq", "serial:///dev/null", "-o", "{OUT}/r.h5",
      "--duration", "0", expect=("--duration 0", " s,")),
    C("record-duration-negative", "record", "--daq", "serial:///dev/null", "-o", "{OUT}/r.h5",
      "--duration=-1", expect=("--duration -1", " s,")),
    C("record-duration-nan", "record", "--daq", "serial:///dev/null", "-o", "{OUT}/r.h5",
      "--duration", "nan", expect=("--duration nan", " s,")),
    C("record-duration-inf", "record", "--daq", "serial:///dev/null", "-o", "{OUT}/r.h5",
      "--duration", "inf", expect="--duration inf"),
    C("record-added-mass-nan", "record", "--daq", "serial:///dev/null", "-o", "{OUT}/r.h5",
      "--added-mass", "nan", expect=("--added-mass nan", "kg")),
    C("record-added-mass-negative", "record", "--daq", "serial:///dev/null", "-o",
      "{OUT}/r.h5", "--added-mass=-3", expect=("--added-mass -3", "kg")),
    C("record-status-interval-zero", "record", "--daq", "serial:///dev/null", "-o",
      "{OUT}/r.h5", "--status-interval", "0", expect="--status-interval 0"),
    C("simulate-duration-zero", "simulate", "-o", "{OUT}/s.h5", "--duration", "0",
      expect="--duration 0"),
    C("simulate-duration-negative", "simulate", "-o", "{OUT}/s.h5", "--duration=-1",
      expect="--duration -1"),
    C("simulate-duration-nan", "simulate", "-o", "{OUT}/s.h5", "--duration", "nan",
      expect="--duration nan"),
    C("simulate-rate-zero", "simulate", "-o", "{OUT}/s.h5", "--rate", "0",
      expect=("--rate 0", "Hz")),
    C("simulate-rate-nan", "simulate", "-o", "{OUT}/s.h5", "--rate", "nan",
      expect=("--rate nan", "Hz")),
    C("simulate-rate-1e9", "simulate", "-o", "{OUT}/s.h5", "--rate", "1e9",
      expect=("--rate 1e9", "Hz")),
    C("simulate-added-mass-nan", "simulate", "-o", "{OUT}/s.h5", "--added-mass", "nan",
      expect=("--added-mass nan", "kg")),
    C("simulate-added-mass-negative", "simulate", "-o", "{OUT}/s.h5", "--added-mass=-1",
      expect=("--added-mass -1", "kg")),
    C("simulate-snr-nan", "simulate", "-o", "{OUT}/s.h5", "--snr-db", "nan",
      expect=("--snr-db nan", "dB")),
    C("simulate-seed-negative", "simulate", "-o", "{OUT}/s.h5", "--seed=-1",
      expect="--seed -1"),
    C("simulate-car-nan", "simulate", "-o", "{OUT}/s.h5", "--car", "body_mass_kg=nan",
      expect="--car body_mass_kg=nan"),
    C("simulate-param-nan", "simulate", "-o", "{OUT}/s.h5", "--effect", "coulomb_friction",
      "--param", "friction_force_n=nan", expect="friction_force_n=nan"),
    C("identify-band-nan", "identify", *BA, "--band", "nan", "30", expect=("--band nan", "Hz")),
    C("identify-band-reversed", "identify", *BA, "--band", "30", "0.5",
      expect=("--band 30 0.5", "low edge first")),
    C("identify-band-zero", "identify", *BA, "--band", "0", "30", expect=("--band 0", "Hz")),
    C("identify-band-1e6", "identify", *BA, "--band", "0.5", "1e6",
      expect=("--band 1e6", "Hz")),
    C("identify-band-negative", "identify", *BA, "--band=-1", "5", expect="--band"),
    C("identify-loops-nan", "identify", *BA, "--loops", "nan", expect=("--loops nan", "Hz")),
    C("identify-loops-zero", "identify", *BA, "--loops", "0", expect=("--loops 0", "Hz")),
    C("fit-band-reversed", "fit", *BA, "--band", "30", "0.5", expect="--band 30 0.5"),
    C("fit-holdout-0.95", "fit", *BA, "--holdout", "0.95", expect="--holdout 0.95"),
    C("fit-holdout-nan", "fit", *BA, "--holdout", "nan", expect="--holdout nan"),
    C("fit-end-before-start", "fit", *BA, "--start", "10", "--end", "5",
      expect=("--end 5", "--start 10")),
    C("fit-body-mass-negative", "fit", *BA, "--body-mass=-100",
      expect=("--body-mass -100", "kg")),
    C("fit-max-iterations-zero", "fit", *BA, "--max-iterations", "0",
      expect="--max-iterations 0"),
    C("fit-terms-unknown", "fit", *BA, "--terms", "warp_drive", expect="--terms warp_drive"),
    C("track-every-zero", "track", "{B}", "--every", "0", expect="--every 0"),
    C("track-block-nan", "track", "{B}", "--block", "nan", expect="--block nan"),
    C("track-cutoff-negative", "track", "{B}", "--cutoff=-1", expect=("--cutoff -1", "Hz")),
    C("demo-duration-nan", "demo", "--out", "{OUT}/demo", "--duration", "nan",
      expect="--duration nan"),
    C("demo-duration-short", "demo", "--out", "{OUT}/demo", "--duration", "10",
      "--no-serve", expect=("--duration 10", "32 s")),
    C("demo-port-zero", "demo", "--out", "{OUT}/demo", "--port", "0", expect="--port 0"),
    C("serve-port-70000", "serve", "--port", "70000", expect="--port 70000"),
    C("serve-upload-nan", "serve", "--max-upload-mb", "nan", expect=("--max-upload-mb nan",
                                                                    "MB")),
    C("reprocess-workers-zero", "reprocess", "{WS}", "--workers", "0", expect="--workers 0"),
    C("reprocess-max-apart-nan", "reprocess", "{WS}", "--max-apart-h", "nan",
      expect="--max-apart-h nan"),
    C("virtual-daq-rate-zero", "virtual-daq", "--rate", "0", expect="--rate 0"),
    C("virtual-daq-corrupt-2", "virtual-daq", "--corrupt", "2", expect="--corrupt 2"),
    C("virtual-daq-channels-zero", "virtual-daq", "--channels", "0", expect="--channels 0"),
    C("virtual-ecu-speed-negative", "virtual-ecu", "--speed-kmh=-5",
      expect=("--speed-kmh -5", "km/h")),
    # ------------------------------------------------------------------- input paths
    C("identify-missing-session", "identify", "{WS}/missing.h5", "{A}",
      expect=("missing.h5", "does not exist")),
    C("identify-folder-as-session", "identify", "{WS}", "{A}", expect="is a folder"),
    C("identify-device-as-session", "identify", "/dev/zero", "{A}",
      expect=("/dev/zero", "not a regular file")),
    C("diagnose-missing-session", "diagnose", "{B}", "{WS}/missing.h5",
      expect="missing.h5"),
    C("diagnose-three-sessions", "diagnose", "{B}", "{A}", "{B}", expect="give one session"),
    C("fit-missing-session", "fit", "{WS}/missing.h5", expect="missing.h5"),
    C("fit-missing-validate", "fit", "{B}", "--validate", "{WS}/missing.h5",
      expect="missing.h5"),
    C("ride-folder", "ride", "{WS}", expect="is a folder"),
    C("export-missing-session", "export", "{WS}/missing.h5", "-o", "{OUT}/x.csv",
      expect="missing.h5"),
    C("track-missing-session", "track", "{WS}/missing.h5", expect="missing.h5"),
    C("info-missing-session", "info", "{WS}/missing.h5", expect="missing.h5"),
    # ----------------------------------------------------------- outputs that cannot be
    C("identify-json-proc", "identify", *BA, "--json", "/proc/x.json", expect="/proc/x.json"),
    C("identify-json-readonly", "identify", *BA, "--json", "{RO}/x.json",
      expect=("x.json", "read-only")),
    C("identify-json-no-folder", "identify", *BA, "--json", "{OUT}/none/x.json",
      expect=("none", "does not exist")),
    C("identify-json-device", "identify", *BA, "--json", "{DEV}",
      expect=("full_dev", "device")),
    C("identify-json-folder", "identify", *BA, "--json", "{OUT}", expect="is a folder"),
    C("identify-plots-readonly", "identify", *BA, "--plots", "{RO}/plots",
      expect="read-only"),
    C("identify-plots-is-file", "identify", *BA, "--plots", "{OUT}/plots",
      expect=("plots", "must name a folder"), setup=_file_named_plots),
    C("diagnose-json-proc", "diagnose", *BA, "--json", "/proc/x.json", expect="/proc/x.json"),
    C("diagnose-json-readonly", "diagnose", *BA, "--json", "{RO}/x.json",
      expect="read-only"),
    C("diagnose-json-device", "diagnose", *BA, "--json", "{DEV}", expect="device"),
    C("diagnose-plots-readonly", "diagnose", *BA, "--plots", "{RO}/p", expect="read-only"),
    C("fit-json-proc", "fit", *BA, "--json", "/proc/x.json", expect="/proc/x.json"),
    C("fit-json-readonly", "fit", *BA, "--json", "{RO}/x.json", expect="read-only"),
    C("ride-json-readonly", "ride", "{B}", "--json", "{RO}/x.json", expect="read-only"),
    C("ride-plots-proc", "ride", "{B}", "--plots", "/proc/p", expect="/proc/p"),
    C("track-json-readonly", "track", "{B}", "--json", "{RO}/x.json", expect="read-only"),
    C("export-csv-readonly", "export", "{B}", "-o", "{RO}/x.csv",
      expect=("x.csv", "read-only")),
    C("export-mf4-readonly", "export", "{B}", "-o", "{RO}/x.mf4",
      expect=("x.mf4", "read-only")),
    C("export-csv-proc", "export", "{B}", "-o", "/proc/x.csv", expect="/proc/x.csv"),
    C("export-over-session", "export", "{B}", "-o", "{OUT}/old.h5", "--format", "mdf4",
      "--overwrite", expect=("old.h5", "never replaces a session"), setup=_existing_session),
    C("export-over-itself", "export", "{B}", "-o", "{B}", "--format", "csv", "--overwrite",
      expect="never replaces a session"),
    C("export-over-device", "export", "{B}", "-o", "{DEV}", "--format", "csv",
      "--overwrite", expect=("full_dev", "device")),
    C("export-over-link-to-device", "export", "{B}", "-o", "{OUT}/link.csv", "--overwrite",
      expect="device", setup=_link_to_device),
    C("export-over-folder", "export", "{B}", "-o", "{OUT}/dir.csv", "--overwrite",
      expect="folder", setup=_folder_named_csv),
    C("export-existing-no-overwrite", "export", "{B}", "-o", "{OUT}/x.csv",
      expect=("x.csv", "--overwrite"), setup=_existing_csv),
    C("export-unknown-suffix", "export", "{B}", "-o", "{OUT}/x.txt", expect="x.txt"),
    C("export-no-folder", "export", "{B}", "-o", "{OUT}/none/x.csv", expect="does not exist"),
    C("import-readonly", "import", "{CSV}", "-o", "{RO}/s.h5", *CSV_ROLES,
      expect="read-only"),
    C("import-proc", "import", "{CSV}", "-o", "/proc/s.h5", *CSV_ROLES, expect="/proc/s.h5"),
    C("import-over-device", "import", "{CSV}", "-o", "{DEV}", "--overwrite", *CSV_ROLES,
      expect="device"),
    C("import-existing-no-overwrite", "import", "{CSV}", "-o", "{OUT}/s.h5", *CSV_ROLES,
      expect=("s.h5", "--overwrite"), setup=_existing_output_session),
    C("simulate-readonly", "simulate", "-o", "{RO}/s.h5", "--duration", "5",
      expect="read-only"),
    C("simulate-over-device", "simulate", "-o", "{DEV}", "--overwrite", "--duration", "5",
      expect="device"),
    C("record-over-device", "record", "--daq", "serial:///dev/null", "-o", "{DEV}",
      "--overwrite", expect="device"),
    C("record-readonly", "record", "--daq", "serial:///dev/null", "-o", "{RO}/r.h5",
      expect="read-only"),
    # ---------------------------------------------------------------- files imported
    C("import-50MB-single-line", "import", "{WS}/long_line.csv", "-o", "{OUT}/s.h5",
      *CSV_ROLES, expect=("long_line.csv", "header row")),
    C("import-binary", "import", "{WS}/binary.csv", "-o", "{OUT}/s.h5", *CSV_ROLES,
      expect=("binary.csv", "binary")),
    C("import-empty", "import", "{WS}/empty.csv", "-o", "{OUT}/s.h5", *CSV_ROLES,
      expect=("empty.csv", "empty")),
    C("import-header-only", "import", "{WS}/header_only.csv", "-o", "{OUT}/s.h5", *CSV_ROLES,
      expect=("header_only.csv", "two samples")),
    C("import-nan-cell", "import", "{WS}/nan_cell.csv", "-o", "{OUT}/s.h5", *CSV_ROLES,
      expect=("nan_cell.csv row 5", "wheel")),
    C("import-text-cell", "import", "{WS}/text_cell.csv", "-o", "{OUT}/s.h5", *CSV_ROLES,
      expect=("text_cell.csv row 4", "not a number")),
    C("import-time-backwards", "import", "{WS}/backwards.csv", "-o", "{OUT}/s.h5",
      *CSV_ROLES, expect=("backwards.csv row", "goes backwards")),
    C("import-short-row", "import", "{WS}/short_row.csv", "-o", "{OUT}/s.h5", *CSV_ROLES,
      expect=("short_row.csv row 6", "fields")),
    C("import-missing-column", "import", "{CSV}", "-o", "{OUT}/s.h5", "--time", "time_s",
      "--role", "wheel=nope", expect="'nope'"),
    C("import-misspelt-role", "import", "{CSV}", "-o", "{OUT}/s.h5", "--time", "time_s",
      "--role", "whel=wheel", expect="did you mean wheel"),
    C("import-role-no-equals", "import", "{CSV}", "-o", "{OUT}/s.h5", "--time", "time_s",
      "--role", "wheel", expect="ROLE=COLUMN"),
    C("import-missing-file", "import", "{WS}/missing.csv", "-o", "{OUT}/s.h5", *CSV_ROLES,
      expect="missing.csv"),
    C("import-unknown-format", "import", "{CSV}", "-o", "{OUT}/s.h5", "--format", "xls",
      expect="xls"),
    C("import-bad-time-unit", "import", "{CSV}", "-o", "{OUT}/s.h5", *CSV_ROLES,
      "--time-unit", "fortnights", expect="fortnights"),
    C("import-pvs-binary", "import", "{WS}/pvs_binary", "--format", "pvs", "-o",
      "{OUT}/s.h5", expect=("dataset_gps_mpu_left.csv", "not a CSV text file")),
    C("import-mdf-garbage", "import", "{WS}/garbage.mf4", "-o", "{OUT}/s.h5",
      expect=("garbage.mf4", "not an MDF file")),
    C("import-canlog-no-dbc", "import", "{WS}/drive.log", "-o", "{OUT}/s.h5",
      expect="DBC"),
    # ---------------------------------------------------------------- session contents
    C("ride-all-nan", "ride", "{WS}/nan.h5", expect=("nan.h5", "not finite")),
    C("identify-all-nan", "identify", "{WS}/nan.h5", "{A}", "--added-mass", "60",
      expect="nan.h5"),
    C("diagnose-all-nan", "diagnose", "{WS}/nan.h5", "{A}", "--added-mass", "60",
      expect="nan.h5"),
    C("fit-all-nan", "fit", "{WS}/nan.h5", expect="nan.h5"),
    C("track-all-nan", "track", "{WS}/nan.h5", expect="nan.h5"),
    # ------------------------------------------------------- a full disk (real tmpfs)
    C("identify-json-full-disk", "identify", *BA, "--json", "{FULL}/r.json",
      expect=("r.json", "No space left"), fill=True),
    C("identify-plots-full-disk", "identify", *BA, "--plots", "{FULL}/plots",
      expect=("plots", "No space left")),
    C("diagnose-json-full-disk", "diagnose", *BA, "--json", "{FULL}/r.json",
      expect=("r.json", "No space left"), fill=True),
    C("ride-plots-full-disk", "ride", "{B}", "--plots", "{FULL}/plots",
      expect="No space left"),
    C("export-csv-full-disk", "export", "{B}", "-o", "{FULL}/x.csv", expect="No space left"),
    C("export-mf4-full-disk", "export", "{B}", "-o", "{FULL}/x.mf4", expect="No space left"),
    C("import-full-disk", "import", "{CSV}", "-o", "{FULL}/s.h5", *CSV_ROLES,
      expect="No space left"),
    C("simulate-full-disk", "simulate", "-o", "{FULL}/s.h5", "--duration", "5",
      expect="No space left"),
    C("fit-json-full-disk", "fit", "{B}", "--max-iterations", "2", "--json", "{FULL}/r.json",
      expect="No space left", fill=True),
    # ----------------------------------------------------------- batch manifest files
    C("manifest-mass-inf", "reprocess", "{B}", "{A}", "--manifest", "{WS}/manifest_inf.csv",
      "--dry-run", "--catalog", "{OUT}/c.sqlite", expect=("line 2", "added_mass_kg inf", "kg")),
    C("manifest-mass-1e12", "reprocess", "{B}", "{A}", "--manifest",
      "{WS}/manifest_1e12.csv", "--dry-run", "--catalog", "{OUT}/c.sqlite",
      expect=("line 2", "added_mass_kg 1e12")),
    C("manifest-mass-negative", "reprocess", "{B}", "{A}", "--manifest",
      "{WS}/manifest_negative.csv", "--dry-run", "--catalog", "{OUT}/c.sqlite",
      expect=("line 2", "added_mass_kg -60")),
    C("manifest-latin1", "reprocess", "{B}", "{A}", "--manifest", "{WS}/manifest_latin1.csv",
      "--dry-run", "--catalog", "{OUT}/c.sqlite", expect=("manifest_latin1.csv", "UTF-8")),
]

#: Pair compatibility (fielddiag/pairs.py): drives that cannot be a before/after pair.
PAIR_CASES = [
    C("pair-swapped", "identify", "{A}", "{B}", "--added-mass", "60",
      expect=("before", "after")),
    C("pair-same-file-twice", "identify", "{B}", "{B}", "--added-mass", "60",
      expect="same"),
    C("pair-different-vehicles", "identify", "{B}", "{WS}/other_car_after.h5",
      "--added-mass", "60", expect="vehicle"),
    C("pair-swapped-diagnose", "diagnose", "{A}", "{B}", "--added-mass", "60",
      expect=("before", "after")),
    C("pair-same-file-twice-diagnose", "diagnose", "{B}", "{B}", "--added-mass", "60",
      expect="same"),
    C("pair-different-vehicles-diagnose", "diagnose", "{B}", "{WS}/other_car_after.h5",
      "--added-mass", "60", expect="vehicle"),
]


# ---------------------------------------------------------------------------- workspace
def _sha(path: Path) -> str:
    if path.stat().st_size > 5_000_000:  # the 50 MB file: size and time stamp suffice
        st = path.stat()
        return f"{st.st_size}:{st.st_mtime_ns}"
    return hashlib.sha256(path.read_bytes()).hexdigest()


def snapshot(folder: Path) -> dict[str, str]:
    """Every entry under ``folder`` (hidden ones included) with its kind and content hash."""
    out: dict[str, str] = {}
    if not folder.exists():
        return out
    for p in sorted(folder.rglob("*")):
        rel = str(p.relative_to(folder))
        if p.is_symlink():
            out[rel] = "link:" + os.readlink(p)
        elif p.is_dir():
            out[rel] = "dir"
        elif p.is_file():
            out[rel] = _sha(p)
        else:  # a device node: never read it
            st = p.stat()
            out[rel] = f"special:{st.st_mode:o}:{st.st_rdev}"
    return out


def _write_csv(path: Path, rows: list[str], header: str = "time_s,wheel,body") -> None:
    path.write_text(header + "\n" + "".join(r + "\n" for r in rows))


def _good_rows(n: int) -> list[str]:
    t = np.arange(n) / 200.0
    return [f"{ti:.5f},{np.sin(7 * ti):.6f},{9.80665 + 0.1 * np.cos(3 * ti):.6f}" for ti in t]


def _mount(target: Path, options: str) -> bool:
    target.mkdir(parents=True, exist_ok=True)
    return subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(target)],
                          capture_output=True).returncode == 0


def _fill(path: Path) -> None:
    """Write zeros to ``path`` until the disk is full."""
    with open(path, "wb", buffering=0) as fh:
        try:
            while True:
                fh.write(b"\0" * 1024)
        except OSError:
            pass


def _umount(target: Path) -> None:
    subprocess.run(["umount", "-l", str(target)], capture_output=True)


@pytest.fixture(scope="module")
def workspace(tmp_path_factory):
    """Input files made once: a simulated before/after pair, a drive of another car, a
    session full of NaN, good and bad CSV files."""
    ws = tmp_path_factory.mktemp("bad_input_inputs")
    params = sim.QuarterCarParams()
    sensor = sim.SensorModel(output_rate_hz=200.0, snr_db=35.0)
    drives = {"before.h5": (0.0, 1, "simulated car"), "after.h5": (60.0, 2, "simulated car"),
              "other_car_after.h5": (60.0, 3, "another car")}
    for name, (mass, seed, vehicle) in drives.items():
        drive = sim.simulate(params, duration_s=35.0, road_class="C", added_mass_kg=mass,
                             sensor=sensor, seed=seed)
        drive_to_session(drive, ws / name, vehicle=vehicle, include_recipe=False)
    n = 200 * 35
    write_session(ws / "nan.h5", SessionMetadata(vehicle="simulated car"),
                  [ChannelSpec("wheel_z", unit="m/s2", role="wheel"),
                   ChannelSpec("body_z", unit="m/s2", role="body")],
                  np.full((n, 2), np.nan), sample_rate_hz=200.0, time_s=np.arange(n) / 200.0)
    good = _good_rows(400)
    _write_csv(ws / "good.csv", good)
    (ws / "long_line.csv").write_text("time_s,wheel,body" + ",x" * 25_000_000)  # 50 MB
    (ws / "binary.csv").write_bytes(np.random.default_rng(0).bytes(20_000) + b"\0")
    (ws / "empty.csv").write_text("")
    _write_csv(ws / "header_only.csv", [])
    _write_csv(ws / "nan_cell.csv", good[:3] + ["0.015,nan,9.8"] + good[4:])
    _write_csv(ws / "text_cell.csv", good[:2] + ["0.01,0.1,abc"] + good[3:])
    _write_csv(ws / "backwards.csv", good[:10] + [good[3]] + good[11:])
    _write_csv(ws / "short_row.csv", good[:4] + ["0.02,0.1"] + good[5:])
    (ws / "pvs_binary").mkdir()
    (ws / "pvs_binary" / "dataset_gps_mpu_left.csv").write_bytes(
        b"\0" + np.random.default_rng(1).bytes(5000))
    (ws / "garbage.mf4").write_bytes(np.random.default_rng(2).bytes(5000))
    (ws / "drive.log").write_text("".join(f"({1e9 + i / 100:.6f}) can0 0B4#0000000000001234\n"
                                          for i in range(50)))
    for name, mass in (("inf", "inf"), ("1e12", "1e12"), ("negative", "-60")):
        (ws / f"manifest_{name}.csv").write_text(
            f"before,after,added_mass_kg\nbefore.h5,after.h5,{mass}\n")
    (ws / "manifest_latin1.csv").write_bytes(
        "before,after,added_mass_kg\nbefore_é.h5,after.h5,60\n".encode("latin-1"))
    return {"WS": ws, "B": ws / "before.h5", "A": ws / "after.h5", "CSV": ws / "good.csv"}


@pytest.fixture(scope="module")
def outcomes(workspace, tmp_path_factory):
    """Run every case (bad inputs and pair cases) once, three at a time."""
    root = tmp_path_factory.mktemp("bad_input_outputs")
    ro = root / "readonly"
    can_mount = os.geteuid() == 0 and _mount(ro, "ro,size=64k")
    mounted = [ro] if can_mount else []
    inputs = workspace["WS"]

    def run(case: Case) -> dict:
        if case.needs_mounts and not can_mount:
            return {"skip": "mounting a read-only or tiny tmpfs needs root"}
        out = root / "out" / case.id
        out.mkdir(parents=True)
        full = root / "full" / case.id
        if case.needs_full:
            if not _mount(full, f"size={FULL_DISK_SIZE}"):
                return {"skip": "could not mount a tiny tmpfs"}
            mounted.append(full)
            if case.fill:
                _fill(full / "filler")
        if any("{DEV}" in a for a in case.args) or case.setup is _link_to_device:
            # a device node of our own like /dev/full (char 1, 7): a run of faulty code
            # must not replace the machine's /dev/full with a regular file
            try:
                os.mknod(out / "full_dev", 0o666 | stat.S_IFCHR, os.makedev(1, 7))
            except OSError:
                return {"skip": "creating a device node needs root"}
        if case.setup:
            case.setup(out, workspace)
        names = {k: str(v) for k, v in workspace.items()}
        names.update(OUT=str(out), RO=str(ro), FULL=str(full), DEV=str(out / "full_dev"))
        argv = [a.format(**names) for a in case.args]
        before = {"out": snapshot(out), "full": snapshot(full), "ro": snapshot(ro),
                  "inputs": snapshot(inputs)}
        t0 = time.perf_counter()
        try:
            proc = subprocess.run([sys.executable, "-m", "fielddiag.cli", *argv],
                                  capture_output=True, text=True, timeout=CASE_TIMEOUT_S,
                                  stdin=subprocess.DEVNULL)
            code, stderr = proc.returncode, proc.stderr
        except subprocess.TimeoutExpired as exc:
            code, stderr = "hang", str(exc.stderr or "")
        after = {"out": snapshot(out), "full": snapshot(full), "ro": snapshot(ro),
                 "inputs": snapshot(inputs)}
        return {"argv": argv, "code": code, "stderr": stderr, "before": before,
                "after": after, "seconds": time.perf_counter() - t0}

    t0 = time.perf_counter()
    try:
        with ThreadPoolExecutor(max_workers=3) as pool:
            results = dict(zip([c.id for c in CASES + PAIR_CASES],
                               pool.map(run, CASES + PAIR_CASES), strict=True))
        results["_wall_s"] = time.perf_counter() - t0
        yield results
    finally:
        for m in mounted:
            _umount(m)


def check(outcome: dict, case: Case) -> None:
    if "skip" in outcome:
        pytest.skip(outcome["skip"])
    err = outcome["stderr"]
    shown = f"fielddiag {' '.join(outcome['argv'])}\nexit {outcome['code']}\n{err}"
    assert outcome["code"] == 1, shown
    assert "Traceback" not in err, shown
    lines = err.strip().splitlines()
    assert len(lines) == 1, shown
    line = lines[0]
    assert line.startswith("fielddiag ") and "error:" in line, shown
    for fragment in case.expect:
        assert fragment in line, f"{fragment!r} not in: {line}"
    assert SAYS_WHAT_TO_DO.search(line.split("error:", 1)[1]), f"says not what to do: {line}"
    for where in ("out", "full", "ro"):
        assert outcome["after"][where] == outcome["before"][where], (
            f"{where} folder changed: {outcome['before'][where]} -> {outcome['after'][where]}")
    assert outcome["after"]["inputs"] == outcome["before"]["inputs"], "an input changed"


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_bad_input(case: Case, outcomes) -> None:
    check(outcomes[case.id], case)


@pytest.mark.parametrize("case", PAIR_CASES, ids=[c.id for c in PAIR_CASES])
def test_incompatible_pair(case: Case, outcomes) -> None:
    check(outcomes[case.id], case)


def test_suite_size_and_time(outcomes) -> None:
    """At least 120 bad inputs and faults; the wall time is printed (pytest -s)."""
    assert len(CASES) + len(PAIR_CASES) >= 120
    slow = sorted(((v["seconds"], k) for k, v in outcomes.items()
                   if isinstance(v, dict) and "seconds" in v), reverse=True)[:15]
    print(f"\n{len(CASES) + len(PAIR_CASES)} cases in {outcomes['_wall_s']:.1f} s wall; "
          "slowest: " + ", ".join(f"{k} {s:.1f} s" for s, k in slow))


# ----------------------------------------------------------- what must still work
def test_latin1_header_is_read(workspace, tmp_path, capsys) -> None:
    """A Latin-1 header (a degree sign, an accent: older Windows tools) is read as Latin-1
    rather than refused; the numbers come through exactly."""
    src = tmp_path / "latin1.csv"
    rows = _good_rows(50)
    src.write_bytes(("time_s,wheel_m/s²,body_é\n" + "\n".join(rows) + "\n").encode("latin-1"))
    assert main(["import", str(src), "-o", str(tmp_path / "s.h5"), "--time", "time_s",
                 "--role", "wheel=wheel_m/s²", "--role", "body=body_é"]) == 0
    expected = np.array([[float(x) for x in r.split(",")] for r in rows])
    with SessionReader(tmp_path / "s.h5") as s:
        assert s.channel_for_role("body").sensor == "csv:body_é"
        np.testing.assert_allclose(s.read_role("wheel"), expected[:, 1], rtol=0, atol=1e-12)
        np.testing.assert_allclose(s.read_role("body"), expected[:, 2], rtol=0, atol=1e-12)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["latin1.csv", "s.h5"]


def test_overwrite_replaces_a_regular_file_whole(workspace, tmp_path, capsys) -> None:
    """--overwrite still replaces a regular file, with the whole new content and no
    temporary file left beside it; a symbolic link to a regular file replaces its target."""
    out = tmp_path / "x.csv"
    out.write_text("old\n")
    assert main(["export", str(workspace["B"]), "-o", str(out), "--overwrite"]) == 0
    with SessionReader(workspace["B"]) as s:
        n = s.n_samples
    assert len(out.read_text().splitlines()) == n + 1  # the header and every sample
    target = tmp_path / "target.json"
    target.write_text("{}")
    (tmp_path / "link.json").symlink_to(target)
    assert main(["ride", str(workspace["B"]), "--json", str(tmp_path / "link.json")]) == 0
    assert (tmp_path / "link.json").is_symlink()
    assert json.loads(target.read_text())["sample_rate_hz"] == pytest.approx(200.0)
    assert not [p.name for p in tmp_path.iterdir() if p.name.startswith(".")]
