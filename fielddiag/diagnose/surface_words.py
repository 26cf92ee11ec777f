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

__all__ = ["describe_force_surface"]

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
    rms = {}
    for key, a in coefficients.items():
        term = key.removeprefix("surface_").removesuffix("_n")
        if term in basis and np.isfinite(a) and a != 0.0:
            rms[term] = (a, float(np.sqrt(np.mean((a * basis[term]) ** 2))))
    if not rms:
        return []
    top = max(v for _, v in rms.values())
    told = sorted((t for t in rms if rms[t][1] >= TOLD_SHARE * top), key=lambda t: -rms[t][1])
    return [_words(t, rms[t][0], unit) for t in told]
