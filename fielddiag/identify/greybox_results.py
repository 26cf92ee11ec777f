"""Result objects of the grey-box fit, JSON-serialisable (``to_dict`` / ``from_dict``).

The CLI (``fielddiag fit --json``), the dashboard and the diagnosis step read these; they
hold numbers and names only, no arrays of samples.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from fielddiag.errors import FieldDiagError

__all__ = ["GreyBoxResult", "ParameterEstimate", "SessionFit", "nrmse"]


def nrmse(residual: np.ndarray, reference: np.ndarray) -> float:
    """Normalised root-mean-square error: ``rms(residual) / rms(reference - mean)``.

    The one definition used by every fit and every comparison of fits (grey-box fit and
    validation, diagnosis candidates, rig mode).

    Parameters
    ----------
    residual : ndarray
        Measured minus modelled values (any unit).
    reference : ndarray
        The measured values, same unit.

    Returns
    -------
    float
        Dimensionless; 0 for a perfect model, about 1 for a model no better than the mean;
        inf when the reference is constant.
    """
    ref = np.asarray(reference, float)
    scale = float(np.sqrt(np.mean((ref - ref.mean()) ** 2)))
    res = np.asarray(residual, float)
    return float(np.sqrt(np.mean(res**2)) / scale) if scale > 0 else math.inf


def _num(x: float | None) -> float | None:
    """JSON has no NaN/inf: map them to None."""
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def _back(x: float | None) -> float:
    return math.nan if x is None else float(x)


@dataclass
class ParameterEstimate:
    """One fitted parameter.

    Attributes
    ----------
    name : str
        SI name as reported (``suspension_stiffness_n_per_m``, or ``..._per_kg`` for a
        per-unit-mass value, or ``body_mass_kg``).
    key : str
        ``"<term>.<param>"`` in the model, or ``body_mass_kg``.
    term : str
        Term name (``body`` for the mass).
    unit : str
        Unit of ``value``.
    value, std : float
        Estimate and its standard deviation (NaN if not estimable).
    rel_std_pct : float
        ``100 * std / |value|``.
    fixed : bool
        Held at ``value``, not fitted.
    at_bound : bool
        Ended on a bound (its std is then only indicative).
    label : str
        Short name for people (``stiffness``).
    """

    name: str
    key: str
    term: str
    unit: str
    value: float
    std: float
    rel_std_pct: float
    fixed: bool = False
    at_bound: bool = False
    label: str = ""

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict of the fields (NaN and inf become None).

        Returns
        -------
        dict
        """
        d = asdict(self)
        for k in ("value", "std", "rel_std_pct"):
            d[k] = _num(d[k])
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ParameterEstimate:
        """Inverse of :meth:`to_dict`.

        Parameters
        ----------
        d : dict
            As made by :meth:`to_dict` (None read back as NaN).

        Returns
        -------
        ParameterEstimate
        """
        d = dict(d)
        for k in ("value", "std", "rel_std_pct"):
            d[k] = _back(d.get(k))
        return cls(**d)


@dataclass
class SessionFit:
    """How well the fitted model reproduces one session (fit or validation data).

    Attributes
    ----------
    name : str
        Session file or label.
    role : str
        ``fit`` or ``validation``.
    added_mass_kg : float
        Mass added on the body for this session.
    samples, duration_s, sample_rate_hz : int, float, float
        Size of the data used.
    nrmse : float
        rms(residual) / rms(measured body acceleration, detrended, in the band).
    residual_rms_mps2 : float
        rms of the body-acceleration residual in the band.
    initial_offset_m, initial_velocity_mps : float
        Fitted deviation of the body's initial state from static equilibrium (nuisance).
    """

    name: str
    role: str
    added_mass_kg: float
    samples: int
    duration_s: float
    sample_rate_hz: float
    nrmse: float
    residual_rms_mps2: float
    initial_offset_m: float = 0.0
    initial_velocity_mps: float = 0.0

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict of the fields (NaN and inf become None).

        Returns
        -------
        dict
        """
        d = asdict(self)
        for k in ("nrmse", "residual_rms_mps2"):
            d[k] = _num(d[k])
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> SessionFit:
        """Inverse of :meth:`to_dict`.

        Parameters
        ----------
        d : dict
            As made by :meth:`to_dict` (None read back as NaN).

        Returns
        -------
        SessionFit
        """
        d = dict(d)
        for k in ("nrmse", "residual_rms_mps2"):
            d[k] = _back(d.get(k))
        return cls(**d)


@dataclass
class GreyBoxResult:
    """Outcome of :func:`fielddiag.identify.greybox.fit_greybox`.

    Attributes
    ----------
    model : dict
        ``ForceModel.to_dict()`` of the fitted model.
    mode : str
        ``absolute`` (two or more added masses: absolute values and the body mass) or
        ``per_unit_mass`` (one mass: force parameters divided by the sprung mass).
    parameters : list of ParameterEstimate
        Reported parameters (absolute or per unit mass), then ``body_mass_kg`` if absolute.
    correlation : list of list of float
        Correlation matrix of the fitted (not fixed) reported parameters, in the order of
        ``correlation_names``.
    correlation_names : list of str
        Names of the rows/columns of ``correlation``.
    per_unit_mass : dict of str to float
        The model parameters per unit sprung mass, by model key (what the on-line
        estimator estimates; geometric parameters such as a gap as they are).
    per_unit_mass_std : dict of str to float
        Their standard deviations.
    sessions : list of SessionFit
        Fit data, then validation data (``role``).
    iterations, model_evaluations : int
        Levenberg-Marquardt iterations and simulations (each with its sensitivities).
    converged : bool
        Met a convergence test (not stopped by the iteration limit).
    message : str
        Why it stopped.
    cost_history : list of float
        0.5 * sum of squared residuals after each accepted step (first: start value).
    band_hz : list of float or None
        Band of the residual comparison; None for the full band (simulated truth).
    uncertainty : dict
        How the standard deviations were computed (method, lag window per session,
        variance inflation per parameter over the white-residual formula).
    wall_time_s : float
        Time taken by the fit.
    """

    model: dict[str, Any]
    mode: str
    parameters: list[ParameterEstimate]
    correlation: list[list[float]]
    correlation_names: list[str]
    per_unit_mass: dict[str, float]
    per_unit_mass_std: dict[str, float]
    sessions: list[SessionFit]
    iterations: int
    model_evaluations: int
    converged: bool
    message: str
    cost_history: list[float] = field(default_factory=list)
    band_hz: list[float] | None = None
    uncertainty: dict[str, Any] = field(default_factory=dict)
    wall_time_s: float = 0.0

    # ------------------------------------------------------------------ access
    def parameter(self, name: str) -> ParameterEstimate:
        """A reported parameter by name or key (``suspension_stiffness_n_per_m``).

        Parameters
        ----------
        name : str
            Name, key (``linear_spring.suspension_stiffness_n_per_m``), or the plain name of a
            parameter reported per unit mass (``..._per_kg``).

        Returns
        -------
        ParameterEstimate

        Raises
        ------
        FieldDiagError
            The fit has no such parameter.
        """
        for p in self.parameters:
            if name in (p.name, p.key):
                return p
        for p in self.parameters:  # plain name in per-unit-mass mode
            if p.name == f"{name}_per_kg" or p.key.endswith(f".{name}"):
                return p
        raise FieldDiagError(
            f"the fit has no parameter {name!r}; it has {[p.name for p in self.parameters]}"
        )

    def value(self, name: str) -> float:
        """Estimate of a reported parameter.

        Parameters
        ----------
        name : str
            As :meth:`parameter`.

        Returns
        -------
        float
            In the parameter's reported unit (SI, or per kg in per-unit-mass mode).

        Raises
        ------
        FieldDiagError
            The fit has no such parameter.
        """
        return self.parameter(name).value

    def std(self, name: str) -> float:
        """Standard deviation of a reported parameter.

        Parameters
        ----------
        name : str
            As :meth:`parameter`.

        Returns
        -------
        float
            In the parameter's reported unit.

        Raises
        ------
        FieldDiagError
            The fit has no such parameter.
        """
        return self.parameter(name).std

    @property
    def body_mass_kg(self) -> float | None:
        """Fitted sprung mass (absolute mode), else None."""
        for p in self.parameters:
            if p.key == "body_mass_kg":
                return p.value
        return None

    def fit_sessions(self) -> list[SessionFit]:
        """The sessions the model was fitted to.

        Returns
        -------
        list of SessionFit
            ``role == "fit"``.
        """
        return [s for s in self.sessions if s.role == "fit"]

    def validation_sessions(self) -> list[SessionFit]:
        """The held-out sessions the fit was checked on.

        Returns
        -------
        list of SessionFit
            ``role == "validation"``.
        """
        return [s for s in self.sessions if s.role == "validation"]

    def correlation_matrix(self) -> np.ndarray:
        """Correlation of the fitted parameters (order of ``correlation_names``).

        Returns
        -------
        numpy.ndarray
            Square, dimensionless; NaN where undefined.
        """
        return np.array(self.correlation, dtype=float)

    # ------------------------------------------------------------------ text
    def summary(self) -> str:
        """Human-readable table of the parameters, fit quality and validation.

        Returns
        -------
        str
            Several lines: model and solver statistics, each parameter with value, std,
            relative std and unit, strong correlations (|rho| > 0.9) and each session's NRMSE.
        """
        lines = [
            f"grey-box fit ({self.mode.replace('_', ' ')}), model: "
            + " + ".join(t["name"] for t in self.model["terms"]),
            f"  {self.iterations} iterations, {self.model_evaluations} simulations with "
            f"sensitivities, {self.wall_time_s:.2f} s; {self.message}",
        ]
        if self.band_hz:
            lines.append(f"  residual compared in {self.band_hz[0]:g}-{self.band_hz[1]:g} Hz")
        lines.append(f"  {'parameter':<38} {'value':>13} {'std':>11} {'rel std':>8}  unit")
        for p in self.parameters:
            flag = " (fixed)" if p.fixed else (" (at bound)" if p.at_bound else "")
            rel = "-" if not math.isfinite(p.rel_std_pct) else f"{p.rel_std_pct:.2f}%"
            std = "-" if not math.isfinite(p.std) else f"{p.std:.4g}"
            lines.append(f"  {p.name:<38} {p.value:>13.6g} {std:>11} {rel:>8}  {p.unit}{flag}")
        names = self.correlation_names
        corr = self.correlation_matrix()
        strong = [
            f"{names[i]}/{names[j]} {corr[i, j]:+.2f}"
            for i in range(len(names)) for j in range(i + 1, len(names))
            if math.isfinite(corr[i, j]) and abs(corr[i, j]) > 0.9
        ]
        if strong:
            lines.append("  strongly correlated: " + ", ".join(strong))
        for s in self.sessions:
            lines.append(
                f"  {s.role:<10} {s.name}: {s.duration_s:.1f} s, added mass "
                f"{s.added_mass_kg:g} kg, NRMSE {s.nrmse:.4f}"
            )
        return "\n".join(lines)

    # ------------------------------------------------------------------ JSON
    def to_dict(self) -> dict[str, Any]:
        """JSON-serialisable dict (NaN and inf become null).

        Returns
        -------
        dict
            ``kind = "fielddiag.greybox_fit"``; values in SI units as named.
        """
        return {
            "kind": "fielddiag.greybox_fit",
            "model": self.model,
            "mode": self.mode,
            "parameters": [p.to_dict() for p in self.parameters],
            "correlation": [[_num(v) for v in row] for row in self.correlation],
            "correlation_names": list(self.correlation_names),
            "per_unit_mass": {k: _num(v) for k, v in self.per_unit_mass.items()},
            "per_unit_mass_std": {k: _num(v) for k, v in self.per_unit_mass_std.items()},
            "sessions": [s.to_dict() for s in self.sessions],
            "iterations": int(self.iterations),
            "model_evaluations": int(self.model_evaluations),
            "converged": bool(self.converged),
            "message": self.message,
            "cost_history": [_num(c) for c in self.cost_history],
            "band_hz": None if self.band_hz is None else [float(b) for b in self.band_hz],
            "uncertainty": self.uncertainty,
            "wall_time_s": float(self.wall_time_s),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> GreyBoxResult:
        """Inverse of :meth:`to_dict`.

        Parameters
        ----------
        d : dict
            As made by :meth:`to_dict`.

        Returns
        -------
        GreyBoxResult

        Raises
        ------
        FieldDiagError
            ``d`` lacks a field of a grey-box result.
        """
        try:
            return cls(
                model=d["model"],
                mode=d["mode"],
                parameters=[ParameterEstimate.from_dict(p) for p in d["parameters"]],
                correlation=[[_back(v) for v in row] for row in d["correlation"]],
                correlation_names=list(d["correlation_names"]),
                per_unit_mass={k: _back(v) for k, v in d["per_unit_mass"].items()},
                per_unit_mass_std={k: _back(v) for k, v in d["per_unit_mass_std"].items()},
                sessions=[SessionFit.from_dict(s) for s in d["sessions"]],
                iterations=int(d["iterations"]),
                model_evaluations=int(d["model_evaluations"]),
                converged=bool(d["converged"]),
                message=str(d["message"]),
                cost_history=[_back(c) for c in d.get("cost_history", [])],
                band_hz=d.get("band_hz"),
                uncertainty=d.get("uncertainty", {}),
                wall_time_s=float(d.get("wall_time_s", 0.0)),
            )
        except (KeyError, TypeError) as exc:
            raise FieldDiagError(f"not a grey-box fit result ({exc}); pass a dict made by "
                                 "GreyBoxResult.to_dict()") from None
