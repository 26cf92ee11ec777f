"""Min/max-preserving downsampling of session channels for plotting.

A browser draws a few thousand points per trace at most (a 1 h channel at 2 kHz has
7.2 million); sending more only makes the page slow. What a plot must not lose is the
envelope: a single spike must stay visible however far one zooms out. The method is
MinMaxLTTB (Van Der Donckt et al., "MinMaxLTTB: Leveraging MinMax-Preselection to Scale
LTTB", 2023): split the window into ``n_out * minmax_ratio / 2`` equal index buckets and
keep each bucket's minimum and maximum sample, then run Largest-Triangle-Three-Buckets on
what is kept to get ``n_out`` points. The first and last sample of the window are always
kept. The preselection runs block by block straight from the HDF5 file, so a window of
any length is downsampled with bounded memory (one block of raw samples at a time); LTTB
is tsdownsample's compiled implementation.

:class:`PlotSource` keeps a session open and caches the full-length overview of each
trace, so a page re-opening a session does not read it again.
"""

from __future__ import annotations

import math
import os
import threading
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tsdownsample import LTTBDownsampler

from fielddiag.errors import ChannelNotFoundError, SessionError
from fielddiag.session import SessionReader

DEFAULT_POINTS = 2000
DEFAULT_MINMAX_RATIO = 4
#: Raw samples read from the file per block during the preselection.
BLOCK_SAMPLES = 1 << 20

__all__ = [
    "DEFAULT_POINTS",
    "PlotSource",
    "Trace",
    "minmax_lttb_indices",
    "minmax_preselect",
    "read_channel_window",
    "read_channels_window",
    "read_signal_window",
]


@dataclass
class Trace:
    """Points of one channel or signal over a time window, ready to plot.

    Attributes
    ----------
    name, unit : str
    kind : {"channel", "signal"}
    time_s, values : ndarray
        The kept points (float64), time increasing.
    start_s, end_s : float
        The window asked for, clipped to the data.
    n_raw : int
        Samples of the trace inside the window before downsampling.
    """

    name: str
    unit: str
    kind: str
    time_s: np.ndarray
    values: np.ndarray
    start_s: float
    end_s: float
    n_raw: int

    @property
    def decimated(self) -> bool:
        """True if points were dropped."""
        return self.time_s.shape[0] < self.n_raw


def _bucket_minmax(block: np.ndarray, bucket: int) -> np.ndarray:
    """Indices (into ``block``) of the min and max of every ``bucket`` samples, sorted."""
    n = block.shape[0]
    n_full = n // bucket
    parts = []
    if n_full:
        view = block[: n_full * bucket].reshape(n_full, bucket)
        base = np.arange(n_full) * bucket
        parts.append(base + np.argmin(view, axis=1))
        parts.append(base + np.argmax(view, axis=1))
    if n_full * bucket < n:
        tail = block[n_full * bucket :]
        parts.append(np.array([n_full * bucket + int(np.argmin(tail))]))
        parts.append(np.array([n_full * bucket + int(np.argmax(tail))]))
    return np.unique(np.concatenate(parts))


def minmax_preselect(
    read_block, n: int, n_buckets: int, block_samples: int = BLOCK_SAMPLES
) -> np.ndarray:
    """Indices of the min and max of ``n_buckets`` equal index buckets over ``[0, n)``.

    Parameters
    ----------
    read_block : callable (i0, i1) -> ndarray
        Returns samples ``[i0, i1)``; called block by block, in order.
    n : int
        Number of samples.
    n_buckets : int
        Number of buckets; about ``2 * n_buckets`` indices are returned.
    block_samples : int
        Largest number of samples read at once (rounded to whole buckets).

    Returns
    -------
    ndarray of int64
        Sorted unique indices, always including 0 and ``n - 1``.
    """
    if n <= 0:
        return np.zeros(0, dtype=np.int64)
    bucket = max(1, math.ceil(n / max(1, n_buckets)))
    step = max(bucket, (block_samples // bucket) * bucket)
    parts = [np.array([0, n - 1], dtype=np.int64)]
    for i0 in range(0, n, step):
        i1 = min(n, i0 + step)
        block = np.asarray(read_block(i0, i1))
        parts.append(i0 + _bucket_minmax(block, bucket).astype(np.int64))
    return np.unique(np.concatenate(parts))


def minmax_lttb_indices(
    x: np.ndarray, y: np.ndarray, n_out: int, minmax_ratio: int = DEFAULT_MINMAX_RATIO
) -> np.ndarray:
    """Indices of about ``n_out`` points of (x, y) chosen by MinMaxLTTB (all if fewer).

    The first, last, smallest and largest samples are always among them (so up to
    ``n_out + 2`` indices are returned).

    ``x`` must increase. NaN values are kept out of the triangle areas but a NaN sample
    can still be chosen as a bucket's extreme (it then shows as a break in the line).
    """
    x = np.asarray(x, dtype="f8")
    y = np.asarray(y, dtype="f8")
    n = y.shape[0]
    if n <= n_out:
        return np.arange(n)
    n_out = max(3, int(n_out))
    sel = minmax_preselect(lambda a, b: y[a:b], n, n_out * minmax_ratio // 2)
    return sel[_lttb(x[sel], y[sel], n_out)]


def _lttb(x: np.ndarray, y: np.ndarray, n_out: int) -> np.ndarray:
    """LTTB indices into (x, y), plus the first, last, smallest and largest points.

    LTTB alone may drop the window's extreme sample when a neighbour makes a larger
    triangle; adding it back (at most two extra points) keeps the envelope exact.
    """
    if x.shape[0] <= n_out:
        return np.arange(x.shape[0])
    finite = np.isfinite(y)
    if not finite.all():
        y = np.where(finite, y, np.interp(x, x[finite], y[finite]) if finite.any() else 0.0)
    idx = np.asarray(LTTBDownsampler().downsample(x, y, n_out=n_out), dtype=np.int64)
    extremes = np.array([0, x.shape[0] - 1, int(np.argmin(y)), int(np.argmax(y))])
    return np.union1d(idx, extremes)


def _calibrate(raw: np.ndarray, scale: float, offset: float) -> np.ndarray:
    out = raw.astype("f8")
    if scale != 1.0:
        out *= scale
    if offset != 0.0:
        out += offset
    return out


def read_channel_window(
    reader: SessionReader,
    name: str,
    start_s: float | None = None,
    end_s: float | None = None,
    n_out: int = DEFAULT_POINTS,
    *,
    minmax_ratio: int = DEFAULT_MINMAX_RATIO,
    block_samples: int = BLOCK_SAMPLES,
) -> Trace:
    """A DAQ channel over ``[start_s, end_s)`` downsampled to about ``n_out`` points.

    Reads the window block by block (at most ``block_samples`` raw samples in memory),
    keeps every bucket's min and max (the envelope), then LTTB to ``n_out`` points. A
    window with at most ``n_out`` samples is returned whole.

    Raises
    ------
    ChannelNotFoundError
        No channel ``name`` in the session.
    """
    return read_channels_window(reader, [name], start_s, end_s, n_out,
                                minmax_ratio=minmax_ratio, block_samples=block_samples)[0]


def read_channels_window(
    reader: SessionReader,
    names: list[str] | tuple[str, ...],
    start_s: float | None = None,
    end_s: float | None = None,
    n_out: int = DEFAULT_POINTS,
    *,
    minmax_ratio: int = DEFAULT_MINMAX_RATIO,
    block_samples: int = BLOCK_SAMPLES,
) -> list[Trace]:
    """Several DAQ channels over one window, in one pass over the file.

    Same as :func:`read_channel_window` per channel; the time stamps of a ``timestamps``
    session are read once per block for all channels.
    """
    specs = [reader.channel(nm) for nm in names]
    i0, i1 = reader.index_range(start_s, end_s)
    n = i1 - i0
    chans = reader._file["daq/channels"]  # noqa: SLF001 - the reader's own lazy datasets
    lo = reader.start_s if start_s is None else max(start_s, reader.start_s)
    hi = reader.end_s if end_s is None else min(end_s, reader.end_s)
    if n <= n_out:
        t = reader.time_at(i0, i1)
        return [Trace(sp.name, sp.unit, "channel", t,
                      _calibrate(chans[sp.name][i0:i1], sp.scale, sp.offset), lo, hi, n)
                for sp in specs]
    n_out = max(3, int(n_out))
    bucket = max(1, math.ceil(n / max(1, n_out * minmax_ratio // 2)))
    step = max(bucket, (block_samples // bucket) * bucket)
    stamped = reader.time_base == "timestamps"
    idx_parts: list[list[np.ndarray]] = [[] for _ in specs]
    v_parts: list[list[np.ndarray]] = [[] for _ in specs]
    t_parts: list[list[np.ndarray]] = [[] for _ in specs]
    for b0 in range(0, n, step):
        b1 = min(n, b0 + step)
        t_block = reader.time_at(i0 + b0, i0 + b1) if stamped else None
        for k, sp in enumerate(specs):
            raw = chans[sp.name][i0 + b0 : i0 + b1]
            local = _bucket_minmax(raw, bucket)
            if b0 == 0 and local[0] != 0:
                local = np.concatenate([[0], local])
            if b1 == n and local[-1] != b1 - b0 - 1:
                local = np.concatenate([local, [b1 - b0 - 1]])
            idx_parts[k].append(b0 + local)
            v_parts[k].append(raw[local])
            if t_block is not None:
                t_parts[k].append(t_block[local])
    out = []
    for k, sp in enumerate(specs):
        sel = np.concatenate(idx_parts[k])
        v_sel = _calibrate(np.concatenate(v_parts[k]), sp.scale, sp.offset)
        if stamped:
            t_sel = np.concatenate(t_parts[k])
        else:
            t_sel = reader.start_s + (i0 + sel) / reader.sample_rate_hz
        keep = _lttb(t_sel, v_sel, n_out)
        out.append(Trace(sp.name, sp.unit, "channel", t_sel[keep], v_sel[keep], lo, hi, n))
    return out


def read_signal_window(
    reader: SessionReader,
    name: str,
    start_s: float | None = None,
    end_s: float | None = None,
    n_out: int = DEFAULT_POINTS,
    *,
    minmax_ratio: int = DEFAULT_MINMAX_RATIO,
) -> Trace:
    """A vehicle (CAN) signal over ``[start_s, end_s)`` downsampled to ``n_out`` points."""
    spec = reader.signal_spec(name)
    t, v = reader.signal(name, start_s, end_s)
    t = np.asarray(t, dtype="f8")
    v = np.asarray(v, dtype="f8")
    if t.size:
        lo = float(t[0]) if start_s is None else float(start_s)
        hi = float(t[-1]) if end_s is None else float(end_s)
    else:
        lo = float(start_s or 0.0)
        hi = float(end_s if end_s is not None else lo)
    idx = minmax_lttb_indices(t, v, n_out, minmax_ratio)
    return Trace(name, spec.unit, "signal", t[idx], v[idx], lo, hi, int(t.size))


class PlotSource:
    """A session kept open for plotting, with the full-length overview of each trace cached.

    Thread-safe: h5py serialises file access, and a lock guards the reader and the cache,
    so a page can fetch windows from a worker thread.

    Parameters
    ----------
    path : path
        Session file.
    n_out : int
        Default number of points per trace.
    """

    def __init__(self, path: str | os.PathLike, n_out: int = DEFAULT_POINTS) -> None:
        self.path = Path(path)
        self.n_out = int(n_out)
        self._reader = SessionReader(self.path)
        self._lock = threading.RLock()
        self._overview: dict[tuple[str, str, int], Trace] = {}
        self._n_at_overview = self._reader.n_samples

    @property
    def reader(self) -> SessionReader:
        return self._reader

    def trace_names(self) -> list[tuple[str, str]]:
        """(kind, name) of every channel, then every signal."""
        r = self._reader
        return [("channel", c.name) for c in r.channels] + [("signal", s.name) for s in r.signals]

    def refresh(self) -> None:
        """See data appended since opening (a session being recorded); drops the cache."""
        with self._lock:
            self._reader.refresh()
            if self._reader.n_samples != self._n_at_overview:
                self._overview.clear()
                self._n_at_overview = self._reader.n_samples

    def trace(
        self,
        kind: str,
        name: str,
        start_s: float | None = None,
        end_s: float | None = None,
        n_out: int | None = None,
    ) -> Trace:
        """One trace over a window (the whole session when both ends are None)."""
        n_out = self.n_out if n_out is None else int(n_out)
        whole = start_s is None and end_s is None
        key = (kind, name, n_out)
        with self._lock:
            if whole and key in self._overview:
                return self._overview[key]
            if kind == "channel":
                tr = read_channel_window(self._reader, name, start_s, end_s, n_out)
            elif kind == "signal":
                tr = read_signal_window(self._reader, name, start_s, end_s, n_out)
            else:
                raise ChannelNotFoundError(f"unknown trace kind {kind!r}: 'channel' or 'signal'")
            if whole:
                self._overview[key] = tr
            return tr

    def traces(
        self, start_s: float | None = None, end_s: float | None = None, n_out: int | None = None
    ) -> list[Trace]:
        """Every channel and signal over a window (channels read in one pass)."""
        n_out = self.n_out if n_out is None else int(n_out)
        whole = start_s is None and end_s is None
        names = self.trace_names()
        channels = [nm for kind, nm in names if kind == "channel"]
        with self._lock:
            missing = [nm for nm in channels if ("channel", nm, n_out) not in self._overview]
            if whole and not missing:
                got = {nm: self._overview[("channel", nm, n_out)] for nm in channels}
            else:
                got = dict(zip(channels, read_channels_window(
                    self._reader, channels, start_s, end_s, n_out), strict=True))
                if whole:
                    for nm, tr in got.items():
                        self._overview[("channel", nm, n_out)] = tr
        return [got[nm] if kind == "channel" else self.trace(kind, nm, start_s, end_s, n_out)
                for kind, nm in names]

    def close(self) -> None:
        with self._lock:
            self._reader.close()

    def __enter__(self) -> PlotSource:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class PlotSourceCache:
    """A few sessions kept open for plotting, least recently used closed first."""

    def __init__(self, max_open: int = 4, n_out: int = DEFAULT_POINTS) -> None:
        self.max_open = int(max_open)
        self.n_out = int(n_out)
        self._open: OrderedDict[tuple[str, int, int], PlotSource] = OrderedDict()
        self._lock = threading.Lock()

    def get(self, path: str | os.PathLike) -> PlotSource:
        """The open PlotSource of ``path`` (reopened if the file changed on disk)."""
        p = Path(path).resolve()
        try:
            st = p.stat()
        except OSError as exc:
            raise SessionError(f"{p} cannot be opened: {exc}") from None
        key = (str(p), st.st_mtime_ns, st.st_size)
        with self._lock:
            src = self._open.pop(key, None)
            if src is None:
                for k in [k for k in self._open if k[0] == key[0]]:
                    self._open.pop(k).close()
                src = PlotSource(p, self.n_out)
            self._open[key] = src
            while len(self._open) > self.max_open:
                _, old = self._open.popitem(last=False)
                old.close()
            return src

    def close(self) -> None:
        with self._lock:
            for src in self._open.values():
                src.close()
            self._open.clear()
