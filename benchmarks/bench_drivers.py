"""Driver benchmarks: frame parser throughput, a real-time recording over a pty, CAN decoding.

    python benchmarks/bench_drivers.py [--duration 60] [--skip-recording]

1. Parser: DATA frames of an 8-channel int32 DAQ (20 samples per channel per frame, as
   the virtual DAQ sends at 2 kHz) fed to drivers.protocol.FrameParser in 4 kB chunks, as
   they come from a serial port; then the same stream with 1e-3 byte corruption and
   garbage bursts; then the whole serial-driver path (parser + sequence bookkeeping +
   device-to-session time mapping with the clock fit). Goal: >= 2 M samples/s on one
   core (a sample = one channel value), over 100x an 8-channel 2 kHz DAQ (16 k samples/s).
2. Recording: `fielddiag virtual-daq --rate 2000 --channels 8` in its own process streams
   over a pseudo-terminal, recorded for --duration seconds into an HDF5 session, twice:
   (a) in this process with fielddiag.recorder.Recorder (no on-line estimator), CPU
   time / wall time from os.times(); (b) by the real command a technician runs,
   `fielddiag record --daq serial://PTY -o S.h5 --duration D --quiet` with its default
   options (on-line estimator on), in its own process, CPU from /proc/<pid>/stat
   (all its threads), frames lost from `fielddiag info --json`. Goal for both: 0 frames
   lost and < 20 % of one core.
3. CAN: the real 60 s RAV4 log (98,800 frames) with its DBC: (a) python-can LogReader
   parse + raw frame conversion + decoding SPEED and the four wheel speeds, end to end;
   (b) the recorder's per-batch work alone (frame conversion + decoding) on frames
   already in memory; (c) cantools decoding of every frame the DBC defines. Goal: >= 20 k
   frames/s.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
DATA = REPO.parent / "shared" / "data" / "can"
if not DATA.is_dir():  # a worktree under /work/wt: the shared data stays in /work/shared
    DATA = Path("/work/shared/data/can")
sys.path.insert(0, str(REPO))

from drivers.base import SessionClock  # noqa: E402
from drivers.protocol import ChannelInfo, DeviceInfo, FrameParser, encode_data  # noqa: E402


def bench_parser() -> None:
    rng = np.random.default_rng(0)
    nch, spf, n_frames = 8, 20, 20000
    frames = [
        encode_data(k, 10_000 * k, rng.integers(-(2**31), 2**31, (spf, nch)), 2)
        for k in range(n_frames)
    ]
    clean = b"".join(frames)
    values = n_frames * spf * nch

    def run(stream: bytes) -> tuple[float, int]:
        p = FrameParser()
        got = 0
        t = time.perf_counter()
        for i in range(0, len(stream), 4096):
            for f in p.feed(stream[i : i + 4096]):
                got += f.n_samples * f.n_channels
        return time.perf_counter() - t, got

    best = min(run(clean)[0] for _ in range(3))
    print("1. frame parser (8 ch int32, 20 samples/frame, 4 kB chunks)")
    print(
        f"   clean stream     {values / best / 1e6:6.2f} M samples/s "
        f"({n_frames / best / 1e3:.0f} k frames/s, {len(clean) / best / 1e6:.0f} MB/s)"
    )
    dirty = bytearray(clean)
    hit = rng.random(len(dirty)) < 1e-3
    arr = np.frombuffer(dirty, "u1").copy()
    arr[hit] ^= rng.integers(1, 256, int(hit.sum()), dtype="u1")
    parts, step = [], 50 * len(frames[0])
    raw = arr.tobytes()
    for i in range(0, len(raw), step):
        parts.append(raw[i : i + step] + rng.integers(0, 256, 300, dtype="u1").tobytes())
    dirty_stream = b"".join(parts)
    dt, got = run(dirty_stream)
    print(
        f"   1e-3 corruption + garbage  {got / dt / 1e6:6.2f} M samples/s of good frames "
        f"({got / values:.0%} of the frames survive)"
    )

    from drivers.serial_daq import SerialDAQSource

    src = SerialDAQSource("serial://bench", "bench")
    src.info = DeviceInfo(
        "B", "bench", 2000.0, 2, spf, tuple(ChannelInfo(100.0) for _ in range(nch))
    )
    src.clock = SessionClock()
    t = time.perf_counter()
    n = 0
    for i in range(0, len(clean), 65536):
        t_arrival = i / len(clean) * n_frames * spf / 2000.0
        src._backlog.extend((f, t_arrival) for f in src._parser.feed(clean[i : i + 65536]))
        b = src._process(b"", t_arrival)
        n += 0 if b is None else b.samples.size
    dt = time.perf_counter() - t
    print(
        f"   driver path (parser + sequence + time mapping, 64 kB reads) "
        f"{n / dt / 1e6:6.2f} M samples/s"
    )
    print(f"   goal >= 2 M samples/s; an 8 ch 2 kHz DAQ needs {nch * 2000 / 1e3:.0f} k samples/s")


def _proc_cpu_s(pid: int) -> float:
    with open(f"/proc/{pid}/stat") as fh:
        fields = fh.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _start_virtual_daq() -> tuple[subprocess.Popen, str]:
    """`fielddiag virtual-daq` at 2 kHz x 8 channels in its own process, and its port."""
    daq = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "fielddiag.cli",
            "virtual-daq",
            "--rate",
            "2000",
            "--channels",
            "8",
            "--duration",
            "30",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        cwd=REPO,
    )
    return daq, daq.stdout.readline().strip()


def _stop(proc: subprocess.Popen) -> None:
    proc.terminate()
    proc.wait(10)


def bench_recording(duration_s: float) -> None:
    from drivers import open_source
    from fielddiag.recorder import Recorder
    from fielddiag.session import SessionReader

    print(f"2. recording 8 ch x 2 kHz over a pseudo-terminal for {duration_s:g} s")
    print("   (a) fielddiag.recorder.Recorder in this process, no on-line estimator")
    daq, port = _start_virtual_daq()
    try:
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "bench.h5"
            src = open_source(f"serial://{port}")
            src.seq_log = []
            rec = Recorder(path, [src])
            rec.start()
            c0, w0, d0 = os.times(), time.monotonic(), _proc_cpu_s(daq.pid)
            rec.wait(duration_s)
            c1, w1, d1 = os.times(), time.monotonic(), _proc_cpu_s(daq.pid)
            final = rec.stop()
            with SessionReader(path) as s:
                n, size = s.n_samples, path.stat().st_size
            seqs = src.seq_log
            missing = (seqs[-1] - seqs[0] + 1 - len(seqs)) if seqs else -1
    finally:
        _stop(daq)
    cpu = (c1.user + c1.system - c0.user - c0.system) / (w1 - w0)
    print(
        f"       samples stored {n} ({n / duration_s:.0f} per s per channel), "
        f"file {size / 1e6:.1f} MB"
    )
    print(
        f"       frames received {final['frames_received']}, frames lost {final['frames_lost']} "
        f"(missing sequence numbers {missing}), CRC errors {final['crc_errors']}, "
        f"gaps {final['gaps']}"
    )
    print(
        f"       recorder CPU {100 * cpu:.1f} % of one core (goal < 20 %); virtual DAQ process "
        f"{100 * (d1 - d0) / (w1 - w0):.1f} %"
    )


def _wait_for_samples(path: Path, proc: subprocess.Popen, timeout_s: float = 60.0) -> None:
    """Return once the session written by ``proc`` holds samples."""
    from fielddiag.errors import SessionError
    from fielddiag.session import SessionReader

    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"fielddiag record exited early: {proc.stderr.read()}")
        if path.exists():
            try:
                with SessionReader(path) as s:
                    if s.n_samples > 0:
                        return
            except SessionError:
                pass
        time.sleep(0.05)
    raise RuntimeError("fielddiag record wrote no samples")


def _cpu_while_running(pid: int, window_s: float) -> list[tuple[float, float]]:
    """(wall, CPU) seconds of process ``pid`` sampled every 0.5 s for ``window_s``."""
    marks = [(time.monotonic(), _proc_cpu_s(pid))]
    end = marks[0][0] + window_s
    while time.monotonic() < end:
        time.sleep(min(0.5, max(0.0, end - time.monotonic())))
        marks.append((time.monotonic(), _proc_cpu_s(pid)))
    return marks


def bench_record_command(duration_s: float) -> None:
    print(
        f"   (b) `fielddiag record --daq serial://PTY -o S.h5 --duration {duration_s:g} --quiet` "
        "in its own process, default options (on-line estimator on)"
    )
    daq, port = _start_virtual_daq()
    try:
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "cli.h5"
            children0 = resource.getrusage(resource.RUSAGE_CHILDREN)
            w_launch = time.monotonic()
            rec = subprocess.Popen(
                [
                    sys.executable,
                    "-m",
                    "fielddiag.cli",
                    "record",
                    "--daq",
                    f"serial://{port}",
                    "-o",
                    str(path),
                    "--duration",
                    f"{duration_s:g}",
                    "--quiet",
                ],
                stdout=subprocess.DEVNULL,
                stderr=subprocess.PIPE,
                text=True,
                cwd=REPO,
            )
            _wait_for_samples(path, rec)
            # while it records: from its first samples to 0.5 s before its --duration ends
            marks = _cpu_while_running(rec.pid, max(0.5, duration_s - 0.5))
            _, err = rec.communicate(timeout=60)
            w_exit = time.monotonic()
            children1 = resource.getrusage(resource.RUSAGE_CHILDREN)
            if rec.returncode != 0:
                raise RuntimeError(f"fielddiag record failed: {err}")
            info = json.loads(
                subprocess.run(
                    [sys.executable, "-m", "fielddiag.cli", "info", "--json", str(path)],
                    capture_output=True,
                    text=True,
                    check=True,
                    cwd=REPO,
                ).stdout
            )
    finally:
        _stop(daq)
    (w0, c0), (w1, c1) = marks[0], marks[-1]
    steady = [(cb - ca) / (wb - wa) for (wa, ca), (wb, cb) in zip(marks, marks[1:], strict=False)]
    steady = steady[len(steady) // 3 :] or steady  # past the estimator's warm-up
    life_cpu_s = children1.ru_utime + children1.ru_stime - children0.ru_utime - children0.ru_stime
    c = info["counters"]
    online = "on (its advice was printed)" if "advice:" in err else "NOT reported"
    print(
        f"       samples stored {info['samples']} in {info['duration_s']:.1f} s, on-line "
        f"estimator {online}"
    )
    print(
        f"       frames received {c['frames_received']}, frames lost {c['frames_lost']}, "
        f"CRC errors {c['crc_errors']}, gaps {len(info['gaps'])} (fielddiag info --json)"
    )
    print(
        f"       recorder CPU {100 * (c1 - c0) / (w1 - w0):.1f} % of one core while recording "
        f"(steady state {100 * float(np.median(steady)):.1f} %: median of the 0.5 s windows "
        f"after the first third); whole process life, start-up included: {life_cpu_s:.1f} "
        f"CPU-s over {w_exit - w_launch:.1f} s"
    )
    print("   goal: 0 frames lost and < 20 % of one core")


def bench_can() -> None:
    import can

    from drivers.can_decode import CanDecoder, load_dbc, messages_to_frames, resolve_signals
    from drivers.can_vehicle import read_can_log

    log, dbc = DATA / "comma2k19_rav4_2018-08-02_seg40.log", DATA / "toyota_new_mc_pt_generated.dbc"
    if not log.exists():
        print(f"3. CAN: skipped, {log} not found")
        return
    sigs = ["vehicle_speed=SPEED.SPEED"] + [f"WHEEL_SPEED_{w}" for w in ("FL", "FR", "RL", "RR")]
    db = load_dbc(dbc)
    read_can_log(log, db, sigs)  # warm up imports
    t = time.perf_counter()
    frames, sig, _, err = read_can_log(log, db, sigs, decode_channel="can0")
    dt = time.perf_counter() - t
    print("3. CAN decoding, real RAV4 log (98,800 frames, 60 s)")
    print(
        f"   (a) read .log + store raw + decode 5 signals: {len(frames) / dt / 1e3:6.0f} k fr/s "
        f"({len(sig['vehicle_speed'][1])} speeds, {err} errors)"
    )
    msgs = list(can.LogReader(str(log)))
    dec = CanDecoder(resolve_signals(db, sigs))
    t = time.perf_counter()
    for i in range(0, len(msgs), 2000):
        batch = msgs[i : i + 2000]
        ts = np.fromiter((m.timestamp for m in batch), "f8", len(batch))
        dec.decode(messages_to_frames(batch, ts, 0))
    dt = time.perf_counter() - t
    print(
        f"   (b) recorder batch work (raw frames + 5 signals):  {len(msgs) / dt / 1e3:6.0f} k fr/s"
    )
    by_id = {m.frame_id: m for m in db.messages}
    todo = [
        (by_id[m.arbitration_id], bytes(m.data))
        for m in msgs
        if m.channel == "can0" and m.arbitration_id in by_id
    ]
    t = time.perf_counter()
    for msg, data in todo:
        msg.decode(data, decode_choices=False, allow_truncated=True)
    dt = time.perf_counter() - t
    print(
        f"   (c) cantools, every signal of every defined frame: {len(todo) / dt / 1e3:6.0f} k fr/s"
    )
    print("   goal >= 20 k frames/s")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=60.0, help="recording length (60 s)")
    ap.add_argument("--skip-recording", action="store_true")
    args = ap.parse_args()
    print(__doc__)
    bench_parser()
    bench_can()
    if not args.skip_recording:
        bench_recording(args.duration)
        bench_record_command(args.duration)


if __name__ == "__main__":
    main()
