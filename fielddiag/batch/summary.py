"""One-line texts of batch results, for the final table and the dashboard's session list."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

__all__ = ["batch_entries", "diagnose_text", "identify_text", "suspension_text"]


def _pm(value: float, std: float | None, scale: float = 1.0, spec: str = ".0f") -> str:
    std_text = "?" if std is None else f"{std / scale:{spec}}"
    return f"{value / scale:{spec}}+-{std_text}"


def identify_text(summary: dict[str, Any], model: str = "linear") -> str:
    """``M 381+-1 kg, K 24.1+-0.1 kN/m, C 1803+-4 Ns/m (linear)`` from a summary with
    ``sprung_mass_kg``, ``stiffness_n_per_m``, ``damping_ns_per_m`` and their ``*_std_*``
    ("-" if none); ``model`` says which model the values come from."""
    m, k, c = (summary.get(key) for key in ("sprung_mass_kg", "stiffness_n_per_m",
                                             "damping_ns_per_m"))
    if m is None or k is None or c is None:
        return "-"
    return (f"M {_pm(m, summary.get('sprung_mass_std_kg'))} kg, "
            f"K {_pm(k, summary.get('stiffness_std_n_per_m'), 1e3, '.1f')} kN/m, "
            f"C {_pm(c, summary.get('damping_std_ns_per_m'))} Ns/m ({model})")


def suspension_text(identify: dict[str, Any], diagnose: dict[str, Any]) -> str:
    """The pair's headline values: refitted with the diagnosis's findings when it has some
    (the linear identification is biased by what it leaves out), else the identification's.
    """
    corrected = (diagnose or {}).get("corrected") or {}
    if corrected:
        return identify_text(corrected, "with the findings")
    return identify_text(identify or {})


def diagnose_text(summary: dict[str, Any]) -> str:
    """``missing_physics: coulomb_friction (warnings: clipping)`` ("-" if none)."""
    verdict = summary.get("verdict", "")
    if not verdict:
        return "-"
    found = ", ".join(summary.get("findings") or [])
    warn = ", ".join(summary.get("warnings") or [])
    text = f"{verdict}: {found}" if found else verdict
    return f"{text} (warnings: {warn})" if warn else text


def batch_entries(catalog_path: str | os.PathLike, root: str | os.PathLike
                  ) -> dict[str, dict[str, Any]]:
    """Session path relative to ``root`` -> what the batch catalog says about its pair.

    Each entry: ``role`` (before/after), ``partner`` (the other session, relative to
    ``root``, or absolute when outside it), ``status``, ``result`` (one line), ``message``
    (why it failed), ``when`` (UTC), ``results`` (step -> result file relative to
    ``root``).
    """
    from fielddiag.batch.store import BatchCatalog
    from fielddiag.batch.task import STEPS

    catalog = BatchCatalog(catalog_path, readonly=True)
    root = Path(root).resolve()

    def rel(stored: str) -> str | None:
        p = catalog.absolute(stored)
        return p.relative_to(root).as_posix() if p.is_relative_to(root) else None

    out: dict[str, dict[str, Any]] = {}
    for row in catalog.rows():
        parts = []
        ident = (row.get("identify_summary") or {}
                 if row.get("identify_status") == "done" else {})
        diag = (row.get("diagnose_summary") or {}
                if row.get("diagnose_status") == "done" else {})
        if ident or diag:
            parts.append(suspension_text(ident, diag))
        if diag:
            parts.append(diagnose_text(diag))
        results = {s: rel(row[f"{s}_json"]) for s in STEPS
                   if row.get(f"{s}_status") == "done" and row.get(f"{s}_json")}
        b, a = rel(row["before"]), rel(row["after"])
        for me, role, other in ((b, "before", row["after"]), (a, "after", row["before"])):
            if me is None:
                continue
            partner = rel(other) or str(catalog.absolute(other))
            out[me] = {
                "role": role,
                "partner": partner,
                "status": row.get("status") or "",
                "result": "; ".join(p for p in parts if p != "-"),
                "message": row.get("message") or "",
                "when": row.get("processed_utc") or "",
                "results": {k: v for k, v in results.items() if v is not None},
            }
    return out
