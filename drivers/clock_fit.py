"""Device clock to host time: a straight line fitted under the arrivals, applied smoothly.

A DAQ stamps its samples with its own clock; the host sees each frame arrive a little
after its last sample was acquired (transmission, USB polling, a busy scheduler). The
arrival delay is never negative and its least value is small and nearly constant, so the
host time of a device instant lies on the *lower envelope* of the points
(device time, arrival time - device time). :class:`DeviceClockFit` fits that envelope
with the linear program of Moon, Skelly and Towsley (1999, "Estimation and removal of
clock skew from network delay measurements"): the line below every point that is
closest to them on average. Its slope is the device clock's rate error (drift), its
value the offset. Points are the least-delayed arrival of every ``window_s`` of device
time over the last ``history_s``, so the fit never integrates host jitter: each refit
starts from the points themselves, not from the previous estimate. A window whose frames
all came in one burst (a backlog after a stall or a reconnect: far less host time than
device time between its first and last arrival) holds no timely arrival and is left out.

The mapping actually applied (:meth:`DeviceClockFit.map`) is continuous and monotonic:
at every :meth:`DeviceClockFit.steer` it is re-anchored where the last emitted sample
ended and its slope is set to the fitted rate plus a bounded correction (at most
``max_slew``) that closes the gap to the fitted line in about ``slew_time_s``.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np


def lower_envelope_line(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """The line ``y = a + b x`` below every point with the least summed distance to them.

    The optimum of this linear program lies on an edge of the points' lower convex hull:
    the edge above the mean of ``x`` (Moon et al. 1999). ``x`` must be increasing.

    Returns
    -------
    a, b : float
        Intercept (at x = 0) and slope.
    """
    hull: list[tuple[float, float]] = []
    for p in zip(x.tolist(), y.tolist(), strict=True):
        while len(hull) >= 2:
            (x0, y0), (x1, y1) = hull[-2], hull[-1]
            if (x1 - x0) * (p[1] - y0) - (y1 - y0) * (p[0] - x0) > 0:
                break
            hull.pop()
        hull.append(p)
    if len(hull) < 2:
        return float(np.min(y)), 0.0
    xm = float(np.mean(x))
    for (x0, y0), (x1, y1) in zip(hull, hull[1:], strict=False):
        if x1 >= xm:
            b = (y1 - y0) / (x1 - x0)
            return y0 - b * x0, b
    (x0, y0), (x1, y1) = hull[-2], hull[-1]
    b = (y1 - y0) / (x1 - x0)
    return y0 - b * x0, b


class DeviceClockFit:
    """Map device time to host (session) time from (device time, arrival time) pairs.

    Parameters
    ----------
    window_s : float
        Device time per point of the fit (the least-delayed arrival in it is kept).
    history_s : float
        Device time of points kept for the fit.
    settle_s : float
        Host time of arrivals to observe before :attr:`settled` (before that the offset
        rests on a few arrivals; a source holds its first samples back until then).
    slew_time_s : float
        Time in which a difference between the applied mapping and the fit is closed.
    max_slew : float
        Largest rate correction of the applied mapping (1.5e-3: 1.5 ms per second). With
        ``max_drift_ppm`` it bounds how far the sample spacing strays from the device's:
        2e-3 at most.
    step_threshold_s : float
        A difference larger than this is stepped, not slewed.
    max_drift_ppm : float
        Drifts beyond this are not believed (quartz clocks are within +-100 ppm, ceramic
        resonators a few hundred).
    min_drift_span_s : float
        Device time the points must span before the drift is reported (:attr:`drift_known`).

    Notes
    -----
    While the points span less than ``young_span_s`` (30 s) the slope is still uncertain,
    so the line is put under the points of the last ``recent_s`` (2 s) instead of under
    the whole history: a slope error then costs its product with 2 s, not with half the
    history (and the line rises above the one under all points by no more than
    ``max_drift_ppm`` over the span: a host busy for the last 2 s does not lift it). A
    fitted slope beyond ``max_drift_ppm`` with arrivals ever later is a backlog growing on
    a busy host: the last slope is kept and the line stays under the timely arrivals. With
    arrivals ever earlier (they cannot precede the acquisition) the offset stepped; only
    the points of the last ``step_memory_s`` (2 s) are kept.
    """

    def __init__(
        self,
        *,
        window_s: float = 0.5,
        history_s: float = 300.0,
        settle_s: float = 0.25,
        slew_time_s: float = 1.0,
        max_slew: float = 1.5e-3,
        step_threshold_s: float = 0.05,
        max_drift_ppm: float = 500.0,
        min_drift_span_s: float = 10.0,
    ) -> None:
        self.window_s = float(window_s)
        self.history_s = float(history_s)
        self.settle_s = float(settle_s)
        self.slew_time_s = float(slew_time_s)
        self.max_slew = float(max_slew)
        self.step_threshold_s = float(step_threshold_s)
        self.max_drift = float(max_drift_ppm) * 1e-6
        self.min_drift_span_s = float(min_drift_span_s)
        self.step_memory_s = 4.0 * self.window_s
        self.young_span_s = 30.0
        self.recent_s = 2.0
        self.reset()

    def reset(self) -> None:
        """Forget everything (the device restarted: a new clock epoch)."""
        self._anchor: tuple[float, float] | None = None
        self._rate = 1.0
        n = max(2, int(math.ceil(self.history_s / self.window_s)))
        self._points: deque[tuple[float, float]] = deque(maxlen=n)
        self._cur_key: int | None = None
        # current window: device time and offset of its least-delayed arrival, host and
        # device time of its first and last arrival
        self._cur = [0.0, math.inf, 0.0, 0.0, 0.0, 0.0]
        self._first_host: float | None = None
        self._last_host = -math.inf
        self._dirty = False
        self._a = 0.0  # fitted offset (host - device) at device time _ref
        self._b = 0.0  # fitted d(offset)/d(device time)
        self._ref = 0.0
        self.fit_offset_s: float | None = None

    # ---------------------------------------------------------------- state
    @property
    def locked(self) -> bool:
        """True once the mapping has been anchored (:meth:`map` may be called)."""
        return self._anchor is not None

    @property
    def settled(self) -> bool:
        """True once arrivals have been observed for ``settle_s`` of host time."""
        return self._first_host is not None and self._last_host - self._first_host >= (
            self.settle_s
        )

    @property
    def drift_ppm(self) -> float:
        """Device clock rate error: positive when the device clock runs fast [ppm]."""
        return -self._b / (1.0 + self._b) * 1e6

    @property
    def drift_known(self) -> bool:
        """True once the points span ``min_drift_span_s`` of device time."""
        return len(self._points) >= 3 and (
            self._points[-1][0] - self._points[0][0] >= self.min_drift_span_s
        )

    # ---------------------------------------------------------------- input
    def observe(self, t_dev_s: float, t_host_s: float) -> None:
        """A device time and the host time at which it was known to have passed."""
        if self._first_host is None:
            self._first_host = t_host_s
        self._last_host = max(self._last_host, t_host_s)
        off = t_host_s - t_dev_s
        key = math.floor(t_dev_s / self.window_s)
        if self._cur_key is not None and key < self._cur_key:
            return  # an older window (seen again, or a restart the caller resets for)
        if key != self._cur_key:
            if self._cur_key is not None and self._timely(self._cur):
                self._points.append((self._cur[0], self._cur[1]))
            self._cur_key = key
            self._cur = [t_dev_s, off, t_host_s, t_host_s, t_dev_s, t_dev_s]
            self._dirty = True
            return
        c = self._cur
        c[3], c[5] = t_host_s, t_dev_s
        if off < c[1]:
            c[0], c[1] = t_dev_s, off
            # early on every better arrival counts; later the closed windows suffice
            self._dirty = self._dirty or len(self._points) < 8

    @staticmethod
    def _timely(c: list[float]) -> bool:
        """False for a window whose arrivals came in a burst (a backlog)."""
        return c[3] - c[2] >= 0.5 * (c[5] - c[4])

    # ---------------------------------------------------------------- fit
    def _fit(self) -> None:
        pts = list(self._points)
        c = self._cur
        if math.isfinite(c[1]) and (self._timely(c) or not pts):
            pts.append((c[0], c[1]))
        if not pts:
            raise RuntimeError("no device time stamp has arrived yet")
        arr = np.array(pts)
        ref = float(arr[-1, 0])
        x, y = arr[:, 0] - ref, arr[:, 1]
        b, a = self._b, None
        if len(pts) >= 3 and x[-1] - x[0] >= 2.0 * self.window_s:
            a, b_fit = lower_envelope_line(x, y)
            if abs(b_fit) <= self.max_drift:
                b = b_fit
            elif b_fit > 0:
                # arrivals later and later, faster than any clock drifts: a backlog
                # growing on a busy host (a device clock set back is a restart the caller
                # resets for). The line stays under the timely arrivals, with the last slope
                a = None
            else:
                a = None
                # arrivals earlier than any drift explains (they cannot precede the
                # acquisition): the offset stepped (a device clock that was set forward,
                # a streamer that skipped). Keep only the points after the step.
                recent = x >= -self.step_memory_s
                x, y = x[recent], y[recent]
                self._points = deque(
                    (p for p in self._points if p[0] - ref >= -self.step_memory_s),
                    maxlen=self._points.maxlen,
                )
        span = float(x[-1] - x[0])
        if a is None:  # too short a span for a slope, or no slope believed: keep the last
            a = float(np.min(y - b * x))
        elif span < self.young_span_s:
            # a young fit's slope is uncertain: put the line under the recent points
            # rather than under the middle of the history, so a slope error is
            # extrapolated over seconds, not over half the history. But no higher than
            # a believable slope error allows: recent arrivals all late (a host busy for
            # seconds) must not lift the line by the backlog
            recent = x >= -self.recent_s
            a = min(float(np.min(y[recent] - b * x[recent])), a + self.max_drift * span)
        self._a, self._b, self._ref = float(a), float(b), ref
        self.fit_offset_s = self._a
        self._dirty = False

    def fitted(self, t_dev_s: float) -> float:
        """Host time of ``t_dev_s`` on the fitted line (not slewed)."""
        if self._dirty or self._first_host is None:
            self._fit()
        return t_dev_s + self._a + self._b * (t_dev_s - self._ref)

    # ---------------------------------------------------------------- output
    def steer(self, t_dev_s: float) -> None:
        """Re-anchor the applied mapping at ``t_dev_s`` toward the newest fit.

        Call it with the device time where the samples mapped so far end: the mapping
        stays continuous there, and samples after it follow the new slope.
        """
        target = self.fitted(t_dev_s)
        if self._anchor is None:
            self._anchor, self._rate = (t_dev_s, target), 1.0 + self._b
            return
        cur = float(self.map(t_dev_s))
        err = target - cur
        if abs(err) > self.step_threshold_s:
            self._anchor, self._rate = (t_dev_s, target), 1.0 + self._b
            return
        corr = min(max(err / self.slew_time_s, -self.max_slew), self.max_slew)
        self._anchor, self._rate = (t_dev_s, cur), 1.0 + self._b + corr

    def map(self, t_dev_s: np.ndarray | float) -> np.ndarray:
        """Host/session time of device times (the applied, continuous mapping)."""
        if self._anchor is None:
            raise RuntimeError("DeviceClockFit.map before the first steer()")
        d0, h0 = self._anchor
        return h0 + self._rate * (np.asarray(t_dev_s, dtype="f8") - d0)
