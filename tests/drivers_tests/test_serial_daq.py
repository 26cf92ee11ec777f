"""Serial DAQ driver end to end over a real pseudo-terminal, against the virtual DAQ.

Streaming tests run a few seconds each; the longest (timestamps against a skewed,
jittery device clock) takes 20 s.
"""

from __future__ import annotations

import os
import threading
import time

import numpy as np
import pytest
from _daq_helpers import collect, expected_samples, missing_seqs, noise_signals

from drivers import open_source, parse_source_url, source_class
from drivers.base import SessionClock
from drivers.can_vehicle import CanLogSource
from drivers.clock_fit import DeviceClockFit
from drivers.serial_daq import SerialDAQSource, SerialTextSource, list_ports
from drivers.virtual import PtyLink, VirtualDAQ
from fielddiag.errors import DeviceError


def _open(daq: VirtualDAQ, query: str = "") -> SerialDAQSource:
    src = open_source(f"serial://{daq.path}{query}")
    src.seq_log = []
    src.open()
    return src


# ------------------------------------------------------------------ URLs and registry
def test_urls_pick_drivers_like_python_can_interfaces(tmp_path):
    s = open_source("serial:///dev/ttyUSB0?baud=115200&roles=body,wheel")
    assert isinstance(s, SerialDAQSource)
    assert (s.port, s.baudrate, s.roles) == ("/dev/ttyUSB0", 115200, ["body", "wheel"])
    t = open_source("serial+ascii:///dev/ttyACM0?rate=100&scale=0.01&unit=m/s2")
    assert isinstance(t, SerialTextSource) and (t.rate_hz, t.scale) == (100.0, 0.01)
    assert source_class("canlog://logs/a.asc?dbc=x.dbc") is CanLogSource
    assert open_source("canlog://logs/a.asc?dbc=x.dbc").path == "logs/a.asc"
    assert open_source("canlog:///abs/a.blf").path == "/abs/a.blf"
    assert parse_source_url("serial://COM3").location == "COM3"
    with pytest.raises(DeviceError, match="no driver for bogus://"):
        open_source("bogus://x")
    with pytest.raises(DeviceError, match="unknown option.*bauds"):
        open_source("serial:///dev/ttyUSB0?bauds=9600")
    with pytest.raises(DeviceError, match="not a source URL"):
        open_source("/dev/ttyUSB0")


# ------------------------------------------------------------------ clean stream
def test_clean_stream_is_stored_bit_for_bit():
    rate = 1000.0
    with VirtualDAQ(noise_signals(20000, 3), sample_rate_hz=rate, sample_format="int32") as daq:
        src = _open(daq)
        assert [c.name for c in src.channels] == ["wheel_z", "body_z", "ch2"]
        assert [c.role for c in src.channels] == ["wheel", "body", "other"]
        assert all(c.dtype == "int32" for c in src.channels)
        assert src.channels[0].scale == pytest.approx(16 * 9.80665 / 2**31, rel=1e-12)
        got = collect(src, 2.0)
        src.close()
    seqs = src.seq_log
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs))) and len(seqs) >= 150
    assert got.samples.dtype == np.int32
    assert np.array_equal(got.samples, expected_samples(daq, seqs))
    t = got.time_s
    # device-timed samples: spacing is the sample period up to the fitted drift and the
    # slew of the clock mapping (<= 500 ppm + 1.5e-3)
    assert np.all(np.abs(np.diff(t) * rate - 1.0) < 2.5e-3)
    assert got.gaps == [] and src.counters()["frames_lost"] == 0
    assert src.counters()["crc_errors"] == 0 and src.counters()["bytes_discarded"] == 0
    # session time of the first sample: acquired just before START was answered
    assert -0.05 < t[0] < 0.2


# ------------------------------------------------------------------ faults
def test_corruption_garbage_and_pulled_cable_counted_exactly():
    rate, nch = 1000.0, 4
    daq = VirtualDAQ(
        noise_signals(40000, nch),
        sample_rate_hz=rate,
        corrupt_rate=1e-3,
        garbage_every_s=0.4,
        disconnect_at_s=1.5,
        disconnect_for_s=2.0,
        seed=5,
    ).start()
    clock = SessionClock()
    try:
        src = _open(daq)
        got = collect(src, 6.5, clock)
        src.close()
    finally:
        daq.stop()
    seqs = src.seq_log
    n = daq.samples_per_frame
    c = src.counters()
    # every sample that passed the CRC is exactly what the device sent
    assert np.array_equal(got.samples, expected_samples(daq, seqs))
    assert np.all(np.diff(got.time_s) > 0)
    # frames lost are counted exactly: every missing sequence number, nothing else
    lost = missing_seqs(seqs)
    assert c["frames_received"] == len(seqs)
    assert c["frames_lost"] == len(lost) > 0
    assert c["samples_lost"] == len(lost) * n == sum(g.samples_lost for g in got.gaps)
    # every frame the device damaged was dropped, and counted as a CRC failure
    st = daq.stats
    damaged = {s for s in st.corrupted_seqs if seqs[0] <= s <= seqs[-1]}
    assert damaged and damaged <= set(lost)
    t_disc = st.disconnect_times[0]
    t_reconn = clock.t0_monotonic_s + next(
        e.time_s for e in got.events if e.label.startswith("DAQ reconnected")
    )
    when = dict(zip(st.written_seqs, st.written_at, strict=True))
    in_outage = {s for s, t in when.items() if t_disc - 0.5 <= t <= t_reconn + 0.1}
    seen_damaged = {s for s in damaged if s in when and s not in in_outage}
    # a damaged frame reaches the host and fails a CRC, unless a flip hit its sync word
    assert c["crc_errors"] >= len(seen_damaged) * 0.9
    assert c["bytes_discarded"] >= st.garbage_bytes * 0.9
    # the pulled cable: one reconnect, one "disconnected" gap covering the outage
    assert c["reconnects"] == 1 and st.disconnects == 1
    outage = [g for g in got.gaps if g.cause == "disconnected"]
    assert outage and max(g.samples_lost for g in outage) >= 2.0 * rate
    for g in got.gaps:
        # device time of the missing samples, seen through the clock mapping whose rate
        # is 1 +- 2e-3 (fitted drift + slew) while it slews the offset in
        dur = g.samples_lost / rate
        assert g.end_s - g.start_s == pytest.approx(dur, abs=1e-3 + 2.5e-3 * dur)
    labels = [e.label for e in got.events]
    assert labels[0] == "DAQ disconnected" and labels[1].startswith("DAQ reconnected")
    # intact frames that never arrived were in the pty when the cable was pulled, or
    # flushed when the port was reopened; frames never written fully were dropped by the
    # device during the outage
    for s in set(lost) - damaged:
        assert s not in when or s in in_outage


def test_device_reboot_gives_an_estimated_gap():
    rate = 500.0
    daq = VirtualDAQ(
        noise_signals(20000, 2),
        sample_rate_hz=rate,
        disconnect_at_s=1.0,
        disconnect_for_s=1.0,
        power_cycle_on_disconnect=True,
    ).start()
    try:
        src = _open(daq)
        got = collect(src, 4.5)
        src.close()
    finally:
        daq.stop()
    restart = [g for g in got.gaps if g.cause.startswith("device restarted")]
    assert len(restart) == 1
    g = restart[0]
    # outage 1 s + reconnect back-off (< 1.6 s) + handshake; estimate from host time
    assert 1.0 <= g.end_s - g.start_s <= 3.5
    assert g.samples_lost == pytest.approx((g.end_s - g.start_s) * rate, abs=1.0)
    assert src.counters()["frames_lost"] == 0  # no sequence gap could be counted
    assert np.all(np.diff(got.time_s) > 0)
    # samples after the reboot are the device's data from its start again
    i = np.searchsorted(got.time_s, g.end_s)
    assert np.array_equal(got.samples[i : i + 5], daq.truth(0)[:5])


def test_stall_loses_nothing_and_keeps_device_timing():
    rate = 500.0
    daq = VirtualDAQ(
        noise_signals(20000, 2), sample_rate_hz=rate, stall_at_s=0.8, stall_for_s=1.2
    ).start()
    try:
        src = _open(daq)
        got = collect(src, 3.5)
        src.close()
    finally:
        daq.stop()
    seqs = src.seq_log
    assert missing_seqs(seqs) == [] and src.counters()["reconnects"] == 0
    assert np.array_equal(got.samples, expected_samples(daq, seqs))
    # the burst after the stall keeps the device's sample times, not arrival times
    assert np.all(np.abs(np.diff(got.time_s) * rate - 1.0) < 2.5e-3)


def test_pulled_cable_loses_exactly_what_the_device_dropped():
    """2 s without cable: the frames lost are the device's own count, no more.

    The device counts what it could not send: frames made while the cable was out, those
    still queued when it was pulled, and those the host had not read from the pty yet.
    Frames it sent after coming back, before the host reopened the port, are kept."""
    rate, outage_s = 1000.0, 2.0
    daq = VirtualDAQ(
        noise_signals(40000, 2), sample_rate_hz=rate, disconnect_at_s=1.0,
        disconnect_for_s=outage_s,
    ).start()
    clock = SessionClock()
    try:
        src = _open(daq)
        got = collect(src, 4.5, clock)
        src.close()
    finally:
        daq.stop()
    seqs, st, n = src.seq_log, daq.stats, daq.samples_per_frame
    dropped = sorted(q for q in st.dropped_seqs if seqs[0] <= q <= seqs[-1])
    assert missing_seqs(seqs) == dropped
    assert src.counters()["frames_lost"] == len(dropped) == st.frames_dropped
    assert len(dropped) >= outage_s * rate / n  # the outage itself: 200 frames
    assert np.array_equal(got.samples, expected_samples(daq, seqs))
    (gap,) = got.gaps
    assert gap.cause == "disconnected" and gap.samples_lost == len(dropped) * n
    # the port is watched every 50 ms: reopened within 0.3 s of the device's return
    back = st.disconnect_times[0] + outage_s - clock.t0_monotonic_s
    reconnected = next(e.time_s for e in got.events if e.label.startswith("DAQ reconnected"))
    assert 0.0 < reconnected - back < 0.3


def test_timestamps_follow_the_device_clock_under_skew_and_jitter():
    """A device clock 300 ppm slow, frames sent 0..10+ ms late (exponential, mean 2 ms).

    The error of a time stamp is its distance from the host time at which the device
    acquired the sample. It has a constant part no host can see, the least delay of the
    path (pty, scheduler: 0.1-0.6 ms here, depending on the machine's load), and the part
    the clock fit is responsible for: how far the stamps stray from the device clock. That
    part stays under 1 ms from the first sample stored."""
    ppm, rate = -300.0, 500.0
    daq = VirtualDAQ(
        noise_signals(20000, 2), sample_rate_hz=rate, clock_drift_ppm=ppm, tx_jitter_s=0.002,
        seed=4,
    )
    clock = SessionClock()
    with daq:
        src = _open(daq)
        got = collect(src, 20.0, clock)
        src.close()
    n = daq.samples_per_frame
    host_rate = rate * (1 + ppm * 1e-6)  # the device's 500 Hz seen on the host clock
    true = (
        np.concatenate([daq.acquired_at(q) + np.arange(n) / host_rate for q in src.seq_log])
        - clock.t0_monotonic_s
    )
    err = got.time_s - true
    assert np.ptp(err) < 1e-3, (err.min(), err.max())  # following the device clock
    # never stamped before it existed; the least delay of a loaded machine included,
    # never more than 1.5 ms late
    assert -0.2e-3 < err.min() and err.max() < 1.5e-3, (err.min(), err.max())
    assert src.status()["drift_ppm"] == pytest.approx(ppm, abs=40.0)
    # no jumps: the mapping slews by <= 1.5e-3 around the device's rate
    assert np.all(np.abs(np.diff(got.time_s) * host_rate - 1.0) < 2.5e-3)


def _mapped_as_a_driver_does(fit: DeviceClockFit, t_dev: np.ndarray,
                             arrival: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Feed each frame's device time and arrival to ``fit`` and map it as the serial driver
    does (steer, map, steer); returns the device and mapped times once it has settled."""
    rows = []
    for d, h in zip(t_dev, arrival, strict=True):
        fit.observe(d, h)
        if fit.settled:
            if not fit.locked:
                fit.steer(d)
            rows.append((d, float(fit.map(d))))
            fit.steer(d)
    return tuple(np.array(rows).T)


def test_clock_fit_on_synthetic_latencies():
    rng = np.random.default_rng(3)
    drift_ppm, offset = -250.0, 123.456
    fit = DeviceClockFit()
    t_dev = np.arange(0.0, 120.0, 0.02)
    t_true = offset + t_dev / (1 + drift_ppm * 1e-6)  # host time when each instant happened
    arrival = t_true + 0.0003 + rng.exponential(0.004, t_dev.size)  # latency, heavy tail
    _, mapped = _mapped_as_a_driver_does(fit, t_dev, arrival)
    assert fit.drift_ppm == pytest.approx(drift_ppm, abs=5.0)
    assert np.all(np.diff(mapped) > 0)
    err = mapped - t_true[-len(mapped):]
    assert np.max(np.abs(err)) < 1.5e-3  # min latency 0.3 ms + fit error, from the start
    assert np.max(np.abs(err[-3000:])) < 0.5e-3  # the last minute


def test_clock_fit_ignores_bursts_and_survives_a_clock_step():
    """A backlog arriving at once (after a stall) does not tilt the fit; a device clock set
    forward by 5 ms is followed within seconds."""
    fit = DeviceClockFit()
    d = np.round(np.arange(0.0, 30.0, 0.01), 2)
    h = 10.0 + d + 0.0002
    h[(d >= 5.0) & (d < 6.5)] = 6.5 + 10.0 + 0.0002  # a 1.5 s stall, then a burst
    h[d >= 15.0] -= 0.005  # the device clock jumps 5 ms ahead
    for di, hi in zip(d, h, strict=True):
        fit.observe(di, hi)
        if di in (4.99, 6.7, 14.99):  # just before the stall, after it, before the step
            assert fit.fitted(di) - (10.0 + di) == pytest.approx(0.0002, abs=2e-5)
            assert abs(fit.drift_ppm) < 20.0
    assert fit.fitted(d[-1]) - h[-1] == pytest.approx(0.0, abs=2e-5)
    assert abs(fit.drift_ppm) < 20.0


@pytest.mark.parametrize("load_from_s, load_s", [(8.0, 4.0), (8.0, 10.0), (20.0, 10.0),
                                                 (40.0, 20.0)])
def test_clock_fit_keeps_a_continuous_time_base_through_a_growing_backlog(load_from_s, load_s):
    """A host busy for seconds reads every frame later and later (here up to 0.8 s), then
    the backlog clears at once. No frame is lost, so the time base must not jump: a
    recorder under CI-like load once stepped it by 0.4 s forward and back, and the
    full-vehicle analysis refused the drive for "gaps in its time base"."""
    fit = DeviceClockFit()
    t_dev = np.arange(0.0, 70.0, 0.01)  # 100 frames a second, device time of each
    true = 100.0 + t_dev  # host time when each frame was complete
    delay = np.full(t_dev.size, 0.0005)
    busy = (t_dev >= load_from_s) & (t_dev < load_from_s + load_s)
    delay[busy] += 0.8 * (t_dev[busy] - load_from_s) / load_s
    arrival = np.maximum.accumulate(true + delay)  # the backlog arrives in a burst after
    d, m = _mapped_as_a_driver_does(fit, t_dev, arrival)
    spacing = np.diff(m) / np.diff(d)
    assert 0.997 < spacing.min() and spacing.max() < 1.003  # slewed (<= 2e-3), never stepped
    assert np.abs(m - (100.0 + d)).max() < 0.02  # the backlog lifted the mapping < 20 ms


# ------------------------------------------------------------------ handshake errors
def test_handshake_errors_say_what_to_do(tmp_path):
    with pytest.raises(DeviceError, match="cannot open .*fielddiag ports"):
        open_source(f"serial://{tmp_path}/nothing").open()
    link = PtyLink("ttySILENT", "test")
    try:
        src = open_source(f"serial://{link.path}?handshake_timeout=0.5")
        with pytest.raises(DeviceError, match="nothing arrived"):
            src.open()
        stop = threading.Event()
        lines = [f"{1000 * k},0.1,0.2\n".encode() for k in range(200)]
        th = threading.Thread(target=_text_streamer, args=(link, stop, lines, 100.0))
        th.start()
        with pytest.raises(DeviceError, match="serial\\+ascii"):
            src.open()
        stop.set()
        th.join()
    finally:
        link.close()


def test_ports_lists_running_virtual_daq():
    with VirtualDAQ(noise_signals(1000, 2), sample_rate_hz=100.0) as daq:
        devices = [p["device"] for p in list_ports()]
        assert daq.path in devices
    assert daq.path not in [p["device"] for p in list_ports()]


# ------------------------------------------------------------------ text mode
def _text_streamer(
    link: PtyLink, stop: threading.Event, lines: list[bytes], rate: float, delay_s: float = 0.0
):
    stop.wait(delay_s)  # like a board that boots after the port was opened
    i = 0
    t0 = time.monotonic()
    while not stop.is_set() and i < len(lines):
        if time.monotonic() - t0 >= i / rate:
            link.write(lines[i])
            i += 1
        else:
            time.sleep(0.001)


def test_text_mode_values_gaps_and_micros_wrap():
    rate = 200.0
    n = 600
    t_us = (2**32 - 1_000_000 + np.arange(n) * 5000) % 2**32  # micros() wraps after 1 s
    vals = np.round(np.random.default_rng(1).normal(0, 3, (n, 2)), 4)
    lines = [b"t_us,wheel,body\n"] + [
        f"{t},{a:.4f},{b:.4f}\n".encode() for t, (a, b) in zip(t_us, vals, strict=True)
    ]
    lines[300] = b"garbage line\n"  # sample 299 damaged
    lines[451] = b""  # sample 450 never sent (its time slot passes in silence)
    link = PtyLink("ttyTXT0", "test")
    stop = threading.Event()
    th = threading.Thread(target=_text_streamer, args=(link, stop, lines, rate, 0.3), daemon=True)
    th.start()
    try:
        src = open_source(f"serial+ascii://{link.path}?rate=200&roles=wheel,body")
        src.open()
        assert [c.name for c in src.channels] == ["wheel", "body"]
        got = collect(src, 3.6)
        src.close()
    finally:
        stop.set()
        th.join()
        link.close()
    # the first lines went by during open(); everything after is exact
    t = got.time_s
    k0 = int(np.flatnonzero(np.all(vals == got.samples[0], axis=1))[0])
    keep = [k for k in range(k0, n) if k not in (299, 450)]
    assert np.array_equal(got.samples, vals[keep])
    assert [g.samples_lost for g in got.gaps] == [1, 1]
    assert src.counters()["crc_errors"] == 1
    # across the 32-bit wrap the times stay uniform
    d = np.diff(t)
    assert np.all(d > 0)
    normal = d[d < 1.5 / rate]
    assert np.all(np.abs(normal * rate - 1) < 3e-3)


def test_pty_link_path_comes_back_after_unplug():
    link = PtyLink("ttyX", "test")
    try:
        first = os.path.realpath(link.path)
        link.disconnect()
        assert not os.path.exists(link.path)
        link.connect()
        assert os.path.exists(link.path) and os.path.realpath(link.path).startswith("/dev/pts/")
        assert first.startswith("/dev/pts/")
    finally:
        link.close()


def test_sequence_wrap_counts_the_frame_lost_across_it():
    """The sequence number wraps at 2**32: a frame missing right at the wrap is one frame
    lost, and the time stamps run on without a jump (fed to the driver without a port)."""
    from drivers.protocol import ChannelInfo, DeviceInfo, FrameParser, encode_data

    rate, n = 1000.0, 10
    src = SerialDAQSource("serial://test", "test")
    src.info = DeviceInfo("T", "test", rate, 2, n, (ChannelInfo(100.0), ChannelInfo(100.0)))
    src.clock = SessionClock()
    parser = FrameParser()
    seqs = [(2**32 - 30 + k) % 2**32 for k in range(60) if k != 30]  # seq 0 never arrives
    blocks = []
    for q in seqs:
        i = (q - (2**32 - 30)) % 2**32
        frame = encode_data(q, 5_000_000 + i * 10_000, np.full((n, 2), i), 2)
        src._backlog.extend((f, 0.001 + i * 0.01) for f in parser.feed(frame))
        b = src._process(b"", 0.001 + i * 0.01)
        if b is not None:
            blocks.append(b)
    t = np.concatenate([b.time_s for b in blocks])
    gaps = [g for b in blocks for g in b.gaps]
    assert src.counters()["frames_lost"] == 1 and src.counters()["frames_received"] == 59
    assert [g.samples_lost for g in gaps] == [n]
    assert np.all(np.abs(np.diff(t) * rate - 1.0)[np.diff(t) < 2 / rate] < 2e-3)
    assert gaps[0].end_s - gaps[0].start_s == pytest.approx(n / rate, abs=1e-4)
