"""What a body accelerometer alone can say: vertical spectrum and its dominant frequencies
against vehicle speed.

Without a wheel-side sensor the transmissibility, and so the mass, stiffness and damping,
cannot be identified (the road input is unknown). The body's vertical acceleration still
shows where the car responds: the body bounce/pitch modes (about 1-2 Hz), the wheel hop
(about 10-15 Hz) and anything tied to wheel rotation (tyre and wheel non-uniformity at
``v / (2 pi R)`` and its harmonics). A resonance stays at the same frequency when the
speed changes; an excitation tied to rotation moves with the speed. This module measures
that: the spectrum of the drive, the dominant peak of every window against the mean speed
of that window, spectra per speed bin, and a regression of each tracked peak on speed.

Irregular time stamps are resampled (linear interpolation) onto a uniform grid at the
median rate before any spectrum; the interpolation attenuates the top of the band a little
(sinc^2), which is stated in the result's notes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import signal

from fielddiag.dsp import (
    find_spectral_peaks,
    integrate_acceleration,
    plateau_noise_floor,
    remove_offset_and_drift,
)
from fielddiag.identify.results import Peak, _Serialisable


@dataclass
class RideWindow(_Serialisable):
    """One analysis window.

    Parameters
    ----------
    start_s : float
        Start from the beginning of the drive [s].
    speed_mps : float
        Mean vehicle speed in the window [m/s] (NaN without a speed signal).
    rms_mps2 : float
        RMS body acceleration about its mean [m/s^2].
    dominant_freq_hz : float
        Frequency of the strongest spectral peak [Hz].
    peaks : list of Peak
        Spectral peaks (magnitude in [(m/s^2)^2/Hz]).
    """

    start_s: float
    speed_mps: float
    rms_mps2: float
    dominant_freq_hz: float
    peaks: list[Peak]


@dataclass
class SpeedBinSpectrum(_Serialisable):
    """Mean spectrum of the windows whose mean speed falls in a bin.

    Parameters
    ----------
    speed_low_mps, speed_high_mps : float
        The speed bin [m/s].
    n_windows : int
        Windows averaged.
    freq_hz : list of float
        Frequencies [Hz].
    psd_mps2_per_hz : list of float
        Mean PSD of the body acceleration [(m/s^2)^2/Hz].
    peaks : list of Peak
        Its peaks.
    """

    speed_low_mps: float
    speed_high_mps: float
    n_windows: int
    freq_hz: list[float]
    psd_mps2_per_hz: list[float]
    peaks: list[Peak]


@dataclass
class PeakTrack(_Serialisable):
    """A spectral peak followed across windows within ``search_band_hz``, regressed on speed.

    ``slope_hz_per_mps`` near 0 (``slope_std`` large in comparison) means a resonance of the
    car; a slope close to ``1 / (2 pi R)`` per harmonic means an excitation tied to wheel
    rotation (R the rolling radius).

    Parameters
    ----------
    search_band_hz : list of float
        Band searched in each window [Hz].
    mean_freq_hz, freq_std_hz : float
        Mean and std of the peak frequency over the windows [Hz].
    slope_hz_per_mps, slope_std_hz_per_mps : float
        Slope of the peak frequency against speed and its std [Hz per m/s].
    correlation : float
        Correlation of frequency with speed.
    n_windows : int
        Windows with the peak.
    implied_rolling_radius_m : float or None
        ``1 / (2 pi slope)`` [m] when the slope is significant and positive, else None.
    window_freq_hz : list of float
        The peak frequency in each window [Hz].
    intercept_hz : float
        Frequency of the regression line at zero speed [Hz].
    """

    search_band_hz: list[float]
    mean_freq_hz: float
    freq_std_hz: float
    slope_hz_per_mps: float
    slope_std_hz_per_mps: float
    correlation: float
    n_windows: int
    implied_rolling_radius_m: float | None
    window_freq_hz: list[float] = field(default_factory=list)
    intercept_hz: float = float("nan")


@dataclass
class RideAnalysis(_Serialisable):
    """Body-only analysis of one drive.

    Parameters
    ----------
    duration_s, sample_rate_hz : float
        Duration [s] and (resampled) sample rate [Hz].
    resampled : bool
        The time stamps were irregular and the signal was resampled.
    timing_jitter_fraction : float
        std(dt) / median(dt) of the original time stamps.
    freq_hz, psd_mps2_per_hz : list of float
        Spectrum of the body acceleration [Hz], [(m/s^2)^2/Hz].
    noise_psd_per_hz : float
        Noise floor [(m/s^2)^2/Hz]; ``noise_floor_found`` says whether a plateau was seen.
    noise_floor_found : bool
        See above.
    rms_mps2 : float
        RMS body acceleration [m/s^2].
    displacement_band_hz : list of float
        Band above the noise in which displacement is integrated [Hz].
    displacement_rms_m : float
        RMS body displacement in that band [m].
    peaks : list of Peak
        Peaks of the whole-drive spectrum.
    windows : list of RideWindow
        Per analysis window.
    speed_bins : list of SpeedBinSpectrum
        Spectra per speed bin (empty without speed).
    tracks : list of PeakTrack
        Peaks regressed on speed.
    spectrogram_time_s, spectrogram_freq_hz : list of float
        Window centres [s] and frequencies [Hz] of the spectrogram.
    spectrogram_db : list of list of float
        ``10 log10`` of the PSD [dB re 1 (m/s^2)^2/Hz], one row per window.
    speed_time_s, speed_mps : list of float
        The speed signal [s], [m/s] (decimated; empty without speed).
    notes : list of str
        Remarks (resampling, missing noise floor).
    """

    duration_s: float
    sample_rate_hz: float
    resampled: bool
    timing_jitter_fraction: float
    freq_hz: list[float]
    psd_mps2_per_hz: list[float]
    noise_psd_per_hz: float
    noise_floor_found: bool
    rms_mps2: float
    displacement_band_hz: list[float]
    displacement_rms_m: float
    peaks: list[Peak]
    windows: list[RideWindow]
    speed_bins: list[SpeedBinSpectrum]
    tracks: list[PeakTrack]
    spectrogram_time_s: list[float]
    spectrogram_freq_hz: list[float]
    spectrogram_db: list[list[float]]
    speed_time_s: list[float]
    speed_mps: list[float]
    notes: list[str] = field(default_factory=list)


def uniform_resample(time_s: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray,
                                                                       float, float]:
    """Linear interpolation onto a grid at the median sample rate.

    Parameters
    ----------
    time_s : ndarray
        Sample times [s], increasing.
    values : ndarray
        Samples at those times (any unit).

    Returns
    -------
    (time_s, values, sample_rate_hz, jitter)
        ``jitter`` is std(dt)/median(dt) of the original time stamps.
    """
    t = np.asarray(time_s, float)
    v = np.asarray(values, float)
    dt = np.diff(t)
    med = float(np.median(dt))
    jitter = float(np.std(dt) / med)
    tu = t[0] + np.arange(int(math.floor((t[-1] - t[0]) / med)) + 1) * med
    return tu, np.interp(tu, t, v), 1.0 / med, jitter


def displacement_band(freq_hz: np.ndarray, psd: np.ndarray, noise_psd_per_hz: float, *,
                      min_freq_hz: float, max_freq_hz: float, snr_min: float = 10.0
                      ) -> tuple[float, float]:
    """From the first to the last line (smoothed over 5) at least ``snr_min`` above noise.

    Parameters
    ----------
    freq_hz : ndarray
        Frequencies [Hz].
    psd : ndarray
        PSD of the signal (e.g. [(m/s^2)^2/Hz]).
    noise_psd_per_hz : float
        Noise floor in the same unit.
    min_freq_hz, max_freq_hz : float
        Lines considered [Hz].
    snr_min : float
        Power ratio over the noise a line needs.

    Returns
    -------
    (float, float)
        ``(low_hz, high_hz)``; NaN, NaN with fewer than two good lines.
    """
    ps = np.convolve(psd, np.ones(5) / 5, mode="same")
    ok = (freq_hz >= min_freq_hz) & (freq_hz <= max_freq_hz) & (ps >= snr_min * noise_psd_per_hz)
    if ok.sum() < 2:
        return float("nan"), float("nan")
    idx = np.flatnonzero(ok)
    return float(freq_hz[idx[0]]), float(freq_hz[idx[-1]])


def _track(windows: list[RideWindow], freqs: np.ndarray, psds: np.ndarray,
           band: tuple[float, float]) -> PeakTrack | None:
    m = (freqs >= band[0]) & (freqs <= band[1])
    if m.sum() < 3 or len(windows) < 4:
        return None
    fpk = []
    for p in psds:
        pk = find_spectral_peaks(freqs[m], p[m], max_peaks=1, min_prominence=0.0)
        fpk.append(pk[0][0] if pk else float(freqs[m][np.argmax(p[m])]))
    fpk = np.array(fpk)
    v = np.array([w.speed_mps for w in windows])
    ok = np.isfinite(v)
    if ok.sum() < 4 or np.ptp(v[ok]) < 1.0:
        slope = slope_std = corr = icpt = float("nan")
    else:
        a = np.column_stack([v[ok], np.ones(ok.sum())])
        coef, *_ = np.linalg.lstsq(a, fpk[ok], rcond=None)
        resid = fpk[ok] - a @ coef
        dof = max(ok.sum() - 2, 1)
        cov = np.linalg.inv(a.T @ a) * float(resid @ resid) / dof
        slope, slope_std, icpt = float(coef[0]), float(math.sqrt(cov[0, 0])), float(coef[1])
        corr = float(np.corrcoef(v[ok], fpk[ok])[0, 1])
    radius = None
    if math.isfinite(slope) and slope > 3 * slope_std and slope > 0:
        radius = float(1.0 / (2 * math.pi * slope))
    return PeakTrack([float(band[0]), float(band[1])], float(fpk.mean()), float(fpk.std()),
                     slope, slope_std, corr, int(fpk.size), radius,
                     [float(x) for x in fpk], icpt)


def analyse_ride(
    body_up_mps2: np.ndarray,
    time_s: np.ndarray,
    *,
    speed_time_s: np.ndarray | None = None,
    speed_mps: np.ndarray | None = None,
    window_s: float = 8.0,
    segment_s: float = 4.0,
    track_bands_hz: tuple[tuple[float, float], ...] | None = None,
    track_width: float = 0.15,
    speed_bin_mps: float = 2.5,
    max_spectrogram_lines: int = 200,
) -> RideAnalysis:
    """Spectrum of the vertical body acceleration and its dominant frequencies vs speed.

    Parameters
    ----------
    body_up_mps2 : ndarray
        Vertical body acceleration, up positive (g included or not) [m/s^2].
    time_s : ndarray
        Sample times (may be irregular) [s].
    speed_time_s, speed_mps : ndarray or None
        Vehicle speed signal.
    window_s : float
        Length of the windows for the speed analysis (50 % overlap).
    segment_s : float
        Welch segment length inside windows and for the whole drive.
    track_bands_hz : tuple of (float, float) or None
        Bands in which a peak is followed across windows and regressed on speed; default
        ``f (1 +- track_width)`` (at least +-2.5 lines) around each peak of the whole
        drive's spectrum.
    track_width : float
        Relative half-width of the default tracking bands.
    speed_bin_mps : float
        Width of the speed bins.
    max_spectrogram_lines : int
        Frequency lines kept in the spectrogram.

    Returns
    -------
    RideAnalysis
    """
    t = np.asarray(time_s, float)
    dt = np.diff(t)
    notes = []
    jitter = float(np.std(dt) / np.median(dt)) if dt.size else 0.0
    resampled = jitter > 1e-6
    if resampled:
        t, x, fs, jitter = uniform_resample(t, body_up_mps2)
        notes.append(f"time stamps irregular (jitter {100 * jitter:.2f} % of the period): "
                     f"resampled linearly to {fs:.2f} Hz; the top of the band is attenuated "
                     f"by up to {100 * (1 - np.sinc(0.5) ** 2):.0f} % at Nyquist")
    else:
        x = np.asarray(body_up_mps2, float)
        fs = 1.0 / float(np.median(dt))
    x = remove_offset_and_drift(x)
    duration = float(t[-1] - t[0] + 1.0 / fs)
    nper = min(int(round(segment_s * fs)), x.size)
    f, p = signal.welch(x, fs, nperseg=nper, detrend="linear")
    nf = plateau_noise_floor(f, p, fs)
    if not nf.found:
        notes.append(f"no flat noise floor at the top of the spectrum ({nf.note})")
    peaks = [Peak(a, b) for a, b in find_spectral_peaks(f, p, max_peaks=6, min_prominence=0.02,
                                                        band_hz=(0.3, 0.45 * fs))]
    band, disp_rms = displacement_band(f, p, nf.psd_per_hz, min_freq_hz=max(2.0 / segment_s, 0.3),
                                       max_freq_hz=0.4 * fs), float("nan")
    if np.all(np.isfinite(band)) and band[1] > band[0]:
        disp_rms = float(np.std(integrate_acceleration(x, fs, band).displacement_m))
        notes.append(f"body displacement integrated in {band[0]:.2f}-{band[1]:.2f} Hz, where the "
                     "acceleration is 10 dB above the noise floor")
    # windows
    n_win = int(round(window_s * fs))
    step = max(1, n_win // 2)
    starts = np.arange(0, max(x.size - n_win, 0) + 1, step)
    wins, psds = [], []
    has_speed = speed_time_s is not None and speed_mps is not None and len(speed_mps) > 0
    for i0 in starts:
        seg = x[i0:i0 + n_win]
        fw, pw = signal.welch(seg, fs, nperseg=min(nper, seg.size), detrend="linear")
        t0, t1 = t[i0], t[min(i0 + n_win, t.size) - 1]
        if has_speed:
            m = (speed_time_s >= t0) & (speed_time_s <= t1)
            v = float(np.mean(speed_mps[m])) if m.any() else float(
                np.interp(0.5 * (t0 + t1), speed_time_s, speed_mps))
        else:
            v = float("nan")
        sel = (fw >= 0.5) & (fw <= 0.45 * fs)
        dom = float(fw[sel][np.argmax(pw[sel])]) if sel.any() else float("nan")
        pk = [Peak(a, b) for a, b in find_spectral_peaks(fw, pw, max_peaks=3, min_prominence=0.05,
                                                         band_hz=(0.5, 0.45 * fs))]
        wins.append(RideWindow(float(t0 - t[0]), v, float(np.std(seg)), dom, pk))
        psds.append(pw)
    psds_arr = np.array(psds) if psds else np.zeros((0, f.size))
    fw = f if not psds else signal.welch(x[:n_win], fs, nperseg=min(nper, n_win))[0]
    # speed bins
    bins = []
    if has_speed and wins:
        v = np.array([w.speed_mps for w in wins])
        edges = np.arange(math.floor(np.nanmin(v) / speed_bin_mps) * speed_bin_mps,
                          np.nanmax(v) + speed_bin_mps, speed_bin_mps)
        for lo, hi in zip(edges[:-1], edges[1:], strict=True):
            m = (v >= lo) & (v < hi)
            if m.sum() == 0:
                continue
            mp = psds_arr[m].mean(axis=0)
            bins.append(SpeedBinSpectrum(
                float(lo), float(hi), int(m.sum()), [float(a) for a in fw],
                [float(a) for a in mp],
                [Peak(a, b) for a, b in find_spectral_peaks(fw, mp, max_peaks=4,
                                                            min_prominence=0.05,
                                                            band_hz=(0.5, 0.45 * fs))]))
    if track_bands_hz is None:
        half = [max(track_width * pk.freq_hz, 2.5 / segment_s) for pk in peaks]
        track_bands_hz = tuple((pk.freq_hz - h, pk.freq_hz + h) for pk, h in zip(peaks, half,
                                                                               strict=True))
    tracks = [tr for band_t in track_bands_hz
              if band_t[1] < 0.5 * fs
              for tr in [_track(wins, fw, psds_arr, band_t)] if tr is not None]
    # spectrogram (compact)
    keep = np.flatnonzero(fw <= 0.5 * fs)
    if keep.size > max_spectrogram_lines:
        keep = keep[:: int(math.ceil(keep.size / max_spectrogram_lines))]
    sg = 10 * np.log10(np.maximum(psds_arr[:, keep], 1e-20)) if wins else np.zeros((0, 0))
    if has_speed:
        st, sv = np.asarray(speed_time_s, float) - t[0], np.asarray(speed_mps, float)
        if st.size > 2000:
            st, sv = st[:: st.size // 2000 + 1], sv[:: sv.size // 2000 + 1]
    else:
        st, sv = np.zeros(0), np.zeros(0)
    return RideAnalysis(
        duration_s=duration, sample_rate_hz=float(fs), resampled=resampled,
        timing_jitter_fraction=jitter, freq_hz=[float(a) for a in f],
        psd_mps2_per_hz=[float(a) for a in p], noise_psd_per_hz=float(nf.psd_per_hz),
        noise_floor_found=bool(nf.found), rms_mps2=float(np.std(x)),
        displacement_band_hz=[float(band[0]), float(band[1])], displacement_rms_m=disp_rms,
        peaks=peaks, windows=wins, speed_bins=bins, tracks=tracks,
        spectrogram_time_s=[w.start_s + 0.5 * window_s for w in wins],
        spectrogram_freq_hz=[float(a) for a in fw[keep]],
        spectrogram_db=[[float(a) for a in row] for row in sg],
        speed_time_s=[float(a) for a in st], speed_mps=[float(a) for a in sv], notes=notes)
