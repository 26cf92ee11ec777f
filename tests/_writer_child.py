"""A real writer process for the SIGKILL test: appends a known sequence and reports progress.

Every line it prints is ``<samples appended> <time.monotonic()>``, printed right after the
append returned, so the parent knows what had been *received* by the writer and when.
"""

import sys
import time

import numpy as np

from fielddiag.channels import ChannelSpec, SessionMetadata
from fielddiag.session import SessionWriter

path = sys.argv[1]
rate_hz = 2000.0
block = 100
channels = [ChannelSpec(f"ch{i}", unit="count", dtype="int16") for i in range(4)]
w = SessionWriter(path, SessionMetadata(vehicle="kill-test"), channels, sample_rate_hz=rate_hz)
n = 0
while True:
    idx = np.arange(n, n + block)
    samples = np.stack([(idx * (c + 1)) % 32768 for c in range(4)], axis=1).astype("int16")
    w.append_daq(samples, time_s=idx / rate_hz)
    w.add_event(n / rate_hz, f"block {n // block}") if n % 2000 == 0 else None
    n += block
    print(n, time.monotonic(), flush=True)
    time.sleep(block / rate_hz)
