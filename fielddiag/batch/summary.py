"""One-line texts of batch results, for the final table and the dashboard's session list."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

__all__ = ["batch_entries", "diagnose_text", "identify_text"]


def identify_text(summary: dict[str, Any]) -> str:
    """``M 381 kg, K 24.1 kN/m, C 1803 Ns/m`` from an identification summary ("-" if none)."""
    m, k, c = (summary.get(key) for key in ("sprung_mass_kg", "stiffness_n_per_m",
                                             "damping_ns_per_m"))
    if m is None or k is None or c is None:
        return "-"
    return f"M {m:.0f} kg, K {k / 1e3:.1f} kN/m, C {c:.0f} Ns/m"


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
        if row.get("identify_status") == "done":
            parts.append(identify_text(row.get("identify_summary") or {}))
        if row.get("diagnose_status") == "done":
            parts.append(diagnose_text(row.get("diagnose_summary") or {}))
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
