"""Where does a model's residual live: in time, in frequency, and over (r, rdot)?

Pure functions over arrays. The residual is recorded minus simulated body acceleration
(both band-limited identically); the noise floor is what the sensors alone would leave.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import signal


@dataclass(frozen=True)
class TimeWindow:
    """A stretch where the residual stands out: [start_s, end_s), RMS over the typical RMS.

    Parameters
    ----------
    start_s, end_s : float
        Start and end in the residual's time [s].
    rms_ratio : float
        Largest moving RMS inside the window over the typical (median) moving RMS.
    """

    start_s: float
    end_s: float
    rms_ratio: float


def rolling_rms(x: np.ndarray, sample_rate_hz: float, window_s: float) -> np.ndarray:
    """Centred moving RMS of ``x`` over ``window_s`` (same length as ``x``).

    Parameters
    ----------
    x : ndarray
        Samples (any unit, e.g. a residual in m/s^2).
    sample_rate_hz : float
        Sample rate [Hz].
    window_s : float
        Window length [s] (at least one sample); the ends are padded with zeros.

    Returns
    -------
    numpy.ndarray
        Moving RMS, in the unit of ``x``.
    """
    n = max(1, int(round(window_s * sample_rate_hz)))
    power = np.convolve(np.asarray(x, float) ** 2, np.ones(n) / n, mode="same")
    return np.sqrt(np.maximum(power, 0.0))


def residual_windows(
    time_s: np.ndarray,
    residual: np.ndarray,
    sample_rate_hz: float,
    *,
    window_s: float = 1.0,
    threshold: float = 2.0,
    max_windows: int = 8,
    reference: np.ndarray | None = None,
) -> list[TimeWindow]:
    """Time windows where the residual's moving RMS exceeds ``threshold`` x its median.

    Parameters
    ----------
    time_s, residual : ndarray
        Residual samples and their times [s].
    sample_rate_hz : float
        Sample rate [Hz].
    window_s : float
        Length of the moving RMS [s]; each window is padded by half of it on either side.
    threshold : float
        Ratio to the median moving RMS (or to ``reference``'s) that marks a window.
    max_windows : int
        Return at most this many, the strongest first.
    reference : ndarray, optional
        A residual to compare with (e.g. the noise-only part); default the residual itself.

    Returns
    -------
    list of TimeWindow
        Strongest first. When the residual is spread evenly (no window stands out) the list
        is empty: the mismatch is everywhere, not in events.
    """
    rms = rolling_rms(residual, sample_rate_hz, window_s)
    ref = rolling_rms(reference, sample_rate_hz, window_s) if reference is not None else rms
    typical = float(np.median(ref))
    if typical <= 0 or not np.isfinite(typical):
        return []
    ratio = rms / typical
    above = ratio > threshold
    if not np.any(above):
        return []
    edges = np.flatnonzero(np.diff(np.concatenate(([0], above.astype(np.int8), [0]))))
    starts, ends = edges[::2], edges[1::2]
    pad = int(round(0.5 * window_s * sample_rate_hz))
    windows = []
    for a, b in zip(starts, ends, strict=True):
        a0, b0 = max(a - pad, 0), min(b + pad, len(time_s) - 1)
        windows.append(TimeWindow(float(time_s[a0]), float(time_s[b0]), float(np.max(ratio[a:b]))))
    windows.sort(key=lambda w: -w.rms_ratio)
    return windows[:max_windows]


def excess_band(
    freq_hz: np.ndarray,
    residual_psd: np.ndarray,
    noise_psd: np.ndarray | float,
    *,
    band_hz: tuple[float, float] | None = None,
    fraction: float = 0.8,
) -> tuple[float, float] | None:
    """The frequency band holding ``fraction`` of the residual power above the noise floor.

    Parameters
    ----------
    freq_hz : ndarray
        Frequencies of the PSD lines [Hz].
    residual_psd : ndarray
        PSD of the residual (e.g. [(m/s^2)^2/Hz], from :func:`residual_psd`).
    noise_psd : ndarray or float
        Noise floor in the same unit; only the power above it counts.
    band_hz : (float, float) or None
        Consider only lines inside this band [Hz].
    fraction : float
        Share of the excess power the band holds (centred: 0.8 gives the 10-90 % quantiles).

    Returns
    -------
    (lo_hz, hi_hz) or None
        The central ``fraction`` of the excess power (10 %-90 % quantiles by default) [Hz];
        None when the residual does not exceed the noise anywhere.
    """
    f = np.asarray(freq_hz, float)
    excess = np.maximum(np.asarray(residual_psd, float) - noise_psd, 0.0)
    if band_hz is not None:
        excess = np.where((f >= band_hz[0]) & (f <= band_hz[1]), excess, 0.0)
    total = float(np.sum(excess))
    if total <= 0:
        return None
    cdf = np.cumsum(excess) / total
    q = (1.0 - fraction) / 2.0
    # fraction = 1 (q = 0): the first and last lines holding power, not f[0] and f[-1]
    lo = float(f[np.searchsorted(cdf, max(q, 1e-12))])
    hi = float(f[min(np.searchsorted(cdf, min(1.0 - q, 1.0 - 1e-12)), f.size - 1)])
    return lo, hi


def residual_psd(
    residual: np.ndarray, sample_rate_hz: float, *, segment_s: float = 8.0
) -> tuple[np.ndarray, np.ndarray]:
    """Welch PSD of a residual (one-sided, units^2/Hz).

    Parameters
    ----------
    residual : ndarray
        Residual samples (e.g. body acceleration [m/s^2]).
    sample_rate_hz : float
        Sample rate [Hz].
    segment_s : float
        Welch segment length [s] (at least 64 samples, at most the whole record).

    Returns
    -------
    freq_hz : ndarray
        Frequencies [Hz].
    psd : ndarray
        One-sided PSD in the residual's unit squared per Hz (e.g. [(m/s^2)^2/Hz]).
    """
    nper = int(min(len(residual), max(64, round(segment_s * sample_rate_hz))))
    return signal.welch(residual, fs=sample_rate_hz, nperseg=nper, detrend="constant")


@dataclass(frozen=True)
class DepartureMap:
    """Mean restoring-force departure from the fitted model over a grid of (r, rdot).

    ``mean[i, j]`` is the mean departure (N, or N/kg per unit mass) of the samples with r in
    bin i and rdot in bin j; ``count`` how many samples fell there (NaN mean where empty).

    Parameters
    ----------
    r_edges_m : ndarray
        Bin edges of the suspension extension r [m] (positive in rebound).
    rdot_edges_mps : ndarray
        Bin edges of its rate [m/s].
    mean : ndarray
        ``(n_r, n_rdot)`` mean departure per bin.
    count : ndarray
        ``(n_r, n_rdot)`` samples per bin.
    """

    r_edges_m: np.ndarray
    rdot_edges_mps: np.ndarray
    mean: np.ndarray
    count: np.ndarray

    def region(self, share: float = 0.5, min_count: int = 20) -> dict[str, list[float]] | None:
        """Bounding box of the bins holding ``share`` of the absolute departure.

        Bins are weighted by |mean| times sqrt(count) (well-populated bins first); bins with
        fewer than ``min_count`` samples are ignored.

        Parameters
        ----------
        share : float
            Share of the total weight the box covers (0..1).
        min_count : int
            Fewest samples a bin needs to count.

        Returns
        -------
        dict or None
            ``{"r_m": [lo, hi], "rdot_mps": [lo, hi]}`` [m], [m/s]; None if the map is empty.
        """
        weight = np.where(self.count >= min_count, np.abs(np.nan_to_num(self.mean)), 0.0)
        weight = weight * np.sqrt(self.count)  # favour well-populated bins
        total = float(weight.sum())
        if total <= 0:
            return None
        order = np.argsort(weight, axis=None)[::-1]
        cum = np.cumsum(weight.ravel()[order]) / total
        chosen = order[: int(np.searchsorted(cum, share)) + 1]
        i, j = np.unravel_index(chosen, weight.shape)
        return {
            "r_m": [float(self.r_edges_m[i.min()]), float(self.r_edges_m[i.max() + 1])],
            "rdot_mps": [
                float(self.rdot_edges_mps[j.min()]),
                float(self.rdot_edges_mps[j.max() + 1]),
            ],
        }


def departure_map(
    r_m: np.ndarray,
    rdot_mps: np.ndarray,
    departure: np.ndarray,
    *,
    bins: int = 15,
    quantile: float = 0.005,
) -> DepartureMap:
    """Bin a force departure over (r, rdot); the grid spans the central data range.

    Parameters
    ----------
    r_m : ndarray
        Suspension extension [m] (positive in rebound).
    rdot_mps : ndarray
        Its rate [m/s].
    departure : ndarray
        Departure of each sample from the fitted model (force on the body [N], or per unit
        mass [N/kg = m/s^2]).
    bins : int
        Bins along each axis.
    quantile : float
        The grid spans the ``quantile`` to ``1 - quantile`` range of r and rdot (outliers
        fall outside).

    Returns
    -------
    DepartureMap

    Examples
    --------
    ::

        dmap = departure_map(val.displacement, val.velocity, baseline.residual_validation)
        dmap.region()   # {"r_m": [...], "rdot_mps": [...]} where the linear model misses
    """
    r = np.asarray(r_m, float)
    v = np.asarray(rdot_mps, float)
    d = np.asarray(departure, float)
    r_edges = np.linspace(*np.quantile(r, [quantile, 1 - quantile]), bins + 1)
    v_edges = np.linspace(*np.quantile(v, [quantile, 1 - quantile]), bins + 1)
    count, _, _ = np.histogram2d(r, v, bins=[r_edges, v_edges])
    total, _, _ = np.histogram2d(r, v, bins=[r_edges, v_edges], weights=d)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(count > 0, total / count, np.nan)
    return DepartureMap(r_edges, v_edges, mean, count.astype(int))
