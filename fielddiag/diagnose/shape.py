"""A model of the force no library effect names: a smooth surface in travel and speed plus
a hysteresis state, and its shape in words.

When the diagnosis is left with structure that no effect of the library explains, it does
not force a name on it. It fits the force the model leaves (the *departure*, in N) as

    departure(r, rdot) = S(r, rdot) + F_h w(t) + D rdot idle_g(t)

with ``S`` a tensor-product cubic B-spline (knots at quantiles of the measured travel and
speed, so each cell holds data), ``w`` a Dahl hysteresis state (``dw/dt = (rdot -
|rdot| w) / x_y``, its yield travel chosen on a grid) and ``D`` a damping that acts only
while the travel is inside a play of ``+-g`` (``rdot`` where a backlash of half-width
``g`` does not follow the travel, ``g`` chosen on a grid: what a free play or a slack
mounting does, the damper idle for the first ``2 g`` after each reversal), by
ridge-regularised linear least squares on the fit part of the drives; each state term is
kept only where it earns its column on the held-out part. The
fitted surface is then read back in words a technician understands: where the force
rises steeper (or softer) than the linear spring, where the damping grows or fades and in
which direction, and how much energy a hysteresis loop holds per cycle.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numba import njit
from scipy.interpolate import BSpline

from fielddiag.diagnose.selection import paired_block_t

__all__ = ["ShapeModel", "describe_shape", "fit_shape_model", "travel_since_reversal"]

#: Interior knots per axis of the spline surface (cubic: knots + 4 basis functions).
INTERIOR_KNOTS = 4
#: Ridge weight relative to the mean diagonal of the normal matrix.
RIDGE = 1e-6
#: Yield travels tried for the hysteresis state [m].
YIELD_GRID_M = (2e-4, 5e-4, 1e-3, 2e-3, 5e-3)
#: A local stiffness or damping counts as different from the linear one beyond this share.
SHAPE_CHANGE = 0.15


def _basis_1d(x: np.ndarray, knots: np.ndarray) -> np.ndarray:
    """Cubic B-spline design matrix on ``knots`` (boundary knots repeated); values outside
    the knot span are clamped to it (the surface continues flat)."""
    lo, hi = knots[0], knots[-1]
    t = np.concatenate([[lo] * 3, knots, [hi] * 3])
    xc = np.clip(x, lo, hi)
    return BSpline.design_matrix(xc, t, 3).toarray()


def _tensor(br: np.ndarray, bv: np.ndarray) -> np.ndarray:
    return (br[:, :, None] * bv[:, None, :]).reshape(br.shape[0], -1)


def travel_since_reversal(r_m: np.ndarray, rdot_mps: np.ndarray,
                          segments: np.ndarray | None = None) -> np.ndarray:
    """Travel since the motion last reversed (the last sign change of ``rdot``) [m].

    Signed like the motion since the reversal; 0 at the start of each segment.

    Parameters
    ----------
    r_m, rdot_mps : ndarray
        Travel [m] and its rate [m/s] along a path.
    segments : ndarray or None
        Segment label per sample (the count restarts in each).

    Returns
    -------
    numpy.ndarray

    Examples
    --------
    >>> r = np.array([0.0, 1.0, 2.0, 1.5, 0.5, 1.0])
    >>> travel_since_reversal(r, np.gradient(r)).tolist()
    [0.0, 1.0, 2.0, -0.5, -1.5, 0.5]
    """
    r = np.asarray(r_m, float)
    v = np.asarray(rdot_mps, float)
    seg = np.zeros(r.size, int) if segments is None else np.asarray(segments)
    out = np.zeros_like(r)
    for label in np.unique(seg):
        on = np.flatnonzero(seg == label)
        rs = r[on]
        start = np.zeros(rs.size, dtype=int)
        turns = np.flatnonzero(np.diff(np.signbit(v[on]))) + 1
        # the turning point is the sample before the rate changes sign
        start[turns] = turns - 1
        start = np.maximum.accumulate(start)
        out[on] = rs - rs[start]
    return out


def dahl_state(rdot_mps: np.ndarray, sample_rate_hz: float, yield_m: float,
               segments: np.ndarray | None = None) -> np.ndarray:
    """The Dahl state ``w`` in [-1, 1] along a path (exact for a rate held over each step).

    Parameters
    ----------
    rdot_mps : ndarray
        Suspension rate [m/s] at the samples.
    sample_rate_hz : float
        Sample rate [Hz].
    yield_m : float
        Yield travel ``x_y`` [m].
    segments : ndarray or None
        Segment label per sample: the state restarts at 0 where the label changes.

    Returns
    -------
    numpy.ndarray
        ``w`` at the samples.
    """
    v = np.ascontiguousarray(rdot_mps, dtype=float)
    seg = (np.zeros(v.size, np.int64) if segments is None
           else np.ascontiguousarray(segments, dtype=np.int64))
    return _dahl(v, 1.0 / sample_rate_hz, float(yield_m), seg)


@njit(cache=True, nogil=True)
def _dahl(v, h, yield_m, seg):  # pragma: no cover - compiled
    w = np.empty(v.size)
    cur = 0.0
    for i in range(v.size):
        if i > 0 and seg[i] != seg[i - 1]:
            cur = 0.0
        w[i] = cur
        target = 1.0 if v[i] > 0 else -1.0
        cur = target + (cur - target) * math.exp(-abs(v[i]) * h / yield_m)
    return w


@dataclass
class ShapeModel:
    """A fitted departure surface (and hysteresis) with its held-out score.

    Attributes
    ----------
    r_knots_m, rdot_knots_mps : ndarray
        Knots of the spline in travel [m] and speed [m/s].
    coefficients_n : ndarray
        ``(len(r basis), len(rdot basis))`` spline coefficients [N].
    hysteretic_force_n : float
        ``F_h`` of the hysteresis state [N] (0 when it did not help).
    yield_displacement_m : float
        Its yield travel [m].
    held_out_gain : float
        ``1 - mse(held-out departure - model) / mse(held-out departure)``.
    held_out_t : float
        Paired-block t of that gain (:func:`~fielddiag.diagnose.selection.paired_block_t`:
        the model's held-out error against none).
    description : list of str
        The shape in words (:func:`describe_shape`).
    """

    r_knots_m: np.ndarray
    rdot_knots_mps: np.ndarray
    coefficients_n: np.ndarray
    hysteretic_force_n: float
    yield_displacement_m: float
    held_out_gain: float
    description: list[str] = field(default_factory=list)
    play_half_width_m: float = math.nan
    play_damping_ns_per_m: float = 0.0
    held_out_t: float = math.nan

    def surface(self, r_m: np.ndarray, rdot_mps: np.ndarray) -> np.ndarray:
        """The memoryless part ``S(r, rdot)`` [N] at the given points.

        Parameters
        ----------
        r_m, rdot_mps : ndarray
            Travel [m] and speed [m/s] (same shape).

        Returns
        -------
        numpy.ndarray
        """
        r = np.asarray(r_m, float).ravel()
        v = np.asarray(rdot_mps, float).ravel()
        b = _tensor(_basis_1d(r, self.r_knots_m), _basis_1d(v, self.rdot_knots_mps))
        return (b @ self.coefficients_n.ravel()).reshape(np.shape(r_m))

    def to_dict(self) -> dict:
        """JSON-ready model: knots, coefficients, hysteresis, gain and the words.

        Returns
        -------
        dict
        """
        return {
            "kind": ("cubic B-spline surface in travel and speed + Dahl hysteresis state"
                     " + damping idle inside a play"),
            "r_knots_m": self.r_knots_m.tolist(),
            "rdot_knots_mps": self.rdot_knots_mps.tolist(),
            "coefficients_n": self.coefficients_n.tolist(),
            "hysteretic_force_n": self.hysteretic_force_n,
            "yield_displacement_m": self.yield_displacement_m,
            "held_out_gain": self.held_out_gain,
            "held_out_t": self.held_out_t,
            "play_half_width_m": self.play_half_width_m,
            "play_damping_ns_per_m": self.play_damping_ns_per_m,
            "description": list(self.description),
        }


#: Half-widths of the play tried for the damping idle inside a play [m].
PLAY_GRID_M = (2.5e-4, 5e-4, 1e-3, 2e-3, 4e-3, 8e-3)


def play_idle(r_m: np.ndarray, half_width_m: float,
              segments: np.ndarray | None = None) -> np.ndarray:
    """Where a backlash of half-width ``g`` on the travel stands still (1.0) or follows
    it (0.0): the play operator ``q = clip(q, r - g, r + g)``, started centred in each
    segment.

    Parameters
    ----------
    r_m : ndarray
        Travel [m] along a path.
    half_width_m : float
        Half-width ``g`` of the play [m].
    segments : ndarray or None
        Segment label per sample (the operator restarts in each).

    Returns
    -------
    numpy.ndarray

    Examples
    --------
    >>> play_idle(np.array([0.0, 1.0, 2.0, 3.0, 2.5, 1.5, 0.5]), 1.0).tolist()
    [1.0, 1.0, 0.0, 0.0, 1.0, 1.0, 0.0]
    """
    r = np.asarray(r_m, float)
    seg = np.zeros(r.size, np.int64) if segments is None else np.asarray(segments, np.int64)
    return _play_idle(r, float(half_width_m), seg)


@njit(cache=True)
def _play_idle(r, g, seg):  # pragma: no cover - compiled
    out = np.ones(r.size)
    q = r[0] if r.size else 0.0
    for i in range(r.size):
        if i == 0 or seg[i] != seg[i - 1]:
            q = r[i]
            continue
        lo, hi = r[i] - g, r[i] + g
        if q < lo:
            q = lo
            out[i] = 0.0
        elif q > hi:
            q = hi
            out[i] = 0.0
    return out


def _knots(x: np.ndarray) -> np.ndarray:
    q = np.quantile(x, np.linspace(0.01, 0.99, INTERIOR_KNOTS + 2))
    q = np.unique(q)
    if q.size < 3:  # a degenerate axis: a span around its value
        c, s = float(np.median(x)), float(np.std(x)) or 1e-6
        q = np.array([c - s, c, c + s])
    return q


def _solve(a: np.ndarray, y: np.ndarray) -> np.ndarray:
    ata = a.T @ a
    lam = RIDGE * float(np.mean(np.diag(ata))) or RIDGE
    return np.linalg.solve(ata + lam * np.eye(ata.shape[0]), a.T @ y)


def fit_shape_model(
    r_m: np.ndarray,
    rdot_mps: np.ndarray,
    departure_n: np.ndarray,
    is_held_out: np.ndarray,
    sample_rate_hz: float,
    segments: np.ndarray | None = None,
    *,
    stiffness_n_per_m: float | None = None,
    damping_ns_per_m: float | None = None,
) -> ShapeModel:
    """Fit the departure on the fit samples; score it on the held-out ones.

    Parameters
    ----------
    r_m, rdot_mps : ndarray
        Measured suspension travel [m] (from the loaded rest position) and speed [m/s].
    departure_n : ndarray
        Force the model leaves [N] at the samples.
    is_held_out : ndarray of bool
        Samples kept out of the fit and used to score it.
    sample_rate_hz : float
        Sample rate [Hz] (for the hysteresis state).
    segments : ndarray or None
        Segment label per sample (drives and parts are not contiguous in time).
    stiffness_n_per_m, damping_ns_per_m : float or None
        The linear model's spring and damper, to word the shape relative to them.

    Returns
    -------
    ShapeModel
    """
    r = np.asarray(r_m, float)
    v = np.asarray(rdot_mps, float)
    y = np.asarray(departure_n, float)
    held = np.asarray(is_held_out, bool)
    fit = ~held
    kr, kv = _knots(r[fit]), _knots(v[fit])
    base = _tensor(_basis_1d(r, kr), _basis_1d(v, kv))
    y0 = y - np.mean(y[fit])

    def score(a: np.ndarray) -> tuple[float, np.ndarray]:
        coef = _solve(a[fit], y0[fit])
        e = y0[held] - a[held] @ coef
        ref = y0[held] - np.mean(y0[held])
        return 1.0 - float(np.mean(e**2) / max(np.mean(ref**2), 1e-300)), coef

    # the best design (its columns: the surface, then the states kept) and its fit
    best_gain, best_coef = score(base)
    best_a = base
    best_yield = math.nan
    best_w = np.zeros((r.size, 0))
    for xy in YIELD_GRID_M:
        w = dahl_state(v, sample_rate_hz, xy, segments)
        a = np.column_stack([base, w])
        gain, coef = score(a)
        if gain > best_gain + 0.01:  # the state must earn its column
            best_gain, best_coef, best_a, best_yield, best_w = gain, coef, a, xy, w[:, None]
    # damping idle inside a play: the speed where a backlash of half-width g stands still
    play_g = math.nan
    for g in PLAY_GRID_M:
        idle = v * play_idle(r, g, segments)
        a = np.column_stack([base, best_w, idle])
        gain, coef = score(a)
        if gain > best_gain + 0.01:  # the state must earn its column
            best_gain, best_coef, best_a, play_g = gain, coef, a, g
    # ... and how surely: the paired-block t of its held-out prediction against none (the
    # departure map's own test, here on the model that is the finding)
    t = paired_block_t(y0[held] - np.mean(y0[held]), y0[held] - best_a[held] @ best_coef)
    n_surface = base.shape[1]
    model = ShapeModel(
        kr, kv, best_coef[:n_surface].reshape(kr.size + 2, kv.size + 2),
        float(best_coef[n_surface]) if best_w.shape[1] else 0.0, best_yield, best_gain,
        play_half_width_m=play_g,
        play_damping_ns_per_m=float(best_coef[-1]) if np.isfinite(play_g) else 0.0,
        held_out_t=float(t))
    model.description = describe_shape(model, r[fit], v[fit], sample_rate_hz,
                                       stiffness_n_per_m, damping_ns_per_m)
    return model


def _amount(change: float) -> str:
    """A relative change of the damping in words: a percentage, or, where a decrease
    passes 100 % (the departure turns the linear term's sign: a departure from a named
    model may), a multiple of the linear damper's own value."""
    if change >= -1.0:
        return f"{100 * abs(change):.0f} %"
    return f"{-change:.1f} times the linear damper's"


def _changed(change: float, how: str) -> str:
    """``37 % lower``, or ``lower by 1.9 times the linear damper's`` (:func:`_amount`)."""
    return f"{_amount(change)} {how}" if change >= -1.0 else f"{how} by {_amount(change)}"


def _first_beyond(x: np.ndarray, change: np.ndarray) -> tuple[float, float] | None:
    """(where along x the relative change first exceeds SHAPE_CHANGE and stays, its mean
    change beyond), scanning outward from the centre."""
    idx = np.flatnonzero(np.abs(change) > SHAPE_CHANGE)
    if idx.size == 0:
        return None
    i0 = idx[0]
    tail = change[i0:]
    if np.mean(np.abs(tail) > SHAPE_CHANGE) < 0.6:
        return None
    return float(x[i0]), float(np.mean(tail))


def describe_shape(model: ShapeModel, r_m: np.ndarray, rdot_mps: np.ndarray,
                   sample_rate_hz: float, stiffness_n_per_m: float | None = None,
                   damping_ns_per_m: float | None = None) -> list[str]:
    """The fitted shape in plain words (sentences), relative to the linear model.

    Parameters
    ----------
    model : ShapeModel
        The fitted surface and hysteresis.
    r_m, rdot_mps : ndarray
        The travel [m] and speed [m/s] the model was fitted on (its range).
    sample_rate_hz : float
        Sample rate [Hz].
    stiffness_n_per_m, damping_ns_per_m : float or None
        The linear spring and damper; without them changes are given in N/m and N s/m.

    Returns
    -------
    list of str
    """
    out: list[str] = []
    k = abs(stiffness_n_per_m) if stiffness_n_per_m else None
    c = abs(damping_ns_per_m) if damping_ns_per_m else None
    # stiffness along the travel at rest speed: the surface's slope adds to the spring's
    # (force on the body is -K r: a departure slope -dS/dr stiffens)
    for word, q in (("compression", 0.005), ("rebound", 0.995)):
        x_end = float(np.quantile(r_m, q))
        if (x_end < 0) != (word == "compression") or abs(x_end) < 1e-6:
            continue
        x = np.linspace(0.0, x_end, 40)
        s = model.surface(x, np.zeros_like(x))
        slope = -np.gradient(s, x)
        rel = slope / k if k else slope / max(np.max(np.abs(slope)), 1e-9)
        hit = _first_beyond(np.abs(x), rel)
        if hit is not None:
            where, change = hit
            how = "steeper" if change > 0 else "softer"
            size = (f"{100 * abs(change):.0f} % {how} than the linear spring"
                    if change >= -1.0
                    else f"{how} than the linear spring, by {-change:.1f} times its stiffness"
                    ) if k else how
            span = (f"beyond {1e3 * where:.0f} mm of {word} (from the unloaded ride height)"
                    if where >= 1e-3 else f"throughout {word}")
            out.append(f"the force rises {size} {span}")
    for side, q in (("compression", 0.005), ("rebound", 0.995)):
        v_end = float(np.quantile(rdot_mps, q))
        if abs(v_end) < 1e-6:
            continue
        v = np.linspace(0.0, v_end, 40)
        s = model.surface(np.zeros_like(v), v)
        slope = -np.gradient(s, v)
        rel = slope / c if c else slope / max(np.max(np.abs(slope)), 1e-9)
        hit = _first_beyond(np.abs(v), rel)
        if hit is not None:
            where, change = hit
            how = "grows" if change > 0 else "fades"
            size = f" by {_amount(change)}" if c else ""
            span = f"above {where:.2g} m/s" if where >= 0.01 else "at every speed"
            out.append(f"in {side} the damping {how}{size} {span}")
    # damping that depends on where the suspension is (a position-sensitive damper)
    v_span = float(np.quantile(np.abs(rdot_mps), 0.9)) or 1e-3
    vv = np.linspace(-v_span, v_span, 21)

    def damping_at(r0: float) -> float:
        s = model.surface(np.full_like(vv, r0), vv)
        return float(-np.polyfit(vv, s, 1)[0])

    at_rest = damping_at(0.0)
    ref = c if c else max(abs(at_rest), 1e-9)
    for word, q in (("compression", 0.02), ("rebound", 0.98)):
        r0 = float(np.quantile(r_m, q))
        if (r0 < 0) != (word == "compression") or abs(r0) < 1e-4:
            continue
        change = (damping_at(r0) - at_rest) / ref
        if abs(change) > SHAPE_CHANGE:
            how = "higher" if change > 0 else "lower"
            out.append(f"the damping is {_changed(change, how)} at {1e3 * abs(r0):.0f} "
                       f"mm of {word} than at the unloaded ride height")
    if model.hysteretic_force_n and math.isfinite(model.yield_displacement_m):
        w = dahl_state(np.asarray(rdot_mps, float), sample_rate_hz, model.yield_displacement_m)
        power = abs(float(np.mean(model.hysteretic_force_n * w * rdot_mps)))
        # loops per second: reversals of the motion after more than twice the yield
        # travel (the loops that close), two a cycle. Not the travel's zero crossings: a
        # slow drift of the integrated travel left them at 0.006 Hz (seed 1795952984)
        freq = _closed_loops_per_s(np.asarray(r_m, float), np.asarray(rdot_mps, float),
                                   sample_rate_hz, 2.0 * model.yield_displacement_m)
        if freq > 0:
            out.append(f"a hysteresis loop of {power / freq:.3g} J per cycle at {freq:.2g} Hz "
                       f"(the force lags the travel by about {1e3 * model.yield_displacement_m:.2g}"
                       f" mm after each reversal, {abs(model.hysteretic_force_n):.3g} N high)")
    if model.play_damping_ns_per_m and math.isfinite(model.play_half_width_m):
        out.append(_play_words(model, c))
    if not out:
        out.append("the force departs from the linear spring and damper without a simple "
                   "trend in travel or speed; see the departure map")
    return out


def _closed_loops_per_s(r_m: np.ndarray, rdot_mps: np.ndarray, sample_rate_hz: float,
                        min_travel_m: float) -> float:
    """Cycles per second of the motion's reversals that follow more than
    ``min_travel_m`` of travel (two reversals a cycle)."""
    if r_m.size < 2:
        return math.nan
    turns = np.flatnonzero(np.diff(np.signbit(rdot_mps))) + 1
    travel = np.abs(travel_since_reversal(r_m, rdot_mps))
    closed = np.count_nonzero(travel[turns - 1] > min_travel_m)
    return closed / 2.0 / (r_m.size / sample_rate_hz)


def _play_words(model: ShapeModel, damping_ns_per_m: float | None) -> str:
    """The damping inside the play in words."""
    # the departure is D rdot idle; the damper's force on the body is -c rdot: damping -D
    change = -model.play_damping_ns_per_m
    g_mm = 1e3 * model.play_half_width_m
    how = "lower" if change < 0 else "higher"
    if damping_ns_per_m:
        size = _changed(change / abs(damping_ns_per_m), how)
    else:
        size = f"{abs(change):.3g} N s/m {how}"
    return (f"the damping is {size} for the first {2 * g_mm:.2g} mm of travel after each "
            f"reversal of the motion (inside a play of +-{g_mm:.2g} mm"
            + (": as a free play or a slack mounting of the damper would make it)"
               if change < 0 else ")"))
