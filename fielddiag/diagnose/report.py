"""Plain-language summaries of a diagnosis (the JSON of ``fielddiag diagnose``)."""

from __future__ import annotations


def _pm(value: float, std: float | None, spec: str = ".4g") -> str:
    """``60.21 +- 0.76`` (the std as "?" where none was estimated)."""
    s = "?" if std is None or std != std else f"{std:.2g}"
    return f"{value:{spec}} +- {s}"


def _fmt_params(params: dict[str, float], stds: dict[str, float] | None = None) -> str:
    stds = stds or {}
    return ", ".join(f"{k} = {_pm(v, stds.get(k))}" for k, v in params.items())


_MODEL_LABELS = (  # key suffix -> (name, unit); the longest suffix that fits wins
    ("sprung_mass_kg", "sprung mass", "kg"),
    ("_n_per_m_per_kg", "", "N/m per kg"),
    ("_ns_per_m_per_kg", "", "N s/m per kg"),
    ("_n_per_m", "", "N/m"),
    ("_ns_per_m", "", "N s/m"),
)


def model_parameter(key: str) -> tuple[str, str]:
    """Readable name and unit of a key of ``linear_model``/``augmented_model``:
    ``suspension_stiffness_n_per_m_per_kg`` -> ("suspension stiffness", "N/m per kg").

    Parameters
    ----------
    key : str
        A parameter key of the diagnosis JSON.

    Returns
    -------
    (str, str)
        Name and unit; the unit is "" for keys without a known unit suffix.
    """
    for suffix, label, unit in _MODEL_LABELS:
        if key.endswith(suffix):
            return label or key[: -len(suffix)].replace("_", " "), unit
    return key.replace("_", " "), ""


#: The data problems' names in a sentence.
_DATA_NAMES = {"sensor_gain_changed": "sensor gain change",
               "channel_time_offset": "channel time offset"}


def data_problem_names(out: dict) -> list[str]:
    """The data problems a diagnosis corrected, in words (``["sensor gain change"]``).

    Parameters
    ----------
    out : dict
        The diagnosis's JSON.

    Returns
    -------
    list of str
    """
    return [_DATA_NAMES.get(p.get("kind"), str(p.get("kind")))
            for p in out.get("data_problems") or [] if isinstance(p, dict)]


def _fmt_model(model: dict, stds: dict | None = None) -> str:
    """``sprung mass 379.7 +- 3.1 kg, suspension stiffness 2.397e+04 +- 210 N/m, ...``"""
    stds = stds or {}
    parts = []
    for key, value in model.items():
        name, unit = model_parameter(key)
        parts.append(f"{name} {_pm(value, stds.get(key))} {unit}".rstrip())
    return ", ".join(parts)


def adequate_words(out: dict) -> str:
    """What an ``adequate`` verdict says: no missing physics, unless a data problem the
    findings assume ties with physics that looks like it (a ``data_problem_or_physics``
    warning), where the physics is not ruled out."""
    if any(w.get("kind") == "data_problem_or_physics" for w in out.get("warnings", [])):
        return ("the linear model is adequate on the drives corrected for a data problem; "
                "physics that looks like that problem is not ruled out (see the warnings)")
    return "the linear model is adequate (no missing physics found)"


def format_summary(out: dict) -> str:
    """Readable text of a diagnosis dict (vehicle or rig mode).

    Parameters
    ----------
    out : dict
        The JSON of ``fielddiag diagnose`` (``verdict``, ``baseline``, ``augmented``,
        ``findings``, and optionally the model values, ``ride_height`` and ``warnings``).

    Returns
    -------
    str
        Several lines: the verdict, the held-out NRMSE of both models, each finding with its
        parameters (SI units), where it acts, the fitted suspension and the warnings.
    """
    lines = []
    mode = out.get("mode", "vehicle")
    head = "rig test" if mode == "rig" else "suspension"
    if out["verdict"] == "adequate":
        lines.append(f"{head}: {adequate_words(out)}")
    elif out["verdict"] == "inconclusive":
        lines.append(f"{head}: INCONCLUSIVE (no missing physics found, and the recording "
                     "cannot show whether the linear model is adequate)")
        if out.get("inconclusive"):
            lines.append(f"  {out['inconclusive']}")
    else:
        lines.append(f"{head}: MISSING PHYSICS")
    b, a = out["baseline"], out["augmented"]
    lines.append(
        f"  linear model   NRMSE fit {b['nrmse']:.3f}, held-out {b['nrmse_validation']:.3f}"
    )
    if out["verdict"] == "missing_physics":
        lines.append(
            f"  with findings  NRMSE fit {a['nrmse']:.3f}, held-out {a['nrmse_validation']:.3f}"
        )
    elif data_problem_names(out) and a:
        lines.append(
            f"  corrected      NRMSE fit {a['nrmse']:.3f}, held-out {a['nrmse_validation']:.3f}"
            " (in the units of the recording)")
    for f in out["findings"]:
        conf = f.get("confidence", 0.0)
        lines.append(f"  * {f['effect']} (confidence {conf:.2f}) "
                     f"{_fmt_params(f['parameters'], f.get('std'))}")
        lines.append(f"    {f['explanation']}")
        where = f.get("where") or {}
        if where.get("band_hz"):
            lo, hi = where["band_hz"]
            lines.append(f"    band {lo:.2g}-{hi:.2g} Hz")
        wins = where.get("time_windows_s") or []
        if wins:
            txt = ", ".join(
                f"{w['session']} {w['start_s']:.1f}-{w['end_s']:.1f} s" for w in wins[:4]
            )
            lines.append(f"    worst windows: {txt}")
    aug, lin = out.get("augmented_model") or {}, out.get("linear_model") or {}
    aug_std, lin_std = out.get("augmented_model_std") or {}, out.get("linear_model_std") or {}
    fixed = data_problem_names(out)
    if mode != "rig":
        if out["verdict"] == "missing_physics" and aug and out["findings"]:
            lines.append("  suspension, fitted with the findings"
                         + (f" and the {' and the '.join(fixed)} corrected" if fixed else "")
                         + ": " + _fmt_model(aug, aug_std))
            if lin and out.get("linear_model_adequate", True):
                lines.append("    (the linear model alone, biased by what it leaves out: "
                             + _fmt_model(lin, lin_std) + ")")
            elif lin:
                lines.append("    (the linear model alone has no meaningful values here: "
                             "see the warning below)")
        elif aug and fixed:
            # a data problem chosen alone: the linear model fitted to the corrected drives
            lines.append(f"  suspension, linear model with the {' and the '.join(fixed)} "
                         "corrected: " + _fmt_model(aug, aug_std))
            if lin:
                lines.append("    (fitted to the drives as recorded: " + _fmt_model(lin, lin_std)
                             + ")")
        elif lin and not out.get("linear_model_adequate", True):
            lines.append("  suspension, linear model: no meaningful values (see the warning "
                         "below)")
        elif lin:
            lines.append("  suspension, linear model: " + _fmt_model(lin, lin_std))
    if "parameters" in out and mode == "rig":
        p = out["parameters"]
        lines.append("  rig: " + ", ".join(
            f"{name} {_pm(p[key]['value'], p[key].get('std'))} {unit}"
            for key, name, unit in (("stiffness", "stiffness", p["stiffness"]["unit"]),
                                    ("damping", "damping", p["damping"]["unit"]),
                                    ("moving_mass_kg", "moving mass", "kg"))))
        if out.get("band"):
            lines.append(f"  band: {out['band'].get('reason', '')}")
    ride = out.get("ride_height")
    if ride:
        lines.append(f"  ride height: {ride['message']}")
    for w in out.get("warnings", []):
        lines.append(f"  WARNING ({w['kind']}): {w['message']}")
    return "\n".join(lines)
