"""Rig mode's band: which frequencies of a force/motion record carry signal, and one
zero-phase filter (with exact spectral derivatives) used alike on every channel.

The band is read from the data, never fixed to the sample rate:

* the displacement spectrum against its own noise floor (the median level of the top
  fifth of the spectrum) gives the highest frequency where the motion stands at least
  10 dB above noise;
* the force/displacement coherence gives the band where the two are related (and, with
  enough averages, significantly so); where it reaches 0.91 (``S/(S+N)`` at 10 dB) the
  motion counts as signal too (a record whose spectrum has no flat noise floor);
* the motion's upper edge is the higher of the two; the low-pass cut-off sits 1.5 times
  above it (the filter passes 99.8 % of the amplitude at the edge), and no filter is used
  when that is within 80 % of Nyquist (the signal fills the sampled band);
* the resonance is read from the dynamic stiffness ``F/X = k - m w^2 + i c w`` fitted to
  the coherent part of the frequency response, and reported only where the measured
  ``Re(F/X)`` turns from positive (spring) below it to negative (mass) above it.

The filter (:func:`lowpass`) is a 8th-order Butterworth run forwards and backwards (zero
phase); it acts on the force, on the displacement and on the model's force alike. The
velocity and acceleration are exact spectral derivatives of the filtered displacement
(:func:`zero_phase`: ``i w`` per derivative, no finite-difference loss; a central
difference loses 12 % of the acceleration at a sixth of the sample rate). Record ends are
extended by a tapered point reflection, which keeps the value and slope continuous, so
there is no wrap-around jump.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import signal

__all__ = ["RigBand", "choose_rig_band", "lowpass", "zero_phase"]

#: The cut-off sits this factor above the motion's upper edge.
CUTOFF_FACTOR = 1.5
#: No filter when the cut-off would reach this fraction of Nyquist.
NO_FILTER_FRACTION = 0.8
#: Motion counts as signal where its spectrum is this factor above the noise floor (10 dB).
SNR_MIN = 10.0
#: Smallest coherence that counts as related.
COHERENCE_MIN = 0.5
#: Butterworth order whose forward-backward response is the filter (8: flat to 0.2 % at
#: the motion edge, 1/1.5 of the cut-off, so the filtered motion is the motion).
ORDER = 8


@dataclass(frozen=True)
class RigBand:
    """The band a rig record is analysed in, and why.

    Attributes
    ----------
    cutoff_hz : float or None
        Low-pass cut-off applied alike to force and motion; None: no filter.
    motion_edge_hz : float
        Highest frequency where the motion carries signal (SNR or coherence).
    snr_edge_hz : float
        Highest frequency where the displacement stands 10 dB above its noise floor.
    coherent_band_hz : tuple of float or None
        Lowest and highest frequency with significant force/displacement coherence.
    resonance_hz : float or None
        Resonance read from the dynamic stiffness, when inside the coherent band.
    sample_rate_hz : float
        Sample rate of the record [Hz].
    reason : str
        One line on how the band was chosen.
    displacement_noise_psd : float
        One-sided noise floor of the displacement [unit^2/Hz] (what the fit's
        errors-in-variables correction takes as white sensor noise).
    frf_mass : float or None
        Moving mass read from ``Re(F/X) = k - m w^2`` over the coherent band, when that
        line explains ``Re(F/X)`` (R^2 >= 0.9) with ``m > 0``; None otherwise.
    """

    cutoff_hz: float | None
    motion_edge_hz: float
    snr_edge_hz: float
    coherent_band_hz: tuple[float, float] | None
    resonance_hz: float | None
    sample_rate_hz: float
    reason: str
    displacement_noise_psd: float = 0.0
    frf_mass: float | None = None

    def to_dict(self) -> dict:
        """JSON form (``band`` of the rig diagnosis)."""
        return {
            "filter": "none" if self.cutoff_hz is None else "zero-phase low-pass",
            "cutoff_hz": self.cutoff_hz,
            "motion_edge_hz": self.motion_edge_hz,
            "snr_edge_hz": self.snr_edge_hz,
            "coherent_band_hz": None if self.coherent_band_hz is None
            else list(self.coherent_band_hz),
            "resonance_hz": self.resonance_hz,
            "sample_rate_hz": self.sample_rate_hz,
            "reason": self.reason,
            "displacement_noise_psd": self.displacement_noise_psd,
            "frf_mass": self.frf_mass,
        }

    def noise_moments(self) -> tuple[float, float, float, float]:
        """Variance per sample of white displacement noise in the fit's columns, after the
        filter on the motion and again on the model's force (``|H|^4``): (x, x with a,
        v, a), i.e. ``int N G``, ``-int w^2 N G``, ``int w^2 N G``, ``int w^4 N G``."""
        f = np.linspace(0.0, self.sample_rate_hz / 2, 4097)
        g = np.ones_like(f) if self.cutoff_hz is None else (
            1.0 / (1.0 + (f / self.cutoff_hz) ** (2 * ORDER))) ** 2
        w2 = (2 * np.pi * f) ** 2
        ng = self.displacement_noise_psd * g
        return (float(np.trapezoid(ng, f)), float(-np.trapezoid(w2 * ng, f)),
                float(np.trapezoid(w2 * ng, f)), float(np.trapezoid(w2 * w2 * ng, f)))


def lowpass(x: np.ndarray, sample_rate_hz: float, cutoff_hz: float | None) -> np.ndarray:
    """The band's zero-phase low-pass: a 8th-order Butterworth run forwards and backwards.

    Parameters
    ----------
    x : array_like, shape (n,) or (n, k)
        Samples (columns filtered independently).
    sample_rate_hz : float
        Sample rate [Hz].
    cutoff_hz : float or None
        Cut-off [Hz] (-3 dB per pass, -6 dB overall); None returns ``x`` unchanged.

    Returns
    -------
    numpy.ndarray
        The shape of ``x``.
    """
    x = np.asarray(x, float)
    if cutoff_hz is None or x.shape[0] < 16:
        return x
    sos = signal.butter(ORDER, cutoff_hz, fs=sample_rate_hz, output="sos")
    pad = int(min(x.shape[0] - 1, np.ceil(3.0 * sample_rate_hz / cutoff_hz)))
    return signal.sosfiltfilt(sos, x, axis=0, padlen=pad)


def _extend(x: np.ndarray, m: int) -> np.ndarray:
    """``x`` with ``m`` samples of tapered point reflection on each side."""
    w = 0.5 * (1.0 - np.cos(np.pi * np.arange(m) / m))  # 0 at the far end, ~1 at the join
    left = x[0] + (x[0] - x[m:0:-1]) * w
    right = x[-1] + (x[-1] - x[-2 : -m - 2 : -1]) * w[::-1]
    return np.concatenate([left, x, right])


def zero_phase(
    x: np.ndarray, sample_rate_hz: float, cutoff_hz: float | None, orders: tuple[int, ...] = (0,)
) -> list[np.ndarray]:
    """Zero-phase low-pass of ``x`` and its exact derivatives.

    Parameters
    ----------
    x : array_like, shape (n,) or (n, k)
        Samples (columns filtered independently).
    sample_rate_hz : float
        Sample rate [Hz].
    cutoff_hz : float or None
        Cut-off of ``|H|^2`` of a 8th-order Butterworth (-6 dB there); None: no filter
        (the derivatives are still spectral).
    orders : tuple of int
        Derivative orders to return (0: the filtered signal, 1: its rate, 2: ...).

    Returns
    -------
    list of numpy.ndarray
        One array per order, the shape of ``x``.
    """
    x = np.asarray(x, float)
    one_d = x.ndim == 1
    xx = x[:, None] if one_d else x
    n = xx.shape[0]
    if n < 4:
        return [np.array(x) if o == 0 else np.zeros_like(x) for o in orders]
    m = n - 1
    ext = np.apply_along_axis(_extend, 0, xx, m) if xx.shape[1] else np.empty((3 * n - 2, 0))
    big = ext.shape[0]
    t = np.arange(big)
    first, last = ext[0], ext[-1]
    slope = (last - first) / (big - 1)
    trend = first + np.outer(t, slope)
    spec = np.fft.rfft(ext - trend, axis=0)
    f = np.fft.rfftfreq(big, 1.0 / sample_rate_hz)
    h = np.ones_like(f) if cutoff_hz is None else 1.0 / (1.0 + (f / cutoff_hz) ** (2 * ORDER))
    out = []
    for o in orders:
        w = (2j * np.pi * f) ** o
        if o % 2 and big % 2 == 0:
            w[-1] = 0.0  # the Nyquist bin has no phase to differentiate
        y = np.fft.irfft(spec * (h * w)[:, None], big, axis=0)
        if o == 0:
            y = y + trend
        elif o == 1:
            y = y + slope * sample_rate_hz
        y = y[m : m + n]
        out.append(y[:, 0] if one_d else y)
    return out


def _psd_setup(n: int) -> int:
    """Welch segment length: a power of two giving about 16 averages, 64..4096."""
    seg = 2 ** int(np.floor(np.log2(max(n / 8.0, 64))))
    return int(min(max(seg, 64), 4096, n))


def choose_rig_band(
    force: np.ndarray, displacement: np.ndarray, sample_rate_hz: float, *,
    motion: str = "displacement",
) -> RigBand:
    """Choose the analysis band of a rig record from its spectra.

    Parameters
    ----------
    force : array_like
        Measured force (any unit).
    displacement : array_like
        Measured displacement (any unit), same samples.
    sample_rate_hz : float
        Sample rate [Hz].
    motion : {"displacement", "acceleration"}
        What ``displacement`` holds; with an acceleration the frequency response is
        turned into ``F/X`` by ``-w^2`` and no displacement noise floor is reported.

    Returns
    -------
    RigBand
        The cut-off (or none), the motion's signal edge, the coherent band and the
        resonance, with the reason in words.
    """
    fs = float(sample_rate_hz)
    nyq = fs / 2
    f_in = signal.detrend(np.asarray(force, float))
    x_in = signal.detrend(np.asarray(displacement, float))
    n = f_in.size
    seg = _psd_setup(n)
    freq, pxx = signal.welch(x_in, fs, nperseg=seg)
    _, coh = signal.coherence(f_in, x_in, fs, nperseg=seg)
    _, pff = signal.welch(f_in, fs, nperseg=seg)
    _, pfx = signal.csd(f_in, x_in, fs, nperseg=seg)
    # noise floor of the displacement: the median level of the top fifth of the spectrum
    top = freq >= 0.8 * nyq
    floor = float(np.median(pxx[top])) if top.any() else float(pxx[-1])
    above = np.flatnonzero((pxx > SNR_MIN * floor) & (freq > 0))
    snr_edge = float(freq[above[-1]]) if above.size else 0.0
    # significant coherence: above 0.5 and above chance for ~n/seg independent averages
    k_avg = max(n / seg, 2.0)
    chance = 1.0 - (0.01 / freq.size) ** (1.0 / max(k_avg - 1.0, 1.0))
    thr = max(COHERENCE_MIN, chance)
    related = np.flatnonzero((coh >= thr) & (freq > 0))
    coherent = (float(freq[related[0]]), float(freq[related[-1]])) if related.size else None
    # the coherence that means 10 dB signal-to-noise: gamma^2 = S / (S + N)
    strong = np.flatnonzero((coh >= max(SNR_MIN / (1.0 + SNR_MIN), thr)) & (freq > 0))
    coh_edge = float(freq[strong[-1]]) if strong.size else 0.0
    edge = max(snr_edge, coh_edge)
    if motion == "acceleration":  # X = -A / w^2, so F/X = -w^2 F/A: Pfx = -Pfa / w^2
        with np.errstate(divide="ignore", invalid="ignore"):
            pfx = np.where(freq > 0, -pfx / (2 * np.pi * np.maximum(freq, 1e-12)) ** 2, 0)
        floor = 0.0
    resonance, frf_mass = _resonance(freq, pff, pfx, coh, thr, coherent)
    if edge <= 0.0:
        edge = 0.1 * fs
        why = "no band stands out of the noise; the motion edge assumed at a tenth of fs"
    else:
        why = (f"motion above noise (10 dB) up to {snr_edge:.3g} Hz"
               + (f", force/displacement coherent {coherent[0]:.3g}-{coherent[1]:.3g} Hz"
                  f" (at 10 dB, coherence >= 0.91, up to {coh_edge:.3g} Hz)"
                  if coherent else ", no significant force/displacement coherence"))
    cutoff: float | None = CUTOFF_FACTOR * edge
    if cutoff >= NO_FILTER_FRACTION * nyq:
        cutoff = None
        why += f"; the signal fills the band to Nyquist ({nyq:.4g} Hz): no filter"
    else:
        why += f"; force and motion low-passed alike at {cutoff:.3g} Hz (1.5 x the edge)"
    if resonance is not None:
        why += f"; resonance near {resonance:.3g} Hz"
    return RigBand(cutoff, edge, snr_edge, coherent, resonance, fs, why, floor, frf_mass)


def _resonance(freq, pff, pfx, coh, thr, coherent) -> tuple[float | None, float | None]:
    """(resonance, mass) from ``F/X = k - m w^2 + i c w`` fitted to the coherent bins.

    The mass is returned when the line ``k - m w^2`` explains ``Re(F/X)`` (R^2 >= 0.9)
    with ``m > 0``; the resonance when, besides, ``k > 0``, it lies inside the band and
    the measured ``Re(F/X)`` changes sign across it."""
    if coherent is None:
        return None, None
    use = (coh >= thr) & (freq > 0) & (np.abs(pfx) > 0)
    if use.sum() < 4:
        return None, None
    w = 2 * np.pi * freq[use]
    dyn = pff[use] / pfx[use]  # F/X, from the H1 receptance X/F = Pfx/Pff (Pfx = E[F* X])
    wt = np.sqrt(coh[use])
    a = np.column_stack([np.ones_like(w), -(w**2)]) * wt[:, None]
    y = dyn.real * wt
    (k, m), *_ = np.linalg.lstsq(a, y, rcond=None)
    r2 = 1.0 - float(np.sum((y - a @ np.array([k, m])) ** 2)) / max(
        float(np.sum((y - y.mean()) ** 2)), 1e-300)
    mass = float(m) if (m > 0 and r2 >= 0.9) else None
    if k <= 0 or m <= 0:
        return None, mass
    fr = float(np.sqrt(k / m) / (2 * np.pi))
    if not coherent[0] <= fr <= coherent[1]:
        return None, mass
    # a resonance is where the dynamic stiffness turns from spring-like to mass-like: the
    # measured Re(F/X) must be positive below it and negative above it (3 bins each)
    f_use = freq[use]
    below = dyn.real[f_use < 0.8 * fr]
    above = dyn.real[f_use > 1.25 * fr]
    if below.size < 3 or above.size < 3:
        return None, mass
    if np.mean(below > 0) < 0.8 or np.mean(above < 0) < 0.8:
        return None, mass
    return fr, mass
