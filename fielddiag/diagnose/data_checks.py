"""Problems of the measurement, not of the suspension.

Each check looks at the recorded signals (or at the before/after transmissibilities) and
returns :class:`DataWarning` objects. They tell the technician to fix the recording rather
than blaming the car: a clipped accelerometer, a drifting bias, a sensor remounted with a
different gain between the drives, a time offset between the wheel and body channels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class DataWarning:
    """A problem of the data; ``kind`` is a stable identifier, ``message`` plain language.

    Parameters
    ----------
    kind : str
        ``clipping``, ``bias_drift``, ``sensor_gain_changed``, ``channel_time_offset``...
    message : str
        What is wrong and what to do.
    session : str
        ``before``, ``after`` or "" for both.
    channel : str
        The channel concerned, or "".
    value : float or None
        The measured size (clipped fraction, drift [m/s^2], gain change, offset [s]).
    """

    kind: str
    message: str
    session: str = ""  # "before", "after" or "" for both
    channel: str = ""
    value: float | None = None

    def to_dict(self) -> dict:
        """The JSON form.

        Returns
        -------
        dict
            ``{"kind", "message"}``, with ``session``, ``channel`` and ``value`` where
            set (the measured size, in the unit :class:`DataWarning` gives: a program
            reading the JSON needs the number, not the sentence).
        """
        out: dict = {"kind": self.kind, "message": self.message}
        if self.session:
            out["session"] = self.session
        if self.channel:
            out["channel"] = self.channel
        if self.value is not None:
            out["value"] = float(self.value)
        return out


def clipped_mask(values: np.ndarray, *, min_run: int = 3) -> np.ndarray:
    """Samples that sit at the signal's extreme value in runs of at least ``min_run``
    (a saturated accelerometer holds its full scale; a noisy signal reaches its maximum
    once). A level counts when at least 0.02 % of the samples (and 5) sit at it.

    Parameters
    ----------
    values : ndarray
        One channel's samples (any unit).
    min_run : int
        Fewest consecutive samples at the extreme that count as clipping.

    Returns
    -------
    ndarray of bool
        True where a sample is clipped (all True for a constant signal; all False below
        100 samples).
    """
    x = np.asarray(values, float)
    out = np.zeros(x.size, bool)
    if x.size < 100:
        return out
    span = float(x.max() - x.min())
    if span <= 0:
        return ~out
    tol = 1e-9 * span
    for level in (x.max(), x.min()):
        at = np.abs(x - level) <= tol
        if int(at.sum()) < max(5, int(2e-4 * x.size)):
            continue
        edges = np.flatnonzero(np.diff(np.concatenate(([0], at.astype(np.int8), [0]))))
        for a, b in zip(edges[::2], edges[1::2], strict=True):
            if b - a >= min_run:
                out[a:b] = True
    return out


def check_clipping(
    values: np.ndarray, *, channel: str, session: str = "", min_run: int = 3
) -> DataWarning | None:
    """Saturation: the signal sits exactly at its extreme value in runs of samples
    (:func:`clipped_mask`). Flags a channel when any sample is clipped.

    Parameters
    ----------
    values : ndarray
        One channel's samples (any unit).
    channel : str
        Channel name, for the message.
    session : str
        ``before``/``after`` or "".
    min_run : int
        As :func:`clipped_mask`.

    Returns
    -------
    DataWarning or None
        ``clipping`` with the clipped fraction as ``value`` (1.0 for a constant signal);
        None when nothing is clipped or with fewer than 100 samples.
    """
    x = np.asarray(values, float)
    if x.size < 100:
        return None
    if float(x.max() - x.min()) <= 0:
        return DataWarning(
            "clipping", f"{channel} is constant: sensor dead or saturated", session, channel, 1.0
        )
    mask = clipped_mask(x, min_run=min_run)
    if not mask.any():
        return None
    worst = float(mask.mean())
    where = f" in the {session} drive" if session else ""
    return DataWarning(
        "clipping",
        f"{channel}{where} is clipped: {100 * worst:.2g} % of samples sit at full scale "
        f"(+-{max(abs(x.max()), abs(x.min())):.3g}). Use a larger measuring range or a softer "
        "mount; peaks are lost, and a mismatch where they are lost is the clipping's",
        session,
        channel,
        worst,
    )


def check_bias_drift(
    time_s: np.ndarray,
    values: np.ndarray,
    *,
    channel: str,
    session: str = "",
    window_s: float = 10.0,
    min_change_mps2: float = 0.05,
) -> DataWarning | None:
    """A drifting offset: the mean reading moves steadily over the drive.

    Vertical acceleration averages to zero over a few seconds (the car does not fly off),
    so the mean of each ``window_s`` window is g + bias. A straight-line trend of the window
    means whose change over the drive exceeds ``min_change_mps2`` and 5x the scatter of the
    window means about it is a drifting bias (warming sensor, failing mount).

    Parameters
    ----------
    time_s : ndarray
        Sample times [s].
    values : ndarray
        Acceleration [m/s^2].
    channel : str
        Channel name, for the message.
    session : str
        ``before``/``after`` or "".
    window_s : float
        Averaging window [s]; at least 6 windows are needed.
    min_change_mps2 : float
        Smallest drift over the drive that is reported [m/s^2].

    Returns
    -------
    DataWarning or None
        ``bias_drift`` with the change over the drive [m/s^2] as ``value``; None for no
        drift or a drive shorter than 6 windows.
    """
    t = np.asarray(time_s, float)
    x = np.asarray(values, float)
    duration = float(t[-1] - t[0])
    n_win = int(duration // window_s)
    if n_win < 6:
        return None
    edges = t[0] + window_s * np.arange(n_win + 1)
    idx = np.searchsorted(t, edges)
    means = np.array([x[a:b].mean() for a, b in zip(idx[:-1], idx[1:], strict=True) if b > a])
    centres = 0.5 * (edges[:-1] + edges[1:])[: means.size]
    slope, intercept = np.polyfit(centres, means, 1)
    scatter = float(np.std(means - (slope * centres + intercept), ddof=2))
    change = float(slope * duration)
    if abs(change) < max(min_change_mps2, 5.0 * scatter):
        return None
    where = f" in the {session} drive" if session else ""
    return DataWarning(
        "bias_drift",
        f"{channel}{where}: the sensor offset drifts by {change:+.3f} m/s2 over "
        f"{duration:.0f} s ({slope * 60:+.4f} m/s2 per minute). Let the sensor warm up, "
        "check its mount and cable; results use only the band above the drift",
        session,
        channel,
        change,
    )


def _model_ratio(freq_hz, measured, model, coherence, band_hz, min_coherence):
    f = np.asarray(freq_hz, float)
    ok = (f >= band_hz[0]) & (f <= band_hz[1]) & (np.asarray(coherence) >= min_coherence)
    ok &= np.abs(model) > 0
    return f[ok], np.asarray(measured)[ok] / np.asarray(model)[ok]


def _t_model(w: np.ndarray, k: float, c: float, k3: float, m: float) -> np.ndarray:
    """Linear body/wheel transmissibility (K2 + jwC2) / (K2 + K3 - w^2 M + jwC2)."""
    num = k + 1j * w * c
    return num / (k + k3 - w * w * m + 1j * w * c)


def _weighted_lines(tr: dict, band_hz, min_coherence: float):
    f = np.asarray(tr["freq_hz"], float)
    coh = np.asarray(tr["coherence"], float)
    ok = (f >= band_hz[0]) & (f <= band_hz[1]) & (coh >= min_coherence)
    t = np.asarray(tr["measured"])[ok]
    wgt = np.sqrt(np.clip(coh[ok] / np.maximum(1.0 - coh[ok], 1e-3), 0.0, 1e3))
    return 2 * np.pi * f[ok], t, wgt


def _log_residual(model: np.ndarray, meas: np.ndarray, wgt: np.ndarray) -> np.ndarray:
    d = np.log(meas / model)
    return np.concatenate([d.real * wgt, d.imag * wgt])


#: Inflation of the gain's least-squares std for correlated Welch lines (see
#: :func:`fit_gain_change`).
GAIN_STD_INFLATION = 1.4


@dataclass(frozen=True)
class GainFit:
    """A gain factor between the drives fitted to their transmissibilities.

    ``change`` is gain - 1 of the second drive's body/wheel ratio against the first's,
    ``std`` its standard deviation (inflated by :data:`GAIN_STD_INFLATION`: neighbouring
    Welch lines correlate), and
    ``explained`` the share of the between-drive inconsistency of one linear car that the
    gain removes (1: all of it; a physical difference between the drives changes the
    shape of T, which a flat gain cannot mimic).
    """

    change: float
    std: float
    explained: float


def fit_gain_change(
    transmissibility: list[dict],
    band_hz: tuple[float, float],
    *,
    added_mass_kg: float,
    start: dict[str, float],
    min_coherence: float = 0.8,
) -> GainFit | None:
    """Fit a gain change of the second drive's transmissibility (see :func:`check_gain_change`).

    Parameters
    ----------
    transmissibility : list of dict
        Two drives' ``freq_hz``, ``measured`` (complex T), ``coherence`` and ``label``.
    band_hz : (float, float)
        Lines used [Hz].
    added_mass_kg : float
        Mass added for the second drive [kg].
    start : dict
        Linear model start values (``sprung_mass_kg``, ``suspension_stiffness_n_per_m``,
        ``suspension_damping_ns_per_m``, ``coupling_stiffness_n_per_m``).
    min_coherence : float
        Lines below it are left out.

    Returns
    -------
    GainFit or None
        None when fewer than 8 lines per drive are usable or the fit is singular.
    """
    from scipy import optimize

    if len(transmissibility) != 2:
        return None
    lines = [_weighted_lines(tr, band_hz, min_coherence) for tr in transmissibility]
    if min(w.size for w, _, _ in lines) < 8:
        return None

    def positive(key: str, typical: float) -> float:
        v = float(start.get(key, typical))
        return v if np.isfinite(v) and v > 0 else typical

    m0 = positive("sprung_mass_kg", 380.0)
    k0 = positive("suspension_stiffness_n_per_m", 2.4e4)
    k3 = float(start.get("coupling_stiffness_n_per_m", 0.0))
    x0 = [np.log(m0), np.log(k0), np.log(positive("suspension_damping_ns_per_m", 1.8e3)),
          k3 / k0 if np.isfinite(k3) else 0.0]

    def joint(x, with_gain: bool):
        m, k, c = np.exp(x[:3])
        k3 = x[3] * k
        g = np.exp(x[4]) if with_gain else 1.0
        res = []
        for i, (w, t, wgt) in enumerate(lines):
            model = _t_model(w, k, c, k3, m + (added_mass_kg if i == 1 else 0.0))
            res.append(_log_residual(model * (g if i == 1 else 1.0), t, wgt))
        return np.concatenate(res)

    with np.errstate(all="ignore"):
        fit0 = optimize.least_squares(joint, x0, args=(False,), method="lm")
        fitg = optimize.least_squares(joint, [*fit0.x, 0.0], args=(True,), method="lm")
    chi0, chig = float(fit0.fun @ fit0.fun), float(fitg.fun @ fitg.fun)
    chis = 0.0
    for w, t, wgt in lines:  # each drive alone, per unit mass

        def one(x, w=w, t=t, wgt=wgt):
            return _log_residual(_t_model(w, np.exp(x[0]), np.exp(x[1]), x[2], 1.0), t, wgt)

        xs = [np.log(np.exp(x0[1]) / m0), np.log(np.exp(x0[2]) / m0), 0.0]
        with np.errstate(all="ignore"):
            sol = optimize.least_squares(one, xs, method="lm")
        chis += float(sol.fun @ sol.fun)
    n = fitg.fun.size
    s2 = chig / max(n - 5, 1)
    try:
        cov = np.linalg.inv(fitg.jac.T @ fitg.jac) * s2
    except np.linalg.LinAlgError:
        return None
    # neighbouring Welch lines correlate, so the least-squares std is too small: the factor
    # is calibrated on fresh random linear pairs (benchmarks/random_cases.py, 54 draws at
    # 200-1000 Hz, 90-300 s, 25-45 dB): with 2.0 the gain's z had a std of 0.63-0.78
    sd = float(np.sqrt(cov[4, 4])) * GAIN_STD_INFLATION if cov[4, 4] > 0 else np.nan
    if not np.isfinite(sd):
        return None
    change = float(np.exp(fitg.x[4]) - 1.0)
    inconsistency = chi0 - chis
    explained = (chi0 - chig) / inconsistency if inconsistency > 0 else 0.0
    return GainFit(change, sd * (1.0 + change), float(explained))


def check_gain_change(
    transmissibility: list[dict],
    band_hz: tuple[float, float],
    *,
    added_mass_kg: float,
    start: dict[str, float],
    min_coherence: float = 0.8,
    min_change: float = 0.03,
) -> DataWarning | None:
    """A sensor remounted with another gain between the drives.

    Three fits of the linear transmissibility to both drives' measured T (log-complex
    residual, weighted by coherence): (a) one car for both drives, (b) one car plus a gain
    factor on the second drive, (c) each drive with its own free linear model (the best a
    linear model can do). A gain change is reported when the gain is significant and
    larger than ``min_change``, and it removes most of the inconsistency between the
    drives that (a) leaves and (c) removes.

    The diagnosis does not use this test as a verdict: it fits the gain as a competing
    hypothesis (:mod:`fielddiag.diagnose.data_hypotheses`); this stand-alone check is for
    quick looks at a pair.

    Parameters
    ----------
    transmissibility, band_hz, added_mass_kg, start, min_coherence
        As :func:`fit_gain_change`.
    min_change : float
        Smallest relative gain change reported (0.03 = 3 %).

    Returns
    -------
    DataWarning or None
        ``sensor_gain_changed`` (relative change as ``value``), or None: no significant
        change, or one that does not explain the inconsistency (at least 70 %).
    """
    fit = fit_gain_change(transmissibility, band_hz, added_mass_kg=added_mass_kg,
                          start=start, min_coherence=min_coherence)
    if fit is None:
        return None
    log_sd = fit.std / (1.0 + fit.change)
    if (abs(fit.change) < min_change or abs(np.log1p(fit.change)) < 4.0 * log_sd
            or fit.explained < 0.7):
        return None
    return gain_warning(transmissibility[0]["label"], transmissibility[1]["label"],
                        fit.change, fit.std)


def gain_warning(label_a: str, label_b: str, change: float, std: float,
                 moved: str = "", evidence: str = "") -> DataWarning:
    """The plain-language warning for a gain change of ``change`` (+- ``std``).

    Parameters
    ----------
    label_a, label_b : str
        Labels of the first and second drive.
    change, std : float
        Relative gain change of the second drive (gain - 1) and its standard deviation.
    moved : str
        Text appended to the advice (e.g. how the fit corrected it), or "".
    evidence : str
        What else says so (the accelerometers' gravity levels), or "".

    Returns
    -------
    DataWarning
        ``sensor_gain_changed`` for ``label_b``.
    """
    if evidence:
        what = (f"the {label_b} drive's body/wheel gain ratio is {100 * change:+.1f} +- "
                f"{100 * std:.1f} % off the {label_a} drive's: {evidence}. A sensor's gain "
                "changed between the drives (remounted, tilted, other range, other "
                "calibration)")
    else:
        what = (f"the {label_b} drive's body/wheel transmissibility is {100 * change:+.1f} "
                f"+- {100 * std:.1f} % off the {label_a} drive's at every frequency, as if a "
                "sensor's gain changed between the drives (remounted, other range, other "
                "calibration)")
    return DataWarning(
        "sensor_gain_changed",
        f"{what}. Check both sensors' calibration and mounting{moved}",
        label_b,
        "",
        change,
    )


def fit_time_offset(
    transmissibility: list[dict],
    band_hz: tuple[float, float],
    *,
    min_coherence: float = 0.9,
) -> tuple[float, float] | None:
    """Fit a wheel/body channel time offset to the transmissibilities' phase error.

    A delay tau of the body channel multiplies the measured transmissibility by
    exp(-j 2 pi f tau): a phase error (measured against the fitted linear model) growing
    linearly with frequency.

    Parameters
    ----------
    transmissibility : list of dict
        Per drive ``freq_hz`` [Hz], ``measured`` and ``model`` (complex T) and ``coherence``.
    band_hz : (float, float)
        Lines used [Hz].
    min_coherence : float
        Lines below it are left out.

    Returns
    -------
    (tau_s, std_s) or None
        The delay of the body channel [s] (positive: the body channel lags) and its
        standard deviation (doubled: neighbouring lines correlate); None with fewer than
        10 usable lines or less than 3 Hz of them.
    """
    fs_, phs = [], []
    for tr in transmissibility:
        f, ratio = _model_ratio(
            tr["freq_hz"], tr["measured"], tr["model"], tr["coherence"], band_hz, min_coherence
        )
        fs_.append(f)
        phs.append(np.angle(ratio))
    f = np.concatenate(fs_)
    ph = np.concatenate(phs)
    if f.size < 10 or np.ptp(f) < 3.0:
        return None
    a = np.column_stack([-2 * np.pi * f, np.ones_like(f)])
    coef, *_ = np.linalg.lstsq(a, ph, rcond=None)
    resid = ph - a @ coef
    dof = max(f.size - 2, 1)
    cov = np.linalg.inv(a.T @ a) * float(resid @ resid) / dof
    return float(coef[0]), float(np.sqrt(cov[0, 0]) * 2.0)


def check_time_offset(
    transmissibility: list[dict],
    band_hz: tuple[float, float],
    *,
    min_coherence: float = 0.9,
    min_offset_s: float = 0.001,
) -> DataWarning | None:
    """A time offset between the wheel and body channels (:func:`fit_time_offset`),
    reported when it exceeds ``min_offset_s`` and 4 standard deviations.

    The diagnosis fits the offset as a competing hypothesis instead
    (:mod:`fielddiag.diagnose.data_hypotheses`): asymmetric damping or a compliant top
    mount also bend the phase, and only held-out data can tell them apart.

    Parameters
    ----------
    transmissibility : list of dict
        As :func:`fit_time_offset`.
    band_hz : (float, float)
        Lines used [Hz].
    min_coherence : float
        Lines below it are left out.
    min_offset_s : float
        Smallest offset reported [s].

    Returns
    -------
    DataWarning or None
        ``channel_time_offset`` with the offset [s] as ``value``.
    """
    fit = fit_time_offset(transmissibility, band_hz, min_coherence=min_coherence)
    if fit is None:
        return None
    tau, tau_std = fit
    if abs(tau) < min_offset_s or abs(tau) < 4.0 * tau_std:
        return None
    return time_offset_warning(tau, tau_std)


def time_offset_warning(tau_s: float, std_s: float, moved: str = "",
                        physics: str = "") -> DataWarning:
    """The plain-language warning for a body channel delayed by ``tau_s`` (+- ``std_s``).

    Parameters
    ----------
    tau_s, std_s : float
        Delay of the body channel [s] (negative: the wheel channel lags) and its standard
        deviation [s].
    moved : str
        Text appended to the advice, or "".
    physics : str
        How the suspension's own lag (a stiff top mount) fared against it, or "".

    Returns
    -------
    DataWarning
        ``channel_time_offset``.
    """
    which = "body channel lags" if tau_s > 0 else "wheel channel lags"
    return DataWarning(
        "channel_time_offset",
        f"the {which} the other by {1000 * abs(tau_s):.2f} +- {1000 * std_s:.2f} ms (a phase "
        "error growing with frequency; of the suspension, only a stiff top mount in series "
        "with the damper delays like this, and only the damper's force). "
        f"{physics}Check that both channels are sampled together (same DAQ clock, same "
        f"filter settings){moved}",
        "",
        "",
        tau_s,
    )
