"""A force-driven one-degree-of-freedom oscillator on a rig (a shaker, an electronic Duffing
oscillator): a moving mass on the library's spring, damper and effects.

A measured force ``f(t)`` drives the mass::

    m a = f + F_s(x, v)          F_s = -k x - c v + effects (fielddiag.effects)

so with a cubic spring this is the Duffing oscillator ``m x'' + c x' + k x + k3 x^3 = f``.
Unlike :mod:`fielddiag.sim.rig` (the rod follows a commanded motion, no resonance), the
motion here is the response: it has a resonance near ``sqrt(k/m)/2pi``, and the force and
displacement are related through it. The equation is integrated by fixed-step RK4 at an
oversampled internal rate (numba, the effect kernels of the library); both channels then
pass the same zero-phase anti-aliasing filter down to ``sample_rate_hz`` (a DAQ's
anti-aliasing filter acts on every channel alike), and sensor noise is added.

Excitations: ``"noise"`` (Gaussian noise with a flat spectrum in ``band_hz``) or
``"multisine"`` (a random-phase multisine, equal amplitudes on a grid of lines in
``band_hz``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import signal

from fielddiag.effects import Effect, ForceModel, LinearDamper, LinearSpring
from fielddiag.effects.compose import model_force_z
from fielddiag.errors import FieldDiagError
from fielddiag.sim.effects import check_effects

__all__ = ["OscillatorRecording", "oscillator_force", "simulate_oscillator"]

#: Internal integration rate as a multiple of the output rate.
OVERSAMPLE = 8


@dataclass(frozen=True)
class OscillatorRecording:
    """Samples of a simulated force-driven oscillator (readings with sensor noise; the
    ``true_*`` arrays without)."""

    sample_rate_hz: float
    time_s: np.ndarray
    force_n: np.ndarray
    displacement_m: np.ndarray
    true_force_n: np.ndarray
    true_displacement_m: np.ndarray
    recipe: dict[str, Any]

    @property
    def resonance_hz(self) -> float:
        """Linear resonance ``sqrt(k/m)/2pi`` of the simulated oscillator [Hz]."""
        r = self.recipe
        return float(np.sqrt(r["stiffness_n_per_m"] / r["moving_mass_kg"]) / (2 * np.pi))


def oscillator_force(
    n: int,
    sample_rate_hz: float,
    *,
    kind: str = "noise",
    band_hz: tuple[float, float],
    rms_n: float,
    seed: int = 0,
) -> np.ndarray:
    """A band-limited drive force of ``n`` samples at ``sample_rate_hz``.

    Parameters
    ----------
    n : int
        Number of samples.
    sample_rate_hz : float
        Sample rate [Hz].
    kind : {"noise", "multisine"}
        Gaussian noise with a flat spectrum in the band, or a random-phase multisine with
        equal line amplitudes (one line every ``8 / duration`` Hz in the band).
    band_hz : (float, float)
        Excited band [Hz].
    rms_n : float
        RMS of the force [N].
    seed : int
        Random seed.

    Returns
    -------
    numpy.ndarray
        Force [N], zero mean.

    Raises
    ------
    FieldDiagError
        An unknown ``kind`` or a band outside (0, Nyquist).
    """
    lo, hi = band_hz
    if not 0 < lo < hi < sample_rate_hz / 2:
        raise FieldDiagError(f"band {band_hz} Hz must lie inside (0, {sample_rate_hz / 2}) Hz")
    rng = np.random.default_rng(seed)
    f = np.fft.rfftfreq(n, 1.0 / sample_rate_hz)
    spec = np.zeros(f.size, complex)
    inband = np.flatnonzero((f >= lo) & (f <= hi))
    if kind == "noise":
        spec[inband] = rng.normal(size=inband.size) + 1j * rng.normal(size=inband.size)
    elif kind == "multisine":
        lines = inband[::8]
        spec[lines] = np.exp(2j * np.pi * rng.uniform(size=lines.size))
    else:
        raise FieldDiagError(f"excitation {kind!r} unknown; use 'noise' or 'multisine'")
    x = np.fft.irfft(spec, n)
    return x * (rms_n / x.std())


def _rhs(x, v, z, f, mass, th, cs, dth, dz):  # pragma: no cover - numba template
    fs, _, _, _ = model_force_z(x, v, x, z, th, cs, dth, dz)
    return (f + fs) / mass


def _integrate_osc(force_half, dt, mass, th, cs, z0):  # pragma: no cover - numba template
    """Fixed-step RK4 driven by ``force_half`` (the force every half step). Returns the
    displacement and velocity at every full step."""
    n = (force_half.shape[0] - 1) // 2
    xs = np.empty(n)
    vs = np.empty(n)
    nz = z0.shape[0]
    z = z0.copy()
    zt = np.empty(nz)
    k1 = np.empty(nz)
    k2 = np.empty(nz)
    k3 = np.empty(nz)
    k4 = np.empty(nz)
    dth = np.empty(max(th.shape[0], 1))
    x = 0.0
    v = 0.0
    h2 = 0.5 * dt
    h6 = dt / 6.0
    for i in range(n):
        xs[i] = x
        vs[i] = v
        f0, fm, f1 = force_half[2 * i], force_half[2 * i + 1], force_half[2 * i + 2]
        a1 = _rhs(x, v, z, f0, mass, th, cs, dth, k1)
        w1 = v + h2 * a1
        for j in range(nz):
            zt[j] = z[j] + h2 * k1[j]
        a2 = _rhs(x + h2 * v, w1, zt, fm, mass, th, cs, dth, k2)
        w2 = v + h2 * a2
        for j in range(nz):
            zt[j] = z[j] + h2 * k2[j]
        a3 = _rhs(x + h2 * w1, w2, zt, fm, mass, th, cs, dth, k3)
        w3 = v + dt * a3
        for j in range(nz):
            zt[j] = z[j] + dt * k3[j]
        a4 = _rhs(x + dt * w2, w3, zt, f1, mass, th, cs, dth, k4)
        x += h6 * (v + 2.0 * (w1 + w2) + w3)
        v += h6 * (a1 + 2.0 * (a2 + a3) + a4)
        for j in range(nz):
            z[j] += h6 * (k1[j] + 2.0 * (k2[j] + k3[j]) + k4[j])
    return xs, vs


def simulate_oscillator(
    *,
    moving_mass_kg: float = 0.5,
    resonance_hz: float = 60.0,
    damping_ratio: float = 0.04,
    effects: Sequence[Effect] = (),
    excitation: str = "noise",
    band_hz: tuple[float, float] | None = None,
    force_rms_n: float = 20.0,
    duration_s: float = 30.0,
    sample_rate_hz: float = 610.0,
    force_noise_rel: float = 0.01,
    displacement_noise_rel: float = 0.01,
    preload_n: float = 0.0,
    seed: int = 0,
) -> OscillatorRecording:
    """Simulate a force-driven oscillator with the library's effects and sensor noise.

    Parameters
    ----------
    moving_mass_kg : float
        Moving mass ``m`` [kg].
    resonance_hz : float
        Linear resonance; the spring is ``k = m (2 pi f)^2`` [Hz].
    damping_ratio : float
        Linear damping ratio; ``c = 2 zeta sqrt(k m)``.
    effects : sequence of Effect
        Effects with values (for example ``make_effect("cubic_stiffness", ...)``).
    excitation : {"noise", "multisine"}
        The drive force (see :func:`oscillator_force`).
    band_hz : (float, float) or None
        Excited band [Hz]; default ``(0.1, 2.0) * resonance_hz``, the top capped at
        0.42 ``sample_rate_hz``.
    force_rms_n : float
        RMS of the drive force [N].
    duration_s, sample_rate_hz : float
        Record length [s] and output sample rate [Hz].
    force_noise_rel, displacement_noise_rel : float
        White sensor noise, as a fraction of each channel's standard deviation.
    preload_n : float
        Constant load-cell offset added to the force reading [N].
    seed : int
        Random seed (excitation and noise).

    Returns
    -------
    OscillatorRecording

    Raises
    ------
    FieldDiagError
        Non-positive mass or resonance, or an effect with internal states.
    """
    if moving_mass_kg <= 0 or resonance_hz <= 0:
        raise FieldDiagError("the moving mass and the resonance must be positive")
    effects = check_effects(effects)
    k = moving_mass_kg * (2 * np.pi * resonance_hz) ** 2
    c = 2 * damping_ratio * np.sqrt(k * moving_mass_kg)
    model = ForceModel([LinearSpring(k), LinearDamper(c), *effects])
    fs = float(sample_rate_hz)
    band = band_hz or (0.1 * resonance_hz, min(2.0 * resonance_hz, 0.42 * fs))
    n = int(round(duration_s * fs))
    fs_half = 2 * OVERSAMPLE * fs
    drive = oscillator_force(2 * OVERSAMPLE * n + 1, fs_half, kind=excitation, band_hz=band,
                             rms_n=force_rms_n, seed=seed)
    kern = model.compile(__name__, "_rhs", "_integrate_osc", error_model="numpy")._integrate_osc
    z0 = np.zeros(model.n_states)
    x_int, _ = kern(drive, 1.0 / (OVERSAMPLE * fs), moving_mass_kg, model.values_of(),
                    model.constant_values(), z0)
    f_int = drive[0:-1:2]
    # the same zero-phase anti-aliasing filter on both channels, then every OVERSAMPLE-th
    x_true = signal.resample_poly(x_int, 1, OVERSAMPLE)
    f_true = signal.resample_poly(f_int, 1, OVERSAMPLE)
    if not np.all(np.isfinite(x_true)):
        raise FieldDiagError("the oscillator diverged; lower the force or the effects")
    rng = np.random.default_rng(seed + 1_000_003)
    f_meas = f_true + preload_n + rng.normal(0, force_noise_rel * f_true.std(), n)
    x_meas = x_true + rng.normal(0, displacement_noise_rel * x_true.std(), n)
    recipe = {
        "generator": "fielddiag.sim.oscillator.simulate_oscillator",
        "moving_mass_kg": moving_mass_kg,
        "stiffness_n_per_m": k,
        "damping_ns_per_m": c,
        "resonance_hz": resonance_hz,
        "effects": [e.to_dict() for e in effects],
        "excitation": excitation,
        "band_hz": list(band),
        "force_rms_n": force_rms_n,
        "sample_rate_hz": fs,
        "duration_s": duration_s,
        "force_noise_rel": force_noise_rel,
        "displacement_noise_rel": displacement_noise_rel,
        "preload_n": preload_n,
        "seed": seed,
    }
    return OscillatorRecording(fs, np.arange(n) / fs, f_meas, x_meas, f_true, x_true, recipe)
