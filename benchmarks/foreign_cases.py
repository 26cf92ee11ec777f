"""Cases from a second, independent quarter-car simulator with force laws the library does
not share (the "unseen recordings" check of issues 16 and 17).

The diagnosis is scored elsewhere on cases drawn from fielddiag's own simulator, whose
effects are the library's own kernels: a family there is always exactly one of the forms
the diagnosis fits. Recordings from outside are not. This module writes the physics again,
from the textbook forms and not from ``fielddiag.effects``, with its own road, integrator
set-up and sensor chain, so that nothing is shared but numpy, scipy and numba:

* force laws (compression ``u`` = wheel minus body displacement from the unloaded ride
  height, ``du`` its rate; the force pushes the body up): LuGre friction with a Stribeck
  peak; a polytropic gas spring (progressive in compression, softening in rebound); a
  rubber bump stop whose force grows with the square of its squeeze; a damper whose slope
  bends smoothly (``tanh``) above a knee; a damper stronger in rebound with a smooth
  change of direction; cubic (progressive) damping; Bouc-Wen hysteresis with exponent 2;
  a Kelvin-Voigt rubber top mount in series with the whole strut; and free play (a
  backlash) in the damper's mounting, which no family of the library describes;
* gravity in the readings (an accelerometer reads acceleration + g), the tyre may leave
  the road, the car starts 2 s before the recording from its static equilibrium (passive
  sag, or ride height restored by a self-levelling car);
* road: slope white in distance (ISO 8608 displacement PSD ~ n^-2, classes B-D), smoothed
  over a 0.2 m tyre patch, with random bumps and potholes; speed varying sinusoidally;
* RK4 at >= 16 kHz, then a linear-phase FIR decimation (scipy.signal.resample_poly, as a
  sigma-delta DAQ does) to 200-1000 Hz, white plus 1/f noise, 16-bit quantisation.

:func:`draw_case` draws a case from a seed; :func:`case_drives` returns the diagnosis's
before/after ``Drive`` pair and the same pair of the linear twin (the same car, roads and
noise without the effect), whose linear held-out NRMSE is the floor the strength is
measured against.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from numba import njit
from scipy import optimize, signal

G_MPS2 = 9.80665

#: Force laws: code, what the diagnosis may rightly call it first (``unexplained``: a
#: shape outside the library, described rather than named).
LAWS: dict[str, tuple[int, frozenset[str]]] = {
    "linear": (0, frozenset()),
    # (LuGre's bristle state is Dahl's with a Stribeck peak: the hysteretic spring's)
    "lugre_friction": (1, frozenset({"coulomb_friction", "dahl_friction", "bouc_wen",
                                     "hysteretic_spring"})),
    "gas_spring": (2, frozenset({"cubic_stiffness", "bump_stop", "unexplained"})),
    "rubber_bump_stop": (3, frozenset({"bump_stop", "cubic_stiffness"})),
    "smooth_digressive_damper": (4, frozenset({"digressive_damping"})),
    "smooth_asymmetric_damper": (5, frozenset({"asymmetric_damping"})),
    "cubic_damping": (6, frozenset({"quadratic_damping", "unexplained"})),
    "bouc_wen_n2": (7, frozenset({"bouc_wen", "dahl_friction", "hysteretic_spring",
                                  "coulomb_friction"})),
    "kelvin_top_mount": (8, frozenset({"series_top_mount"})),
    "damper_free_play": (9, frozenset({"unexplained"})),
}
#: Probability of the linear car (the rest is shared evenly by the other laws).
LINEAR_PROBABILITY = 0.25

SPRUNG_MASS_KG = (250.0, 600.0)
BODY_FREQ_HZ = (1.0, 1.8)
DAMPING_RATIO = (0.2, 0.45)
SPRUNG_TO_WHEEL_MASS = (6.0, 12.0)
WHEEL_HOP_HZ = (10.0, 15.0)
TYRE_DAMPING_NS_PER_M = (50.0, 300.0)
ROAD_G0_M3 = {"B": 64e-6, "C": 256e-6, "D": 1024e-6}  # Gd(n0 = 0.1 cycle/m)
SPEED_MPS = (4.0, 30.0)
RATE_HZ = (200, 1000)
SNR_DB = (25.0, 45.0)
ADDED_MASS_FRACTION = (0.05, 0.15)
SELF_LEVELLING_PROBABILITY = 0.2
STRENGTH = (0.5, 20.0)  # log-uniform; about 1: an effect near the noise
LEAD_IN_S = 2.0
MIN_INTERNAL_RATE_HZ = 16000.0
PINK_SHARE = 0.3  # share of the noise power that is 1/f


@dataclass(frozen=True)
class ForeignCase:
    """One drawn case (JSON-serialisable with :func:`dataclasses.asdict`)."""

    seed: int
    law: str
    strength: float
    car: dict[str, float]
    road_class: str
    speed_mps: tuple[float, float]
    rate_hz: int
    snr_db: float
    duration_s: float
    added_mass_kg: float
    self_levelling: bool
    law_shape: dict[str, float] = field(default_factory=dict)  # relative knobs of the law

    @property
    def accepted(self) -> frozenset[str]:
        """Names the diagnosis may rightly give first."""
        return LAWS[self.law][1]

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def draw_case(seed: int, *, duration_s: float = 60.0, law: str | None = None) -> ForeignCase:
    """Draw a case from ``seed`` (``law`` forces the force law)."""
    rng = np.random.default_rng([seed, 0xF0E1])
    m = float(rng.uniform(*SPRUNG_MASS_KG))
    fb = float(rng.uniform(*BODY_FREQ_HZ))
    zeta = float(rng.uniform(*DAMPING_RATIO))
    k = m * (2 * math.pi * fb) ** 2
    c = 2 * zeta * math.sqrt(k * m)
    mw = m / float(rng.uniform(*SPRUNG_TO_WHEEL_MASS))
    fh = float(rng.uniform(*WHEEL_HOP_HZ))
    kt = mw * (2 * math.pi * fh) ** 2 - k
    car = {"body_mass_kg": m, "wheel_mass_kg": mw, "suspension_stiffness_n_per_m": k,
           "suspension_damping_ns_per_m": c, "tyre_stiffness_n_per_m": kt,
           "tyre_damping_ns_per_m": float(rng.uniform(*TYRE_DAMPING_NS_PER_M))}
    others = [n for n in LAWS if n != "linear"]
    drawn = "linear" if rng.random() < LINEAR_PROBABILITY else str(rng.choice(others))
    law = drawn if law is None else law  # the rest of the case drawn alike either way
    lo, hi = SPEED_MPS
    v1, v2 = sorted(rng.uniform(lo, hi, 2))
    shape = {"u1": float(rng.random()), "u2": float(rng.random()), "u3": float(rng.random())}
    return ForeignCase(
        seed=seed, law=law,
        strength=float(math.exp(rng.uniform(*np.log(STRENGTH)))),
        car=car, road_class=str(rng.choice(list(ROAD_G0_M3))),
        speed_mps=(float(v1), float(max(v2, v1 + 3.0))),
        rate_hz=int(rng.integers(RATE_HZ[0], RATE_HZ[1] + 1)),
        snr_db=float(rng.uniform(*SNR_DB)), duration_s=float(duration_s),
        added_mass_kg=m * float(rng.uniform(*ADDED_MASS_FRACTION)),
        self_levelling=bool(rng.random() < SELF_LEVELLING_PROBABILITY), law_shape=shape)


# ----------------------------------------------------------------------------- physics
@njit(cache=True)
def _force(law, p, u, du, s1, base_f):  # pragma: no cover - compiled
    """Suspension force on the body (up) and the internal state's rate."""
    k, c = p[0], p[1]
    if law == 1:  # LuGre: p2 Fc, p3 Fs, p4 vs, p5 sigma0, p6 sigma1
        g = p[2] + (p[3] - p[2]) * math.exp(-(du / p[4]) ** 2)
        ds = du - p[5] * abs(du) * s1 / g
        return base_f + k * u + c * du + p[5] * s1 + p[6] * ds, ds
    if law == 2:  # gas spring: p2 P0*A, p3 column length L, p4 gamma, p5 its linear k
        left = max(p[3] - u, 0.2 * p[3])
        return base_f + k * u + c * du + p[2] * ((p[3] / left) ** p[4] - 1.0) - p[5] * u, 0.0
    if law == 3:  # rubber bump stop: p2 k_bs [N/m2], p3 gap
        extra = p[2] * (u - p[3]) ** 2 if u > p[3] else 0.0
        return base_f + k * u + c * du + extra, 0.0
    if law == 4:  # smooth digressive damper: p2 high-speed slope, p3 knee velocity
        return base_f + k * u + p[2] * du + (c - p[2]) * p[3] * math.tanh(du / p[3]), 0.0
    if law == 5:  # smooth asymmetric damper: p2 asymmetry a, p3 transition velocity
        return base_f + k * u + c * du * (1.0 - p[2] * math.tanh(du / p[3])), 0.0
    if law == 6:  # cubic damping: p2 c3
        return base_f + k * u + c * du + p[2] * du ** 3, 0.0
    if law == 7:  # Bouc-Wen n = 2: p2 hysteretic stiffness, p3 beta = gamma
        ds = du - p[3] * abs(du) * s1 * abs(s1) - p[3] * du * s1 * s1
        return base_f + k * u + c * du + p[2] * s1, ds
    if law == 8:  # Kelvin-Voigt mount (p2 k_m, p3 c_m) in series with the strut; s1 mount
        ds = (k * (u - s1) + c * du - p[2] * s1) / (c + p[3])
        return base_f + p[2] * s1 + p[3] * ds, ds
    if law == 9:  # free play +-p2 in the damper's mounting; s1 the damper's position
        e = u - s1
        sgn = 1.0 if du >= 0.0 else -1.0
        w = 0.5 * (1.0 + math.tanh((e * sgn - p[2]) / (0.05 * p[2])))
        ds = du * w
        return base_f + k * u + c * ds, ds
    return base_f + k * u + c * du, 0.0


@njit(cache=True)
def _rhs(law, p, car, x, zr, zrd, base_f, mb, out):  # pragma: no cover - compiled
    u = x[2] - x[0]
    du = x[3] - x[1]
    f, ds = _force(law, p, u, du, x[4], base_f)
    ft = car[3] + car[0] * (zr - x[2]) + car[1] * (zrd - x[3])  # static + dynamic
    if ft < 0.0:
        ft = 0.0  # the tyre leaves the road
    out[0] = x[1]
    out[1] = (f - mb * G_MPS2) / mb
    out[2] = x[3]
    out[3] = (ft - f - car[2] * G_MPS2) / car[2]
    out[4] = ds
    return out


@njit(cache=True)
def _integrate(law, p, car, x0, zr, zrd, dt, base_f, mb):  # pragma: no cover - compiled
    """RK4; ``zr``/``zrd`` at half steps (2 n + 1). Returns body and wheel accelerations
    and compression at every step."""
    n = (zr.shape[0] - 1) // 2
    ab = np.empty(n)
    aw = np.empty(n)
    uu = np.empty(n)
    x = x0.copy()
    k1 = np.empty(5)
    k2 = np.empty(5)
    k3 = np.empty(5)
    k4 = np.empty(5)
    tmp = np.empty(5)
    for i in range(n):
        _rhs(law, p, car, x, zr[2 * i], zrd[2 * i], base_f, mb, k1)
        ab[i] = k1[1]
        aw[i] = k1[3]
        uu[i] = x[2] - x[0]
        for j in range(5):
            tmp[j] = x[j] + 0.5 * dt * k1[j]
        _rhs(law, p, car, tmp, zr[2 * i + 1], zrd[2 * i + 1], base_f, mb, k2)
        for j in range(5):
            tmp[j] = x[j] + 0.5 * dt * k2[j]
        _rhs(law, p, car, tmp, zr[2 * i + 1], zrd[2 * i + 1], base_f, mb, k3)
        for j in range(5):
            tmp[j] = x[j] + dt * k3[j]
        _rhs(law, p, car, tmp, zr[2 * i + 2], zrd[2 * i + 2], base_f, mb, k4)
        for j in range(5):
            x[j] += dt / 6.0 * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j])
    return ab, aw, uu


def law_params(case: ForeignCase, u_rms_m: float, du_rms_mps: float) -> np.ndarray:
    """The law's parameter vector (``k, c`` first), scaled to the car and its travel."""
    car, s, sh = case.car, case.strength, case.law_shape
    k, c, m, mw = (car["suspension_stiffness_n_per_m"], car["suspension_damping_ns_per_m"],
                   car["body_mass_kg"], car["wheel_mass_kg"])
    p = np.zeros(8)
    p[0], p[1] = k, c
    law = case.law
    if law == "lugre_friction":
        fc = s * 0.007 * m * G_MPS2
        sigma0 = fc / (1e-4 + 4e-4 * sh["u1"])
        p[2:7] = fc, fc * (1.2 + 0.4 * sh["u2"]), 0.005 + 0.025 * sh["u3"], sigma0, \
            0.3 * math.sqrt(sigma0 * mw)
    elif law == "gas_spring":
        kg, gamma = 0.5 * k, 1.3
        length = max(3.0 * u_rms_m, 40.0 * u_rms_m / s)
        p[2:6] = kg * length / gamma, length, gamma, kg
    elif law == "rubber_bump_stop":
        p[2:4] = 0.5 * s * k / u_rms_m, (1.0 + 1.5 * sh["u1"]) * u_rms_m
    elif law == "smooth_digressive_damper":
        p[2:4] = c * (1.0 - 0.8 * math.tanh(0.15 * s)), (0.5 + sh["u1"]) * du_rms_mps
    elif law == "smooth_asymmetric_damper":
        p[2:4] = 0.8 * math.tanh(0.125 * s), 0.1 * du_rms_mps
    elif law == "cubic_damping":
        p[2] = 0.1 * s * c / (2.0 * du_rms_mps) ** 2
    elif law == "bouc_wen_n2":
        fy = s * 0.007 * m * G_MPS2
        zy = (0.05 + 0.25 * sh["u1"]) * u_rms_m
        p[2:4] = fy / zy, 0.5 / zy ** 2  # beta = gamma: z saturates at zy
    elif law == "kelvin_top_mount":
        p[2:4] = c / (0.3e-3 * s), 0.2 * sh["u1"] * c
    elif law == "damper_free_play":
        p[2] = min(0.5, 0.03 * s) * u_rms_m
    return p


def _road(rng: np.random.Generator, length_m: float, g0: float) -> tuple[float, np.ndarray]:
    """Road height every ``dx`` over ``length_m``: white slope (Gd ~ n^-2), high-passed at
    0.01 cycle/m, smoothed over a 0.2 m patch, with bumps and potholes."""
    dx = 0.02
    n = int(length_m / dx) + 10
    slope_psd = (2 * math.pi * 0.1) ** 2 * g0  # one-sided, of dz/dx
    slope = rng.standard_normal(n) * math.sqrt(slope_psd / (2 * dx))
    z = np.cumsum(slope) * dx
    b, a = signal.butter(1, 0.01 * 2 * dx)
    z = z - signal.filtfilt(b, a, z)
    z = np.convolve(z, np.ones(10) / 10, mode="same")
    if rng.random() < 0.5:
        for _ in range(int(rng.integers(2, 9))):
            at, span = rng.uniform(0, length_m), rng.uniform(0.3, 4.0)
            h = rng.uniform(0.03, 0.08) * (1 if rng.random() < 0.7 else -1)
            xs = np.arange(n) * dx
            on = np.abs(xs - at) < span / 2
            z[on] += h * 0.5 * (1 + np.cos(2 * math.pi * (xs[on] - at) / span))
    return dx, z


def _pink(rng: np.random.Generator, n: int, rate_hz: float) -> np.ndarray:
    spec = np.fft.rfft(rng.standard_normal(n))
    f = np.fft.rfftfreq(n, 1 / rate_hz)
    spec /= np.sqrt(np.maximum(f, 0.05))
    x = np.fft.irfft(spec, n)
    return x / x.std()


def _static_compression(law: int, p: np.ndarray, load_n: float) -> tuple[float, float]:
    """Compression and internal state at rest under ``load_n`` more than the preload."""
    if load_n == 0.0:
        return 0.0, 0.0
    k = p[0]
    if law == 8:
        return load_n / k + load_n / p[2], load_n / p[2]
    if law in (2, 3):
        def net(u: float) -> float:
            return float(_force(law, p, u, 0.0, 0.0, 0.0)[0]) - load_n
        return float(optimize.brentq(net, 0.0, 5 * load_n / k)), 0.0
    return load_n / k, 0.0


def _simulate(case: ForeignCase, law: int, p: np.ndarray, added_kg: float, road_seed: int,
              noise_seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One drive: (wheel reading, body reading, compression at the internal rate)."""
    car = case.car
    rate = case.rate_hz
    q = int(math.ceil(MIN_INTERNAL_RATE_HZ / rate))
    fs_int = rate * q
    total_s = case.duration_s + LEAD_IN_S
    n = int(round(total_s * fs_int))
    dt = 1.0 / fs_int
    rng = np.random.default_rng([road_seed, 7])
    t_half = np.arange(2 * n + 1) * dt / 2
    v_lo, v_hi = case.speed_mps
    period = rng.uniform(20.0, 60.0)
    phase = rng.uniform(0, 2 * math.pi)
    speed = 0.5 * (v_lo + v_hi) + 0.5 * (v_hi - v_lo) * np.sin(2 * math.pi * t_half / period
                                                                 + phase)
    x = np.concatenate([[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * dt / 2)])
    dx, road = _road(rng, float(x[-1]) + 5.0, ROAD_G0_M3[case.road_class])
    zr = np.interp(x, np.arange(road.size) * dx, road)
    zrd = np.gradient(zr, dt / 2)
    mb = car["body_mass_kg"] + added_kg
    base_f = mb * G_MPS2 if case.self_levelling else car["body_mass_kg"] * G_MPS2
    u0, s0 = _static_compression(law, p, mb * G_MPS2 - base_f)
    static_tyre = (mb + car["wheel_mass_kg"]) * G_MPS2
    carv = np.array([car["tyre_stiffness_n_per_m"], car["tyre_damping_ns_per_m"],
                     car["wheel_mass_kg"], static_tyre])
    xw0 = zr[0]
    x0 = np.array([xw0 - u0, 0.0, xw0, 0.0, s0])
    ab, aw, uu = _integrate(law, p, carv, x0, zr, zrd, dt, base_f, mb)
    lead = int(round(LEAD_IN_S * fs_int))
    nrng = np.random.default_rng([noise_seed, 11])
    readings = []
    for a in (aw, ab):
        r = signal.resample_poly(a[lead:] + G_MPS2, 1, q)
        dyn = float(np.std(r))
        std = dyn / 10 ** (case.snr_db / 20)
        noise = std * (math.sqrt(1 - PINK_SHARE) * nrng.standard_normal(r.size)
                       + math.sqrt(PINK_SHARE) * _pink(nrng, r.size, rate))
        full_scale = G_MPS2 * 2 ** math.ceil(math.log2(max(2.0, 1.5 * np.abs(r).max()
                                                            / G_MPS2)))
        step = 2 * full_scale / 65536
        readings.append(np.round((r + noise) / step) * step)
    return readings[0], readings[1], uu[lead:]


def simulate_pair(case: ForeignCase, *, linear_twin: bool = False
                  ) -> list[tuple[np.ndarray, np.ndarray]]:
    """(wheel, body) readings of the before and after drives (of the linear twin: the same
    car, roads and noise without the effect)."""
    lin = np.array([case.car["suspension_stiffness_n_per_m"],
                    case.car["suspension_damping_ns_per_m"], 0, 0, 0, 0, 0, 0], float)
    if linear_twin or case.law == "linear":
        p, code = lin, 0
    else:
        _, _, u = _simulate(case, 0, lin, 0.0, case.seed * 2, case.seed * 2)
        u_rms = float(np.std(u))
        du_rms = float(np.std(np.diff(u))) * case.rate_hz * math.ceil(
            MIN_INTERNAL_RATE_HZ / case.rate_hz)
        p, code = law_params(case, u_rms, du_rms), LAWS[case.law][0]
    out = []
    for i, added in enumerate((0.0, case.added_mass_kg)):
        w, b, _ = _simulate(case, code, p, added, case.seed * 2 + i, case.seed * 2 + i)
        out.append((w, b))
    return out


def case_drives(case: ForeignCase, *, linear_twin: bool = False) -> list[Any]:
    """The diagnosis's before/after :class:`fielddiag.diagnose.engine.Drive` pair."""
    from fielddiag.diagnose.engine import Drive

    pair = simulate_pair(case, linear_twin=linear_twin)
    return [Drive(wheel_accel_mps2=w, body_accel_mps2=b, sample_rate_hz=float(case.rate_hz),
                  added_mass_kg=added, label=label, name=f"foreign_{case.seed}", start_s=0.0)
            for (w, b), label, added in zip(pair, ("before", "after"),
                                            (0.0, case.added_mass_kg), strict=True)]
