"""The HDF5 session format: round trip, crash safety, lazy reading, refusal to overwrite."""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from pathlib import Path

import h5py
import numpy as np
import pytest

import fielddiag
from fielddiag.channels import (
    COUNTER_NAMES,
    ChannelSpec,
    Event,
    Gap,
    SessionMetadata,
    SignalSpec,
)
from fielddiag.errors import ChannelNotFoundError, SessionError
from fielddiag.session import (
    CAN_FRAME_DTYPE,
    SCHEMA_VERSION,
    SessionReader,
    SessionWriter,
    write_session,
)

META = SessionMetadata(
    vehicle="Toyota Camry",
    corner="rear-left",
    operator="J. Doe",
    added_mass_kg=42.5,
    notes="bumpy road, 2 passengers; ünïcode ok",
    t0_unix_s=1_700_000_000.25,
    extra={"road": "B-class", "tyre_pressure_bar": 2.3},
)
CHANNELS = [
    ChannelSpec(
        "wheel_z",
        unit="m/s2",
        role="wheel",
        axis="z",
        sensor="ADXL355 #17",
        scale=3.9e-6 * 9.80665,
        offset=0.0,
        dtype="int32",
    ),
    ChannelSpec(
        "body_z",
        unit="m/s2",
        role="body",
        axis="z",
        sensor="ADXL355 #18",
        scale=3.9e-6 * 9.80665,
        offset=-0.01,
        dtype="int32",
    ),
    ChannelSpec("temp", unit="degC", role="other", axis="", sensor="NTC", dtype="float32"),
]
SIGNALS = [SignalSpec("vehicle_speed", unit="m/s", source="can", message="SPEED", role="speed")]


@dataclass
class Sent:
    """What :func:`_record` gave the writer, to compare with what comes back."""

    raw: list[dict[str, np.ndarray]]  # DAQ blocks, channel name -> raw samples
    time_s: np.ndarray  # every DAQ sample time, concatenated
    signal_time_s: np.ndarray  # vehicle_speed times, concatenated
    signal_value: np.ndarray  # vehicle_speed values, concatenated
    frames: np.ndarray  # raw CAN frames


def _record(path: Path, rng: np.random.Generator, meta: SessionMetadata = META) -> Sent:
    n_blocks, block = 37, 1000
    raw, times, sig_t, sig_v = [], [], [], []
    with SessionWriter(
        path,
        meta,
        CHANNELS,
        sample_rate_hz=1000.0,
        signals=SIGNALS,
        store_can_frames=True,
        flush_interval_s=0.05,
    ) as w:
        for b in range(n_blocks):
            blk = {
                "wheel_z": rng.integers(-(2**20), 2**20, block, dtype="int32"),
                "body_z": rng.integers(-(2**20), 2**20, block, dtype="int32"),
                "temp": rng.normal(25, 1, block).astype("float32"),
            }
            t = (b * block + np.arange(block)) / 1000.0 + 1e-7 * b  # device jitter
            w.append_daq(blk, time_s=t)
            raw.append(blk)
            times.append(t)
            # speed with full-precision noise so that every bit of the value matters
            st, sv = t[::20], 10.0 + b + rng.normal(0.0, 1e-3, block // 20)
            w.append_signal("vehicle_speed", st, sv)
            sig_t.append(st)
            sig_v.append(sv)
        frames = np.zeros(3, dtype=CAN_FRAME_DTYPE)
        frames["time_s"] = [0.1, 0.2, 0.3]
        frames["arbitration_id"] = [0x0B4, 0x18FEF100, 0x0AA]
        frames["flags"] = [0, 1, 0]
        frames["dlc"] = [8, 8, 8]
        frames["data"][0, :8] = [0, 0, 0, 0, 0x1D, 0x0B, 0x7A, 0x5E]
        w.append_can_frames(frames)
        w.add_event(1.5, "speed bump")
        w.add_event(20.0, "pothole")
        w.add_gap(10.0, 10.2, 200, "sequence gap")
        w.set_counters(frames_received=370, frames_lost=2, crc_errors=5)
    return Sent(raw, np.concatenate(times), np.concatenate(sig_t), np.concatenate(sig_v), frames)


def test_round_trip_every_attribute_and_sample(tmp_path, rng):
    path = tmp_path / "s.h5"
    meta = dataclasses.replace(
        META, created="2024-05-06T07:08:09.123Z", software_version="9.8.7-roundtrip"
    )
    sent = _record(path, rng, meta)
    with SessionReader(path) as s:
        # every root attribute, the given created/software_version included
        assert s.metadata == meta
        assert s.metadata.created == "2024-05-06T07:08:09.123Z"
        assert s.metadata.software_version == "9.8.7-roundtrip"
        assert s.closed_cleanly
        # the DAQ group: schema, time base, rate
        assert s.info()["schema_version"] == SCHEMA_VERSION == 1
        assert s.time_base == "timestamps"
        assert s.sample_rate_hz == 1000.0
        # every channel attribute, through the reader and as stored in the file
        assert s.channels == CHANNELS
        for got, want in zip(s.channels, CHANNELS, strict=True):
            assert (got.unit, got.role, got.axis, got.sensor) == (
                want.unit,
                want.role,
                want.axis,
                want.sensor,
            )
            assert (got.scale, got.offset, got.dtype) == (want.scale, want.offset, want.dtype)
        with h5py.File(path, "r") as f:
            assert f.attrs["schema_version"] == SCHEMA_VERSION
            assert f["daq"].attrs["time_base"] == "timestamps"
            assert f["daq"].attrs["sample_rate_hz"] == 1000.0
            for c in CHANNELS:
                attrs = f["daq/channels"][c.name].attrs
                assert (attrs["unit"], attrs["role"], attrs["axis"], attrs["sensor"]) == (
                    c.unit,
                    c.role,
                    c.axis,
                    c.sensor,
                )
                assert json.loads(attrs["calibration"]) == {"scale": c.scale, "offset": c.offset}
        # every DAQ sample and time stamp, bit for bit
        for name in ("wheel_z", "body_z", "temp"):
            stored = s.read(name, raw=True)
            sent_col = np.concatenate([b[name] for b in sent.raw])
            assert stored.dtype == sent_col.dtype
            assert stored.tobytes() == sent_col.tobytes()
        assert s.time_s().tobytes() == sent.time_s.tobytes()
        cal = s.read("body_z")
        np.testing.assert_allclose(
            cal,
            np.concatenate([b["body_z"] for b in sent.raw]) * CHANNELS[1].scale - 0.01,
            rtol=1e-12,
        )
        # the CAN signal: spec, times and values bit for bit
        assert s.signals == SIGNALS
        t, v = s.signal("vehicle_speed")
        assert t.tobytes() == sent.signal_time_s.tobytes()
        assert v.tobytes() == sent.signal_value.tobytes()
        assert len(t) == 37 * 50
        # events, gaps, counters and raw CAN frames exactly
        assert s.events == [Event(1.5, "speed bump"), Event(20.0, "pothole")]
        assert s.gaps == [Gap(10.0, 10.2, 200, "sequence gap")]
        assert s.counters == {
            **dict.fromkeys(COUNTER_NAMES, 0),
            "frames_received": 370,
            "frames_lost": 2,
            "crc_errors": 5,
        }
        assert s.can_frames().tobytes() == sent.frames.tobytes()
        assert s.n_samples == 37000
        assert s.duration_s == pytest.approx(37.0, abs=1e-5)
        info = s.info()
        json.dumps(info)
        assert info["samples_lost"] == 200 and info["channels"][0]["role"] == "wheel"


def test_writer_fills_in_created_and_software_version(tmp_path, rng):
    path = tmp_path / "s.h5"
    before = datetime.now(UTC)
    _record(path, rng)
    with SessionReader(path) as s:
        md = s.metadata
    created = datetime.fromisoformat(md.created.replace("Z", "+00:00"))
    assert md.created.endswith("Z")
    assert before - timedelta(seconds=1) <= created <= datetime.now(UTC)
    assert md.software_version == fielddiag.__version__
    assert dataclasses.replace(md, created="", software_version="") == META


def test_slicing_by_time_and_roles(tmp_path, rng):
    path = tmp_path / "s.h5"
    sent = _record(path, rng)
    times = sent.time_s
    with SessionReader(path) as s:
        t, v = s.read_with_time("wheel_z", 5.0, 7.5)
        assert t[0] >= 5.0 and t[-1] < 7.5 and len(t) == 2500
        mask = (times >= 5.0) & (times < 7.5)
        np.testing.assert_array_equal(t, times[mask])
        assert s.channel_for_role("body").name == "body_z"
        with pytest.raises(ChannelNotFoundError, match="no channel with role 'force'"):
            s.channel_for_role("force")
        with pytest.raises(ChannelNotFoundError, match="has no channel 'nope'"):
            s.read("nope")
        # CAN speed onto DAQ time: the last value received, or interpolated
        sp = s.signal_on_daq_time("vehicle_speed", 3.0, 4.0, method="previous")
        held = np.searchsorted(sent.signal_time_s, times[(times >= 3.0) & (times < 4.0)], "right")
        np.testing.assert_array_equal(sp, sent.signal_value[held - 1])
        assert np.all(np.abs(sp - 13.0) < 0.01)  # block 3 of the drive
        lin = s.signal_on_daq_time("vehicle_speed", 0.0, 37.0)
        assert lin.shape == (37000,)
        np.testing.assert_array_equal(lin, np.interp(times, sent.signal_time_s, sent.signal_value))


def test_uniform_time_base(tmp_path):
    data = np.arange(5000, dtype="f8").reshape(-1, 1)
    write_session(
        tmp_path / "u.h5", META, [ChannelSpec("x", role="body")], data, sample_rate_hz=200.0
    )
    with SessionReader(tmp_path / "u.h5") as s:
        assert s.time_base == "uniform"
        t, v = s.read_with_time("x", 1.0, 2.0)
        assert len(t) == 200 and t[0] == 1.0 and v[0] == 200.0
        assert s.duration_s == pytest.approx(25.0)


def test_never_overwrites_unless_asked(tmp_path):
    path = tmp_path / "keep.h5"
    data = np.ones((10, 1))
    write_session(path, META, [ChannelSpec("x")], data, sample_rate_hz=10.0)
    before = path.read_bytes()
    with pytest.raises(SessionError, match="already exists"):
        write_session(path, META, [ChannelSpec("x")], 2 * data, sample_rate_hz=10.0)
    with pytest.raises(SessionError, match="already exists"):
        SessionWriter(path, META, [ChannelSpec("x")], sample_rate_hz=10.0)
    assert path.read_bytes() == before
    write_session(path, META, [ChannelSpec("x")], 2 * data, sample_rate_hz=10.0, overwrite=True)
    with SessionReader(path) as s:
        assert s.read("x")[0] == 2.0


def test_atomic_write_leaves_nothing_on_error(tmp_path):
    path = tmp_path / "a.h5"
    with pytest.raises(RuntimeError):
        with SessionWriter(path, META, [ChannelSpec("x")], sample_rate_hz=10.0, atomic=True) as w:
            w.append_daq(np.ones((5, 1)), time_s=np.arange(5.0))
            raise RuntimeError("import failed half way")
    assert list(tmp_path.iterdir()) == []


def test_bad_files_get_clear_errors(tmp_path):
    with pytest.raises(SessionError, match="does not exist"):
        SessionReader(tmp_path / "missing.h5")
    junk = tmp_path / "junk.h5"
    junk.write_bytes(b"not hdf5 at all")
    with pytest.raises(SessionError, match="not a readable session"):
        SessionReader(junk)
    with h5py.File(tmp_path / "other.h5", "w") as f:
        f["x"] = 1
    with pytest.raises(SessionError, match="not a fielddiag session"):
        SessionReader(tmp_path / "other.h5")


def test_a_truncated_copy_is_refused_not_read_as_zeros(tmp_path):
    path = tmp_path / "cut.h5"
    data = np.arange(200_000, dtype="f8").reshape(-1, 2) + 1.0
    write_session(path, META, [ChannelSpec("x"), ChannelSpec("y")], data, sample_rate_hz=500.0)
    whole = path.read_bytes()
    path.write_bytes(whole[: len(whole) // 2])  # an interrupted copy
    with pytest.raises(SessionError, match=r"not a complete fielddiag session "
                       r"\(truncated at \d+ of \d+ bytes\): copy it again"):
        SessionReader(path)


def test_read_while_recording(tmp_path):
    path = tmp_path / "live.h5"
    w = SessionWriter(path, META, [ChannelSpec("x")], sample_rate_hz=100.0, flush_interval_s=0.05)
    w.append_daq(np.arange(100.0)[:, None], time_s=np.arange(100) / 100)
    time.sleep(0.3)
    r = SessionReader(path)
    assert not r.closed_cleanly
    assert r.n_samples == 100
    w.append_daq(np.arange(100.0, 250.0)[:, None], time_s=np.arange(100, 250) / 100)
    time.sleep(0.3)
    r.refresh()
    assert r.n_samples == 250 and r.read("x")[-1] == 249.0
    w.close()
    r.close()
    with SessionReader(path) as s:
        assert s.closed_cleanly


class _SlowDiskWriter(SessionWriter):
    """A writer whose every flush takes ``flush_cost_s`` (a slow SD card); it notes
    when each flush starts and sets ``enough`` after ``wanted`` of them."""

    flush_cost_s = 0.15
    wanted = 7

    def __init__(self, *args, **kwargs) -> None:
        self.flush_starts: list[float] = []
        self.enough = threading.Event()
        super().__init__(*args, **kwargs)

    def flush(self) -> None:
        self.flush_starts.append(time.monotonic())
        time.sleep(self.flush_cost_s)  # the slow disk, not a synchronisation
        super().flush()
        if len(self.flush_starts) >= self.wanted:
            self.enough.set()


def test_flushes_start_every_interval_even_when_flushing_is_slow(tmp_path):
    """The durable period is the flush interval, not interval + flush time."""
    interval_s = 0.25
    w = _SlowDiskWriter(
        tmp_path / "slow.h5",
        META,
        [ChannelSpec("x")],
        sample_rate_hz=100.0,
        flush_interval_s=interval_s,
    )
    try:
        w.append_daq(np.arange(100.0)[:, None], time_s=np.arange(100) / 100)
        assert w.enough.wait(10.0)
    finally:
        w.close()
    gaps_s = np.diff(w.flush_starts[: w.wanted])
    # waiting a fixed interval after each flush would give 0.25 + 0.15 = 0.40 s
    assert gaps_s.max() < interval_s + 0.06, gaps_s
    assert np.mean(gaps_s) == pytest.approx(interval_s, abs=0.02)
    with SessionReader(tmp_path / "slow.h5") as s:
        assert s.read("x").tolist() == list(range(100))


def test_sigkill_loses_at_most_one_second(tmp_path):
    """A real writer process is killed with SIGKILL; the file must open and hold every
    sample the writer had received up to 1 s before the kill, bit for bit."""
    path = tmp_path / "killed.h5"
    child = Path(__file__).with_name("_writer_child.py")
    proc = subprocess.Popen(
        [sys.executable, str(child), str(path)], stdout=subprocess.PIPE, text=True
    )
    progress: list[tuple[int, float]] = []
    assert proc.stdout is not None
    live_checked = False
    for line in proc.stdout:
        n, t = line.split()
        progress.append((int(n), float(t)))
        if not live_checked and progress[-1][1] - progress[0][1] > 1.5:
            with SessionReader(path) as live:  # another process reads while it records
                assert live.swmr and not live.closed_cleanly
                assert live.n_samples >= max(k for k, tk in progress if tk <= time.monotonic() - 1)
            live_checked = True
        if progress[-1][1] - progress[0][1] > 2.5:  # the writer has run 2.5 s
            break
    kill_time = time.monotonic()
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert proc.returncode == -signal.SIGKILL
    received_1s_before = max(n for n, t in progress if t <= kill_time - 1.0)
    with SessionReader(path) as s:
        assert not s.closed_cleanly
        n = s.n_samples
        assert n >= received_1s_before, (n, received_1s_before)
        assert n <= progress[-1][0] + 100
        idx = np.arange(n)
        for c in range(4):
            expected = ((idx * (c + 1)) % 32768).astype("int16")
            assert s.read(f"ch{c}", raw=True).tobytes() == expected.tobytes()
        np.testing.assert_array_equal(s.time_s(), idx / 2000.0)
        assert s.events[0] == Event(0.0, "block 0")
