"""A sensor's gain change between two drives, read off its gravity level.

An accelerometer with a DC response (MEMS, capacitive, piezo-resistive) reads
``gain * (a + g) + bias``. The vertical acceleration ``a`` of a car that returns to the road
averages to ``(v_end - v_start) / T``: nothing over a drive of minutes. So the mean reading
of each channel is ``gain * g + bias``, and the ratio of a channel's mean readings in two
drives is the ratio of its gains, up to the change of its bias between the drives. This is
independent of the suspension's physics, which is what makes it worth having beside the
transmissibility's level (:func:`fielddiag.diagnose.data_checks.fit_gain_change`): physics
that changes the transmissibility's level between the drives (a damper that meets another
part of its stroke under the added mass) cannot move the gravity level, and a gain change
moves both.

Uncertainty of a channel's level, per drive (all in m/s^2, added in quadrature):

* the scatter of 10 s window means about their straight-line trend, over the square root
  of the number of windows (slow motion, road grade, noise);
* a drifting bias: the trend's change over the drive divided by sqrt(12) (where the drift
  started is not known: the level of the drive's middle is used);
* clipped readings: the excess beyond full scale that they lost is estimated from the
  readings just inside it and added back, with half of it as its std
  (:func:`clipped_excess_mps2`);
* and, for the ratio between drives, the bias change of the sensor between the drives:
  :data:`BIAS_CHANGE_STD_MPS2` (a MEMS sensor's offset moves 0.1-0.5 mg per kelvin; a few
  kelvin between the drives).

Channels without gravity in them (AC-coupled IEPE sensors, or readings with gravity
removed) give no estimate: their mean is not within :data:`GRAVITY_BAND` of g.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fielddiag.diagnose.data_checks import clipped_mask
from fielddiag.units import GRAVITY_MPS2

__all__ = ["BIAS_CHANGE_STD_MPS2", "GRAVITY_BAND", "ChannelGain", "GravityGain",
           "GravityLevel", "clipped_excess_mps2", "gain_from_gravity", "gravity_level"]

#: Standard deviation of a sensor's bias change between two drives [m/s^2] (2 mg).
BIAS_CHANGE_STD_MPS2 = 0.02
#: A channel carries gravity when its mean reading / g lies in this band.
GRAVITY_BAND = (0.8, 1.2)
#: Length of the windows whose means are compared [s].
WINDOW_S = 10.0
#: Fewest windows for a level with a scatter.
MIN_WINDOWS = 4
#: A gain change is a fault of one sensor: when one channel's level moved by at least
#: this many standard deviations and the other's is consistent with no change (within
#: :data:`UNCHANGED_Z`), the ratio is the moved channel's change with its own std (the
#: other's reading, uninformative where its level is noisy or clipped, is not added).
SINGLE_CHANNEL_Z = 3.0
#: Readings just inside full scale, per clipped reading, that the clipped tail's scale is
#: read from (:func:`clipped_excess_mps2`).
TAIL_READINGS_PER_CLIPPED = 4
UNCHANGED_Z = 2.0


@dataclass(frozen=True)
class GravityLevel:
    """One channel's static reading during one drive.

    Attributes
    ----------
    level_mps2 : float
        Mean reading at the middle of the drive [m/s^2] (``gain * g + bias``).
    std_mps2 : float
        Its standard deviation [m/s^2] (scatter, drift, clipping; not the bias change).
    drift_mps2 : float
        Change of the straight-line trend over the drive [m/s^2].
    """

    level_mps2: float
    std_mps2: float
    drift_mps2: float


def gravity_level(time_s: np.ndarray, values_mps2: np.ndarray) -> GravityLevel | None:
    """The static level of one accelerometer channel over a drive.

    Parameters
    ----------
    time_s : ndarray
        Sample times [s].
    values_mps2 : ndarray
        Readings [m/s^2], up positive, gravity included.

    Returns
    -------
    GravityLevel or None
        None when the drive is shorter than :data:`MIN_WINDOWS` windows or the channel
        does not carry gravity (mean / g outside :data:`GRAVITY_BAND`).
    """
    t = np.asarray(time_s, float)
    x = np.asarray(values_mps2, float)
    if t.size < 2 or x.size != t.size:
        return None
    duration = float(t[-1] - t[0])
    n_win = int(duration // WINDOW_S)
    if n_win < MIN_WINDOWS:
        return None
    edges = t[0] + WINDOW_S * np.arange(n_win + 1)
    idx = np.searchsorted(t, edges)
    means = np.array([x[a:b].mean() for a, b in zip(idx[:-1], idx[1:], strict=True)
                      if b > a])
    if means.size < MIN_WINDOWS:
        return None
    centres = (np.arange(means.size) + 0.5) * WINDOW_S
    slope, intercept = np.polyfit(centres - centres.mean(), means, 1)
    level = float(intercept)
    if not GRAVITY_BAND[0] <= abs(level) / GRAVITY_MPS2 <= GRAVITY_BAND[1]:
        return None
    scatter = float(np.std(means - (intercept + slope * (centres - centres.mean())),
                           ddof=2)) if means.size > 2 else 0.0
    drift = float(slope * duration)
    lost, clip_term = clipped_excess_mps2(x)
    std = math.sqrt(scatter**2 / means.size + drift**2 / 12.0 + clip_term**2)
    return GravityLevel(level + lost, std, drift)


def clipped_excess_mps2(values_mps2: np.ndarray) -> tuple[float, float]:
    """What clipping took from a channel's mean, and its standard deviation [m/s^2].

    A clipped reading sits at full scale ``L`` while the acceleration went beyond it. Per
    clipped side, the tail beyond ``L`` is taken as exponential, its scale read off the
    readings just inside: when ``n`` readings sit at ``L`` and ``k`` lie within ``w`` of it,
    the tail's scale is ``w / ln(1 + k / n)`` (the share beyond ``L`` of the tail from
    ``L - w`` on is ``n / (n + k)``), and that is each clipped reading's expected excess.
    The std is half of each side's estimate (a Gaussian tail has less excess than an
    exponential one, a heavier tail more): on simulated clipped wheel channels (0.4-1.8 %
    of the samples at full scale) the estimate was 8-32 % of the mean actually lost away
    from it, and the sides' errors cancel in part.

    Parameters
    ----------
    values_mps2 : ndarray
        One channel's readings [m/s^2].

    Returns
    -------
    (float, float)
        The mean's shift to add back (positive where the upper side lost more) and its std;
        ``(0, 0)`` without clipping.
    """
    x = np.asarray(values_mps2, float)
    clipped = clipped_mask(x)
    if not clipped.any() or clipped.all():
        return 0.0, 0.0
    tol = 1e-9 * float(x.max() - x.min())
    shift = var = 0.0
    for side, full_scale in ((1.0, float(x.max())), (-1.0, float(x.min()))):
        at = np.abs(x - full_scale) <= tol
        if not (clipped & at).any():
            continue
        n_at = int(at.sum())
        inside = side * (full_scale - x[~at])
        k = min(TAIL_READINGS_PER_CLIPPED * n_at, inside.size // 2)
        if k < 1:
            continue
        width = float(np.partition(inside, k)[k])
        scale = width / math.log1p(k / n_at)
        lost = n_at * scale / x.size
        shift += side * lost
        var += (0.5 * lost) ** 2
    return shift, math.sqrt(var)


@dataclass(frozen=True)
class ChannelGain:
    """A channel's gain in the second drive relative to the first.

    Attributes
    ----------
    channel : str
        ``wheel`` or ``body``.
    change : float
        Gain ratio - 1.
    std : float
        Its standard deviation.
    levels_mps2 : (float, float)
        The gravity levels of the two drives [m/s^2].
    """

    channel: str
    change: float
    std: float
    levels_mps2: tuple[float, float]

    @property
    def z(self) -> float:
        """|change| / std."""
        return abs(self.change) / self.std if self.std > 0 else math.inf


@dataclass(frozen=True)
class GravityGain:
    """Both channels' gain changes and the body/wheel ratio the dynamics see.

    Attributes
    ----------
    wheel, body : ChannelGain
    ratio_change : float
        ``(1 + body.change) / (1 + wheel.change) - 1``: what scales the second drive's
        transmissibility.
    ratio_std : float
        Its standard deviation.
    single_channel : bool
        The ratio is one channel's change, the other's taken as unchanged
        (:data:`SINGLE_CHANNEL_Z`).
    """

    wheel: ChannelGain
    body: ChannelGain
    ratio_change: float
    ratio_std: float
    single_channel: bool = False

    def culprit(self) -> ChannelGain:
        """The channel whose gain moved more (in standard deviations)."""
        return self.body if self.body.z >= self.wheel.z else self.wheel

    def describe(self) -> str:
        """``"the wheel accelerometer's gravity reading went from 9.807 to 9.611 m/s2
        (-2.0 +- 0.2 %); the body's stayed within 0.1 %"``."""
        c = self.culprit()
        o = self.wheel if c is self.body else self.body
        return (f"the {c.channel} accelerometer's gravity reading went from "
                f"{c.levels_mps2[0]:.3f} to {c.levels_mps2[1]:.3f} m/s2 "
                f"({100 * c.change:+.1f} +- {100 * c.std:.1f} %); the {o.channel}'s "
                f"moved {100 * o.change:+.1f} +- {100 * o.std:.1f} %"
                + (" (consistent with no change: taken as unchanged)"
                   if self.single_channel else ""))


def _channel_gain(channel: str, a: GravityLevel, b: GravityLevel) -> ChannelGain:
    ratio = b.level_mps2 / a.level_mps2
    rel_var = ((a.std_mps2**2 + BIAS_CHANGE_STD_MPS2**2) / a.level_mps2**2
               + b.std_mps2**2 / b.level_mps2**2)
    return ChannelGain(channel, ratio - 1.0, abs(ratio) * math.sqrt(rel_var),
                       (a.level_mps2, b.level_mps2))


def gain_from_gravity(drives) -> GravityGain | None:
    """Gain changes of both accelerometers between two drives, from their gravity levels.

    Parameters
    ----------
    drives : sequence of CornerDrive-like
        Two drives with ``time_s``, ``wheel_accel_mps2`` and ``body_accel_mps2``
        (readings in m/s^2, gravity included).

    Returns
    -------
    GravityGain or None
        None unless there are two drives and both channels carry gravity in both.
    """
    if len(drives) != 2:
        return None
    levels = {}
    for ch in ("wheel", "body"):
        pair = [gravity_level(d.time_s, getattr(d, f"{ch}_accel_mps2")) for d in drives]
        if any(p is None for p in pair) or np.sign(pair[0].level_mps2) != np.sign(
                pair[1].level_mps2):
            return None
        levels[ch] = _channel_gain(ch, pair[0], pair[1])
    w, b = levels["wheel"], levels["body"]
    for moved, still in ((b, w), (w, b)):
        if moved.z >= SINGLE_CHANNEL_Z and still.z < UNCHANGED_Z and moved.z > still.z:
            if moved is b:
                return GravityGain(w, b, b.change, b.std, single_channel=True)
            ratio = 1.0 / (1.0 + w.change)
            return GravityGain(w, b, ratio - 1.0, ratio * ratio * w.std, single_channel=True)
    ratio = (1.0 + b.change) / (1.0 + w.change)
    std = abs(ratio) * math.hypot(b.std / (1.0 + b.change), w.std / (1.0 + w.change))
    return GravityGain(w, b, ratio - 1.0, std)
