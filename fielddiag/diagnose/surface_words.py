"""The shape of a fitted force surface in words a technician understands.

:class:`fielddiag.effects.force_surface.ForceSurface` is a sum of monomials in the scaled
travel ``q = r / 20 mm`` and speed ``w = rdot / 0.2 m/s``. Each monomial is a shape with a
plain meaning (``q^2 w``: damping that changes with travel; ``w^3``: damping that rises
with speed). The terms that carry most of the surface's force over the recorded travel
and speeds are told, strongest first, each with a figure at 20 mm or 0.2 m/s.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from fielddiag.effects.force_surface import SURFACE_SPEED_MPS, SURFACE_TRAVEL_M

__all__ = ["describe_force_surface", "describe_memory_surface"]

#: A term is told where its rms force over the recording is at least this share of the
#: strongest term's.
TOLD_SHARE = 0.25

_MM = 1e3 * SURFACE_TRAVEL_M


def _words(term: str, a: float, unit: str) -> str:
    """One sentence for one term ``-a phi`` (a force on the body, ``a`` in ``unit``)."""
    k = abs(a) / SURFACE_TRAVEL_M  # [unit/m] at q = 1
    c = abs(a) / SURFACE_SPEED_MPS  # [unit s/m] at w = 1
    up = a > 0
    if term == "travel2":
        side = "rebound (extension)" if up else "compression"
        return (f"the spring is stiffer toward {side} than toward the other side of the "
                f"ride height (by {2 * k:.3g} {unit}/m at {_MM:.0f} mm of travel)")
    if term == "travel3":
        how = "stiffens" if up else "softens"
        return (f"the spring {how} away from the ride height at both ends (by {3 * k:.3g} "
                f"{unit}/m at {_MM:.0f} mm of travel)")
    if term == "speed2":
        side = "rebound" if up else "compression"
        return (f"the damping is stronger in {side} than in the other direction (by "
                f"{2 * c:.3g} {unit} s/m at {SURFACE_SPEED_MPS:g} m/s)")
    if term == "speed3":
        how = "rises" if up else "falls"
        return (f"the damping {how} with speed in both directions (by {3 * c:.3g} "
                f"{unit} s/m at {SURFACE_SPEED_MPS:g} m/s)")
    if term == "travel_speed":
        side = "rebound" if up else "compression"
        return (f"the damping changes across the travel: stronger on the {side} side of the "
                f"ride height (by {c:.3g} {unit} s/m at {_MM:.0f} mm of travel)")
    if term == "travel2_speed":
        how = "grows" if up else "drops"
        return (f"the damping {how} with travel away from the ride height, in both "
                f"directions (by {c:.3g} {unit} s/m at {_MM:.0f} mm of travel): a "
                "position-sensitive damper")
    if term == "travel_speed2":
        return (f"the spring force depends on speed: at {SURFACE_SPEED_MPS:g} m/s it "
                f"{'rises' if up else 'falls'} by {k:.3g} {unit}/m of travel")
    raise ValueError(f"unknown surface term {term!r}")


def describe_force_surface(coefficients: Mapping[str, float], r_m: np.ndarray,
                           rdot_mps: np.ndarray, unit: str = "N") -> list[str]:
    """Sentences for the terms that carry the surface's force over the recorded states.

    Parameters
    ----------
    coefficients : mapping
        ``surface_<term>_n`` (or without the prefix and suffix) to the coefficient, in
        ``unit``.
    r_m, rdot_mps : ndarray
        The recorded suspension travel [m] from the unloaded ride height and its rate
        [m/s] (where the surface is told).
    unit : str
        The force unit of the coefficients (``N``, or ``N/kg`` per unit mass).

    Returns
    -------
    list of str
        Strongest first; empty where the surface is flat.

    Examples
    --------
    >>> describe_force_surface({"travel2_speed": 120.0}, np.array([0.02, -0.02]),
    ...                        np.array([0.2, -0.2]))  # doctest: +ELLIPSIS
    ['the damping grows with travel away from the ride height, ... at 20 mm of travel)...']
    """
    q = np.asarray(r_m, float) / SURFACE_TRAVEL_M
    w = np.asarray(rdot_mps, float) / SURFACE_SPEED_MPS
    basis = {"travel2": q * q, "travel_speed": q * w, "speed2": w * w, "travel3": q**3,
             "travel2_speed": q * q * w, "travel_speed2": q * w * w, "speed3": w**3}
    terms = {key.removeprefix("surface_").removesuffix("_n"): a
             for key, a in coefficients.items()}
    return [_words(t, a, unit) for t, a in _strongest(terms, basis)]


def _strongest(coefficients: Mapping[str, float], basis: Mapping[str, np.ndarray]
               ) -> list[tuple[str, float]]:
    """``(term, coefficient)`` of the terms of ``basis`` whose rms force over the recorded
    states is at least :data:`TOLD_SHARE` of the strongest's, strongest first."""
    rms = {}
    for term, phi in basis.items():
        a = float(coefficients.get(term, 0.0))
        if np.isfinite(a) and a != 0.0 and np.size(phi):
            rms[term] = (a, float(np.sqrt(np.mean((a * phi) ** 2))))
    if not rms:
        return []
    top = max(v for _, v in rms.values())
    return [(t, rms[t][0]) for t in sorted((t for t in rms if rms[t][1] >= TOLD_SHARE * top),
                                           key=lambda t: -rms[t][1])]


def describe_memory_surface(coefficients: Mapping[str, float], r_m: np.ndarray,
                            rdot_mps: np.ndarray, unit: str = "N",
                            damping: float | None = None) -> list[str]:
    """Sentences for the terms of a force with memory of each reversal
    (:class:`fielddiag.effects.memory_surface.MemorySurface`) that carry its force over
    the recorded states, strongest first.

    Parameters
    ----------
    coefficients : mapping
        ``memory_<term>_n`` (``loop``, ``loop_speed``, ``loop_travel``) in ``unit``, and
        ``memory_travel_m`` [m] (the prefix may be left off).
    r_m, rdot_mps : ndarray
        The recorded suspension travel [m] from the unloaded ride height and its rate [m/s].
    unit : str
        The force unit of the coefficients (``N``, or ``N/kg`` per unit mass).
    damping : float or None
        The linear damping fitted beside the surface [``unit`` s/m]: the damping's change
        after a reversal is then told as a share of it.

    Returns
    -------
    list of str
        Empty where the surface carries no force.

    Examples
    --------
    >>> describe_memory_surface({"loop_speed": 300.0, "memory_travel_m": 0.002},
    ...                         np.array([0.02, -0.02]), np.array([0.2, -0.2]),
    ...                         damping=2000.0)  # doctest: +ELLIPSIS
    ["the damping is 86 % weaker for about the first 2 mm after each reversal of the motion..."]
    """
    vals = {k.removeprefix("memory_").removesuffix("_n").removesuffix("_m"): v
            for k, v in coefficients.items()}
    z_m = float(vals.get("travel", np.nan))
    q = np.asarray(r_m, float) / SURFACE_TRAVEL_M
    w = np.asarray(rdot_mps, float) / SURFACE_SPEED_MPS
    basis = {"loop": np.ones_like(q), "loop_speed": np.abs(w), "loop_travel": q}
    told = _strongest(vals, basis) if np.isfinite(z_m) else []
    # after a reversal the memory's share left of the old side decays as exp(-travel / z_m):
    # summed over the travel, a force lost (or added) in full over the first z_m
    reach_mm = 1e3 * z_m
    amplitude_m = float(np.sqrt(2.0) * np.std(r_m)) if np.size(r_m) else 0.0
    out = []
    for t, a in told:
        if t == "loop_speed":
            dc = abs(a) / SURFACE_SPEED_MPS  # each way from the mean damping
            share = (min(2 * dc / (damping + dc), 1.0)
                     if damping is not None and damping + dc > 0 and a > 0 else None)
            if a > 0:
                first = f"for about the first {reach_mm:.2g} mm after each reversal of the motion"
                if share is None:
                    how = (f"the damping is {2 * dc:.3g} {unit} s/m weaker {first} than later "
                           "in the stroke")
                elif share >= 0.9:
                    how = (f"the damping all but vanishes {first} ({damping + dc:.3g} {unit} "
                           "s/m later in the stroke)")
                else:
                    how = (f"the damping is {100 * share:.0f} % weaker {first} "
                           f"({damping - dc:.3g} against {damping + dc:.3g} {unit} s/m later "
                           "in the stroke)")
                out.append(f"{how}: as free play in the damper's mounting, or a damper slow "
                           "to build pressure, would make it")
            else:
                out.append(
                    f"the damping is {2 * dc:.3g} {unit} s/m stronger for about the first "
                    f"{reach_mm:.2g} mm after each reversal of the motion than later in the "
                    "stroke")
        elif t == "loop":
            energy = 4.0 * abs(a) * amplitude_m
            what = ("a hysteresis loop" if a > 0 else
                    "a loop that gives energy back (the force leads the motion)")
            out.append(
                f"{what} {2 * abs(a):.3g} {unit} high that closes over about "
                f"{reach_mm:.2g} mm after each reversal ({energy:.3g} "
                f"{'J' if unit == 'N' else 'J/kg'} per cycle of +-{1e3 * amplitude_m:.2g} mm)")
        else:
            side = "rebound (extension)" if a > 0 else "compression"
            out.append(
                f"a hysteresis loop whose height changes along the travel: "
                f"{2 * abs(a):.3g} {unit} higher per {_MM:.0f} mm toward {side}")
    return out
