"""Parameters of a full vehicle: body, four corners, anti-roll bars; a random car.

Conventions: :mod:`fielddiag.vehicle.geometry`. The body (sprung mass) has its centre of
gravity at ``(x_cg, y_cg)`` and at ``cog_height_m`` above the roll and pitch axes (the arm
of the moments of the lateral and longitudinal inertial forces); pitch and roll inertias
are about axes through the centre of gravity (no product of inertia there).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, fields, replace
from typing import Any

import numpy as np

from fielddiag.channels import CORNERS
from fielddiag.errors import FieldDiagError
from fielddiag.sim._common import check_number
from fielddiag.vehicle.geometry import VehicleGeometry

__all__ = ["CornerParams", "VehicleParams", "random_vehicle"]


@dataclass(frozen=True)
class CornerParams:
    """One corner: its linear suspension, its unsprung mass and its tyre.

    Parameters
    ----------
    stiffness_n_per_m, damping_ns_per_m : float
        Suspension spring K (> 0) and damper C (>= 0) between hub and body.
    wheel_mass_kg : float
        Unsprung mass (> 0).
    tire_stiffness_n_per_m, tire_damping_ns_per_m : float
        Linear tyre between hub and road (> 0, >= 0).
    """

    stiffness_n_per_m: float = 28e3
    damping_ns_per_m: float = 2200.0
    wheel_mass_kg: float = 40.0
    tire_stiffness_n_per_m: float = 230e3
    tire_damping_ns_per_m: float = 150.0

    def __post_init__(self) -> None:
        for f in fields(self):
            damping = "damping" in f.name
            check_number("CornerParams", f.name, getattr(self, f.name), low=0.0,
                         strict=not damping)


@dataclass(frozen=True)
class VehicleParams:
    """A full vehicle for the simulator (and the truth the identification is scored on).

    Parameters
    ----------
    geometry : VehicleGeometry
        Wheelbase, tracks, body-sensor positions.
    sprung_mass_kg : float
        Body mass M (> 0).
    cog_behind_front_axle_m, cog_left_of_centre_m : float
        Centre of gravity (x_cg, y_cg) [m].
    cog_height_m : float
        Height of the centre of gravity above the roll and pitch axes [m] (>= 0): the arm
        of the roll moment ``M h a_lat`` and of the pitch moment ``-M h a_long``.
    pitch_inertia_kgm2, roll_inertia_kgm2 : float
        Inertias about the centre of gravity (> 0).
    corners : mapping corner -> CornerParams
        The four corners (default: all :class:`CornerParams()`).
    anti_roll_stiffness_front_n_per_m, anti_roll_stiffness_rear_n_per_m : float
        Anti-roll bars (>= 0): ``F_left = -k (r_left - r_right)``, ``F_right = -F_left``.
    """

    geometry: VehicleGeometry = field(default_factory=VehicleGeometry)
    sprung_mass_kg: float = 1350.0
    cog_behind_front_axle_m: float = 1.15
    cog_left_of_centre_m: float = 0.0
    cog_height_m: float = 0.45
    pitch_inertia_kgm2: float = 2000.0
    roll_inertia_kgm2: float = 480.0
    corners: Mapping[str, CornerParams] = field(default_factory=dict)
    anti_roll_stiffness_front_n_per_m: float = 15e3
    anti_roll_stiffness_rear_n_per_m: float = 8e3

    def __post_init__(self) -> None:
        o = "VehicleParams"
        if not isinstance(self.geometry, VehicleGeometry):
            raise FieldDiagError(f"{o}: geometry must be a VehicleGeometry")
        for name, low, strict in (("sprung_mass_kg", 0.0, True), ("pitch_inertia_kgm2", 0.0, True),
                                  ("roll_inertia_kgm2", 0.0, True), ("cog_height_m", 0.0, False),
                                  ("anti_roll_stiffness_front_n_per_m", 0.0, False),
                                  ("anti_roll_stiffness_rear_n_per_m", 0.0, False),
                                  ("cog_behind_front_axle_m", None, False),
                                  ("cog_left_of_centre_m", None, False)):
            check_number(o, name, getattr(self, name), low=low, strict=strict)
        corners = dict(self.corners) or {c: CornerParams() for c in CORNERS}
        if sorted(corners) != sorted(CORNERS) or not all(
                isinstance(v, CornerParams) for v in corners.values()):
            raise FieldDiagError(f"{o}: corners must map each of {', '.join(CORNERS)} to a "
                                 "CornerParams")
        object.__setattr__(self, "corners", {c: corners[c] for c in CORNERS})

    def corner(self, corner: str) -> CornerParams:
        """The parameters of one corner."""
        return self.corners[corner]

    def anti_roll_stiffness_n_per_m(self, axle: str) -> float:
        """The anti-roll bar of ``"front"`` or ``"rear"`` [N/m]."""
        return (self.anti_roll_stiffness_front_n_per_m if axle == "front"
                else self.anti_roll_stiffness_rear_n_per_m)

    def with_corner(self, corner: str, **changes: float) -> VehicleParams:
        """A copy with one corner's parameters changed (``damping_ns_per_m=...``)."""
        corners = dict(self.corners)
        corners[corner] = replace(corners[corner], **changes)
        return replace(self, corners=corners)

    def truth(self) -> dict[str, Any]:
        """The identified quantities' true values, keyed like the identification's JSON."""
        return {
            "sprung_mass_kg": self.sprung_mass_kg,
            "cog_behind_front_axle_m": self.cog_behind_front_axle_m,
            "cog_left_of_centre_m": self.cog_left_of_centre_m,
            "pitch_inertia_kgm2": self.pitch_inertia_kgm2,
            "roll_inertia_kgm2": self.roll_inertia_kgm2,
            "corners": {c: {"stiffness_n_per_m": p.stiffness_n_per_m,
                            "damping_ns_per_m": p.damping_ns_per_m}
                        for c, p in self.corners.items()},
            "anti_roll_stiffness_front_n_per_m": self.anti_roll_stiffness_front_n_per_m,
            "anti_roll_stiffness_rear_n_per_m": self.anti_roll_stiffness_rear_n_per_m,
        }

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready description (geometry as the vehicle file, SI units)."""
        d = {f.name: getattr(self, f.name) for f in fields(self)}
        d["geometry"] = self.geometry.to_dict()
        d["corners"] = {c: asdict(p) for c, p in self.corners.items()}
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> VehicleParams:
        """Inverse of :meth:`to_dict`."""
        d = dict(d)
        geom = VehicleGeometry.from_dict(d.pop("geometry"))
        corners = {c: CornerParams(**p) for c, p in d.pop("corners").items()}
        return cls(geometry=geom, corners=corners, **d)


def random_vehicle(seed: int | np.random.Generator | None = None) -> VehicleParams:
    """A plausible random passenger car (for tests and benchmarks).

    Mass 1000-1900 kg, wheelbase 2.4-3.0 m, tracks 1.45-1.65 m, CoG 38-52 % of the
    wheelbase behind the front axle and up to 3 cm off centre, height 0.35-0.6 m, pitch
    radius of gyration 0.95-1.35 m, roll 0.50-0.65 m; body frequencies 1.1-1.6 Hz front,
    1.2-1.8 Hz rear with corner stiffness within +-8 % of the axle's, damping ratio
    0.2-0.4; anti-roll bars 30-80 % of the axle's corner stiffness; body sensors within
    0.3 m of the struts.
    """
    rng = np.random.default_rng(seed)
    u = rng.uniform
    wb = u(2.4, 3.0)
    tf, tr = u(1.45, 1.65), u(1.45, 1.65)
    sensors = {}
    for c in CORNERS:
        x = u(-0.1, 0.3) if c[0] == "f" else wb - u(-0.1, 0.3)
        y = (0.5 * (tf if c[0] == "f" else tr) - u(0.0, 0.3)) * (1 if c[1] == "l" else -1)
        sensors[c] = (float(x), float(y))
    geom = VehicleGeometry(wb, tf, tr, sensors)
    m = u(1000.0, 1900.0)
    xc = u(0.38, 0.52) * wb
    yc = u(-0.03, 0.03)
    corners = {}
    loads = {"f": m * (wb - xc) / wb / 2, "r": m * xc / wb / 2}
    freqs = {"f": u(1.1, 1.6), "r": u(1.2, 1.8)}
    zeta = {"f": u(0.2, 0.4), "r": u(0.2, 0.4)}
    for c in CORNERS:
        mc = loads[c[0]]
        k = mc * (2 * np.pi * freqs[c[0]]) ** 2 * u(0.92, 1.08)
        cdamp = 2 * zeta[c[0]] * np.sqrt(k * mc) * u(0.92, 1.08)
        corners[c] = CornerParams(float(k), float(cdamp), float(u(30.0, 50.0)),
                                  float(u(200e3, 280e3)), 150.0)
    k_axle_f = 0.5 * (corners["fl"].stiffness_n_per_m + corners["fr"].stiffness_n_per_m)
    k_axle_r = 0.5 * (corners["rl"].stiffness_n_per_m + corners["rr"].stiffness_n_per_m)
    return VehicleParams(
        geometry=geom, sprung_mass_kg=float(m), cog_behind_front_axle_m=float(xc),
        cog_left_of_centre_m=float(yc), cog_height_m=float(u(0.35, 0.6)),
        pitch_inertia_kgm2=float(m * u(0.95, 1.35) ** 2),
        roll_inertia_kgm2=float(m * u(0.50, 0.65) ** 2), corners=corners,
        anti_roll_stiffness_front_n_per_m=float(u(0.3, 0.8) * k_axle_f),
        anti_roll_stiffness_rear_n_per_m=float(u(0.3, 0.8) * k_axle_r))
