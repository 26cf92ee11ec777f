"""Problems of the recording as hypotheses that compete with the suspension's physics.

A sensor whose gain changed between the drives, or a body channel delayed against the
wheel channel, distorts the comparison of model and recording just as missing physics
does. Which explains the recording is decided the same way for both: each data problem
is estimated (from the before/after transmissibilities, with its standard deviation),
the drives are corrected for it, the models are fitted again to the corrected drives,
and the corrected model competes on the held-out data with the physical candidates
(:func:`fielddiag.diagnose.selection.select_model`). A data problem is reported only
when modelling it predicts unseen data better than physics does, and it never hides a
physical finding: the two can be chosen together.

The residuals of a corrected model are compared in the units of the recording: a gain
``g`` on the second drive's body channel makes its residual ``g`` times the corrected
one; a time shift of a few milliseconds leaves the block mean squares of the residual
unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from fielddiag.diagnose.gravity_gain import GravityGain

#: Kinds of data hypotheses (their names in ``Diagnosis.to_dict()['warnings']``).
GAIN_CHANGE = "sensor_gain_changed"
TIME_OFFSET = "channel_time_offset"
KINDS = (GAIN_CHANGE, TIME_OFFSET)

#: A hypothesis is fitted only when its estimate is this many standard deviations from
#: zero (a cheap pre-selection: the held-out comparison decides whether it is reported).
MIN_Z = 2.0
#: A data hypothesis whose size is at least this many standard deviations from zero is
#: chosen when it predicts the held-out data at all better (t >= :data:`MIN_T_SIGNIFICANT`),
#: even below the gain per parameter a physical effect must show: the linear model
#: absorbs a small gain change in its mass and stiffness (that is the bias it causes), so
#: its held-out gain is small while the estimate itself is decisive. On linear pairs drawn
#: with fresh seeds the gain's z has a std of about 1 (its std inflation calibrated so),
#: the delay's 0.6-0.7 (conservative).
DECISIVE_Z = 3.0
MIN_T_SIGNIFICANT = 1.0
#: ... and at least this large (below it no recording would be worth correcting).
MIN_GAIN_CHANGE = 0.003
#: A gain change's std from the transmissibility's level beyond which that estimate is not
#: told as evidence (a sensor's gain does not move by half)
UNINFORMATIVE_GAIN_STD = 0.5
MIN_TIME_OFFSET_S = 2e-4


@dataclass(frozen=True)
class DataHypothesis:
    """One data problem with its estimated size.

    Attributes
    ----------
    kind : str
        :data:`GAIN_CHANGE` (``value`` = gain - 1 of the second drive's body/wheel ratio)
        or :data:`TIME_OFFSET` (``value`` = delay of the body channel [s], positive: the
        body channel lags).
    value, std : float
        The estimate and its standard deviation.
    """

    kind: str
    value: float
    std: float
    prior: DataHypothesis | None = None  # a problem corrected before this one
    evidence: str = ""  # what besides the transmissibility says so (the gravity levels)
    #: a gain change measured twice, independently, with the same result: the gravity
    #: levels and the transmissibility's level each at least MIN_Z std from zero, same
    #: sign, within 3 std of each other
    confirmed: bool = False
    #: the physics the estimate was refined against (a delay measured against the model
    #: with that physics): its correction competes only beside that physics
    refined_with: tuple[str, ...] = ()

    @property
    def chain(self) -> list[DataHypothesis]:
        """The problems corrected, in order: ``prior``'s chain, then this one."""
        return [*(self.prior.chain if self.prior is not None else []), self]

    @property
    def z(self) -> float:
        """|value| / std: how many standard deviations the estimate is from zero."""
        return abs(self.value) / self.std if self.std > 0 else np.inf

    @property
    def worth_correcting(self) -> bool:
        """Whether the estimate is at least the smallest size worth correcting
        (:data:`MIN_TIME_OFFSET_S`, :data:`MIN_GAIN_CHANGE`): a refined estimate may end
        below the size its first estimate was screened by."""
        least = MIN_TIME_OFFSET_S if self.kind == TIME_OFFSET else MIN_GAIN_CHANGE
        return abs(self.value) >= least


def combine_gain(dynamic: tuple[float, float] | None, gravity: GravityGain | None
                 ) -> DataHypothesis | None:
    """One gain-change estimate from the transmissibility's level and the gravity levels.

    Two independent measurements of the second drive's body/wheel gain ratio: where both
    exist and agree (within 3 standard deviations of their difference) they are averaged
    with inverse-variance weights; where they disagree, the transmissibility's level moved
    for another reason than a sensor's gain (physics that acts differently under the added
    mass) and the gravity levels, which no suspension moves, are the estimate.

    Parameters
    ----------
    dynamic : (float, float) or None
        Gain - 1 and its std from the transmissibilities, or None.
    gravity : GravityGain or None
        The gravity levels' estimate (:func:`fielddiag.diagnose.gravity_gain.gain_from_gravity`),
        or None (a channel without gravity).

    Returns
    -------
    DataHypothesis or None
        :data:`GAIN_CHANGE` with ``evidence`` naming the gravity levels when they took part.
    """
    if gravity is None:
        return None if dynamic is None else DataHypothesis(GAIN_CHANGE, *dynamic)
    g, gs = gravity.ratio_change, gravity.ratio_std
    evidence = gravity.describe()
    if dynamic is None:
        return DataHypothesis(GAIN_CHANGE, g, gs, evidence=evidence)
    d, ds = dynamic
    if not ds < UNINFORMATIVE_GAIN_STD:
        # the transmissibility's level fit did not settle (+880 +- 560 %): it agrees with
        # anything and says nothing
        return DataHypothesis(GAIN_CHANGE, g, gs, evidence=(
            f"{evidence}; the transmissibility's level cannot tell (+- {100 * ds:.0f} %)"))
    if abs(d - g) > 3.0 * float(np.hypot(ds, gs)):
        return DataHypothesis(GAIN_CHANGE, g, gs, evidence=(
            f"{evidence}; the transmissibility's level moved {100 * d:+.1f} +- "
            f"{100 * ds:.1f} %, which the gravity levels do not confirm (physics, not the "
            "sensor)"))
    w_d, w_g = 1.0 / ds**2, 1.0 / gs**2
    value = (w_d * d + w_g * g) / (w_d + w_g)
    confirmed = bool(abs(d) >= MIN_Z * ds and abs(g) >= MIN_Z * gs and d * g > 0)
    return DataHypothesis(GAIN_CHANGE, float(value), float(1.0 / np.sqrt(w_d + w_g)),
                          evidence=f"{evidence}; the transmissibility's level agrees "
                                   f"({100 * d:+.1f} +- {100 * ds:.1f} %)",
                          confirmed=confirmed)


def from_transmissibility(trs: list[dict], band_hz: tuple[float, float],
                          added_mass_kg: float, start: dict[str, float],
                          gravity: GravityGain | None = None) -> list[DataHypothesis]:
    """Data hypotheses worth fitting, estimated from two drives' transmissibilities (and,
    for a gain change, the accelerometers' gravity levels).

    Parameters
    ----------
    trs : list of dict
        Before and after transmissibilities (``freq_hz``, ``measured``, ``model``,
        ``coherence``, ``label``) from the linear identification; may be empty.
    band_hz : (float, float)
        Band of the identification [Hz].
    added_mass_kg : float
        Mass added for the second drive [kg].
    start : dict
        The identification's linear values (start of the gain fit).
    gravity : GravityGain or None
        Both channels' gain changes from their gravity levels (:func:`combine_gain`).

    Returns
    -------
    list of DataHypothesis
        Those at least :data:`MIN_Z` standard deviations from zero and above the minimum
        sizes; empty when none is.
    """
    from fielddiag.diagnose import data_checks

    out = []
    g = None
    if trs:
        try:
            g = data_checks.fit_gain_change(trs, band_hz, added_mass_kg=added_mass_kg,
                                            start=start)
        except (ValueError, ZeroDivisionError, FloatingPointError, np.linalg.LinAlgError):
            g = None  # no estimate: the physics competes without this hypothesis
    gain = combine_gain(None if g is None else (g.change, g.std), gravity)
    if gain is not None and abs(gain.value) >= MIN_GAIN_CHANGE and gain.z >= MIN_Z:
        out.append(gain)
    if not trs:
        return out
    try:
        tau = data_checks.fit_time_offset(trs, band_hz)
    except (ValueError, np.linalg.LinAlgError):
        tau = None
    if tau is not None and abs(tau[0]) >= MIN_TIME_OFFSET_S and abs(tau[0]) >= MIN_Z * tau[1]:
        out.append(DataHypothesis(TIME_OFFSET, tau[0], tau[1]))
    return out


def shift_signal(x: np.ndarray, shift_samples: float) -> np.ndarray:
    """``x`` advanced by a (fractional) number of samples: ``y[n] = x[n + shift]``.

    By a linear phase in the frequency domain, after removing the mean and padding to
    twice the length so the ends do not wrap into each other.

    Parameters
    ----------
    x : ndarray
        Uniformly sampled signal.
    shift_samples : float
        Advance in samples (negative: delay).

    Returns
    -------
    ndarray
        Same length and mean as ``x``.
    """
    x = np.asarray(x, float)
    mean = float(np.mean(x))
    n = x.size
    spec = np.fft.rfft(x - mean, 2 * n)
    f = np.fft.rfftfreq(2 * n)
    return np.fft.irfft(spec * np.exp(2j * np.pi * f * shift_samples), 2 * n)[:n] + mean


def correct_drives(drives: list[Any], hyp: DataHypothesis) -> list[Any]:
    """The drives with the data problem undone (a gain divided out of the second drive's
    body channel, or the body channel moved back by the delay).

    Parameters
    ----------
    drives : list
        :class:`fielddiag.drive.CornerDrive`-like dataclasses with ``body_accel_mps2``
        [m/s^2] and ``sample_rate_hz``; the last is the drive with the added mass.
    hyp : DataHypothesis

    Returns
    -------
    list
        New drives (the inputs are not changed).
    """
    if hyp.prior is not None:
        drives = correct_drives(drives, hyp.prior)
    if hyp.kind == GAIN_CHANGE:
        last = drives[-1]
        return [*drives[:-1],
                replace(last, body_accel_mps2=last.body_accel_mps2 / (1.0 + hyp.value))]
    if hyp.kind == TIME_OFFSET:
        return [replace(d, body_accel_mps2=shift_signal(d.body_accel_mps2,
                                                        hyp.value * d.sample_rate_hz))
                for d in drives]
    raise ValueError(f"unknown data hypothesis {hyp.kind!r}")


def residual_scale(hyp: DataHypothesis, index: int, n_drives: int) -> float:
    """Factor from a corrected drive's residual to the recording's units.

    Parameters
    ----------
    hyp : DataHypothesis
    index, n_drives : int
        Which drive of how many (the gain acts on the last).

    Returns
    -------
    float
    """
    scale = residual_scale(hyp.prior, index, n_drives) if hyp.prior is not None else 1.0
    if hyp.kind == GAIN_CHANGE and index == n_drives - 1:
        return scale * (1.0 + hyp.value)
    return scale


_MOVED = {
    "sprung_mass_kg": ("sprung mass", "kg"),
    "suspension_stiffness_n_per_m": ("stiffness", "N/m"),
    "suspension_damping_ns_per_m": ("damping", "N s/m"),
}


def moved_text(uncorrected: dict[str, float], corrected: dict[str, float]) -> str:
    """``"; correcting it moves the sprung mass from 380 to 392 kg (+3.2 %), ..."``.

    Parameters
    ----------
    uncorrected, corrected : dict
        Linear values (``sprung_mass_kg``, ``suspension_stiffness_n_per_m``,
        ``suspension_damping_ns_per_m``) fitted to the drives as recorded and corrected.

    Returns
    -------
    str
        Empty when no value can be compared.
    """
    parts = []
    for key, (label, unit) in _MOVED.items():
        a, b = uncorrected.get(key), corrected.get(key)
        if a and b and np.isfinite(a) and np.isfinite(b):
            parts.append(f"{label} from {a:.4g} to {b:.4g} {unit} ({100 * (b / a - 1):+.1f} %)")
    return "; correcting it moves the " + ", the ".join(parts) if parts else ""
