"""Faults of the recording path: a pulled cable, the device clock, a killed recorder.

    python benchmarks/bench_faults.py [--minutes 10] [--pulls 3] [--kills 5]
                                      [--skew-ppm 100] [--jitter-ms 1] [--only 1,2,3]

1. Pulled cable. `fielddiag virtual-daq --rate 500 --channels 2 --disconnect-at 3
   --disconnect-for 2` in its own process, recorded by `fielddiag record --duration 8
   --no-online` in another. The recorder's frames lost (`fielddiag info --json`) are set
   against the frames the device itself dropped, from the JSON line it prints when it
   stops: made while the cable was out + queued or unread in the link when it was
   pulled + dropped because its transmit buffer was full. Goal: equal.
2. Time stamps against the device clock. A virtual DAQ (500 Hz, 2 channels) runs in a
   child process with its clock --skew-ppm off and every frame sent late by an
   exponentially distributed delay of mean --jitter-ms (frames stay in order); this
   process records it with fielddiag.recorder.Recorder into a real HDF5 session for
   --minutes. Each stored sample's error is its session time minus the session time at
   which the device acquired it (known from the device's clock: boot instant, rate
   error, start of the run; CLOCK_MONOTONIC is shared by both processes). Printed: the
   error's least value (the path's least delay: pty, scheduler, which no host can see),
   its spread (max - min: how far the stamps stray from the device clock), its largest
   value, per minute, and the drift estimate. Goal: error < 1 ms over the whole run.
3. SIGKILL. `fielddiag record --no-online` of a virtual DAQ (1 kHz, 3 channels, 2e-4
   byte corruption) is killed with SIGKILL --kills times at random instants 2-4 s after
   its first samples reached the file. Lost = kill instant - session time of the last
   sample in the file. Also checked: the file's counters count exactly its samples and
   gaps. Goal: <= 0.5 s lost, counters consistent every time.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def _fielddiag(*args: str) -> list[str]:
    return [sys.executable, "-m", "fielddiag.cli", *args]


def _info(path: Path) -> dict:
    out = subprocess.run(
        _fielddiag("info", "--json", str(path)), capture_output=True, text=True, check=True
    )
    return json.loads(out.stdout)


# ------------------------------------------------------------------------ 1. cable pull
def bench_cable_pull(pulls: int) -> None:
    from fielddiag.session import SessionReader

    print("1. pulled cable: 2 s out, 3 s after the start of an 8 s recording (500 Hz, 2 ch)")
    print("   run  frames lost (recorder)  frames the device dropped  difference  reconnected")
    diffs = []
    for k in range(pulls):
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "pull.h5"
            vdaq = subprocess.Popen(
                _fielddiag("virtual-daq", "--rate", "500", "--channels", "2",
                           "--disconnect-at", "3", "--disconnect-for", "2", "--seed", str(k)),
                stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, cwd=REPO,
            )
            try:
                port = vdaq.stdout.readline().strip()
                rec = subprocess.run(
                    _fielddiag("record", "--daq", f"serial://{port}", "-o", str(path),
                               "--duration", "8", "--no-online", "--quiet"),
                    capture_output=True, text=True, cwd=REPO, timeout=120,
                )
            finally:
                vdaq.send_signal(signal.SIGINT)
                out, _ = vdaq.communicate(timeout=30)
            if rec.returncode != 0:
                raise RuntimeError(rec.stderr)
            dev = json.loads(out.strip().splitlines()[-1])
            info = _info(path)
            with SessionReader(path) as sess:
                back = [e.label for e in sess.events if "reconnected" in e.label]
        dropped = (
            dev["frames_dropped_outage"] + dev["frames_lost_in_link"]
            + dev["frames_dropped_overflow"]
        )
        lost = info["counters"]["frames_lost"]
        diffs.append(lost - dropped)
        print(f"   {k + 1:3d}  {lost:22d}  {dropped:25d}  {lost - dropped:10d}  "
              f"{back[0] if back else '?'}")
    print(f"   frames lost - frames dropped by the device: {diffs} (goal: 0)")


# ------------------------------------------------------------------ 2. device clock
def _device(conn, kwargs: dict) -> None:
    """A virtual DAQ in this (child) process until told to stop; then its clock."""
    from drivers.virtual import VirtualDAQ

    sig = np.random.default_rng(0).normal(0.0, 20.0, (20000, 2))
    daq = VirtualDAQ(sig, **kwargs).start()
    conn.send(daq.path)
    conn.recv()
    daq.stop()
    conn.send(
        {
            "boot_mono": daq._boot_mono,
            "drift_ppm": daq.clock_drift_ppm,
            "run_start_dev_s": daq._run_start_dev_s,
            "run_seq0": daq._run_seq0,
            "samples_per_frame": daq.samples_per_frame,
            "frames_dropped": daq.stats.frames_dropped,
        }
    )


def bench_clock(minutes: float, skew_ppm: float, jitter_ms: float) -> None:
    from drivers import open_source
    from fielddiag.recorder import Recorder
    from fielddiag.session import SessionReader

    rate = 500.0
    print(
        f"2. time stamps against the device clock: {minutes:g} min at {rate:g} Hz, device clock "
        f"{skew_ppm:+g} ppm, frames sent {jitter_ms:g} ms late on average (exponential)"
    )
    ctx = mp.get_context("fork")
    here, there = ctx.Pipe()
    child = ctx.Process(
        target=_device,
        args=(there, {"sample_rate_hz": rate, "clock_drift_ppm": skew_ppm,
                      "tx_jitter_s": jitter_ms / 1000.0, "seed": 1}),
    )
    child.start()
    try:
        port = here.recv()
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "clock.h5"
            src = open_source(f"serial://{port}")
            src.seq_log = []
            rec = Recorder(path, [src]).start()
            rec.wait(minutes * 60.0)
            final = rec.stop()
            t0_mono = rec.clock.t0_monotonic_s
            with SessionReader(path) as s:
                t = s.time_s()
        here.send("stop")
        dev = here.recv()
    finally:
        child.join(30)
    n = dev["samples_per_frame"]
    seqs = np.array(src.seq_log, dtype="f8")
    t_dev = (
        dev["run_start_dev_s"] + (seqs[:, None] - dev["run_seq0"]) * n / rate
        + np.arange(n) / rate
    ).ravel()
    true = dev["boot_mono"] + t_dev / (1.0 + dev["drift_ppm"] * 1e-6) - t0_mono
    assert len(true) == len(t), (len(true), len(t))
    err_ms = (t - true) * 1e3
    print(f"   samples {len(t)}, frames lost {final['frames_lost']}, device dropped "
          f"{dev['frames_dropped']}")
    print("   minute   least error (path delay)   largest error   spread (max - min)")
    minute = np.floor((true - true[0]) / 60.0)
    for m in np.unique(minute):
        e = err_ms[minute == m]
        print(f"   {int(m) + 1:6d}   {e.min():21.3f} ms   {e.max():10.3f} ms   "
              f"{np.ptp(e):13.3f} ms")
    print(
        f"   whole run: error {err_ms.min():.3f} .. {err_ms.max():.3f} ms "
        f"(99.9th percentile {np.percentile(err_ms, 99.9):.3f} ms), spread "
        f"{np.ptp(err_ms):.3f} ms; drift estimated {final['drift_ppm']:+.2f} ppm "
        f"(true {skew_ppm:+g})"
    )
    print(f"   goal: error < 1 ms -> largest |error| {np.abs(err_ms).max():.3f} ms")


# ------------------------------------------------------------------------ 3. SIGKILL
def bench_sigkill(kills: int) -> None:
    from drivers.virtual import VirtualDAQ
    from fielddiag.errors import SessionError
    from fielddiag.session import SessionReader

    print(f"3. SIGKILL of `fielddiag record` (1 kHz, 3 ch, 2e-4 corruption), {kills} times")
    print("   kill  after first samples  seconds lost  frames  counters match samples and gaps")
    rng = np.random.default_rng(11)
    losses = []
    for k in range(kills):
        sig = np.random.default_rng(k).normal(0.0, 20.0, (40000, 3))
        with tempfile.TemporaryDirectory() as tmp, VirtualDAQ(
            sig, sample_rate_hz=1000.0, corrupt_rate=2e-4, seed=k
        ) as daq:
            path = Path(tmp) / "killed.h5"
            proc = subprocess.Popen(
                _fielddiag("record", "--daq", f"serial://{daq.path}", "-o", str(path),
                           "--no-online", "--quiet"),
                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, cwd=REPO,
            )
            while True:
                if proc.poll() is not None:
                    raise RuntimeError(proc.stderr.read())
                try:
                    with SessionReader(path) as s:
                        if s.n_samples > 0:
                            break
                except (SessionError, OSError):
                    pass
                time.sleep(0.05)
            wait = rng.uniform(2.0, 4.0)
            time.sleep(wait)
            killed_at = time.time()
            proc.send_signal(signal.SIGKILL)
            proc.wait(10)
            with SessionReader(path) as s:
                lost_s = killed_at - s.metadata.t0_unix_s - s.end_s
                c = s.counters
                n_frames = s.n_samples // daq.samples_per_frame
                gap_sum = sum(g.samples_lost for g in s.gaps)
                ok = (
                    c["frames_received"] * daq.samples_per_frame == s.n_samples
                    and c["samples_lost"] == gap_sum
                    == c["frames_lost"] * daq.samples_per_frame
                )
        losses.append(lost_s)
        print(f"   {k + 1:4d}  {wait:17.2f} s  {lost_s:12.3f}  {n_frames:6d}  {ok}")
    print(f"   seconds lost: max {max(losses):.3f}, median {np.median(losses):.3f} "
          "(goal <= 0.5 s)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=10.0, help="clock run length (10)")
    ap.add_argument("--pulls", type=int, default=3, help="cable pulls (3)")
    ap.add_argument("--kills", type=int, default=5, help="SIGKILLs (5)")
    ap.add_argument("--skew-ppm", type=float, default=100.0, help="device clock error (100)")
    ap.add_argument("--jitter-ms", type=float, default=1.0, help="mean send delay (1 ms)")
    ap.add_argument("--only", default="1,2,3", help="which parts to run (1,2,3)")
    args = ap.parse_args()
    parts = {p.strip() for p in args.only.split(",")}
    print(__doc__)
    if "1" in parts:
        bench_cable_pull(args.pulls)
    if "2" in parts:
        bench_clock(args.minutes, args.skew_ppm, args.jitter_ms)
    if "3" in parts:
        bench_sigkill(args.kills)


if __name__ == "__main__":
    main()
