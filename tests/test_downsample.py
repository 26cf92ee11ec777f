"""Min/max-preserving downsampling of session channels for plots."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from tsdownsample import MinMaxLTTBDownsampler

from fielddiag.channels import ChannelSpec, SessionMetadata, SignalSpec
from fielddiag.downsample import (
    PlotSource,
    PlotSourceCache,
    minmax_lttb_indices,
    minmax_preselect,
    read_channel_window,
    read_signal_window,
)
from fielddiag.errors import ChannelNotFoundError
from fielddiag.session import SessionReader, SessionWriter, write_session

FS_HZ = 1000.0
N = 400_000  # 400 s at 1 kHz


@pytest.fixture(scope="module")
def signal_data() -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(7)
    t = np.arange(N) / FS_HZ
    y = np.sin(2 * np.pi * 1.1 * t) + 0.2 * rng.standard_normal(N)
    y[123_457] = 9.0  # one spike of one sample
    y[300_001] = -7.5
    return t, y


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory, signal_data) -> Path:
    t, y = signal_data
    path = tmp_path_factory.mktemp("ds") / "s.h5"
    raw = np.round(y / 1e-3).astype("int16")  # counts of 1 mm/s2, as a DAQ would send
    speed = SignalSpec("vehicle_speed", unit="m/s", role="speed")
    ts = np.arange(0, N / FS_HZ, 0.01)
    write_session(
        path,
        SessionMetadata(),
        [ChannelSpec("wheel_z", role="wheel", dtype="int16", scale=1e-3, offset=0.5),
         ChannelSpec("body_z", role="body")],
        {"wheel_z": raw, "body_z": y},
        sample_rate_hz=FS_HZ,
        signals={speed: (ts, 10 + np.sin(ts))},
    )
    return path


def test_agrees_with_tsdownsample_minmaxlttb_and_keeps_the_extremes(signal_data) -> None:
    t, y = signal_data
    ours = minmax_lttb_indices(t, y, 1000)
    ref = np.asarray(MinMaxLTTBDownsampler().downsample(t, y, n_out=1000))
    # Same method; tsdownsample bins [1, n-1) by time, we bin [0, n) by index, so a few
    # bucket edges differ by one sample and LTTB then picks a neighbour.
    assert np.intersect1d(ours, ref).size >= 0.95 * ref.size
    assert int(np.argmax(y)) in ours and int(np.argmin(y)) in ours
    assert ours[0] == 0 and ours[-1] == N - 1
    assert len(ours) <= 1002 and np.all(np.diff(ours) > 0)


def test_preselection_keeps_every_bucket_envelope_whatever_the_block_size(signal_data) -> None:
    _, y = signal_data
    n_buckets = 500
    a = minmax_preselect(lambda i0, i1: y[i0:i1], N, n_buckets, block_samples=1 << 20)
    b = minmax_preselect(lambda i0, i1: y[i0:i1], N, n_buckets, block_samples=3000)
    np.testing.assert_array_equal(a, b)
    bucket = int(np.ceil(N / n_buckets))
    for k in range(0, N, bucket):
        seg = y[k : k + bucket]
        kept = y[a[(a >= k) & (a < k + bucket)]]
        assert kept.max() == seg.max() and kept.min() == seg.min()
    assert a[0] == 0 and a[-1] == N - 1


def test_channel_overview_keeps_spikes_and_calibrates(session: Path, signal_data) -> None:
    _, y = signal_data
    with SessionReader(session) as r:
        tr = read_channel_window(r, "wheel_z", n_out=800, block_samples=50_000)
        raw_all = r.read("wheel_z")
    assert tr.n_raw == N and tr.decimated and len(tr.time_s) <= 802
    assert tr.unit == "m/s2" and tr.kind == "channel"
    # calibration applied: raw * 1e-3 + 0.5; the spike and the dip survive exactly
    assert tr.values.max() == pytest.approx(raw_all.max(), abs=1e-12)
    assert tr.values.max() == pytest.approx(9.0 + 0.5, abs=1e-3)
    assert tr.values.min() == pytest.approx(-7.5 + 0.5, abs=1e-3)
    assert tr.time_s[np.argmax(tr.values)] == pytest.approx(123_457 / FS_HZ)
    assert np.all(np.diff(tr.time_s) > 0)
    assert tr.time_s[0] == 0.0 and tr.time_s[-1] == pytest.approx((N - 1) / FS_HZ)
    # every point is a real sample at its true time
    idx = np.round(tr.time_s * FS_HZ).astype(int)
    np.testing.assert_allclose(tr.values, raw_all[idx], atol=1e-12)


def test_zoom_window_reads_only_the_window(session: Path) -> None:
    with SessionReader(session) as r:
        tr = read_channel_window(r, "body_z", 100.0, 110.0, n_out=500)
        full = r.read("body_z", 100.0, 110.0)
        small = read_channel_window(r, "body_z", 100.0, 100.2, n_out=500)
    assert tr.n_raw == 10_000
    assert tr.time_s[0] >= 100.0 and tr.time_s[-1] < 110.0
    assert tr.values.max() == full.max() and tr.values.min() == full.min()
    assert (tr.start_s, tr.end_s) == (100.0, 110.0)
    # a window with fewer samples than points comes back whole
    assert small.n_raw == 200 and not small.decimated
    np.testing.assert_array_equal(small.values, full[:200])


def test_timestamped_session_with_a_gap(tmp_path: Path) -> None:
    t = np.concatenate([np.arange(0, 50, 1e-3), np.arange(60, 100, 1e-3)])
    y = np.sin(t)
    y[70_000] = 5.0
    path = tmp_path / "ts.h5"
    with SessionWriter(path, SessionMetadata(), [ChannelSpec("a")], sample_rate_hz=1000.0,
                       time_base="timestamps") as w:
        w.append_daq(y[:, None], t)
    with SessionReader(path) as r:
        tr = read_channel_window(r, "a", n_out=300, block_samples=7777)
    assert tr.values.max() == 5.0
    assert tr.time_s[np.argmax(tr.values)] == pytest.approx(t[70_000])
    assert not np.any((tr.time_s > 50) & (tr.time_s < 60))  # nothing invented in the gap
    np.testing.assert_allclose(tr.values, np.interp(tr.time_s, t, y), atol=1e-12)


def test_signal_window_and_unknown_names(session: Path) -> None:
    with SessionReader(session) as r:
        tr = read_signal_window(r, "vehicle_speed", 10.0, 20.0, n_out=2000)
        assert tr.n_raw == 1000 and not tr.decimated and tr.kind == "signal"
        assert tr.values.min() >= 9.0 and tr.values.max() <= 11.0
        with pytest.raises(ChannelNotFoundError):
            read_channel_window(r, "nope")
        with pytest.raises(ChannelNotFoundError):
            read_signal_window(r, "nope")


def test_plot_source_caches_the_overview(session: Path) -> None:
    with PlotSource(session, n_out=600) as src:
        assert src.trace_names() == [("channel", "wheel_z"), ("channel", "body_z"),
                                     ("signal", "vehicle_speed")]
        first = src.traces()
        again = src.traces()
        assert all(a is b for a, b in zip(first, again, strict=True))
        zoom = src.traces(5.0, 6.0)
        assert all(z is not f for z, f in zip(zoom, first, strict=True))
        assert zoom[0].n_raw == 1000


def test_plot_source_cache_reuses_and_evicts(session: Path, tmp_path: Path) -> None:
    other = write_session(tmp_path / "o.h5", SessionMetadata(), [ChannelSpec("a")],
                          np.zeros((10, 1)), sample_rate_hz=10.0)
    cache = PlotSourceCache(max_open=1)
    a = cache.get(session)
    assert cache.get(session) is a
    cache.get(other)
    assert cache.get(session) is not a  # evicted and reopened
    cache.close()


def test_all_channels_in_one_pass_equal_one_by_one(tmp_path: Path) -> None:
    from fielddiag.downsample import read_channels_window

    rng = np.random.default_rng(3)
    t = np.cumsum(rng.uniform(0.9e-3, 1.1e-3, 50_000))  # jittered time stamps
    y = rng.standard_normal((50_000, 3))
    path = tmp_path / "three.h5"
    with SessionWriter(path, SessionMetadata(), [ChannelSpec(c) for c in "abc"],
                       sample_rate_hz=1000.0, time_base="timestamps") as w:
        w.append_daq(y, t)
    with SessionReader(path) as r:
        together = read_channels_window(r, ["a", "b", "c"], 5.0, 40.0, 300, block_samples=4096)
        for tr in together:
            alone = read_channel_window(r, tr.name, 5.0, 40.0, 300)
            np.testing.assert_array_equal(tr.time_s, alone.time_s)
            np.testing.assert_array_equal(tr.values, alone.values)
    col = {"a": 0, "b": 1, "c": 2}
    for tr in together:
        inside = (t >= 5.0) & (t < 40.0)
        assert tr.n_raw == int(inside.sum())
        assert tr.values.max() == y[inside, col[tr.name]].max()
