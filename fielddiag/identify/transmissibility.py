"""Body/wheel transmissibility: H1, H2 and H-v estimators, sensor noise floors, band, peaks.

The transmissibility ``T = X2/X1 = A2/A1`` of the linear quarter-car body equation is a
deterministic function of frequency: the measured body and wheel accelerations would be
fully coherent without sensor noise. Noise on the wheel channel (the input) biases H1 low,
noise on the body channel biases H2 high. Here the two noise floors are estimated from the
data and used by the H-v (total least squares) estimator, which weights the two channels
by their noise and is unbiased under both.

Noise floors (white noise assumed, as from an ADC after its anti-alias filter):

* the plateau at the top of each channel's spectrum, where the anti-alias filter has
  removed the signal (:func:`fielddiag.dsp.plateau_noise_floor`);
* the loss of coherence: with white noise ``Nx``, ``Ny`` on otherwise fully coherent
  channels, ``coh = (1 - Nx/Gxx)(1 - Ny/Gyy)`` on every line, which is fitted for
  ``(Nx, Ny)`` (in Fisher z, bias-corrected for the number of averages).

Both are upper bounds (residual signal on the plateau; leakage or nonlinearity in the
coherence), so the smaller is used.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import optimize

from fielddiag.dsp import CrossSpectra, NoiseFloor, find_spectral_peaks, plateau_noise_floor

#: Effective number of independent averages per Welch segment (Hann, 50 % overlap).
WELCH_EFFICIENCY = 1.0 / 1.06


@dataclass
class SessionNoise:
    """Sensor noise floors of the two channels of one recording.

    Attributes
    ----------
    wheel_psd_per_hz, body_psd_per_hz : float
        One-sided white-noise densities used [(m/s^2)^2/Hz].
    wheel_plateau, body_plateau : NoiseFloor
        What the top of each spectrum says.
    coherence_fit : (float, float) or None
        (wheel, body) densities from the coherence fit, None if it could not be done.
    notes : list of str
        How each floor was chosen.
    """

    wheel_psd_per_hz: float
    body_psd_per_hz: float
    wheel_plateau: NoiseFloor
    body_plateau: NoiseFloor
    coherence_fit: tuple[float, float] | None
    notes: list[str] = field(default_factory=list)


def coherence_noise_fit(
    spectra: CrossSpectra, band_hz: tuple[float, float], *, min_lines: int = 20
) -> tuple[float, float] | None:
    """Fit white noise densities (Nx, Ny) to the coherence of two channels.

    Model per line: ``coh = (1 - Nx/Gxx)(1 - Ny/Gyy)`` plus the bias of a coherence
    estimated from ``n`` averages, ``(1 - coh)^2 / n``; residuals in Fisher z
    (``atanh(sqrt(coh))``, variance ``1/(2n)``).

    Parameters
    ----------
    spectra : CrossSpectra
        Wheel (x) and body (y) acceleration spectra.
    band_hz : (float, float)
        Lines used [Hz].
    min_lines : int
        Fewest lines needed.

    Returns
    -------
    (Nx, Ny) or None
        Noise densities in the spectra's unit [(m/s^2)^2/Hz]; None when fewer than
        ``min_lines`` lines lie in ``band_hz``.
    """
    f = spectra.freq_hz
    m = (f >= band_hz[0]) & (f <= band_hz[1]) & (spectra.gxx > 0) & (spectra.gyy > 0)
    if m.sum() < min_lines:
        return None
    gxx, gyy = spectra.gxx[m], spectra.gyy[m]
    coh = np.clip(spectra.coherence[m], 1e-6, 1 - 1e-9)
    n_eff = max(spectra.n_averages * WELCH_EFFICIENCY, 1.0)
    z = np.arctanh(np.sqrt(coh))
    w = np.sqrt(2.0 * n_eff)

    def residuals(p: np.ndarray) -> np.ndarray:
        nx, ny = np.exp(p)
        c = np.clip(1 - nx / gxx, 1e-9, 1.0) * np.clip(1 - ny / gyy, 1e-9, 1.0)
        c = np.clip(c + (1 - c) ** 2 / n_eff, 1e-9, 1 - 1e-12)
        return (z - np.arctanh(np.sqrt(c))) * w

    best = None
    for qx in (0.01, 0.1):
        for qy in (0.01, 0.1):
            x0 = np.log([np.quantile(gxx, qx) * 0.1, np.quantile(gyy, qy) * 0.1])
            r = optimize.least_squares(residuals, x0, method="trf")
            if best is None or r.cost < best.cost:
                best = r
    nx, ny = np.exp(best.x)
    return float(nx), float(ny)


def estimate_session_noise(spectra: CrossSpectra, *, fit_band_hz: tuple[float, float]
                           ) -> SessionNoise:
    """Noise floors of the wheel (x) and body (y) channels of one recording.

    Parameters
    ----------
    spectra : CrossSpectra
        Spectra over the full Nyquist range (for the plateau).
    fit_band_hz : (float, float)
        Lines used by the coherence fit (keep it below the anti-alias filter).

    Returns
    -------
    SessionNoise
    """
    fs = spectra.sample_rate_hz
    px = plateau_noise_floor(spectra.freq_hz, spectra.gxx, fs)
    py = plateau_noise_floor(spectra.freq_hz, spectra.gyy, fs)
    coh = coherence_noise_fit(spectra, fit_band_hz)
    notes = []
    chosen = []
    for name, plat, cfit, g in (("wheel", px, None if coh is None else coh[0], spectra.gxx),
                                ("body", py, None if coh is None else coh[1], spectra.gyy)):
        floor = 1e-12 * float(np.max(g)) if g.size else 1e-30
        if cfit is not None and cfit <= plat.psd_per_hz:
            chosen.append(max(cfit, floor))
            notes.append(f"{name}: from the coherence ({cfit:.3g} (m/s2)^2/Hz; plateau "
                         f"{plat.psd_per_hz:.3g}{'' if plat.found else ' (upper bound)'})")
        elif plat.found or cfit is None:
            chosen.append(max(plat.psd_per_hz, floor))
            notes.append(f"{name}: from the spectrum top ({plat.psd_per_hz:.3g} (m/s2)^2/Hz; "
                         f"{plat.note})")
        else:
            chosen.append(max(plat.psd_per_hz, floor))
            notes.append(f"{name}: no noise plateau and the coherence fit is above the top of "
                         f"the spectrum; using the lowest level at the top, "
                         f"{plat.psd_per_hz:.3g} (m/s2)^2/Hz (an upper bound)")
    return SessionNoise(chosen[0], chosen[1], px, py, coh, notes)


def hv_transmissibility(spectra: CrossSpectra, noise_x: float, noise_y: float) -> np.ndarray:
    """H-v (total least squares) transmissibility with noise ratio ``noise_y / noise_x``.

    Per line, the slope of a complex Deming regression of Y on X with known error ratio
    ``lam = Ny/Nx``: ``H = (Gyy - lam Gxx + sqrt((Gyy - lam Gxx)^2 + 4 lam |Gxy|^2)) /
    (2 conj(Gxy))``. It tends to H2 when the wheel is the noisy channel (lam -> 0) and to
    H1 when the body is (lam -> inf); both limits are then unbiased.

    Parameters
    ----------
    spectra : CrossSpectra
        Wheel (x) and body (y) acceleration spectra.
    noise_x, noise_y : float
        Wheel and body noise densities [(m/s^2)^2/Hz]; ``noise_x <= 0`` gives H1.

    Returns
    -------
    numpy.ndarray
        Complex body/wheel transmissibility (dimensionless) per line.
    """
    gxx, gyy, gxy = spectra.gxx, spectra.gyy, spectra.gxy
    if noise_x <= 0:
        return gxy / gxx
    lam = noise_y / noise_x
    a = gyy - lam * gxx
    denom = 2 * np.conj(gxy)
    denom = np.where(np.abs(denom) > 0, denom, 1e-300)
    return (a + np.sqrt(a * a + 4 * lam * np.abs(gxy) ** 2)) / denom


def debiased_coherence(spectra: CrossSpectra) -> np.ndarray:
    """Coherence with the small-sample bias ``(1 - coh)^2 / n`` removed (clipped to [0, 1]).

    Parameters
    ----------
    spectra : CrossSpectra
        Spectra with ``coherence`` and ``n_averages``.

    Returns
    -------
    numpy.ndarray
        Coherence per line (dimensionless).
    """
    n_eff = max(spectra.n_averages * WELCH_EFFICIENCY, 1.0)
    c = spectra.coherence
    # invert c_hat = c + (1 - c)^2 / n for c (smaller root)
    a = 1.0 / n_eff
    b = 1.0 - 2.0 / n_eff
    disc = np.maximum(b * b - 4 * a * (a - c), 0.0)
    root = (-b + np.sqrt(disc)) / (2 * a)
    return np.clip(np.where(c < 1.0, root, 1.0), 0.0, 1.0)


def choose_band(
    spectra: list[CrossSpectra],
    *,
    coherence_min: float = 0.5,
    min_freq_hz: float = 0.0,
    max_freq_hz: float = 40.0,
    anchor_hz: float | None = None,
    smooth_lines: int = 5,
) -> tuple[float, float]:
    """The band where every session's coherence stays above ``coherence_min``.

    The smoothed, bias-corrected coherence of each session is taken; their minimum must
    stay above the threshold over a contiguous run of lines, which must contain
    ``anchor_hz`` (the body resonance) when given, else the best run is the longest.

    Parameters
    ----------
    spectra : list of CrossSpectra
        The sessions' spectra (same line spacing).
    coherence_min : float
        Threshold of the smoothed, debiased coherence.
    min_freq_hz, max_freq_hz : float
        Lines considered [Hz].
    anchor_hz : float or None
        Frequency the band must contain [Hz].
    smooth_lines : int
        Moving-average length over lines.

    Returns
    -------
    (low_hz, high_hz)

    Raises
    ------
    ValueError
        No run of at least five good lines.
    """
    n = min(sp.freq_hz.size for sp in spectra)  # same line spacing; rates may differ
    f = spectra[0].freq_hz[:n]
    cmin = np.ones(n)
    kern = np.ones(smooth_lines) / smooth_lines
    for sp in spectra:
        c = np.convolve(debiased_coherence(sp)[:n], kern, mode="same")
        cmin = np.minimum(cmin, c)
    good = (cmin >= coherence_min) & (f >= max(min_freq_hz, f[1])) & (f <= max_freq_hz)
    runs = []
    i = 0
    while i < f.size:
        if good[i]:
            j = i
            while j + 1 < f.size and good[j + 1]:
                j += 1
            runs.append((i, j))
            i = j + 1
        else:
            i += 1
    runs = [r for r in runs if r[1] - r[0] + 1 >= 5]
    if not runs:
        raise ValueError("no band with enough coherence")
    pick = None
    if anchor_hz is not None:
        for r in runs:
            if f[r[0]] <= anchor_hz <= f[r[1]]:
                pick = r
    if pick is None:
        pick = max(runs, key=lambda r: r[1] - r[0])
    return float(f[pick[0]]), float(f[pick[1]])


def resonance_peaks(freq_hz: np.ndarray, transmissibility: np.ndarray,
                    band_hz: tuple[float, float], max_peaks: int = 4) -> list[tuple[float, float]]:
    """Peaks of |T| inside the band, most prominent first: [(freq_hz, |T|)].

    Parameters
    ----------
    freq_hz : ndarray
        Frequencies [Hz].
    transmissibility : ndarray
        Complex (or real) T per line.
    band_hz : (float, float)
        Band searched [Hz].
    max_peaks : int
        Return at most this many.

    Returns
    -------
    list of (float, float)
        Frequency [Hz] and |T| (dimensionless) of each peak.
    """
    return find_spectral_peaks(freq_hz, np.abs(transmissibility), max_peaks=max_peaks,
                               min_prominence=0.05, band_hz=band_hz)
