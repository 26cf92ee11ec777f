"""Linear quarter-car parameters and the analytic body/wheel transmissibility."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

import numpy as np

from fielddiag.sim._common import check_number


@dataclass(frozen=True)
class QuarterCarParams:
    """Linear quarter-car parameters (defaults: a mid-size car corner).

    Parameters
    ----------
    wheel_mass_kg, body_mass_kg : float
        Unsprung mass M1 and sprung mass M2 (> 0).
    tire_stiffness_n_per_m, tire_damping_ns_per_m : float
        Tyre K1 (> 0) and C1 (>= 0) between wheel and road.
    suspension_stiffness_n_per_m, suspension_damping_ns_per_m : float
        Suspension K2 (> 0) and C2 (>= 0) between body and wheel.
    coupling_stiffness_n_per_m : float
        K3 from the body to ground (rest of the vehicle); may be 0 or negative.
    """

    wheel_mass_kg: float = 40.0
    tire_stiffness_n_per_m: float = 220e3
    tire_damping_ns_per_m: float = 150.0
    body_mass_kg: float = 380.0
    suspension_stiffness_n_per_m: float = 24e3
    suspension_damping_ns_per_m: float = 1800.0
    coupling_stiffness_n_per_m: float = 0.0

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name == "coupling_stiffness_n_per_m":
                check_number("QuarterCarParams", f.name, v)
            elif "damping" in f.name:
                check_number("QuarterCarParams", f.name, v, low=0.0)
            else:
                check_number("QuarterCarParams", f.name, v, low=0.0, strict=True)

    def body_natural_frequency_hz(self, added_mass_kg: float = 0.0) -> float:
        """Undamped body frequency sqrt((K2 + K3) / (M2 + dM)) / 2 pi, wheel held still."""
        k = self.suspension_stiffness_n_per_m + self.coupling_stiffness_n_per_m
        return math.sqrt(max(k, 0.0) / (self.body_mass_kg + added_mass_kg)) / (2 * math.pi)

    def wheel_hop_frequency_hz(self) -> float:
        """Undamped wheel frequency sqrt((K1 + K2) / M1) / 2 pi, body held still."""
        k = self.tire_stiffness_n_per_m + self.suspension_stiffness_n_per_m
        return math.sqrt(k / self.wheel_mass_kg) / (2 * math.pi)

    def to_dict(self) -> dict[str, float]:
        """Plain dict of the parameters (JSON-serialisable)."""
        return {k: float(v) for k, v in asdict(self).items()}


#: The default car (a mid-size car corner).
DEFAULT_PARAMS = QuarterCarParams()


def analytic_transmissibility(
    params: QuarterCarParams, freq_hz: np.ndarray | float, added_mass_kg: float = 0.0
) -> np.ndarray:
    """Linear body/wheel transmissibility T21 = X2/X1 (equally A2/A1).

    ``T21 = (K2 + jwC2) / (K2 + K3 - w^2 (M2 + dM) + jwC2)``.

    Parameters
    ----------
    params : QuarterCarParams
        The car.
    freq_hz : array_like
        Frequencies [Hz].
    added_mass_kg : float
        Mass added on the body.

    Returns
    -------
    numpy.ndarray of complex
        T21 at each frequency.
    """
    w = 2 * np.pi * np.asarray(freq_hz, dtype=float)
    k2, c2 = params.suspension_stiffness_n_per_m, params.suspension_damping_ns_per_m
    m2 = params.body_mass_kg + added_mass_kg
    num = k2 + 1j * w * c2
    return num / (k2 + params.coupling_stiffness_n_per_m - w**2 * m2 + 1j * w * c2)
