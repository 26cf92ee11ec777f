"""Session write and read throughput (not a test: prints figures).

Method: append blocks of a typical DAQ shape (8 channels of int32 counts with float64
time stamps, blocks of 1000 samples) to a fresh SWMR session through SessionWriter, with
its background flush every 0.5 s, until 40 M samples (5 M per channel) are written; the
rate is samples (all channels) per second of wall time including the final close. Read
throughput: read every channel whole, then 1000 random 1 s slices by time.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from fielddiag.channels import ChannelSpec, SessionMetadata
from fielddiag.session import SessionReader, SessionWriter

N_CH = 8
BLOCK = 1000
PER_CHANNEL = 5_000_000
RATE_HZ = 2000.0


def main() -> None:
    rng = np.random.default_rng(0)
    block = rng.integers(-(2**20), 2**20, size=(BLOCK, N_CH), dtype="int32")
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "bench.h5"
        chans = [ChannelSpec(f"ch{i}", unit="m/s2", dtype="int32", scale=1e-5) for i in range(N_CH)]
        t0 = time.perf_counter()
        with SessionWriter(path, SessionMetadata(), chans, sample_rate_hz=RATE_HZ) as w:
            for b in range(PER_CHANNEL // BLOCK):
                w.append_daq(block, time_s=(b * BLOCK + np.arange(BLOCK)) / RATE_HZ)
        dt = time.perf_counter() - t0
        total = PER_CHANNEL * N_CH
        size_mb = path.stat().st_size / 1e6
        print(__doc__)
        print(
            f"append: {total / dt / 1e6:.1f} M samples/s ({total / 1e6:.0f} M samples in "
            f"{dt:.2f} s, file {size_mb:.0f} MB)  goal >= 5 M samples/s"
        )
        print(
            f"        = {total / dt / (N_CH * RATE_HZ):.0f}x an {N_CH}-channel {RATE_HZ:g} Hz DAQ"
        )
        with SessionReader(path) as s:
            t0 = time.perf_counter()
            for c in s.channels:
                s.read(c.name)
            s.time_s()
            dt = time.perf_counter() - t0
            print(f"read whole: {total / dt / 1e6:.1f} M samples/s (calibrated float64)")
            starts = rng.uniform(0, s.duration_s - 1, 1000)
            t0 = time.perf_counter()
            for a in starts:
                s.read("ch0", a, a + 1.0)
            dt = time.perf_counter() - t0
            print(
                f"read 1 s slices by time: {1000 / dt:.0f} slices/s "
                f"({dt / 1000 * 1e3:.2f} ms per slice of {RATE_HZ:g} samples)"
            )


if __name__ == "__main__":
    main()
