"""What a clipped accelerometer lost, and how far that reaches into the model's input.

A saturated accelerometer holds its full scale while the true acceleration goes beyond
it: the area above the rail is lost. The wheel's motion is integrated from its
acceleration, so a lost peak is a step in the wheel's velocity and a ramp in its
displacement, which the band filter turns into tails that last seconds, not the clipped
samples alone (a wheel channel clipped on 1 % of its samples, its true peaks up to 13
times the rail, left an error of half the wheel's displacement four seconds away, seed
1795886491). A reconstruction of the peaks from the readings beside them does not help:
a cubic spline through them found a third of the lost speed on road bumps.

So the clipping is modelled by what it leaves unknown: each clipped peak took an unknown
wheel speed, whose effect on the predicted body acceleration has a known shape (the
peak's impulse integrated as the drive is and passed through the linear body:
:func:`lost_peak_response`, :func:`lost_peak_basis`). Their sizes are fitted with every
model compared (``GreyBoxData.disturbance_basis``, by variable projection): what is left
is what the peaks cannot explain whatever their true height.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import signal

from .. import dsp
from .data_checks import clipped_mask


def at_rails(values: np.ndarray) -> np.ndarray:
    """Every sample at a clipped channel's rails (True where it sits at full scale).

    A channel counts as clipped where :func:`~fielddiag.diagnose.data_checks.clipped_mask`
    finds runs at its extreme; then every sample at that extreme is clipped, single
    ones included (a peak that crossed the rail for one sample lost its top too).
    """
    x = np.asarray(values, float)
    out = np.zeros(x.size, bool)
    mask = clipped_mask(x)
    if not mask.any() or mask.all():
        return out
    tol = 1e-9 * float(x.max() - x.min())
    for level in np.unique(x[mask]):
        out |= np.abs(x - level) <= tol
    return out


def _body_response(disp_m: np.ndarray, vel_mps: np.ndarray, sample_rate_hz: float,
                   stiffness_per_kg: float, damping_per_kg: float) -> np.ndarray:
    """The acceleration of a linear body per unit mass driven through its spring and
    damper by a wheel motion, from rest."""
    k, c = float(stiffness_per_kg), float(damping_per_kg)
    n = np.size(disp_m)
    if n < 2 or not (np.isfinite(k) and np.isfinite(c)) or k <= 0:
        return np.zeros(n)
    # states: body displacement and velocity; inputs: wheel displacement and velocity
    sys = signal.StateSpace([[0.0, 1.0], [-k, -c]], [[0.0, 0.0], [k, c]],
                            [[-k, -c]], [[k, c]])
    _, y, _ = signal.lsim(sys, np.column_stack([disp_m, vel_mps]),
                          np.arange(n) / sample_rate_hz)
    return np.asarray(y, float).reshape(-1)


def clipped_runs_s(values: np.ndarray, sample_rate_hz: float, start_s: float = 0.0
                   ) -> np.ndarray:
    """The first and last reading of every run of clipped readings [s], one row a run
    (none where nothing is clipped)."""
    at = np.concatenate(([0], at_rails(values).astype(np.int8), [0]))
    edges = np.flatnonzero(np.diff(at))
    return start_s + np.column_stack([edges[::2], edges[1::2] - 1]) / sample_rate_hz


def lost_peak_response(sample_rate_hz: float, n_samples: int, band_hz: tuple[float, float],
                       output_rate_hz: float, stiffness_per_kg: float,
                       damping_per_kg: float, channel: str = "wheel"
                       ) -> tuple[np.ndarray, np.ndarray]:
    """What one lost unit of area above the rail does to the residual of a linear body's
    predicted acceleration: the reading's impulse integrated as the drive is (same band,
    rate and length); on the wheel channel (1 m/s of lost speed) passed through the body
    (the prediction's input), on the body channel (1 m/s of lost area in what the
    prediction is compared with) as the band leaves it.

    Returns
    -------
    lag_s, response : ndarray
        Time from the peak [s] and the change of the residual [m/s^2 per m/s] (the band
        filter is zero-phase: it starts before the peak).
    """
    lag, w, b = _integrated_impulse(sample_rate_hz, n_samples, band_hz, output_rate_hz,
                                    channel)
    y = (_body_response(w.displacement_m, w.velocity_mps, w.sample_rate_hz,
                        stiffness_per_kg, damping_per_kg) if channel == "wheel"
         else b.acceleration_mps2)
    return lag, y


def _integrated_impulse(sample_rate_hz: float, n_samples: int, band_hz: tuple[float, float],
                        output_rate_hz: float, channel: str):
    """1 m/s of area lost at mid-record on ``channel``, integrated as the drive is: the
    time from the peak [s] and the wheel's and body's integrated motion."""
    impulse = np.zeros(int(n_samples))
    mid = impulse.size // 2
    impulse[mid] = sample_rate_hz  # 1 m/s of area
    on_wheel = channel == "wheel"
    w, b = dsp.integrate_pair(impulse if on_wheel else np.zeros_like(impulse),
                              np.zeros_like(impulse) if on_wheel else impulse,
                              sample_rate_hz, band_hz, output_rate_hz=output_rate_hz)
    return np.arange(w.displacement_m.size) / w.sample_rate_hz - mid / sample_rate_hz, w, b


def lost_peak_travel_force(sample_rate_hz: float, n_samples: int,
                           band_hz: tuple[float, float], output_rate_hz: float,
                           stiffness: float, damping: float, channel: str = "wheel"
                           ) -> tuple[np.ndarray, np.ndarray]:
    """What one lost unit of area above the rail does to the force a linear suspension
    (``stiffness``, ``damping``, in the departure's units) reads from the measured travel
    and speed: the impulse integrated as the drive is, through the spring and damper.

    The equation-error departure (force on the measured states) takes a lost wheel peak
    directly, not through the body: a speed step and a displacement ramp in the travel,
    which the band turns into tails seconds long (:func:`lost_peak_response` is the
    same loss seen in the simulated body's acceleration instead).

    Returns
    -------
    lag_s, response : ndarray
        Time from the peak [s] and the change of the force [departure units per m/s].
    """
    lag, w, b = _integrated_impulse(sample_rate_hz, n_samples, band_hz, output_rate_hz,
                                    channel)
    m = w if channel == "wheel" else b
    return lag, float(stiffness) * m.displacement_m + float(damping) * m.velocity_mps


def lost_peak_basis(time_s: np.ndarray, runs_s: np.ndarray, lag_s: np.ndarray,
                    response: np.ndarray, band_top_hz: float) -> np.ndarray:
    """The shapes of what the clipped peaks lost, at ``time_s``: one column per shape.

    What a run of clipped readings lost is unknown sample by sample; within the band
    (up to ``band_top_hz``) it is described by impulses every half period of the band's
    top across the run, each with its lost speed and its first moment: the response
    ``response`` at ``lag_s`` from the impulse, and its slope. Runs whose response does
    not reach ``time_s`` (beyond 0.1 % of its peak) give no column.

    Returns
    -------
    ndarray
        ``(time_s.size, p)``.
    """
    t = np.asarray(time_s, float)
    big = np.flatnonzero(np.abs(response) >= 1e-3 * np.max(np.abs(response)))
    if t.size == 0 or big.size == 0:
        return np.zeros((t.size, 0))
    reach = (lag_s[big[0]], lag_s[big[-1]])
    runs = runs_s[(runs_s[:, 1] >= t[0] - reach[1]) & (runs_s[:, 0] <= t[-1] - reach[0])]
    step = 0.5 / band_top_hz
    at = [np.linspace(a, b, max(1, int(np.ceil((b - a) / step)) + 1)) for a, b in runs]
    if not at:
        return np.zeros((t.size, 0))
    slope = np.gradient(response, lag_s)
    return np.column_stack([np.interp(t - tk, lag_s, shape, left=0.0, right=0.0)
                            for tk in np.concatenate(at) for shape in (response, slope)])


@dataclass(frozen=True)
class ClippedPeaks:
    """A drive's clipped peaks and how its readings are integrated.

    ``wheel_runs_s``, ``body_runs_s``: the first and last reading of every run of clipped
    readings of each channel [s] (``(0, 2)`` where it is not clipped); the rest as
    :func:`lost_peak_response` takes it."""

    wheel_runs_s: np.ndarray
    body_runs_s: np.ndarray
    sample_rate_hz: float
    n_samples: int
    band_hz: tuple[float, float]
    output_rate_hz: float

    @classmethod
    def of(cls, wheel_accel_mps2: np.ndarray, body_accel_mps2: np.ndarray,
           sample_rate_hz: float, band_hz: tuple[float, float], output_rate_hz: float,
           start_s: float = 0.0) -> ClippedPeaks | None:
        """The clipped peaks of a drive's channels (None where neither is clipped)."""
        wheel, body = (clipped_runs_s(x, sample_rate_hz, start_s)
                       for x in (wheel_accel_mps2, body_accel_mps2))
        if wheel.size == 0 and body.size == 0:
            return None
        return cls(wheel, body, float(sample_rate_hz), int(np.size(wheel_accel_mps2)),
                   (float(band_hz[0]), float(band_hz[1])), float(output_rate_hz))

    def basis(self, time_s: np.ndarray, stiffness_per_kg: float, damping_per_kg: float
              ) -> np.ndarray:
        """What the peaks lost, as shapes at ``time_s`` (:func:`lost_peak_basis`): the
        wheel's through one linear body (per unit mass: ``stiffness_per_kg`` [N/m/kg],
        ``damping_per_kg`` [N s/m/kg]; none where that body is unknown), the body's as
        the band leaves them."""
        return self._shapes(time_s, lambda channel: lost_peak_response(
            self.sample_rate_hz, self.n_samples, self.band_hz, self.output_rate_hz,
            stiffness_per_kg, damping_per_kg, channel))

    def travel_force_basis(self, time_s: np.ndarray, stiffness: float, damping: float
                           ) -> np.ndarray:
        """What the peaks of either channel lost, as shapes at ``time_s`` of the force a
        linear suspension reads from the measured travel and speed
        (:func:`lost_peak_travel_force`, :func:`lost_peak_basis`)."""
        if not (np.isfinite(stiffness) and np.isfinite(damping)):
            return np.zeros((np.size(time_s), 0))
        return self._shapes(time_s, lambda channel: lost_peak_travel_force(
            self.sample_rate_hz, self.n_samples, self.band_hz, self.output_rate_hz,
            stiffness, damping, channel))

    def _shapes(self, time_s: np.ndarray, response) -> np.ndarray:
        """The shapes at ``time_s`` of every clipped channel's runs, ``response(channel)``
        giving one lost unit's ``(lag_s, response)`` (:func:`lost_peak_basis`)."""
        cols = [np.zeros((np.size(time_s), 0))]
        for channel, runs in (("wheel", self.wheel_runs_s), ("body", self.body_runs_s)):
            if runs.size == 0:
                continue
            lag, resp = response(channel)
            if np.any(resp):
                cols.append(lost_peak_basis(time_s, runs, lag, resp,
                                            self.band_hz[1] * (1 + dsp.BAND_TAPER)))
        return np.hstack(cols)
