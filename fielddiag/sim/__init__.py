"""Quarter-car simulator: road profiles, speed profiles, suspension effects and sensors.

One corner of a car, vertical positions positive up, SI units. ``x1`` is the wheel
(unsprung mass M1) on the tyre (K1, C1) over the road ``u(t)``; ``x2`` the body (sprung
mass M2) on the suspension (K2, C2) with an optional coupling K3 to ground. All positions
are deviations from the static equilibrium of the car *without* added mass, so
``r = x2 - x1`` is the suspension extension measured from the unloaded ride height::

    F_s(r, rdot) = -K2 r - C2 rdot + N(r, rdot)          force of the suspension on the body
    (M2 + dM) a2 = F_s + L - K3 x2 - dM g
    M1 a1        = K1 (u - x1) + C1 (udot - v1) - F_s - L

``L`` is the static force of a levelling system: 0 for a passive car (the suspension sags
under ``dM``), ``dM g K1 / (K1 + K3)`` with ``ride_height_restored`` (self-levelling: the
suspension keeps its unloaded static deflection).

``N`` is the sum of the :data:`EFFECTS` switched on (each defined once, in the effect
library :mod:`fielddiag.effects`). A drive starts from the static
equilibrium of the loaded car, is integrated by fixed-step RK4 (numba) at an internal rate
``k * output_rate >= 4000 Hz`` and is read by two accelerometers (:class:`SensorModel`):
gain, bias and drift, a causal Butterworth anti-alias filter, decimation, then ADC noise,
quantisation and saturation. Entry points: :func:`simulate` and :func:`simulate_pair`.

Modules: ``vehicle`` (parameters, analytic T21), ``effects`` (the library's effects with
values), ``dynamics`` (numba RK4 loop compiled around the effects' kernels, static
equilibrium from their static contributions, step choice from their speed bounds),
``road`` (ISO 8608, events, speed), ``sensors`` (accelerometer chain), ``drive``
(:func:`simulate` and its result).

The road height between profile samples is a Catmull-Rom cubic (it passes through the
samples like linear interpolation, but its slope is continuous), and ``udot = du/ds * v``.
With linear interpolation ``udot`` jumps at every sample; through the tyre damper C1 the
jumps put broadband energy into the wheel acceleration that aliases onto the low
frequencies (3-4 % error in the body/wheel transmissibility near 0.5 Hz at 25 m/s).
"""

from fielddiag.sim._common import G_MPS2, MIN_INTERNAL_RATE_HZ
from fielddiag.sim.drive import (
    EventPassage,
    InitialOffset,
    SimulatedDrive,
    simulate,
    simulate_from_dict,
    simulate_pair,
)
from fielddiag.sim.dynamics import (
    internal_rate_factor,
    levelling_force_n,
    static_state,
    suspension_force_n,
)
from fielddiag.sim.effects import (
    EFFECTS,
    AsymmetricDamping,
    BumpStop,
    CoulombFriction,
    CubicStiffness,
    Effect,
    HystereticSpring,
    QuadraticDamping,
    effects_from_dicts,
    make_effect,
)
from fielddiag.sim.road import (
    ISO8608_GD_M3,
    ISO8608_N0_CYCLES_PER_M,
    ROAD_EVENTS,
    Pothole,
    RoadEvent,
    SpeedBump,
    SpeedProfile,
    iso8608_profile,
    iso8608_variance_m2,
    road_event_from_dict,
)
from fielddiag.sim.sensors import SensorModel
from fielddiag.sim.vehicle import QuarterCarParams, analytic_transmissibility

__all__ = [
    "EFFECTS",
    "G_MPS2",
    "ISO8608_GD_M3",
    "ISO8608_N0_CYCLES_PER_M",
    "MIN_INTERNAL_RATE_HZ",
    "ROAD_EVENTS",
    "AsymmetricDamping",
    "BumpStop",
    "CoulombFriction",
    "CubicStiffness",
    "Effect",
    "EventPassage",
    "HystereticSpring",
    "InitialOffset",
    "Pothole",
    "QuadraticDamping",
    "QuarterCarParams",
    "RoadEvent",
    "SensorModel",
    "SimulatedDrive",
    "SpeedBump",
    "SpeedProfile",
    "analytic_transmissibility",
    "effects_from_dicts",
    "internal_rate_factor",
    "iso8608_profile",
    "iso8608_variance_m2",
    "levelling_force_n",
    "make_effect",
    "road_event_from_dict",
    "simulate",
    "simulate_from_dict",
    "simulate_pair",
    "static_state",
    "suspension_force_n",
]
