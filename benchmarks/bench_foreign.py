"""The diagnosis on cases from an independent simulator with foreign force laws.

Usage: python benchmarks/bench_foreign.py --seed S --n N [--jobs 2] [--out rows.json]
       python benchmarks/bench_foreign.py --tables rows.json   (reprint from saved rows)

Method: N cases are drawn by benchmarks/foreign_cases.py from the seeds S .. S+N-1 (a
quarter car written again from textbook force laws, its own road, RK4 at >= 16 kHz, FIR
decimation, gravity in the readings, white + 1/f noise, 16-bit quantisation; nothing of
fielddiag.sim or fielddiag.effects is used) and diagnosed as a before/after pair with
fielddiag.diagnose.engine.diagnose_drives. The strength of a case is the linear model's
held-out NRMSE on it over the same on its linear twin (same car, roads and noise, the
effect left out): how far the effect lifts the linear model's misfit. Scoring: a false
alarm is a suspension finding on a linear car; detected = any suspension finding; top-1 =
the first suspension finding is one of the names the law may rightly get
(foreign_cases.LAWS; ``unexplained`` for free play in the damper's mounting, which no
family describes); a "forced name" is a named family first where only ``unexplained`` is
right. Use a fresh seed for every run: never tune on one set.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import traceback
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

import foreign_cases as fc  # noqa: E402
import random_scoring as rs  # noqa: E402


def run_case(seed: int, duration_s: float, law: str | None = None) -> dict[str, Any]:
    """Draw, simulate, diagnose and score one case; a failure becomes a row with ``error``."""
    case = fc.draw_case(seed, duration_s=duration_s, law=law)
    row: dict[str, Any] = {"seed": seed, "law": case.law, "case": case.to_dict()}
    try:
        from fielddiag.diagnose.engine import diagnose_drives, known_model_nrmse

        t0 = time.perf_counter()
        drives = fc.case_drives(case)
        twin = drives if case.law == "linear" else fc.case_drives(case, linear_twin=True)
        t1 = time.perf_counter()
        out = diagnose_drives(drives).to_dict()
        t2 = time.perf_counter()
        lin = known_model_nrmse(drives, [])
        floor = lin if twin is drives else known_model_nrmse(twin, [])
        named = [f.get("effect") for f in rs.suspension_findings(out)]
        row.update({
            "strength_ratio": lin / floor if floor > 0 else None,
            "verdict": out.get("verdict"),
            "named": named,
            "detected": bool(named),
            "false_alarm": case.law == "linear" and bool(named),
            "data_problems": sorted(rs.data_problems_reported(out)),
            "findings": [{k: f.get(k) for k in ("effect", "parameters") if k in f}
                         for f in out.get("findings", [])],
            "warnings": [{"kind": w.get("kind"), "message": w.get("message")}
                         for w in out.get("warnings", [])],
            "wall_s": {"simulate": t1 - t0, "diagnose": t2 - t1},
        })
        row.update(rescore(row))
    except Exception as exc:  # noqa: BLE001 - a benchmark counts failures, it does not stop
        row["error"] = f"{type(exc).__name__}: {exc}"
        row["traceback"] = traceback.format_exc(limit=6)
    return row


def _pct(k: int, n: int) -> str:
    return f"{k}/{n}" + (f" ({100 * k / n:.0f} %)" if n else "")


def rescore(row: dict[str, Any]) -> dict[str, Any]:
    """The row's top-1 and forced-name marks from :data:`foreign_cases.LAWS` as it is now
    (saved rows are scored again when the tables are printed)."""
    accepted = fc.LAWS[row["law"]][1]
    named = row["named"]
    return {**row, "top1": bool(named) and named[0] in accepted,
            "forced_name": accepted == {rs.UNEXPLAINED} and bool(named)
            and named[0] != rs.UNEXPLAINED}


def tables(rows: list[dict]) -> list[str]:
    ok = [rescore(r) for r in rows if "error" not in r]
    out = [f"{len(rows)} cases, {len(rows) - len(ok)} failed",
           f"{'law':<26} {'n':>3} {'<2x det':>8} {'>=2x n':>6} {'det':>8} {'top-1':>12}"
           "  first names at >=2x"]
    for law in fc.LAWS:
        rs_ = [r for r in ok if r["law"] == law]
        if not rs_:
            continue
        if law == "linear":
            fa = sum(r["false_alarm"] for r in rs_)
            dp = sum(bool(r["data_problems"]) for r in rs_)
            out.append(f"{law:<26} {len(rs_):>3}  false alarms {_pct(fa, len(rs_))}; a data "
                       f"problem reported {dp} (none simulated)")
            continue
        weak = [r for r in rs_ if (r["strength_ratio"] or 0) < 2]
        strong = [r for r in rs_ if (r["strength_ratio"] or 0) >= 2]
        firsts: dict[str, int] = {}
        for r in strong:
            key = r["named"][0] if r["named"] else f"none ({r['verdict']})"
            firsts[key] = firsts.get(key, 0) + 1
        out.append(f"{law:<26} {len(rs_):>3} {sum(r['detected'] for r in weak):>3}/{len(weak):<4}"
                   f" {len(strong):>6} {sum(r['detected'] for r in strong):>4}/{len(strong):<3}"
                   f" {_pct(sum(r['top1'] for r in strong), len(strong)):>12}  "
                   + ", ".join(f"{k} {v}" for k, v in sorted(firsts.items(),
                                                             key=lambda kv: -kv[1])))
    strong = [r for r in ok if r["law"] != "linear" and (r["strength_ratio"] or 0) >= 2]
    out.append(f"all effects >= 2x: top-1 {_pct(sum(r['top1'] for r in strong), len(strong))}, "
               f"detected {_pct(sum(r['detected'] for r in strong), len(strong))}; "
               f"data problems reported on effect cases (none simulated): "
               f"{sum(bool(r['data_problems']) for r in ok if r['law'] != 'linear')}")
    walls = sorted(r["wall_s"]["diagnose"] for r in ok)
    if walls:
        out.append(f"diagnosis wall per case: median {walls[len(walls) // 2]:.1f} s, "
                   f"worst {walls[-1]:.1f} s")
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int)
    ap.add_argument("--n", type=int, default=40)
    ap.add_argument("--jobs", type=int, default=max(1, min(2, os.cpu_count() or 1)))
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--law", choices=list(fc.LAWS))
    ap.add_argument("--out")
    ap.add_argument("--tables")
    a = ap.parse_args(argv)
    if a.tables:
        print("\n".join(tables(json.loads(Path(a.tables).read_text())["rows"])))
        return 0
    if a.seed is None:
        ap.error("--seed is required (use a fresh one, e.g. `date +%s`)")
    print(__doc__.split("Method: ")[1].split("Use a fresh")[0].strip())
    print(f"seeds {a.seed}..{a.seed + a.n - 1}, {a.duration:g} s drives, {a.jobs} jobs")
    rows: list[dict] = []
    t0 = time.perf_counter()
    with ProcessPoolExecutor(a.jobs) as pool:
        futs = [pool.submit(run_case, a.seed + i, a.duration, a.law) for i in range(a.n)]
        for i, f in enumerate(as_completed(futs), 1):
            r = f.result()
            rows.append(r)
            print(f"[{i}/{a.n}] {r['seed']} {r['law']}: "
                  + (r["error"] if "error" in r else
                     f"{r['strength_ratio']:.1f}x {r['verdict']} {r['named']}"),
                  file=sys.stderr, flush=True)
            if a.out:
                Path(a.out).write_text(json.dumps({"seed": a.seed, "rows": rows}, default=str))
    rows.sort(key=lambda r: r["seed"])
    if a.out:
        Path(a.out).write_text(json.dumps({"seed": a.seed, "rows": rows}, default=str))
    print("\n".join(tables(rows)))
    print(f"wall {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
