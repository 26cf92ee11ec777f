"""Signal processing for field recordings: offsets, zero-phase filters, integration, spectra.

Pure functions and small value classes over numpy arrays plus a sample rate; no I/O.

* :func:`remove_offset_and_drift`: gravity, sensor bias and linear drift out of a reading.
* :func:`zero_phase_filter`: Butterworth applied forwards and backwards (no phase shift).
* :func:`integrate_acceleration`: acceleration to velocity and displacement in a stated
  band, by division by ``j w`` in the frequency domain (default) or by zero-phase
  high-pass filtering and cumulative integration in the time domain.
* :func:`block_cross_spectra`: Welch auto- and cross-spectra of two channels, kept as sums
  per time block so that a block can be left out (jackknife) without recomputing anything.
* :func:`plateau_noise_floor`: the white-noise floor of a channel, read from the flat top
  of its spectrum where an anti-alias filter has removed the signal.
* :func:`choose_integration_band`: the band in which an integrated signal is above noise.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy import fft as sp_fft
from scipy import signal

from fielddiag.units import GRAVITY_MPS2  # noqa: F401 - re-exported: dsp.GRAVITY_MPS2

# ---------------------------------------------------------------------------------------
# Offsets and filters
# ---------------------------------------------------------------------------------------


def remove_offset_and_drift(x: np.ndarray) -> np.ndarray:
    """Remove the mean and the least-squares linear trend (gravity, bias, bias drift).

    Parameters
    ----------
    x : ndarray
        One channel, for example an accelerometer reading including g [m/s^2].

    Returns
    -------
    ndarray
        A float64 copy with zero mean and no linear trend.
    """
    y = np.array(x, dtype=float)
    n = y.size
    if n < 2:
        return y - y.mean() if n else y
    # closed-form least-squares line (O(n), no n x 2 design matrix)
    t = np.arange(n, dtype=float)
    t -= 0.5 * (n - 1)
    slope = float(t @ y) / float(t @ t)
    y -= y.mean()
    y -= slope * t
    return y


def zero_phase_filter(
    x: np.ndarray,
    sample_rate_hz: float,
    *,
    low_hz: float | None = None,
    high_hz: float | None = None,
    order: int = 4,
) -> np.ndarray:
    """Butterworth high-, low- or band-pass applied forwards and backwards (no phase shift).

    Parameters
    ----------
    x : ndarray
        Signal (last axis is time).
    sample_rate_hz : float
        Sample rate [Hz].
    low_hz, high_hz : float or None
        Lower and upper cutoff [Hz]; give one or both.
    order : int
        Order of the Butterworth prototype (the magnitude response is squared by the
        forward-backward pass).

    Returns
    -------
    ndarray
        Filtered signal, same shape.
    """
    nyq = 0.5 * sample_rate_hz
    if low_hz is not None and not 0 < low_hz < nyq:
        raise ValueError(f"low_hz={low_hz} must be in (0, {nyq})")
    if high_hz is not None and not 0 < high_hz < nyq:
        raise ValueError(f"high_hz={high_hz} must be in (0, {nyq})")
    if low_hz is not None and high_hz is not None:
        sos = signal.butter(order, [low_hz, high_hz], "bandpass", fs=sample_rate_hz, output="sos")
    elif low_hz is not None:
        sos = signal.butter(order, low_hz, "highpass", fs=sample_rate_hz, output="sos")
    elif high_hz is not None:
        sos = signal.butter(order, high_hz, "lowpass", fs=sample_rate_hz, output="sos")
    else:
        return np.array(x, dtype=float)
    return signal.sosfiltfilt(sos, np.asarray(x, dtype=float), axis=-1)


#: Width of the band window's raised-cosine tapers (a share of each band edge): the
#: integrated signals hold frequencies up to the band's top times (1 + this).
BAND_TAPER = 0.3


def band_window(freq_hz: np.ndarray, band_hz: tuple[float, float], taper: float = BAND_TAPER
                ) -> np.ndarray:
    """Smooth band-pass weights: 1 inside ``band_hz``, raised-cosine tapers outside.

    The lower taper runs from ``low * (1 - taper)`` to ``low``, the upper one from ``high``
    to ``high * (1 + taper)``; the weights are 0 beyond. Smooth edges keep the impulse
    response of a frequency-domain filter short (little ringing at the record ends).

    Parameters
    ----------
    freq_hz : ndarray
        Frequencies at which to give the weights [Hz].
    band_hz : (float, float)
        The pass band (low, high) [Hz].
    taper : float
        Width of each taper as a fraction of its band edge.

    Returns
    -------
    ndarray
        Weights in [0, 1], one per frequency (dimensionless).

    Examples
    --------
    >>> band_window(np.array([0.5, 1.0, 5.0, 20.0]), (1.0, 10.0)).tolist()
    [0.0, 1.0, 1.0, 0.0]
    """
    f = np.asarray(freq_hz, dtype=float)
    lo, hi = band_hz
    w = np.zeros_like(f)
    w[(f >= lo) & (f <= hi)] = 1.0
    lo0 = lo * (1.0 - taper)
    m = (f > lo0) & (f < lo)
    if lo > lo0:
        w[m] = 0.5 - 0.5 * np.cos(np.pi * (f[m] - lo0) / (lo - lo0))
    hi1 = hi * (1.0 + taper)
    m = (f > hi) & (f < hi1)
    w[m] = 0.5 + 0.5 * np.cos(np.pi * (f[m] - hi) / (hi1 - hi))
    return w


# ---------------------------------------------------------------------------------------
# Integration
# ---------------------------------------------------------------------------------------


@dataclass
class IntegratedMotion:
    """Acceleration, velocity and displacement of one channel, valid in ``band_hz``.

    All three are band-limited by the same filter, so a linear equation that holds between
    the true signals also holds between these (in the band).

    Attributes
    ----------
    sample_rate_hz : float
        Sample rate of the three arrays [Hz] (the output rate when resampled).
    band_hz : (float, float)
        Band in which they are valid [Hz].
    acceleration_mps2, velocity_mps, displacement_m : ndarray
        The band-limited acceleration [m/s^2], velocity [m/s] and displacement [m].
    method : str
        ``frequency`` or ``time`` (the integration route used).
    """

    sample_rate_hz: float
    band_hz: tuple[float, float]
    acceleration_mps2: np.ndarray
    velocity_mps: np.ndarray
    displacement_m: np.ndarray
    method: str

    @property
    def time_s(self) -> np.ndarray:
        """Sample times from 0 [s]."""
        return np.arange(self.acceleration_mps2.size) / self.sample_rate_hz


def _fft_integrate(
    channels: Sequence[np.ndarray],
    sample_rate_hz: float,
    band_hz: tuple[float, float],
    output_rate_hz: float | None,
    taper: float,
) -> tuple[float, list[tuple[np.ndarray, np.ndarray, np.ndarray]]]:
    """Frequency-domain band-limited integration of several equal-length channels."""
    n = channels[0].size
    lo, hi = band_hz
    pad = int(min(n, math.ceil(4.0 / (lo * (1 - taper)) * sample_rate_hz)))
    nfft = sp_fft.next_fast_len(n + pad, real=True)
    freq = np.fft.rfftfreq(nfft, 1.0 / sample_rate_hz)
    w = 2 * np.pi * freq
    win = band_window(freq, band_hz, taper)
    keep = int(np.searchsorted(freq, hi * (1 + taper) + 2 * sample_rate_hz / nfft)) + 1
    keep = min(keep, freq.size)
    if output_rate_hz is None or output_rate_hz >= sample_rate_hz:
        fs_out = sample_rate_hz
        n_out_fft, n_out = nfft, n
    else:
        if hi * (1 + taper) >= 0.5 * output_rate_hz:
            raise ValueError("output_rate_hz must exceed twice the upper band edge (with taper)")
        n_out_fft = int(round(nfft * output_rate_hz / sample_rate_hz))
        n_out_fft += n_out_fft % 2
        fs_out = sample_rate_hz * n_out_fft / nfft
        n_out = int(math.floor(n * n_out_fft / nfft))
        keep = min(keep, n_out_fft // 2)
    scale = n_out_fft / nfft
    wk = w[:keep].copy()
    wk[0] = 1.0  # DC is removed by the window anyway
    out = []
    for x in channels:
        spec = sp_fft.rfft(remove_offset_and_drift(x), nfft)[:keep] * (win[:keep] * scale)
        buf = np.zeros(n_out_fft // 2 + 1, dtype=complex)
        buf[:keep] = spec
        acc = sp_fft.irfft(buf, n_out_fft)[:n_out]
        buf[:keep] = spec / (1j * wk)
        vel = sp_fft.irfft(buf, n_out_fft)[:n_out]
        buf[:keep] = -spec / (wk * wk)
        disp = sp_fft.irfft(buf, n_out_fft)[:n_out]
        out.append((acc, vel, disp))
    return fs_out, out


def integrate_acceleration(
    acceleration_mps2: np.ndarray,
    sample_rate_hz: float,
    band_hz: tuple[float, float],
    *,
    method: str = "frequency",
    output_rate_hz: float | None = None,
    taper: float = BAND_TAPER,
) -> IntegratedMotion:
    """Integrate an acceleration to velocity and displacement, valid in ``band_hz``.

    Gravity, bias and linear drift are removed first. Below the band integration would
    amplify drift and low-frequency noise (as 1/w^2 for displacement); above it there is
    no signal. Outside the band the result is zero, so state the band with the result.

    Parameters
    ----------
    acceleration_mps2 : ndarray
        Accelerometer reading [m/s^2] (g, bias and drift may be included).
    sample_rate_hz : float
        Uniform sample rate [Hz].
    band_hz : (float, float)
        Valid band [Hz]; see :func:`choose_integration_band`.
    method : {"frequency", "time"}
        ``frequency``: FFT of the zero-padded record, smooth band-pass window (raised
        cosine tapers of relative width ``taper``), division by ``j w`` and ``-w^2``.
        ``time``: zero-phase Butterworth band-pass, cumulative trapezoidal integration,
        zero-phase high-pass after each integration.
    output_rate_hz : float or None
        With ``frequency``, return the signals resampled to about this rate (spectral
        truncation; must exceed twice the upper edge); the actual rate is in the result.
    taper : float
        Relative width of the raised-cosine band edges (``frequency``).

    Returns
    -------
    IntegratedMotion
    """
    lo, hi = float(band_hz[0]), float(band_hz[1])
    if not 0 < lo < hi < 0.5 * sample_rate_hz:
        raise ValueError(f"band {band_hz} must satisfy 0 < low < high < {0.5 * sample_rate_hz}")
    x = np.asarray(acceleration_mps2, dtype=float)
    if method == "frequency":
        fs_out, [(acc, vel, disp)] = _fft_integrate([x], sample_rate_hz, (lo, hi),
                                                   output_rate_hz, taper)
        return IntegratedMotion(fs_out, (lo, hi), acc, vel, disp, method)
    if method == "time":
        hi_f = min(hi * (1 + taper), 0.45 * sample_rate_hz)
        acc = zero_phase_filter(remove_offset_and_drift(x), sample_rate_hz,
                                low_hz=lo, high_hz=hi_f)
        dt = 1.0 / sample_rate_hz
        vel = np.concatenate(([0.0], np.cumsum(0.5 * (acc[1:] + acc[:-1])) * dt))
        vel = zero_phase_filter(vel - vel.mean(), sample_rate_hz, low_hz=lo)
        disp = np.concatenate(([0.0], np.cumsum(0.5 * (vel[1:] + vel[:-1])) * dt))
        disp = zero_phase_filter(disp - disp.mean(), sample_rate_hz, low_hz=lo)
        return IntegratedMotion(sample_rate_hz, (lo, hi), acc, vel, disp, method)
    raise ValueError(f"method must be 'frequency' or 'time', not {method!r}")


def integrate_pair(
    wheel_mps2: np.ndarray,
    body_mps2: np.ndarray,
    sample_rate_hz: float,
    band_hz: tuple[float, float],
    *,
    output_rate_hz: float | None = None,
    taper: float = BAND_TAPER,
) -> tuple[IntegratedMotion, IntegratedMotion]:
    """Integrate two channels of one recording with the same frequency-domain filter.

    The wheel and body motion go through one filter, so that the body model driven by the
    wheel motion is compared with a body acceleration limited in the same way.

    Parameters
    ----------
    wheel_mps2, body_mps2 : ndarray
        Equal-length accelerometer readings [m/s^2] (gravity, bias and drift allowed: the
        band removes them).
    sample_rate_hz : float
        Sample rate [Hz].
    band_hz : (float, float)
        Band in which the integrated signals are valid [Hz].
    output_rate_hz : float or None
        Resample the result to this rate [Hz] (None: keep ``sample_rate_hz``).
    taper : float
        Width of the band's raised-cosine tapers (see :func:`band_window`).

    Returns
    -------
    wheel, body : IntegratedMotion
        Acceleration [m/s^2], velocity [m/s] and displacement [m] of each channel.

    Raises
    ------
    ValueError
        The band does not fit the record (see :func:`integrate_acceleration`).

    Examples
    --------
    >>> t = np.arange(20000) / 200.0
    >>> w, b = integrate_pair(np.sin(2 * np.pi * 2 * t), np.zeros_like(t), 200.0, (0.5, 20))
    >>> round(float(np.std(w.displacement_m)) * (2 * np.pi * 2) ** 2, 1)  # about 1/sqrt(2)
    0.7
    """
    fs_out, res = _fft_integrate([np.asarray(wheel_mps2, float), np.asarray(body_mps2, float)],
                                 sample_rate_hz, band_hz, output_rate_hz, taper)
    band = (float(band_hz[0]), float(band_hz[1]))
    return tuple(IntegratedMotion(fs_out, band, *r, "frequency") for r in res)  # type: ignore


# ---------------------------------------------------------------------------------------
# Spectra
# ---------------------------------------------------------------------------------------


@dataclass
class CrossSpectra:
    """Averaged one-sided spectral densities of an input x and an output y.

    ``gxy = E[conj(X) Y]`` (the convention of :func:`scipy.signal.csd`), so H1 = gxy/gxx.

    Attributes
    ----------
    freq_hz : ndarray
        Frequency lines [Hz].
    gxx, gyy : ndarray
        Auto spectral densities of x and y [(unit of x)^2/Hz, (unit of y)^2/Hz].
    gxy : ndarray of complex
        Cross spectral density [(unit of x)(unit of y)/Hz].
    n_averages : int
        Number of Welch segments averaged.
    sample_rate_hz : float
        Sample rate of the signals [Hz].
    segment_s : float
        Welch segment length [s].
    """

    freq_hz: np.ndarray
    gxx: np.ndarray
    gyy: np.ndarray
    gxy: np.ndarray
    n_averages: int
    sample_rate_hz: float
    segment_s: float

    @property
    def coherence(self) -> np.ndarray:
        """Ordinary coherence |gxy|^2 / (gxx gyy)."""
        return np.abs(self.gxy) ** 2 / np.maximum(self.gxx * self.gyy, 1e-300)

    @property
    def h1(self) -> np.ndarray:
        """H1 = gxy / gxx (biased low by noise on x)."""
        return self.gxy / self.gxx

    @property
    def h2(self) -> np.ndarray:
        """H2 = gyy / gyx (biased high by noise on y)."""
        return self.gyy / np.conj(self.gxy)

    def subset(self, mask: np.ndarray) -> CrossSpectra:
        """The lines where ``mask`` is true."""
        return CrossSpectra(self.freq_hz[mask], self.gxx[mask], self.gyy[mask], self.gxy[mask],
                            self.n_averages, self.sample_rate_hz, self.segment_s)


@dataclass
class BlockCrossSpectra:
    """Welch spectra kept as sums over the segments of each time block.

    ``sxx[b]`` is the sum over the segments whose centre lies in block ``b`` of the
    density-scaled ``|X|^2`` (likewise ``syy``, ``sxy``); ``n_segments[b]`` counts them.
    The average over all blocks is :meth:`total`; :meth:`leave_out` drops one block (a
    delete-a-group jackknife replicate) at no cost.
    """

    freq_hz: np.ndarray
    sample_rate_hz: float
    segment_s: float
    block_edges_s: np.ndarray
    sxx: np.ndarray
    syy: np.ndarray
    sxy: np.ndarray
    n_segments: np.ndarray

    @property
    def n_blocks(self) -> int:
        """Number of time blocks."""
        return int(self.n_segments.size)

    def _avg(self, keep: np.ndarray) -> CrossSpectra:
        n = int(self.n_segments[keep].sum())
        if n == 0:
            raise ValueError("no segments left")
        return CrossSpectra(self.freq_hz, self.sxx[keep].sum(0) / n, self.syy[keep].sum(0) / n,
                            self.sxy[keep].sum(0) / n, n, self.sample_rate_hz, self.segment_s)

    def total(self) -> CrossSpectra:
        """Spectra averaged over every segment."""
        return self._avg(np.ones(self.n_blocks, bool))

    def leave_out(self, block: int) -> CrossSpectra:
        """Spectra averaged over every segment outside ``block``."""
        keep = np.ones(self.n_blocks, bool)
        keep[block] = False
        return self._avg(keep)

    def subset(self, mask: np.ndarray) -> BlockCrossSpectra:
        """Only the frequency lines where ``mask`` is true."""
        return BlockCrossSpectra(self.freq_hz[mask], self.sample_rate_hz, self.segment_s,
                                 self.block_edges_s, self.sxx[:, mask], self.syy[:, mask],
                                 self.sxy[:, mask], self.n_segments)


def contiguous_pieces(time_s: np.ndarray | None, n: int, sample_rate_hz: float,
                      tolerance: float = 0.5) -> list[tuple[int, int]]:
    """Index ranges [i0, i1) without gaps: a step above (1 + tolerance)/rate breaks a piece.

    Parameters
    ----------
    time_s : ndarray or None
        Sample times [s]; None for a uniform time base (one piece).
    n : int
        Number of samples.
    sample_rate_hz : float
        Nominal sample rate [Hz].
    tolerance : float
        A step longer than ``(1 + tolerance)`` sample periods, or not positive, is a gap.

    Returns
    -------
    list of (int, int)
        The contiguous index ranges, in order.

    Examples
    --------
    >>> contiguous_pieces(np.array([0.0, 0.01, 0.02, 0.5, 0.51]), 5, 100.0)
    [(0, 3), (3, 5)]
    """
    if time_s is None or n < 2:
        return [(0, n)]
    dt = np.diff(np.asarray(time_s, dtype=float))
    breaks = np.flatnonzero((dt > (1 + tolerance) / sample_rate_hz) | (dt <= 0)) + 1
    edges = np.concatenate(([0], breaks, [n]))
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:], strict=True) if b > a]


def block_cross_spectra(
    x: np.ndarray,
    y: np.ndarray,
    sample_rate_hz: float,
    *,
    segment_s: float,
    n_blocks: int,
    pieces: Sequence[tuple[int, int]] | None = None,
    overlap: float = 0.5,
    max_freq_hz: float | None = None,
    chunk_segments: int = 64,
) -> BlockCrossSpectra:
    """Welch (Hann, 50 % overlap, linear detrend per segment) spectra summed per time block.

    Parameters
    ----------
    x, y : ndarray
        Input and output channel, same length, uniform sampling.
    sample_rate_hz : float
        Sample rate [Hz].
    segment_s : float
        Welch segment length [s]; the resolution is 1/segment_s.
    n_blocks : int
        Number of equal time blocks (jackknife groups); a segment belongs to the block
        that holds its centre.
    pieces : sequence of (i0, i1) or None
        Contiguous index ranges (a recording with gaps); segments never cross a gap.
    overlap : float
        Segment overlap fraction.
    max_freq_hz : float or None
        Keep only lines up to this frequency (saves memory; the noise floor needs all).
    chunk_segments : int
        Segments transformed at once (bounds memory).

    Returns
    -------
    BlockCrossSpectra
    """
    x = np.asarray(x)
    y = np.asarray(y)
    n = x.size
    if y.size != n:
        raise ValueError("x and y must have the same length")
    nper = int(round(segment_s * sample_rate_hz))
    step = max(1, int(round(nper * (1 - overlap))))
    if pieces is None:
        pieces = [(0, n)]
    win = signal.get_window("hann", nper)
    scale = 1.0 / (sample_rate_hz * np.sum(win * win))
    freq = np.fft.rfftfreq(nper, 1.0 / sample_rate_hz)
    n_keep = freq.size if max_freq_hz is None else int(np.searchsorted(freq, max_freq_hz, "right"))
    freq = freq[:n_keep]
    onesided = np.full(n_keep, 2.0)
    onesided[0] = 1.0
    if nper % 2 == 0 and n_keep == nper // 2 + 1:
        onesided[-1] = 1.0
    starts = np.concatenate([np.arange(a, b - nper + 1, step) for a, b in pieces
                             if b - a >= nper] or [np.zeros(0, int)]).astype(int)
    if starts.size == 0:
        raise ValueError(f"no contiguous stretch of {segment_s:g} s in the recording")
    duration = n / sample_rate_hz
    edges = np.linspace(0.0, duration, n_blocks + 1)
    centre = (starts + nper / 2) / sample_rate_hz
    block_of = np.clip(np.searchsorted(edges, centre, side="right") - 1, 0, n_blocks - 1)
    sxx = np.zeros((n_blocks, n_keep))
    syy = np.zeros((n_blocks, n_keep))
    sxy = np.zeros((n_blocks, n_keep), dtype=complex)
    counts = np.bincount(block_of, minlength=n_blocks)
    t_axis = np.arange(nper, dtype=float)
    t_axis -= t_axis.mean()
    t_norm = np.sum(t_axis * t_axis)
    for c0 in range(0, starts.size, chunk_segments):
        st = starts[c0:c0 + chunk_segments]
        idx = st[:, None] + np.arange(nper)[None, :]
        specs = []
        for ch in (x, y):
            seg = ch[idx].astype(float)
            seg -= seg.mean(axis=1, keepdims=True)
            slope = seg @ t_axis / t_norm
            seg -= slope[:, None] * t_axis[None, :]
            seg *= win
            specs.append(sp_fft.rfft(seg, axis=1)[:, :n_keep])
        fx, fy = specs
        pxx = (fx.real**2 + fx.imag**2) * (scale * onesided)
        pyy = (fy.real**2 + fy.imag**2) * (scale * onesided)
        pxy = np.conj(fx) * fy * (scale * onesided)
        b = block_of[c0:c0 + chunk_segments]
        for blk in np.unique(b):
            m = b == blk
            sxx[blk] += pxx[m].sum(0)
            syy[blk] += pyy[m].sum(0)
            sxy[blk] += pxy[m].sum(0)
    keep = counts > 0
    return BlockCrossSpectra(freq, float(sample_rate_hz), nper / sample_rate_hz, edges,
                             sxx[keep], syy[keep], sxy[keep], counts[keep])


def spectrum_on_grid(freq_hz: np.ndarray, values: np.ndarray, grid_hz: np.ndarray) -> np.ndarray:
    """Values of a spectrum (real or complex) at other frequencies, by linear interpolation.

    Two drives recorded at slightly different rates (500 and 500.001 Hz) have Welch lines
    at slightly different frequencies; every before/after comparison puts them on one grid
    with this. Real and imaginary parts are interpolated separately; outside ``freq_hz``
    the result is NaN (nothing is extrapolated).

    Parameters
    ----------
    freq_hz : ndarray
        Increasing frequencies of ``values`` [Hz].
    values : ndarray
        The spectrum at ``freq_hz`` (same length), real or complex.
    grid_hz : ndarray
        Frequencies wanted [Hz].

    Returns
    -------
    ndarray
        ``values`` at ``grid_hz``, of the same kind (real or complex).

    Examples
    --------
    >>> spectrum_on_grid(np.array([1.0, 2.0]), np.array([1 + 1j, 3 + 1j]), np.array([1.5]))
    array([2.+1.j])
    """
    f = np.asarray(freq_hz, dtype=float)
    v = np.asarray(values)
    g = np.asarray(grid_hz, dtype=float)
    if np.iscomplexobj(v):
        return (np.interp(g, f, v.real, left=np.nan, right=np.nan)
                + 1j * np.interp(g, f, v.imag, left=np.nan, right=np.nan))
    return np.interp(g, f, v.astype(float), left=np.nan, right=np.nan)


def welch_psd(x: np.ndarray, sample_rate_hz: float, segment_s: float) -> tuple[np.ndarray,
                                                                                 np.ndarray]:
    """One-sided PSD by Welch (Hann, 50 % overlap, linear detrend): (freq_hz, psd).

    Parameters
    ----------
    x : ndarray
        The signal, uniformly sampled.
    sample_rate_hz : float
        Sample rate [Hz].
    segment_s : float
        Welch segment length [s] (at most the whole record); the resolution is its inverse.

    Returns
    -------
    freq_hz : ndarray
        Frequency lines [Hz].
    psd : ndarray
        One-sided power spectral density [(unit of x)^2/Hz].

    Examples
    --------
    >>> f, p = welch_psd(np.random.default_rng(0).normal(size=20000), 100.0, 10.0)
    >>> round(float(np.mean(p[1:-1])), 2)  # white noise of variance 1: 2/fs per Hz
    0.02
    """
    nper = min(int(round(segment_s * sample_rate_hz)), np.asarray(x).size)
    return signal.welch(np.asarray(x, float), sample_rate_hz, nperseg=nper, detrend="linear")


# ---------------------------------------------------------------------------------------
# Noise floor and bands
# ---------------------------------------------------------------------------------------


@dataclass
class NoiseFloor:
    """White-noise floor of one channel.

    Attributes
    ----------
    psd_per_hz : float
        One-sided density [(unit)^2/Hz]; the noise standard deviation over the whole
        Nyquist band is ``sqrt(psd_per_hz * sample_rate_hz / 2)``.
    found : bool
        A flat floor was detected. When False, ``psd_per_hz`` is the lowest level seen at
        the top of the spectrum (an upper bound).
    band_hz : (float, float) or None
        Where the floor was read.
    note : str
        How it was found, or why not.
    """

    psd_per_hz: float
    found: bool
    band_hz: tuple[float, float] | None
    note: str


def plateau_noise_floor(
    freq_hz: np.ndarray,
    psd: np.ndarray,
    sample_rate_hz: float,
    *,
    n_bands: int = 40,
    tolerance_db: float = 1.5,
    min_bands: int = 4,
    min_contrast_db: float = 10.0,
    max_drift_db: float = 1.0,
) -> NoiseFloor:
    """Detect the flat noise floor at the top of a spectrum (above an anti-alias filter).

    The range from 5 % of Nyquist to Nyquist is cut into ``n_bands`` bands and each band's
    mean level is taken (many lines, so little scatter). Starting from the band just below
    Nyquist, bands are added downwards while their level stays within ``tolerance_db`` of
    the plateau's median level and the level's fitted trend across the plateau stays within
    ``max_drift_db`` (a signal still falling towards Nyquist is not a floor). The plateau
    is accepted when it spans at least
    ``min_bands`` bands and the spectrum below rises at least ``min_contrast_db`` above
    it (there is signal, and the plateau is its floor, not a white signal).

    Returns
    -------
    NoiseFloor
    """
    f = np.asarray(freq_hz, float)
    p = np.asarray(psd, float)
    nyq = 0.5 * sample_rate_hz
    edges = np.linspace(0.05 * nyq, 0.995 * nyq, n_bands + 1)
    idx = np.searchsorted(f, edges)
    levels = np.array([p[a:b].mean() if b > a else np.nan for a, b in zip(idx[:-1], idx[1:],
                                                                          strict=True)])
    if np.any(~np.isfinite(levels)) or np.any(levels <= 0):
        lvl = float(np.nanmin(levels[levels > 0])) if np.any(levels > 0) else 0.0
        return NoiseFloor(lvl, False, None, "spectrum too coarse to look for a noise floor")
    db = 10 * np.log10(levels)
    top = n_bands - 1
    k = top
    while k - 1 >= 0:
        cand = db[k - 1:top + 1]
        med = np.median(cand)
        drift = abs(np.polyfit(np.arange(cand.size), cand, 1)[0]) * (cand.size - 1)
        if np.all(np.abs(cand - med) <= tolerance_db) and drift <= max_drift_db:
            k -= 1
        else:
            break
    width = top - k + 1
    plateau_db = float(np.median(db[k:]))
    level = float(np.mean(levels[k:]))
    below = db[:k]
    band = (float(edges[k]), float(edges[-1]))
    if width < min_bands:
        return NoiseFloor(float(levels[k:].min()), False, None,
                          "no flat top in the spectrum (signal reaches Nyquist); the noise level"
                          " is an upper bound")
    if below.size == 0 or below.max() - plateau_db < min_contrast_db:
        return NoiseFloor(level, False, band,
                          "the whole spectrum is flat: either noise only or a white signal")
    return NoiseFloor(level, True, band,
                      f"flat floor {band[0]:.1f}-{band[1]:.1f} Hz, {below.max() - plateau_db:.0f}"
                      " dB below the signal")


def choose_integration_band(
    freq_hz: np.ndarray,
    psd: np.ndarray,
    noise_psd_per_hz: float,
    *,
    snr_min: float = 10.0,
    min_freq_hz: float = 0.0,
    max_freq_hz: float | None = None,
    smooth_lines: int = 5,
) -> tuple[float, float]:
    """The band around the spectral peak where a channel stays ``snr_min`` above its noise.

    Below the low edge, integration would turn noise and drift into large displacements
    (they grow as 1/w^2); above the high edge there is no signal to integrate.

    Parameters
    ----------
    freq_hz, psd : ndarray
        Spectrum of the acceleration.
    noise_psd_per_hz : float
        White-noise floor (see :func:`plateau_noise_floor`).
    snr_min : float
        Power ratio signal/noise required (10 = 10 dB).
    min_freq_hz, max_freq_hz : float
        Bounds the band never crosses.
    smooth_lines : int
        Moving-average length over lines before the comparison.

    Returns
    -------
    (low_hz, high_hz)
    """
    f = np.asarray(freq_hz, float)
    p = np.asarray(psd, float)
    if smooth_lines > 1:
        p = np.convolve(p, np.ones(smooth_lines) / smooth_lines, mode="same")
    hi_lim = f[-1] if max_freq_hz is None else max_freq_hz
    lo_lim = max(min_freq_hz, f[1] if f.size > 1 else 0.0)
    sel = (f >= lo_lim) & (f <= hi_lim)
    if not np.any(sel):
        raise ValueError("no lines between the band limits")
    good = sel & (p >= snr_min * max(noise_psd_per_hz, 1e-300))
    if not np.any(good):
        raise ValueError("the signal never rises above the noise")
    ipk = int(np.argmax(np.where(good, p, -np.inf)))
    i0 = ipk
    while i0 - 1 >= 0 and good[i0 - 1]:
        i0 -= 1
    i1 = ipk
    while i1 + 1 < f.size and good[i1 + 1]:
        i1 += 1
    return float(f[i0]), float(f[i1])


def find_spectral_peaks(
    freq_hz: np.ndarray, magnitude: np.ndarray, *, max_peaks: int = 5,
    min_prominence: float = 0.1, band_hz: tuple[float, float] | None = None,
) -> list[tuple[float, float]]:
    """Local maxima of a magnitude curve, most prominent first: [(freq_hz, magnitude)].

    Each peak is refined by a parabola through its line and the two neighbours.

    Parameters
    ----------
    freq_hz : ndarray
        Frequency lines [Hz].
    magnitude : ndarray
        The curve (a transmissibility magnitude, a PSD; not in dB).
    max_peaks : int
        Most peaks returned.
    min_prominence : float
        Least prominence, as a fraction of the largest value in the band.
    band_hz : (float, float) or None
        Only look in this band [Hz].

    Returns
    -------
    list of (float, float)
        (frequency [Hz], magnitude) of each peak, most prominent first; empty when the
        band holds fewer than three lines.

    Examples
    --------
    >>> f = np.linspace(0, 10, 101)
    >>> [(round(a, 2), round(b, 2)) for a, b in find_spectral_peaks(f, np.exp(-(f - 3) ** 2))]
    [(3.0, 1.0)]
    """
    f = np.asarray(freq_hz, float)
    m = np.asarray(magnitude, float)
    sel = np.ones(f.size, bool) if band_hz is None else (f >= band_hz[0]) & (f <= band_hz[1])
    if sel.sum() < 3:
        return []
    fs, ms = f[sel], m[sel]
    peaks, props = signal.find_peaks(ms, prominence=min_prominence * float(np.nanmax(ms)))
    order = np.argsort(props["prominences"])[::-1][:max_peaks]
    out = []
    for i in order:
        k = peaks[i]
        fk, mk = float(fs[k]), float(ms[k])
        if 0 < k < fs.size - 1:  # parabola through the peak line and its neighbours
            a, b, c = ms[k - 1], ms[k], ms[k + 1]
            den = a - 2 * b + c
            if den < 0:
                d = 0.5 * (a - c) / den
                fk = float(fs[k] + d * (fs[k + 1] - fs[k - 1]) / 2)
                mk = float(b - 0.25 * (a - c) * d)
        out.append((fk, mk))
    return out
