"""Cost of opening sessions through the guard, and how fast bad files are refused.

Method: a recorder-like session (2 channels x 20 000 samples at 500 Hz with time stamps, a
CAN signal, raw CAN frames, events, a gap; ~1 MB) is written with SessionWriter. Timed
with time.perf_counter, median over the repeats:

* ``SessionReader`` open + close alone (the baseline, no guard);
* ``precheck`` alone (signature, superblock checksum, EOF vs size, root header);
* ``open_untrusted`` of a file never seen (a fresh copy: pre-check + probe in the worker
  + open in this process), with the worker forked (a single-threaded process, the CLI) and
  with the worker a new interpreter (a process with threads, the dashboard); the start of
  the worker is shown apart (once per process);
* ``open_untrusted`` of a file already found good (the cached verdict);
* ``untrusted_info`` of a file never seen (what the session list and ``fielddiag info``
  use: the worker's read is the only open) against ``SessionReader`` + ``info()``.

Bad files, time until the one-line refusal: the first 2000 bytes of the session, half of
it, a flipped byte in a dataset header of a file whose writer was killed (SWMR read mode),
and the same file with HDF5's default 100 metadata read attempts (a real hang: refused at
the worker's time limit, set to 3 s here).

Usage: python benchmarks/bench_session_open.py
"""

from __future__ import annotations

import shutil
import statistics
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from fielddiag import session_guard as guard
from fielddiag.channels import ChannelSpec, SessionMetadata, SignalSpec
from fielddiag.errors import FieldDiagError
from fielddiag.session import SessionReader, SessionWriter


def record(path: Path, *, close: bool = True) -> Path:
    rng = np.random.default_rng(1)
    tmp = path.with_name("writing-" + path.name)
    w = SessionWriter(tmp, SessionMetadata(vehicle="bench"),
                      [ChannelSpec("wheel_z", role="wheel"), ChannelSpec("body_z", role="body")],
                      sample_rate_hz=500.0, signals=[SignalSpec("speed", role="speed")],
                      store_can_frames=True, flush_interval_s=3600.0)
    for i in range(20):
        t = (np.arange(1000) + 1000 * i) / 500.0
        w.append_daq(rng.normal(size=(1000, 2)), t)
        w.append_signal("speed", t[::50], np.full(20, 10.0))
        w.add_event(t[0], f"block {i}")
    w.add_gap(3.0, 3.1, 50, "bench")
    w.flush()
    if not close:
        shutil.copy(tmp, path)
    w.close()
    if close:
        tmp.rename(path)
    else:
        tmp.unlink()
    return path


def ms(samples: list[float]) -> str:
    return f"{statistics.median(samples) * 1e3:8.3f} ms (median of {len(samples)})"


def timed(fn, repeat: int) -> list[float]:
    out = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
    return out


def fresh_copies(src: Path, folder: Path, n: int, tag: str) -> list[Path]:
    paths = []
    for i in range(n):
        p = folder / f"{tag}-{i}.h5"
        shutil.copy(src, p)
        paths.append(p)
    return paths


def refuse_s(path: Path) -> tuple[float, str]:
    t0 = time.perf_counter()
    try:
        guard.open_untrusted(path).close()
        return time.perf_counter() - t0, "opened (not refused)"
    except FieldDiagError as exc:
        return time.perf_counter() - t0, str(exc)


def main() -> None:
    folder = Path(tempfile.mkdtemp(prefix="bench-open-"))
    good = record(folder / "good.h5")
    killed = record(folder / "killed.h5", close=False)
    print(f"session: {good.stat().st_size} bytes; killed-writer copy "
          f"{killed.stat().st_size} bytes\n")

    base = timed(lambda: SessionReader(good).close(), 50)
    pre = timed(lambda: guard.precheck(good), 200)
    print(f"SessionReader open+close (no guard)      {ms(base)}")
    print(f"precheck alone                           {ms(pre)}")

    for mode in ("fork", "spawn"):
        guard.stop_worker()
        guard.clear_cache()
        stop = threading.Event()
        if mode == "spawn":  # a second thread, as in the dashboard
            threading.Thread(target=stop.wait, daemon=True).start()
        first = fresh_copies(good, folder, 1, f"{mode}-first")[0]
        t0 = time.perf_counter()
        guard.open_untrusted(first).close()
        start_s = time.perf_counter() - t0
        paths = fresh_copies(good, folder, 30, mode)
        it = iter(paths)
        new = timed(lambda it=it: guard.open_untrusted(next(it)).close(), len(paths))
        cached = timed(lambda p=paths[0]: guard.open_untrusted(p).close(), 50)
        verdict = timed(lambda p=paths[0]: guard.verify_untrusted(p), 500)
        infos = fresh_copies(good, folder, 30, mode + "-info")
        it2 = iter(infos)
        new_info = timed(lambda it2=it2: guard.untrusted_info(next(it2)), len(infos))
        stop.set()
        base_info = statistics.median(timed(lambda: SessionReader(good).__enter__().info(), 20))
        print(f"\nworker {mode}: first open incl. worker start {start_s * 1e3:8.1f} ms")
        print(f"  open_untrusted, new good file          {ms(new)}"
              f"  -> overhead {(statistics.median(new) - statistics.median(base)) * 1e3:.1f} ms")
        print(f"  open_untrusted, good file seen before  {ms(cached)}"
              f"  -> overhead {(statistics.median(cached) - statistics.median(base)) * 1e3:.3f}"
              " ms")
        print(f"  verify_untrusted alone, seen before    {ms(verdict)}")
        print(f"  untrusted_info, new good file          {ms(new_info)}"
              f"  (SessionReader open + info() in-process "
              f"{base_info * 1e3:.1f} ms, no guard)")

    whole = good.read_bytes()
    cases = {}
    for n in (2000, len(whole) // 2):
        p = folder / f"cut-{n}.h5"
        p.write_bytes(whole[:n])
        cases[f"first {n} bytes"] = p
    data = bytearray(killed.read_bytes())
    ohdr = [i for i in range(len(data) - 4) if data[i:i + 4] == b"OHDR"]
    data[ohdr[3] + 12] ^= 1
    flipped = folder / "killed-flipped.h5"
    flipped.write_bytes(bytes(data))
    cases["killed writer, a dataset header flipped"] = flipped

    print("\nbad files (fork worker), time to the refusal:")
    guard.stop_worker()
    guard.clear_cache()
    guard.open_untrusted(good).close()  # worker started
    for what, p in cases.items():
        s, msg = refuse_s(p)
        print(f"  {what:<42} {s * 1e3:8.1f} ms: {msg}")
    guard.stop_worker()
    guard.clear_cache()
    guard.SWMR_READ_ATTEMPTS = 100  # HDF5's default: retries for ages
    guard.DEFAULT_TIMEOUT_S = 3.0
    guard.open_untrusted(good).close()
    s, msg = refuse_s(flipped)
    print(f"  {'same, HDF5 default 100 read attempts':<42} {s * 1e3:8.1f} ms: {msg}")
    guard.stop_worker()
    shutil.rmtree(folder)


if __name__ == "__main__":
    main()
