"""Helpers for tests that stream through a virtual DAQ on a real pseudo-terminal."""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field

import numpy as np

from drivers.base import Block, SessionClock
from drivers.serial_daq import SerialDAQSource
from drivers.virtual import VirtualDAQ


@dataclass
class Collected:
    """Everything a source produced while :func:`collect` read it."""

    blocks: list[Block] = field(default_factory=list)

    @property
    def time_s(self) -> np.ndarray:
        parts = [b.time_s for b in self.blocks if b.n_samples]
        return np.concatenate(parts) if parts else np.zeros(0)

    @property
    def samples(self) -> np.ndarray:
        parts = [b.samples for b in self.blocks if b.n_samples]
        return np.concatenate(parts) if parts else np.zeros((0, 0))

    @property
    def gaps(self) -> list:
        return [g for b in self.blocks for g in b.gaps]

    @property
    def events(self) -> list:
        return [e for b in self.blocks for e in b.events]


def noise_signals(n: int, n_channels: int, seed: int = 0) -> np.ndarray:
    """Distinct random accelerations [m/s2] so that every frame's content is unique."""
    return np.random.default_rng(seed).normal(0.0, 20.0, (n, n_channels))


def collect(src: SerialDAQSource, seconds: float, clock: SessionClock | None = None) -> Collected:
    """Start ``src`` and read it for ``seconds``."""
    clock = clock or SessionClock()
    src.start(clock)
    out = Collected()
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        b = src.read(0.1)
        if b is not None:
            out.blocks.append(b)
    return out


def expected_samples(daq: VirtualDAQ, seqs: list[int]) -> np.ndarray:
    """What the device sent, frame by frame, for these sequence numbers."""
    return np.concatenate([daq.truth(s) for s in seqs])


def missing_seqs(seqs: list[int]) -> list[int]:
    """Sequence numbers between the first and last received that never arrived."""
    got = set(seqs)
    return [s for s in range(seqs[0], seqs[-1] + 1) if s not in got]


class SchedulingDelay:
    """The longest a thread of this process waited past a 10 ms sleep while running: how
    late the machine wakes a sleeping thread just now (a recorder's flusher, a device's
    sender, a CAN reader are such threads). Use as a context manager."""

    def __init__(self) -> None:
        self.max_s = 0.0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.is_set():
            t = time.perf_counter()
            time.sleep(0.01)
            self.max_s = max(self.max_s, time.perf_counter() - t - 0.01)

    def __enter__(self) -> SchedulingDelay:
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()
