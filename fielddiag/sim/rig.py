"""A one-degree-of-freedom test rig: a damper or spring driven by a prescribed motion.

On a damper dyno or a shaker the rod follows a commanded displacement ``x(t)`` and a load
cell reads the force that takes::

    force = m a + F0 - F_s(x, v)

where ``F_s`` is the suspension force of :mod:`fielddiag.sim` (linear spring and damper
plus effects, with ``r = x``), ``m`` the moving mass and ``F0`` a static preload / load-cell
offset. Positions up positive; ``x`` is the extension from the rig's zero.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from fielddiag.sim.dynamics import suspension_force_n, suspension_model
from fielddiag.sim.effects import Effect
from fielddiag.sim.vehicle import QuarterCarParams


@dataclass(frozen=True)
class RigRecording:
    """Samples of a simulated rig test (readings include noise; ``true_force_n`` does not)."""

    sample_rate_hz: float
    time_s: np.ndarray
    displacement_m: np.ndarray
    acceleration_mps2: np.ndarray
    force_n: np.ndarray
    true_force_n: np.ndarray
    recipe: dict[str, Any]


def rig_motion(
    duration_s: float,
    sample_rate_hz: float,
    *,
    amplitude_m: float = 0.03,
    band_hz: tuple[float, float] = (0.3, 8.0),
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A smooth random rod motion (band-limited, Gaussian) and its exact derivatives.

    Returns displacement [m], velocity [m/s] and acceleration [m/s^2].
    """
    rng = np.random.default_rng(seed)
    n = int(round(duration_s * sample_rate_hz))
    f = np.fft.rfftfreq(n, 1.0 / sample_rate_hz)
    spec = np.zeros(f.size, complex)
    inband = (f >= band_hz[0]) & (f <= band_hz[1])
    spec[inband] = np.exp(2j * np.pi * rng.uniform(size=inband.sum())) / np.maximum(f[inband], 0.5)
    w = 2j * np.pi * f
    x = np.fft.irfft(spec, n)
    scale = amplitude_m / x.std()
    v = np.fft.irfft(spec * w, n) * scale
    a = np.fft.irfft(spec * w * w, n) * scale
    return x * scale, v, a


def simulate_rig(
    *,
    stiffness_n_per_m: float = 20e3,
    damping_ns_per_m: float = 1500.0,
    moving_mass_kg: float = 2.0,
    preload_n: float = 150.0,
    effects: tuple[Effect, ...] = (),
    duration_s: float = 60.0,
    sample_rate_hz: float = 500.0,
    amplitude_m: float = 0.03,
    band_hz: tuple[float, float] = (0.3, 8.0),
    force_noise_n: float = 5.0,
    displacement_noise_m: float = 2e-5,
    seed: int = 0,
) -> RigRecording:
    """Simulate a rig test with load-cell and displacement-sensor noise."""
    x, v, a = rig_motion(
        duration_s, sample_rate_hz, amplitude_m=amplitude_m, band_hz=band_hz, seed=seed
    )
    params = QuarterCarParams(
        suspension_stiffness_n_per_m=stiffness_n_per_m, suspension_damping_ns_per_m=damping_ns_per_m
    )
    model, theta = suspension_model(params, effects)
    if model.n_states:
        # hysteresis: its states integrated along the rod's motion, from rest at the start
        f_s = model.force_along_path(x, v, 0.0, theta, sample_rate_hz, state_jacobian=False)[0]
    else:
        f_s = suspension_force_n(x, v, params, effects)
    true_force = moving_mass_kg * a + preload_n - f_s
    rng = np.random.default_rng(seed + 1)
    n = x.size
    recipe = {
        "generator": "fielddiag.sim.rig.simulate_rig",
        "stiffness_n_per_m": stiffness_n_per_m,
        "damping_ns_per_m": damping_ns_per_m,
        "moving_mass_kg": moving_mass_kg,
        "preload_n": preload_n,
        "effects": [e.to_dict() for e in effects],
        "duration_s": duration_s,
        "sample_rate_hz": sample_rate_hz,
        "amplitude_m": amplitude_m,
        "force_noise_n": force_noise_n,
        "displacement_noise_m": displacement_noise_m,
        "seed": seed,
    }
    return RigRecording(
        sample_rate_hz=float(sample_rate_hz),
        time_s=np.arange(n) / sample_rate_hz,
        displacement_m=x + rng.normal(0, displacement_noise_m, n),
        acceleration_mps2=a + rng.normal(0, 0.02, n),
        force_n=true_force + rng.normal(0, force_noise_n, n),
        true_force_n=true_force,
        recipe=recipe,
    )
