"""A source's arrival rate is read by the recorder while its reading thread adds to it."""

from __future__ import annotations

import threading
import time

from drivers.base import RateWindow


def test_the_rate_is_read_while_another_thread_adds():
    # a deque iterated while another thread appends raises "deque mutated during
    # iteration": it stopped a demo recording once, from the CAN source's status
    window = RateWindow(maxlen=100_000)
    stop = threading.Event()

    def arrive() -> None:
        while not stop.is_set():
            window.add(1)

    reader = threading.Thread(target=arrive)
    reader.start()
    try:
        deadline = time.monotonic() + 1.0
        reads = 0
        while time.monotonic() < deadline:
            window.rate_per_s()
            reads += 1
    finally:
        stop.set()
        reader.join()
    assert reads > 10
    assert window.rate_per_s() > 1000.0


def test_the_rate_counts_the_arrivals_after_the_first_within_the_span():
    window = RateWindow(span_s=5.0)
    assert window.rate_per_s() is None
    window.add(10)
    assert window.rate_per_s() is None  # one arrival tells no rate
    t0 = time.monotonic()
    for _ in range(5):
        time.sleep(0.02)
        window.add(10)
    elapsed_s = time.monotonic() - t0
    # 50 items after the first arrival, over at least 5 sleeps of 20 ms and at most the
    # time measured around them (a loaded machine oversleeps)
    assert 50 / (elapsed_s + 0.005) <= window.rate_per_s() <= 50 / 0.1
