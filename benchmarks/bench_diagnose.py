"""Diagnosis over the whole scenario catalogue (not a test: prints a score table).

Method: every scenario of fielddiag.scenarios (concealed single effects at three sizes,
pairs of effects, an effect outside the library, linear cars including noisy/short/200 Hz
and bias-drifting ones, and sensor problems) is simulated from its seed and diagnosed with
fielddiag.diagnose.engine.diagnose_drives. Printed per case: the verdict, the effects named
(first = ranked first), parameter errors against the truth, the data warnings, the linear
and augmented held-out NRMSE, and wall time. For cases whose effects are all in the
library, also the noise floor: the held-out NRMSE of the true model structure (the true
effects, fitted like the candidates from the true values, engine.known_model_nrmse), and
the ratio linear NRMSE / floor (how far the effect stands above the noise: 1.3-2 is a
small effect). Then the scores: top-1 effect correct, false alarms on linear cases, worst
parameter error, unexplained found, sensor problems flagged.

With ``--reseed N`` every scenario is drawn again with its seed shifted by N (new roads,
speeds and sensor noise; the effects and their sizes stay), and a per-family table is
printed: effect family and size (small = near the noise floor), cases, top-1 correct,
false alarms, nuisance (sensor) problems flagged, outside the library reported unexplained.

Usage: python benchmarks/bench_diagnose.py [--reseed N] [NAME ...]
"""

from __future__ import annotations

import dataclasses
import sys
import time

from fielddiag.diagnose.engine import EFFECT_LIBRARY, Drive, diagnose_drives, known_model_nrmse
from fielddiag.scenarios import SCENARIOS, Scenario, simulate_scenario


def true_values(sc: Scenario) -> dict[str, float]:
    """The scenario's true parameters by model key (start values of the floor fit)."""
    car = sc.car
    vals = {
        "body_mass_kg": car.body_mass_kg,
        "linear_spring.suspension_stiffness_n_per_m": car.suspension_stiffness_n_per_m,
        "linear_damper.suspension_damping_ns_per_m": car.suspension_damping_ns_per_m,
        "coupling_spring.coupling_stiffness_n_per_m": car.coupling_stiffness_n_per_m,
    }
    for eff, params in sc.effects:
        vals.update({f"{eff}.{k}": v for k, v in params.items()})
    return vals


def noise_floor(sc: Scenario, drives: list[Drive]) -> float | None:
    """Held-out NRMSE of the true model structure (None outside the library)."""
    effects = [e for e, _ in sc.effects]
    if not effects or any(e not in EFFECT_LIBRARY for e in effects):
        return None
    return known_model_nrmse(
        drives,
        effects,
        initial=true_values(sc),
        coupling=sc.car.coupling_stiffness_n_per_m != 0.0,
    )


RESEED = 0


def run(name: str, floor: bool = False) -> dict:
    sc = SCENARIOS[name]
    if RESEED:
        sc = dataclasses.replace(sc, seed=sc.seed + RESEED)
    before, after = simulate_scenario(sc)
    drives = [
        Drive(
            d.wheel_accel_mps2, d.body_accel_mps2, d.sample_rate_hz,
            added_mass_kg=d.added_mass_kg, label=lab, name=name,
        )
        for lab, d in (("before", before), ("after", after))
    ]
    t0 = time.perf_counter()
    out = diagnose_drives(drives).to_dict()
    wall = time.perf_counter() - t0
    nf = noise_floor(sc, drives) if floor else None
    named = [f["effect"] for f in out["findings"]]
    errors = []
    for eff, params in sc.effects:
        f = next((f for f in out["findings"] if f["effect"] == eff), None)
        for key, true in params.items():
            if f is not None and key in f["parameters"]:
                errors.append(abs(f["parameters"][key] / true - 1.0))
    return {
        "name": name,
        "sc": sc,
        "out": out,
        "named": named,
        "errors": errors,
        "warnings": [w["kind"] for w in out["warnings"]],
        "wall": wall,
        "floor": nf,
        "ratio": None if nf is None else out["baseline"]["nrmse_validation"] / nf,
    }


def family(sc: Scenario) -> str:
    """The row of the per-family table a scenario counts in."""
    if sc.expected_warnings and not sc.expected_effects:
        return "nuisance: " + ",".join(sc.expected_warnings)
    if not sc.expected_effects:
        return "linear"
    if sc.expected_effects == ("unexplained",):
        return "outside the library"
    return " + ".join(sc.expected_effects) + (" (small)" if sc.small else "")


def family_table(rows: list[dict]) -> None:
    print(f"\n{'family':<44} {'cases':>5}  {'right':>5}  what 'right' means")
    fams: dict[str, list[dict]] = {}
    for r in rows:
        fams.setdefault(family(r["sc"]), []).append(r)
    for fam, rs in sorted(fams.items()):
        sc = rs[0]["sc"]
        if fam == "linear":
            ok, what = sum(r["out"]["verdict"] != "missing_physics" for r in rs), "no alarm"
        elif fam.startswith("nuisance"):
            ok = sum(set(r["sc"].expected_warnings) <= set(r["warnings"]) for r in rs)
            what = "flagged as a data problem"
        elif fam == "outside the library":
            ok, what = sum("unexplained" in r["named"] for r in rs), "reported unexplained"
        else:
            ok = sum(bool(r["named"]) and r["named"][0] in sc.expected_effects for r in rs)
            what = "top-1 effect correct"
        ratios = [r["ratio"] for r in rs if r["ratio"] is not None]
        strength = f"; linear/floor {min(ratios):.2f}-{max(ratios):.2f}" if ratios else ""
        print(f"{fam:<44} {len(rs):>5}  {ok:>5}  {what}{strength}")


def main() -> None:
    global RESEED
    args = sys.argv[1:]
    if args[:1] == ["--reseed"]:
        RESEED, args = int(args[1]), args[2:]
    names = args or list(SCENARIOS)
    print(__doc__)
    rows = []
    for name in names:
        r = run(name, floor=True)
        rows.append(r)
        out = r["out"]
        err = f"{100 * max(r['errors']):.1f} %" if r["errors"] else "-"
        ratio = "" if r["ratio"] is None else f" floor {r['floor']:.3f} ratio {r['ratio']:.2f}"
        print(
            f"{name:<26} {out['verdict']:<16} named {','.join(r['named']) or '-':<40} "
            f"param err {err:>7}  warn {','.join(r['warnings']) or '-':<32} NRMSE "
            f"{out['baseline']['nrmse_validation']:.3f} -> "
            f"{out['augmented']['nrmse_validation']:.3f}  {r['wall']:.0f} s{ratio}",
            flush=True,
        )
    effect_cases = [
        r for r in rows if r["sc"].expected_effects and r["sc"].expected_effects != ("unexplained",)
    ]
    top1 = sum(bool(r["named"]) and r["named"][0] in r["sc"].expected_effects for r in effect_cases)
    both = sum(set(r["sc"].expected_effects) <= set(r["named"]) for r in effect_cases)
    linear = [
        r
        for r in rows
        if not r["sc"].expected_effects
        and not r["sc"].expected_warnings
        or r["name"] == "linear_bias_drift"
    ]
    false_alarms = sum(r["out"]["verdict"] == "missing_physics" for r in linear)
    errs = [e for r in effect_cases for e in r["errors"]]
    outside = [r for r in rows if r["sc"].expected_effects == ("unexplained",)]
    sensors = [r for r in rows if r["sc"].expected_warnings]
    flagged = sum(set(r["sc"].expected_warnings) <= set(r["warnings"]) for r in sensors)
    print()
    print(f"top-1 effect correct      {top1}/{len(effect_cases)}")
    print(f"all effects of a case named {both}/{len(effect_cases)}")
    print(f"false alarms (linear)     {false_alarms}/{len(linear)}")
    if errs:
        errs.sort()
        print(
            f"parameter error           median {100 * errs[len(errs) // 2]:.1f} %, "
            f"worst {100 * errs[-1]:.1f} %"
        )
    print(
        f"outside the library -> unexplained "
        f"{sum('unexplained' in r['named'] for r in outside)}/{len(outside)}"
    )
    print(f"sensor problems flagged   {flagged}/{len(sensors)}")
    print(f"wall time                 {sum(r['wall'] for r in rows):.0f} s for {len(rows)} cases")
    family_table(rows)


if __name__ == "__main__":
    main()
