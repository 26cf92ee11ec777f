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
    """A problem of the data; ``kind`` is a stable identifier, ``message`` plain language."""

    kind: str
    message: str
    session: str = ""  # "before", "after" or "" for both
    channel: str = ""
    value: float | None = None

    def to_dict(self) -> dict:
        return {"kind": self.kind, "message": self.message}


def check_clipping(
    values: np.ndarray, *, channel: str, session: str = "", min_run: int = 3
) -> DataWarning | None:
    """Saturation: the signal sits exactly at its extreme value in runs of samples.

    A continuous signal with noise reaches its maximum once; an accelerometer at full
    scale holds it for consecutive samples. Flags a channel when at least 0.02 % of its
    samples (and at least 5) sit at the max or min, in runs of at least ``min_run``.
    """
    x = np.asarray(values, float)
    if x.size < 100:
        return None
    span = float(x.max() - x.min())
    if span <= 0:
        return DataWarning(
            "clipping", f"{channel} is constant: sensor dead or saturated", session, channel, 1.0
        )
    tol = 1e-9 * span
    worst = 0.0
    for level in (x.max(), x.min()):
        at = np.abs(x - level) <= tol
        n_at = int(at.sum())
        if n_at < max(5, int(2e-4 * x.size)):
            continue
        runs = np.diff(np.flatnonzero(np.diff(np.concatenate(([0], at.astype(np.int8), [0])))))
        longest = int(runs[::2].max()) if runs.size else 0
        if longest >= min_run:
            worst = max(worst, n_at / x.size)
    if worst == 0.0:
        return None
    where = f" in the {session} drive" if session else ""
    return DataWarning(
        "clipping",
        f"{channel}{where} is clipped: {100 * worst:.2g} % of samples sit at full scale "
        f"(+-{max(abs(x.max()), abs(x.min())):.3g}). Use a larger measuring range or a softer "
        "mount; peaks are lost and the fit will blame the suspension for it",
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
