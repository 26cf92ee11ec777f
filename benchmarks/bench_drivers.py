"""Driver benchmarks: frame parser throughput, a real-time recording over a pty, CAN decoding.

    python benchmarks/bench_drivers.py [--duration 60] [--skip-recording]

1. Parser: DATA frames of an 8-channel int32 DAQ (20 samples per channel per frame, as
   the virtual DAQ sends at 2 kHz) fed to drivers.protocol.FrameParser in 4 kB chunks, as
   they come from a serial port; then the same stream with 1e-3 byte corruption and
   garbage bursts; then the whole serial-driver path (parser + sequence bookkeeping +
   device-to-session time mapping). Goal: >= 2 M samples/s on one core (a sample = one
   channel value), over 100x an 8-channel 2 kHz DAQ (16 k samples/s).
2. Recording: `fielddiag virtual-daq --rate 2000 --channels 8` in its own process streams
   over a pseudo-terminal; this process records it with fielddiag.recorder.Recorder into
   an HDF5 session for --duration seconds. Reports frames lost (goal 0) and this
   process's CPU time / wall time (goal < 20 % of one core), read from os.times().
3. CAN: the real 60 s RAV4 log (98,800 frames) with its DBC: (a) python-can LogReader
   parse + raw frame conversion + decoding SPEED and the four wheel speeds, end to end;
   (b) the recorder's per-batch work alone (frame conversion + decoding) on frames
   already in memory; (c) cantools decoding of every frame the DBC defines. Goal: >= 20 k
   frames/s.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
DATA = REPO.parent / "shared" / "data" / "can"
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
        b = src._process(clean[i : i + 65536], i / len(clean) * n_frames * spf / 2000.0)
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


def bench_recording(duration_s: float) -> None:
    from drivers import open_source
    from fielddiag.recorder import Recorder
    from fielddiag.session import SessionReader

    print(f"2. recording 8 ch x 2 kHz over a pseudo-terminal for {duration_s:g} s")
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
    try:
        port = daq.stdout.readline().strip()
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
        daq.terminate()
        daq.wait(10)
    cpu = (c1.user + c1.system - c0.user - c0.system) / (w1 - w0)
    print(
        f"   samples stored {n} ({n / duration_s:.0f} per s per channel), file {size / 1e6:.1f} MB"
    )
    print(
        f"   frames received {final['frames_received']}, frames lost {final['frames_lost']} "
        f"(missing sequence numbers {missing}), CRC errors {final['crc_errors']}, "
        f"gaps {final['gaps']}"
    )
    print(
        f"   recorder CPU {100 * cpu:.1f} % of one core (goal < 20 %); virtual DAQ process "
        f"{100 * (d1 - d0) / (w1 - w0):.1f} %"
    )


def bench_can() -> None:
    import can

    from drivers.can_vehicle import (
        SignalDecoder,
        load_dbc,
        messages_to_frames,
        read_can_log,
        resolve_signals,
    )

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
    dec = SignalDecoder(db, resolve_signals(db, sigs))
    t = time.perf_counter()
    for i in range(0, len(msgs), 2000):
        batch = msgs[i : i + 2000]
        ts = np.fromiter((m.timestamp for m in batch), "f8", len(batch))
        fr, data = messages_to_frames(batch, ts, 0)
        dec.decode(fr, data)
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


if __name__ == "__main__":
    main()
