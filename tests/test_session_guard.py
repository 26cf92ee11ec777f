"""Opening damaged session files never hangs and never crashes (issue 14, item 2).

A truncated session of a few kB used to hang h5py for 15 minutes and more (SWMR read mode
skips HDF5's end-of-file check, and retried a bad checksum 100 times with a doubling
sleep). Every case here runs in a child process (``tests/_guard_runner.py``) with a time
limit, so a hang fails the test instead of hanging it, and a crash shows as the child's
pipe closing.
"""

from __future__ import annotations

import itertools
import json
import os
import select
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from fielddiag.channels import ChannelSpec, SessionMetadata, SignalSpec
from fielddiag.errors import SessionError
from fielddiag.session import SessionReader, SessionWriter
from fielddiag.session_guard import (
    SessionCorruptError,
    clear_cache,
    lookup3,
    open_untrusted,
    precheck,
    probe,
    stop_worker,
    untrusted_info,
    verify_untrusted,
)

RUNNER = Path(__file__).with_name("_guard_runner.py")
CASE_LIMIT_S = 20.0  # per case; a good read takes ~0.1 s, a refusal less
N_SAMPLES = 3000
CHANNELS = [ChannelSpec("wheel_z", role="wheel"), ChannelSpec("body_z", role="body")]


def _record(path: Path, *, close: bool) -> Path:
    """A session written by the recorder's writer (time stamps, a CAN signal, raw CAN
    frames, events, gaps). ``close=False`` copies the file while the writer still has it
    open, as a writer killed after its last flush leaves it."""
    rng = np.random.default_rng(7)
    w = SessionWriter(path.with_name(path.stem + "-writing.h5"),
                      SessionMetadata(vehicle="fuzz car", corner="front-left"), CHANNELS,
                      sample_rate_hz=500.0, signals=[SignalSpec("speed", role="speed")],
                      store_can_frames=True, flush_interval_s=3600.0)
    for i in range(3):
        t = (np.arange(1000) + 1000 * i) / 500.0
        w.append_daq(rng.normal(size=(1000, 2)), t)
        w.append_signal("speed", t[::50], np.full(20, 10.0 + i))
        w.add_event(t[0], f"block {i}")
    w.add_gap(2.0, 2.1, 50, "test gap")
    w.flush()
    if not close:
        path.write_bytes(w.path.read_bytes())
    w.close()
    if close:
        w.path.rename(path)
    else:
        w.path.unlink()
    return path


@pytest.fixture(scope="module")
def sources(tmp_path_factory) -> dict[str, bytes]:
    folder = tmp_path_factory.mktemp("sources")
    closed = _record(folder / "closed.h5", close=True)
    killed = _record(folder / "killed.h5", close=False)
    assert not precheck(closed).writer_open and precheck(killed).writer_open
    for p in (closed, killed):
        with SessionReader(p) as s:
            assert s.n_samples == N_SAMPLES
    return {"closed": closed.read_bytes(), "killed": killed.read_bytes()}


class Runner:
    """The child that opens and reads files; restarted after a hang or a crash."""

    def __init__(self, env: dict[str, str] | None = None) -> None:
        self.env = {**os.environ, **(env or {})}
        self.proc: subprocess.Popen | None = None

    def _start(self) -> None:
        self.proc = subprocess.Popen([sys.executable, str(RUNNER)], stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, env=self.env, text=True)
        assert json.loads(self.proc.stdout.readline()) == {"ready": True}

    def read(self, path: Path, mode: str = "guarded", limit_s: float = CASE_LIMIT_S) -> dict:
        """The child's answer, with ``elapsed_s``; status ``hang`` or ``crash`` otherwise."""
        if self.proc is None or self.proc.poll() is not None:
            self._start()
        t0 = time.monotonic()
        self.proc.stdin.write(json.dumps({"path": str(path), "mode": mode}) + "\n")
        self.proc.stdin.flush()
        ready, _, _ = select.select([self.proc.stdout], [], [], limit_s)
        if not ready:
            self.stop()
            return {"status": "hang", "elapsed_s": time.monotonic() - t0}
        line = self.proc.stdout.readline()
        if not line:
            code = self.proc.wait()
            self.proc = None
            return {"status": "crash", "message": f"exit {code}",
                    "elapsed_s": time.monotonic() - t0}
        return {**json.loads(line), "elapsed_s": time.monotonic() - t0}

    def stop(self) -> None:
        if self.proc is not None:
            self.proc.kill()
            self.proc.wait()
            self.proc.stdin.close()
            self.proc.stdout.close()
            self.proc = None


@pytest.fixture(scope="module")
def runner():
    r = Runner()
    yield r
    r.stop()


def test_lookup3_matches_the_reference_vectors():
    # from Bob Jenkins' lookup3.c driver5(); HDF5 stores this hash after its metadata
    assert lookup3(b"") == 0xDEADBEEF
    assert lookup3(b"Four score and seven years ago") == 0x17770551
    assert lookup3(b"Four score and seven years ago", 1) == 0xCD628161


@pytest.mark.parametrize("kind", ["closed", "killed"])
def test_small_truncated_session_is_refused_at_once_not_hung(tmp_path, sources, runner, kind):
    """The reported bug: the first 500-8000 bytes of a real session hung the reader."""
    whole = sources[kind]
    for n in (500, 1000, 2000, 3000, 4000, 6000, 8000):
        path = tmp_path / f"{kind}-{n}.h5"
        path.write_bytes(whole[:n])
        for mode in ("direct", "guarded"):
            answer = runner.read(path, mode)
            assert answer["status"] == "fielddiag", (n, mode, answer)
            assert answer["message"].startswith(
                f"{path} is not a complete fielddiag session (truncated at {n} of "
                f"{len(whole)} bytes)"), answer
            assert "\n" not in answer["message"]
            assert answer["elapsed_s"] < 2.0, (n, mode, answer)


def _damage(whole: bytes, cut: int | None, flips: list[tuple[int, int]]) -> bytes:
    data = bytearray(whole if cut is None else whole[:cut])
    for at, bit in flips:
        if at < len(data):
            data[at] ^= 1 << bit
    return bytes(data)


_names = itertools.count()


@st.composite
def damage(draw):
    kind = draw(st.sampled_from(["closed", "killed"]))
    if draw(st.booleans()):
        return kind, draw(st.floats(0.0, 1.0, exclude_max=True)), []
    # most metadata (superblock, object headers, B-tree/index blocks) is in the first
    # few kB and right behind the data; flip anywhere, biased to the start
    where = st.one_of(st.integers(0, 8191), st.floats(0.0, 1.0, exclude_max=True))
    flips = draw(st.lists(st.tuples(where, st.integers(0, 7)), min_size=1, max_size=4))
    return kind, None, flips


@settings(max_examples=200, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture,
                                 HealthCheck.too_slow])
@given(case=damage())
def test_fuzzed_sessions_read_or_refuse_never_hang_never_crash(tmp_path, sources, runner,
                                                               case):
    kind, cut_frac, flips = case
    whole = sources[kind]
    cut = None if cut_frac is None else int(cut_frac * len(whole))
    flips_at = [(a if isinstance(a, int) else int(a * len(whole)), b) for a, b in flips]
    path = tmp_path / f"case-{next(_names)}.h5"
    path.write_bytes(_damage(whole, cut, flips_at))
    answer = runner.read(path)
    path.unlink()
    event(f"{kind} {'cut' if cut is not None else 'flipped'}: {answer['status']}")
    assert answer["status"] in ("ok", "fielddiag"), (kind, cut, flips_at, answer)
    assert answer["elapsed_s"] < CASE_LIMIT_S
    if answer["status"] == "ok":
        # a valid read is the whole recording: damage is in the samples, not the layout
        assert answer["samples"] == N_SAMPLES and answer["values"] == 2 * N_SAMPLES, answer
        assert cut is None  # a cut file is never read as if it were whole
    else:
        assert "\n" not in answer["message"] and str(path) in answer["message"], answer


def _ohdr_offsets(data: bytes) -> list[int]:
    out, at = [], data.find(b"OHDR")
    while at >= 0:
        out.append(at)
        at = data.find(b"OHDR", at + 1)
    return out


def test_a_reader_that_hangs_is_killed_and_the_file_refused(tmp_path, sources):
    """With HDF5's own 100 metadata read attempts a damaged file of a killed writer makes
    the reader sleep for ages: the worker is killed at the time limit, the file refused,
    and the next file is read by a new worker."""
    whole = sources["killed"]
    offsets = _ohdr_offsets(whole)
    bad = tmp_path / "hangs.h5"
    bad.write_bytes(_damage(whole, None, [(offsets[3] + 12, 0)]))  # a dataset's header
    good = tmp_path / "good.h5"
    good.write_bytes(sources["closed"])
    r = Runner({"FIELDDIAG_SWMR_READ_ATTEMPTS": "100", "FIELDDIAG_OPEN_TIMEOUT_S": "3"})
    try:
        hung = r.read(bad, "direct", limit_s=4.0)
        assert hung["status"] == "hang"  # what the guard is for
        refused = r.read(bad, "guarded", limit_s=CASE_LIMIT_S)
        assert refused["status"] == "fielddiag", refused
        assert refused["message"] == (
            f"{bad} is not a complete fielddiag session (it did not open within 3 s; the "
            "reader was stopped): copy it again from the original")
        assert 3.0 <= refused["elapsed_s"] < 3.0 + 4.0, refused  # limit + killing + load
        ok = r.read(good, "guarded")
        assert ok["status"] == "ok" and ok["samples"] == N_SAMPLES, ok
    finally:
        r.stop()


def test_good_files_are_probed_once_then_cost_a_stat(tmp_path, sources):
    clear_cache()
    paths = []
    for i in range(5):
        p = tmp_path / f"good{i}.h5"
        p.write_bytes(sources["closed"])
        paths.append(p)
    verify_untrusted(paths[0])  # starts the worker
    t0 = time.perf_counter()
    for p in paths[1:]:
        verify_untrusted(p)
    first_s = (time.perf_counter() - t0) / 4
    t0 = time.perf_counter()
    for _ in range(20):
        for p in paths:
            verify_untrusted(p)
    cached_s = (time.perf_counter() - t0) / 100
    print(f"probe of a new good file {first_s * 1e3:.1f} ms, cached {cached_s * 1e3:.3f} ms")
    assert cached_s < 2e-3  # a stat and a dict look-up (~0.02 ms)
    assert first_s < 1.0
    # a file changed in place is probed again
    paths[0].write_bytes(sources["closed"][:3000])
    with pytest.raises(SessionCorruptError, match=r"truncated at 3000 of \d+ bytes"):
        verify_untrusted(paths[0])


def test_probe_reports_damage_inside_the_file_by_name(tmp_path, sources):
    whole = sources["closed"]
    path = tmp_path / "flipped.h5"
    path.write_bytes(_damage(whole, None, [(_ohdr_offsets(whole)[3] + 12, 0)]))
    precheck(path)  # the superblock and the root group are fine
    why = probe(path)
    assert why.startswith(f"{path} is not a ") and "\n" not in why, why
    stop_worker()


def test_not_a_session_at_all(tmp_path):
    junk = tmp_path / "junk.h5"
    junk.write_bytes(b"\0" * 4096)
    with pytest.raises(SessionCorruptError, match="4096 bytes, no HDF5 signature"):
        precheck(junk)
    with pytest.raises(SessionError, match="is a folder"):
        precheck(tmp_path)
    with pytest.raises(SessionError, match="does not exist"):
        verify_untrusted(tmp_path / "missing.h5")


def test_a_session_being_recorded_is_read_through_the_guard(tmp_path):
    """The dashboard lists and shows a session while its writer appends to it."""
    path = tmp_path / "live.h5"
    w = SessionWriter(path, SessionMetadata(vehicle="live"), [ChannelSpec("x")],
                      sample_rate_hz=100.0, flush_interval_s=3600.0)
    try:
        w.append_daq(np.arange(100.0)[:, None], time_s=np.arange(100) / 100)
        w.flush()
        assert precheck(path).writer_open
        info = untrusted_info(path)  # read by the worker, in SWMR mode
        assert info["samples"] == 100 and not info["closed_cleanly"]
        w.append_daq(np.arange(100.0, 250.0)[:, None], time_s=np.arange(100, 250) / 100)
        w.flush()
        assert untrusted_info(path)["samples"] == 250  # changed: read again
        with open_untrusted(path) as r:
            assert r.n_samples == 250 and r.read("x")[-1] == 249.0
    finally:
        w.close()
    info = untrusted_info(path)
    assert info["closed_cleanly"] and info["samples"] == 250


_FORKED_WORKER_AND_SOCKETS = r"""
import json, socket, sys
from fielddiag import session_guard

listener = socket.create_server(("127.0.0.1", 0))
client = socket.create_connection(listener.getsockname())
served, _ = listener.accept()  # a keep-alive connection the server holds when it forks
verdict = session_guard.probe(sys.argv[1])
forked = session_guard._worker is not None and session_guard._worker._proc is None
port = listener.getsockname()[1]
served.close()  # the server is done with the connection (a keep-alive timeout)
listener.close()
client.settimeout(5.0)
try:
    eof = client.recv(1) == b""
except TimeoutError:
    eof = False  # the worker's copy kept the connection open: no FIN reached the client
try:
    socket.create_connection(("127.0.0.1", port), timeout=5.0).close()
    refused = False  # the worker's copy of the listening socket still queued connections
except ConnectionRefusedError:
    refused = True
session_guard.stop_worker()
print(json.dumps({"verdict": verdict, "forked": forked, "eof": eof, "refused": refused}))
"""


def test_a_forked_worker_keeps_none_of_the_parents_sockets(tmp_path, sources):
    """The worker forked by a one-thread process (the dashboard does so when a page
    opens a new session on its event-loop thread) closes the descriptors it inherits.
    It used to keep the server's keep-alive connections: closed by the server, they stayed
    open, the browser sent its next request into one of them and waited forever (the
    dashboard stopped updating after a session page)."""
    good = tmp_path / "good.h5"
    good.write_bytes(sources["closed"])
    out = subprocess.run([sys.executable, "-c", _FORKED_WORKER_AND_SOCKETS, str(good)],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    answer = json.loads(out.stdout.strip().splitlines()[-1])
    assert answer["verdict"] == "" and answer["forked"]
    assert answer["eof"], "the client saw no end of the connection the server closed"
    assert answer["refused"], "the closed listening socket still accepted connections"
