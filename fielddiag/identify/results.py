"""Results of the identification: small dataclasses that serialise to JSON and back.

Every physical quantity is SI with the unit in its name. Arrays are plain lists of floats
(limited to a few hundred points) so that the dashboard can plot them; complex series are
``{"re": [...], "im": [...]}``; NaN becomes ``null``.

``IdentificationResult.to_dict()`` holds at its top level, each as ``{"value", "std"}``:
``sprung_mass_kg``, ``suspension_stiffness_n_per_m``, ``suspension_damping_ns_per_m``,
``coupling_stiffness_n_per_m``, ``body_natural_frequency_hz`` (and ``damping_ratio``),
plus ``band_hz`` and ``coherence``.
"""

from __future__ import annotations

import json
import math
import types
import typing
from dataclasses import dataclass, field, fields, is_dataclass
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

T = TypeVar("T")


def _plain(value: Any) -> Any:
    if is_dataclass(value) and not isinstance(value, type):
        return {f.name: _plain(getattr(value, f.name)) for f in fields(value)}
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return [_plain(v) for v in value.tolist()]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _build(tp: Any, value: Any) -> Any:
    if value is None:
        return None
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        inner = [a for a in args if a is not type(None)]
        return _build(inner[0], value) if len(inner) == 1 else value
    if origin is list:
        return [_build(args[0], v) for v in value] if args else list(value)
    if origin is tuple:
        return tuple(_build(args[0], v) for v in value) if args else tuple(value)
    if origin is dict:
        return {k: _build(args[1], v) for k, v in value.items()} if args else dict(value)
    if isinstance(tp, type) and is_dataclass(tp):
        return _from_dict(tp, value)
    if tp is float:
        return float(value)
    if tp is int:
        return int(value)
    return value


def _from_dict(cls: type[T], data: dict[str, Any]) -> T:
    hints = typing.get_type_hints(cls)
    kw = {}
    for f in fields(cls):  # type: ignore[arg-type]
        if f.name in data:
            v = data[f.name]
            kw[f.name] = float("nan") if v is None and hints[f.name] is float else _build(
                hints[f.name], v)
    return cls(**kw)


class _Serialisable:
    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-serialisable dict (NaN as None)."""
        return _plain(self)

    @classmethod
    def from_dict(cls: type[T], data: dict[str, Any]) -> T:
        """Inverse of :meth:`to_dict`."""
        return _from_dict(cls, data)

    def to_json(self, path: str | Path | None = None, *, indent: int = 1) -> str:
        """JSON text; also written to ``path`` when given."""
        text = json.dumps(self.to_dict(), indent=indent, allow_nan=False)
        if path is not None:
            Path(path).write_text(text + "\n")
        return text

    @classmethod
    def from_json(cls: type[T], text_or_path: str | Path) -> T:
        """Read what :meth:`to_json` wrote (a JSON string or a file path)."""
        p = Path(text_or_path) if not str(text_or_path).lstrip().startswith("{") else None
        text = p.read_text() if p is not None else str(text_or_path)
        return cls.from_dict(json.loads(text))  # type: ignore[attr-defined]


@dataclass
class Estimate(_Serialisable):
    """A value with its standard deviation (same unit)."""

    value: float
    std: float

    @property
    def relative_std(self) -> float:
        """std / |value| (inf for a zero value)."""
        return abs(self.std / self.value) if self.value else float("inf")

    def __format__(self, spec: str) -> str:
        spec = spec or ".4g"
        return f"{self.value:{spec}} +- {self.std:{spec}}"


@dataclass
class ComplexSeries(_Serialisable):
    """A complex array as two lists.

    Parameters
    ----------
    re, im : list of float
        Real and imaginary parts (unit of the array).
    """

    re: list[float]
    im: list[float]

    @classmethod
    def of(cls, z: np.ndarray) -> ComplexSeries:
        """From a complex array.

        Parameters
        ----------
        z : array_like
            Complex values.

        Returns
        -------
        ComplexSeries
        """
        z = np.asarray(z, dtype=complex)
        return cls([float(v) for v in z.real], [float(v) for v in z.imag])

    def array(self) -> np.ndarray:
        """The complex array back.

        Returns
        -------
        numpy.ndarray
            ``re + 1j * im``.
        """
        return np.asarray(self.re, float) + 1j * np.asarray(self.im, float)


@dataclass
class Band(_Serialisable):
    """Frequency band of the identification and why it was chosen.

    Parameters
    ----------
    low_hz, high_hz : float
        Band edges [Hz].
    source : str
        ``"data"`` (chosen from the coherence) or ``"user"``.
    note : str
        How it was chosen.
    """

    low_hz: float
    high_hz: float
    source: str  # "data" or "user"
    note: str = ""


@dataclass
class NoiseResult(_Serialisable):
    """Sensor noise floors of one session (white, one-sided densities).

    Parameters
    ----------
    wheel_psd_per_hz, body_psd_per_hz : float
        Noise densities of the wheel and body accelerometers [(m/s^2)^2/Hz].
    wheel_rms_mps2, body_rms_mps2 : float
        The same as RMS over the full band up to Nyquist [m/s^2].
    wheel_plateau_found, body_plateau_found : bool
        A flat noise plateau was found at high frequency (else the floor is a bound).
    notes : list of str
        Remarks on the estimate.
    """

    wheel_psd_per_hz: float
    body_psd_per_hz: float
    wheel_rms_mps2: float
    body_rms_mps2: float
    wheel_plateau_found: bool
    body_plateau_found: bool
    notes: list[str] = field(default_factory=list)


@dataclass
class Peak(_Serialisable):
    """A resonance peak of a transmissibility magnitude.

    Parameters
    ----------
    freq_hz : float
        Frequency [Hz].
    magnitude : float
        Magnitude at the peak (|T| dimensionless, or the spectrum's unit).
    """

    freq_hz: float
    magnitude: float


@dataclass
class TransmissibilityResult(_Serialisable):
    """Body/wheel transmissibility of one session, with the fitted model on the same lines.

    Parameters
    ----------
    label : str
        ``before`` or ``after``.
    added_mass_kg : float
        Mass added on the body in this session [kg].
    freq_hz : list of float
        Display frequencies [Hz].
    h1, h2, hv : ComplexSeries
        The H1, H2 and H-v estimates of T = A2/A1 (dimensionless).
    coherence : list of float
        Coherence of the wheel and body accelerations.
    model : ComplexSeries
        The fitted linear model's T.
    peaks : list of Peak
        Resonance peaks of |H-v| in the band.
    mean_coherence_in_band : float
        Mean coherence over the analysis band.
    n_averages : int
        Welch segments averaged.
    segment_s : float
        Welch segment length [s].
    noise : NoiseResult
        The session's sensor noise floors.
    """

    label: str
    added_mass_kg: float
    freq_hz: list[float]
    h1: ComplexSeries
    h2: ComplexSeries
    hv: ComplexSeries
    coherence: list[float]
    model: ComplexSeries
    peaks: list[Peak]
    mean_coherence_in_band: float
    n_averages: int
    segment_s: float
    noise: NoiseResult


@dataclass
class RestoringForceSurface(_Serialisable):
    """Mean restoring force per unit mass over a grid of (r, rdot) for one session.

    ``force_per_mass_mps2[i][j]`` is the mean of ``-a2 - (K3/M2) x2`` [m/s^2] in bin
    (``r_centers_m[i]``, ``rdot_centers_mps[j]``), None where fewer than the minimum count
    fell. ``stiffness_per_mass`` [N/m/kg = 1/s^2] and ``damping_per_mass`` [1/s] are the
    slopes of a plane fitted to the samples (noise-compensated); multiplied by the mass
    (``mass_kg``, when known) they give ``stiffness_n_per_m`` and ``damping_ns_per_m``.
    ``label`` names the session, ``band_hz`` the integration band [Hz] and ``counts`` the
    samples per bin. r is the suspension extension, positive in rebound.
    """

    label: str
    band_hz: list[float]
    r_centers_m: list[float]
    rdot_centers_mps: list[float]
    force_per_mass_mps2: list[list[float | None]]
    counts: list[list[int]]
    stiffness_per_mass: Estimate
    damping_per_mass: Estimate
    mass_kg: float | None = None
    stiffness_n_per_m: Estimate | None = None
    damping_ns_per_m: Estimate | None = None


@dataclass
class HysteresisLoop(_Serialisable):
    """Restoring force against travel and rate, narrow-band around ``freq_hz``.

    Parameters
    ----------
    label : str
        ``before`` or ``after``.
    freq_hz : float
        Centre frequency [Hz].
    band_hz : list of float
        Band-pass edges [Hz].
    r_m, rdot_mps : list of float
        Suspension extension [m] (positive in rebound) and its rate [m/s].
    force_per_mass_mps2 : list of float
        Restoring force per unit mass ``-a2 - (K3/M) x2`` [m/s^2 = N/kg].
    mass_kg : float or None
        Body mass of the session [kg] (M2 + dM), when known.
    """

    label: str
    freq_hz: float
    band_hz: list[float]
    r_m: list[float]
    rdot_mps: list[float]
    force_per_mass_mps2: list[float]
    mass_kg: float | None = None


@dataclass
class RouteResult(_Serialisable):
    """The estimate of one route (``frequency`` or ``time``).

    Parameters
    ----------
    name : str
        ``frequency`` or ``time``.
    sprung_mass_kg, suspension_stiffness_n_per_m : Estimate
        M2 [kg] and K2 [N/m] with their std.
    suspension_damping_ns_per_m, coupling_stiffness_n_per_m : Estimate
        C2 [N s/m] and K3 [N/m] with their std.
    body_natural_frequency_hz, damping_ratio : Estimate
        Derived values [Hz], [-].
    k3_included : bool
        K3 was fitted.
    n_residuals : int
        Number of residuals.
    cost : float
        Final cost (dimensionless).
    least_squares_std : dict of str to float
        The asymptotic std by parameter name (SI), for comparison with the jackknife.
    notes : list of str
        Remarks.
    """

    name: str
    sprung_mass_kg: Estimate
    suspension_stiffness_n_per_m: Estimate
    suspension_damping_ns_per_m: Estimate
    coupling_stiffness_n_per_m: Estimate
    body_natural_frequency_hz: Estimate
    damping_ratio: Estimate
    k3_included: bool
    n_residuals: int
    cost: float
    least_squares_std: dict[str, float] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)


@dataclass
class SessionSummary(_Serialisable):
    """Which recording played which part.

    Parameters
    ----------
    label : str
        ``before`` or ``after``.
    path : str
        Session file.
    duration_s : float
        Duration [s].
    sample_rate_hz : float
        Sample rate [Hz].
    added_mass_kg : float
        Mass added on the body [kg].
    """

    label: str
    path: str
    duration_s: float
    sample_rate_hz: float
    added_mass_kg: float


@dataclass
class IdentificationResult(_Serialisable):
    """Sprung mass, suspension stiffness and damping from two drives, with everything to
    show how they were found.

    The headline estimates are those of the frequency route; ``routes`` holds both routes
    and ``route_agreement`` their difference in combined standard deviations.

    Parameters
    ----------
    sprung_mass_kg, suspension_stiffness_n_per_m : Estimate
        M2 [kg] and K2 [N/m] with their std (frequency route).
    suspension_damping_ns_per_m, coupling_stiffness_n_per_m : Estimate
        C2 [N s/m] and K3 [N/m] with their std.
    body_natural_frequency_hz, damping_ratio : Estimate
        Derived values [Hz], [-].
    added_mass_kg : float
        Mass added for the second drive [kg].
    band_hz : Band
        The analysis band.
    coherence : dict of str to float
        Mean coherence in the band per session label, and ``min_in_band``.
    k3_included : bool
        K3 was kept (significant, or asked for).
    k3_test : dict of str to float
        The fitted K3 ``value`` and ``std`` [N/m], their ratio ``z`` and the
        ``cost_reduction`` it brings.
    routes : dict of str to RouteResult
        ``frequency`` and ``time``.
    route_agreement : dict of str to float
        Difference of the routes per parameter in combined std.
    transmissibility : list of TransmissibilityResult
        Per session.
    restoring_force : list of RestoringForceSurface
        Per session (empty without display data).
    hysteresis : list of HysteresisLoop
        Narrow-band loops.
    warnings : list of str
        What the technician should know.
    sessions : list of SessionSummary
        The two drives.
    method : str
        How the numbers were found, in words.
    software_version : str
        fielddiag version.
    """

    sprung_mass_kg: Estimate
    suspension_stiffness_n_per_m: Estimate
    suspension_damping_ns_per_m: Estimate
    coupling_stiffness_n_per_m: Estimate
    body_natural_frequency_hz: Estimate
    damping_ratio: Estimate
    added_mass_kg: float
    band_hz: Band
    coherence: dict[str, float]
    k3_included: bool
    k3_test: dict[str, float]
    routes: dict[str, RouteResult]
    route_agreement: dict[str, float]
    transmissibility: list[TransmissibilityResult]
    restoring_force: list[RestoringForceSurface]
    hysteresis: list[HysteresisLoop]
    warnings: list[str]
    sessions: list[SessionSummary]
    method: str
    software_version: str

    def summary(self) -> str:
        """A readable multi-line summary.

        Returns
        -------
        str
            The sessions, the band, the coherence, M2 [kg], K2 [N/m], C2 [N s/m], K3 [N/m],
            the body natural frequency [Hz] and damping ratio with standard deviations, and the
            checks and warnings.
        """
        def line(label: str, e: Estimate, unit: str, spec: str = ".4g") -> str:
            rel = f"  ({100 * e.relative_std:.1f} %)" if e.value else ""
            return f"  {label:<26} {e.value:{spec}} +- {e.std:{spec}} {unit}{rel}"

        b = self.band_hz
        out = [
            f"Identification from {len(self.sessions)} drives, added mass "
            f"{self.added_mass_kg:g} kg",
        ]
        for s in self.sessions:
            out.append(f"  {s.label:<7} {s.path}  ({s.duration_s:.0f} s at "
                       f"{s.sample_rate_hz:g} Hz, added {s.added_mass_kg:g} kg)")
        out += [
            f"Band {b.low_hz:.2f}-{b.high_hz:.2f} Hz ({b.source}; {b.note})",
            "Coherence in band: " + ", ".join(f"{k} {v:.2f}" for k, v in self.coherence.items()),
            "Result, linear model (frequency route; std from a jackknife over time blocks):",
            line("sprung mass M2", self.sprung_mass_kg, "kg"),
            line("suspension stiffness K2", self.suspension_stiffness_n_per_m, "N/m"),
            line("suspension damping C2", self.suspension_damping_ns_per_m, "N s/m"),
        ]
        k3 = self.coupling_stiffness_n_per_m
        if self.k3_included:
            out.append(line("coupling stiffness K3", k3, "N/m"))
        else:
            out.append(f"  {'coupling stiffness K3':<26} 0 (not significant: fitted "
                       f"{self.k3_test.get('value', float('nan')):.4g} +- {k3.std:.4g} N/m)")
        out += [
            line("body natural frequency", self.body_natural_frequency_hz, "Hz", ".4f"),
            line("damping ratio", self.damping_ratio, "", ".3f"),
        ]
        if "time" in self.routes:
            t = self.routes["time"]
            z = self.route_agreement
            out.append(
                "Time route: M2 {:.4g} +- {:.2g} kg, K2 {:.4g} +- {:.2g} N/m, C2 {:.4g} +- {:.2g}"
                " N s/m  (differences {:.1f}, {:.1f}, {:.1f} std)".format(
                    t.sprung_mass_kg.value, t.sprung_mass_kg.std,
                    t.suspension_stiffness_n_per_m.value, t.suspension_stiffness_n_per_m.std,
                    t.suspension_damping_ns_per_m.value, t.suspension_damping_ns_per_m.std,
                    z.get("sprung_mass_kg", float("nan")),
                    z.get("suspension_stiffness_n_per_m", float("nan")),
                    z.get("suspension_damping_ns_per_m", float("nan"))))
        for tr in self.transmissibility:
            pk = ", ".join(f"{p.freq_hz:.2f} Hz (|T| {p.magnitude:.2f})" for p in tr.peaks[:3])
            out.append(f"Transmissibility {tr.label}: peaks {pk or 'none'}; noise wheel "
                       f"{tr.noise.wheel_rms_mps2:.3g}, body {tr.noise.body_rms_mps2:.3g} m/s2 rms")
        if self.warnings:
            out.append("Warnings:")
            out += [f"  - {w}" for w in self.warnings]
        return "\n".join(out)
