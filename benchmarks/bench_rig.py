"""Rig mode on a simulated 610 Hz Duffing oscillator, on linear oscillators at fs/f_res from
5 to 100, and on the 52 real MR-damper records (issue 16 item 5).

Method
------
* Duffing: ``m x'' + c x' + k x + k3 x^3 = f`` simulated by
  :func:`fielddiag.sim.oscillator.simulate_oscillator` (fs 610 Hz, resonance drawn in
  55-65 Hz, damping ratio 2-6 %, k3 drawn so that the cubic force at 2.5 displacement std
  is 5-20 % of the linear spring's, sensor noise 0.5-2 % of each channel's std). Each case
  is fitted on one record (band-limited noise) and validated on another of the same
  oscillator (a random-phase multisine, another seed). Reported: the first finding, the
  k3 error, the held-out NRMSE on the other record, the band chosen.
* Ratio sweep: the same with fs/f_res in {5, 10, 20, 50, 100}, and linear oscillators
  (no effect) at the same ratios, which must give no finding. The drive spans 0.1-2 f_res,
  capped at fs/6 so that the cubic's third harmonic stays below Nyquist (at fs/f_res = 5
  this drives below the resonance); one line (*) shows fs/f_res = 5 driven to 2 f_res =
  0.8 Nyquist, where the harmonics alias into the band and no sampled-data fit can recover
  k3 exactly.
* The 610 Hz / 60 Hz cases drive 0.1-2 f_res (to about 120 Hz, the simulator's default;
  not capped).
* MR damper: each of the 52 records of ``shared/data/mr_damper`` (mm converted to m) is
  diagnosed twice: "before" with the candidates rig mode had before the build-up
  hysteresis (friction, cubic, bump stop, asymmetric damping, Dahl friction), "after" with
  today's (:data:`fielddiag.diagnose.rig.RIG_EFFECTS`). Within: the held-out NRMSE on the
  record's last 30 %. Cross: the chosen model (fitted on the first 70 %) scored on all of
  another record with the load-cell offset re-estimated there (it differs between files:
  +100 N in most, -15..0 N in ``exp*``, ``ensaio15/16``); the internal states start at
  rest and warm up on the first 0.5 s of motion, not scored. Three pairings: (a) every
  ordered pair of the README's two coil-voltage families; (b) every ordered pair of a
  naming group (``ensaioN`` with ``ensaioNa`` and ``exp*``; ``ensaioN.1``; ``ensaioN.2``;
  ``ensaioN.2.2``), whose force levels differ systematically at the same stroke and speed
  (other coil currents or days); (c) the next record of the family at the same sample
  rate (sorted names, cyclic). "Scaled": the same with one force scale re-estimated on
  the other record as well (what a change of coil current does, to first order): a check
  of the model's form across operating points, not a prediction. NRMSE = residual std /
  force std, both through the validation record's band. Parameter spread per family and
  per naming group: median, inter-quartile range and range over the records.

Seeds are fresh every run (printed); ``--seed`` repeats a run. Nothing is tuned on them.

Usage: ``python benchmarks/bench_rig.py [--seed S] [--cases N] [--skip-mr | --only-mr]
[--forced]`` (``--forced``: also score Coulomb friction + build-up hysteresis on every MR
record, whatever the selection chose: a diagnostic of the selection)
"""

from __future__ import annotations

import argparse
import csv
import os
import sys
import time
from pathlib import Path

import numpy as np

from fielddiag.diagnose import rig as rigmod
from fielddiag.diagnose.rig import diagnose_rig, rig_data_from_displacement
from fielddiag.sim import make_effect

MR_DIR = Path(os.environ.get("FIELDDIAG_SHARED_DATA", "/work/shared/data")) / "mr_damper"


def cross_nrmse(cand, other) -> float:
    """NRMSE of a fitted candidate on another record, offset re-estimated."""
    model, z = cand.extra["model"], np.array(cand.extra["z"], float)
    res, _ = rigmod._residual_and_jac(model, z, other)
    res = res - res.mean()
    return float(res.std() / other.force.std())


def duffing_case(rng: np.random.Generator, fs: float, f_res: float, effect: bool,
                 alias_safe: bool = True) -> dict:
    from fielddiag.sim.oscillator import simulate_oscillator

    top = min(2.0 * f_res, 0.42 * fs)
    if alias_safe:
        top = min(top, fs / 6.0)  # the cubic's 3rd harmonic stays below Nyquist
    band = (0.1 * f_res, top)
    zeta = rng.uniform(0.02, 0.06)
    noise = rng.uniform(0.005, 0.02)
    m = 0.5
    k = m * (2 * np.pi * f_res) ** 2
    force_rms = 20.0
    seed = int(rng.integers(2**31))
    effects = ()
    k3 = 0.0
    if effect:
        # linear response std, to set the cubic's strength relative to the spring
        probe = simulate_oscillator(resonance_hz=f_res, damping_ratio=zeta, band_hz=band,
                                    force_rms_n=force_rms, sample_rate_hz=fs, duration_s=5,
                                    seed=seed)
        sx = probe.true_displacement_m.std()
        k3 = rng.uniform(0.05, 0.2) * k / (2.5 * sx) ** 2
        effects = (make_effect("cubic_stiffness", cubic_stiffness_n_per_m3=k3),)
    common = dict(moving_mass_kg=m, resonance_hz=f_res, damping_ratio=zeta, effects=effects,
                  band_hz=band,
                  force_rms_n=force_rms, sample_rate_hz=fs, duration_s=30.0,
                  force_noise_rel=noise, displacement_noise_rel=noise, preload_n=5.0)
    fit_rec = simulate_oscillator(excitation="noise", seed=seed, **common)
    val_rec = simulate_oscillator(excitation="multisine", seed=seed + 1, **common)
    fit = rig_data_from_displacement(fit_rec.time_s, fit_rec.force_n, fit_rec.displacement_m, fs)
    val = rig_data_from_displacement(val_rec.time_s, val_rec.force_n, val_rec.displacement_m, fs)
    t0 = time.perf_counter()
    diag = diagnose_rig(fit)
    secs = time.perf_counter() - t0
    out = diag.to_dict()
    first = out["findings"][0]["effect"] if out["findings"] else "-"
    k3_fit = next((f["parameters"]["cubic_stiffness_n_per_m3"] for f in out["findings"]
                   if f["effect"] == "cubic_stiffness"), float("nan"))
    band = out.get("band", {})
    return {"seed": seed, "fs": fs, "f_res": f_res, "k3": k3, "k3_fit": k3_fit,
            "k3_err": (k3_fit / k3 - 1) if k3 else float("nan"), "first": first,
            "n_findings": len(out["findings"]), "verdict": out["verdict"],
            "nrmse_val_lin": out["baseline"]["nrmse_validation"],
            "nrmse_other": cross_nrmse(diag.selection.chosen, val), "cutoff": band.get("cutoff_hz"),
            "resonance": band.get("resonance_hz"), "mass": out["parameters"]["moving_mass_kg"]
            ["value"], "secs": secs}


def _fmt(x, spec=".3g"):
    return "-" if x is None or (isinstance(x, float) and not np.isfinite(x)) else format(x, spec)


def run_duffing(rng, n_cases: int) -> None:
    print(f"\n== Duffing oscillator, fs 610 Hz, resonance 55-65 Hz: {n_cases} fresh cases ==")
    print("fit on band-limited noise, validate on a multisine record of the same oscillator")
    print(f"{'seed':>11} {'f_res':>6} {'k3 true':>9} {'k3 fit':>9} {'k3 err':>7} {'first':>16} "
          f"{'NRMSE other':>11} {'cutoff':>7} {'res. det':>8} {'m kg':>6} {'s':>5}")
    rows = []
    for _ in range(n_cases):
        r = duffing_case(rng, 610.0, rng.uniform(55, 65), True, alias_safe=False)
        rows.append(r)
        print(f"{r['seed']:>11} {r['f_res']:6.2f} {r['k3']:9.3g} {r['k3_fit']:9.3g} "
              f"{100 * r['k3_err']:+6.2f}% {r['first']:>16} {r['nrmse_other']:11.4f} "
              f"{_fmt(r['cutoff']):>7} {_fmt(r['resonance']):>8} {r['mass']:6.3f} "
              f"{r['secs']:5.1f}")
    first = sum(r["first"] == "cubic_stiffness" for r in rows)
    within = sum(abs(r["k3_err"]) <= 0.05 for r in rows)
    errs = np.array([r["k3_err"] for r in rows])
    print(f"cubic named first {first}/{len(rows)}; k3 within 5 % {within}/{len(rows)}; "
          f"k3 error mean {100 * np.nanmean(errs):+.2f} %, max |err| "
          f"{100 * np.nanmax(np.abs(errs)):.2f} %")


def run_ratios(rng, per_ratio: int) -> None:
    print(f"\n== fs/f_res sweep (fs 610 Hz), {per_ratio} cubic + {per_ratio} linear cases per "
          "ratio ==")
    print(f"{'fs/f_res':>8} {'cubic first':>11} {'k3 within 5%':>12} {'max |k3 err|':>12} "
          f"{'linear: findings':>16} {'cutoffs (Hz)':>24}")
    fa_total = n_lin = 0
    for ratio in (5, 10, 20, 50, 100):
        if ratio == 5:
            cub = [duffing_case(rng, 610.0, 610.0 / ratio, True, alias_safe=False)
                   for _ in range(per_ratio)]
            errs = np.abs([r["k3_err"] for r in cub])
            print(f"{'5 (*)':>8} {sum(r['first'] == 'cubic_stiffness' for r in cub):>7}/"
                  f"{len(cub)} {int(np.sum(errs <= 0.05)):>8}/{len(cub)} "
                  f"{100 * np.nanmax(errs):11.2f}%   (*) drive to 2 f_res = 0.8 Nyquist: the "
                  "cubic's harmonics alias")
        f_res = 610.0 / ratio
        cub = [duffing_case(rng, 610.0, f_res, True) for _ in range(per_ratio)]
        lin = [duffing_case(rng, 610.0, f_res, False) for _ in range(per_ratio)]
        fa = sum(r["n_findings"] > 0 for r in lin)
        fa_total += fa
        n_lin += len(lin)
        errs = np.abs([r["k3_err"] for r in cub])
        cut = ", ".join(_fmt(r["cutoff"], ".0f") for r in cub + lin)
        print(f"{ratio:8d} {sum(r['first'] == 'cubic_stiffness' for r in cub):>7}/{len(cub)} "
              f"{int(np.sum(errs <= 0.05)):>8}/{len(cub)} {100 * np.nanmax(errs):11.2f}% "
              f"{fa:>12}/{len(lin)} {cut:>24}")
        for r in lin:
            if r["n_findings"]:
                print(f"    false alarm: seed {r['seed']} first {r['first']}")
    print(f"false alarms on linear oscillators: {fa_total}/{n_lin}")


def _family(name: str) -> str:
    """The README's coil-voltage family of a record (file name or stem)."""
    stem = name[:-4] if name.endswith(".csv") else name
    return "high" if stem.endswith(".2") or stem.endswith(".2.2") else "low"


def _naming_group(stem: str) -> str:
    """The naming group of a record: ``N``, ``N.1``, ``N.2`` or ``N.2.2`` (plain names,
    ``ensaioNa`` and ``exp*`` are ``N``). The groups sit at systematically different force
    levels at the same stroke and speed (other coil currents or days)."""
    for tail in (".2.2", ".2", ".1"):
        if stem.endswith(tail):
            return "N" + tail
    return "N"


def load_mr(path: Path):
    with path.open() as fh:
        rows = list(csv.DictReader(fh))
    t = np.array([float(r["time_s"]) for r in rows])
    x = np.array([float(r["displacement_mm"]) for r in rows]) * 1e-3
    f = np.array([float(r["force_N"]) for r in rows])
    fs = 1.0 / float(np.median(np.diff(t)))
    return rig_data_from_displacement(t, f, x, fs)


#: Rig mode's candidates before the build-up hysteresis (Dahl friction the only hysteresis).
BEFORE_EFFECTS = tuple(e for e in rigmod.RIG_EFFECTS if e != "buildup_hysteresis")
#: Effects that are hysteresis (internal states with a rate-independent loop).
HYSTERESIS = {"hysteretic_spring", "dahl_friction", "bouc_wen", "buildup_hysteresis"}


def scaled_cross_nrmse(cand, other) -> float:
    """NRMSE of a fitted candidate on another record with the load-cell offset AND one
    force scale re-estimated there (the whole model force times ``s``: what a change of
    coil current does to an MR damper, to first order). Not a prediction: a check of the
    model's form across operating points."""
    model, z = cand.extra["model"], np.array(cand.extra["z"], float)
    z[0] = 0.0
    res, _ = rigmod._residual_and_jac(model, z, other, state_jacobian=False)
    pred = other.force - res
    a = np.column_stack([np.ones_like(pred), pred])
    coef, *_ = np.linalg.lstsq(a, other.force, rcond=None)
    r = other.force - a @ coef
    return float(r.std() / other.force.std())


def _spread(vals) -> str:
    v = np.asarray([x for x in vals if np.isfinite(x)], float)
    if not v.size:
        return "-"
    q1, med, q3 = np.percentile(v, [25, 50, 75])
    rel = f"{100 * (q3 - q1) / abs(med):5.1f} %" if med else "    - "
    return (f"median {med:10.4g}  IQR {q1:10.4g} .. {q3:10.4g}  (IQR/median {rel})  "
            f"range {v.min():.4g} .. {v.max():.4g}  n={v.size}")


def _med(vals) -> str:
    v = np.asarray(list(vals), float)
    if not v.size:
        return "-"
    return (f"{np.median(v):.4f} (IQR {np.percentile(v, 25):.4f}-{np.percentile(v, 75):.4f}, "
            f"n={v.size})")


#: ``--forced``: the model the MR records favour across strokes, scored on every record
#: whatever the selection chose (a diagnostic of the selection, not what rig mode reports).
FORCED = ("coulomb_friction", "buildup_hysteresis")


def run_mr(forced: bool = False) -> None:
    files = sorted(MR_DIR.glob("*.csv"))
    print(f"\n== real MR damper: {len(files)} records in {MR_DIR} ==")
    if not files:
        print("no records found")
        return
    print("before: rig mode with", BEFORE_EFFECTS)
    print("after:  rig mode with", rigmod.RIG_EFFECTS)
    print("within: held-out NRMSE on the record's last 30 % (fitted on the first 70 %)")
    print("cross:  the chosen model (fitted on the first 70 % of a record) scored on all of "
          "another record, load-cell offset\n        re-estimated there; the states start at "
          "rest and warm up on the first 0.5 s of motion, not scored.\n"
          "        (a) every other record of the README family (ordered pairs); (b) every "
          "other record of the naming group\n        (N, N.1, N.2, N.2.2); (c) the next "
          "record of the family at the same sample rate (sorted names, cyclic)")
    print("scaled: as cross, with one force scale re-estimated on the other record too "
          "(offset + scale: a current change), not a prediction")
    stems = [p.stem for p in files]
    data = {p.stem: load_mr(p) for p in files}
    fam = {n: _family(n) for n in stems}
    grp = {n: _naming_group(n) for n in stems}
    rate = {n: round(data[n].sample_rate_hz) for n in stems}
    fams = sorted(set(fam.values()))

    def next_of(n: str) -> str:
        group = [m for m in stems if fam[m] == fam[n]]
        sub = [m for m in group if rate[m] == rate[n]]
        sub = sub if len(sub) > 1 else group
        return sub[(sub.index(n) + 1) % len(sub)]

    print(f"{'record':>12} {'fam':>4} {'group':>5} {'fs':>5} | {'before':>30} {'within':>6} "
          f"| {'after':>42} {'within':>6} {'s':>5}")
    rows = []
    for n in stems:
        d = data[n]
        before = diagnose_rig(d, effects=BEFORE_EFFECTS)
        t0 = time.perf_counter()
        after = diagnose_rig(d)
        secs = time.perf_counter() - t0
        ob, oa = before.to_dict(), after.to_dict()
        nb = [f["effect"] for f in ob["findings"]]
        na = [f["effect"] for f in oa["findings"]]
        params = {f["effect"] + "." + k: v for f in oa["findings"]
                  for k, v in {**f.get("parameters", {}), **f.get("shape", {})}.items()}
        params["damping"] = oa["parameters"]["damping"]["value"]
        params["stiffness"] = oa["parameters"]["stiffness"]["value"]
        others = [m for m in stems if m != n and fam[m] == fam[n]]
        r = {"name": n, "fam": fam[n], "grp": grp[n], "named_before": nb, "named": na,
             "within_before": ob["augmented"]["nrmse_validation"],
             "within_after": oa["augmented"]["nrmse_validation"],
             "params": params, "secs": secs, "next": next_of(n)}
        models = [("before", before.selection.chosen), ("after", after.selection.chosen)]
        if forced:
            cand = next((c for c, _ in after.selection.ranking if c.effects == FORCED), None)
            if cand is None:  # not tried there (its effects did not help alone)
                cand = diagnose_rig(d, effects=FORCED).selection.chosen
            r["within_forced"] = cand.nrmse_validation
            models.append(("forced", cand))
        for key, ch in models:
            r[f"cross_{key}"] = {m: cross_nrmse(ch, data[m]) for m in others}
            r[f"scaled_{key}"] = {m: scaled_cross_nrmse(ch, data[m]) for m in others}
        rows.append(r)
        print(f"{n:>12} {fam[n]:>4} {grp[n]:>5} {d.sample_rate_hz:5.1f} | {'+'.join(nb):>30} "
              f"{r['within_before']:6.4f} | {'+'.join(na):>42} {r['within_after']:6.4f} "
              f"{secs:5.1f}", flush=True)
    n_rec = len(rows)
    hyst = sum(any(e in HYSTERESIS for e in r["named"]) for r in rows)
    first = sum(bool(r["named"]) and r["named"][0] in HYSTERESIS for r in rows)
    print(f"\nafter: hysteresis named on {hyst}/{n_rec}, first on {first}/{n_rec}; "
          f"build-up hysteresis chosen on "
          f"{sum('buildup_hysteresis' in r['named'] for r in rows)}/{n_rec}, Dahl friction on "
          f"{sum('dahl_friction' in r['named'] for r in rows)}/{n_rec}; Coulomb friction "
          f"added on {sum('coulomb_friction' in r['named'] for r in rows)}/{n_rec}; "
          f"'unexplained' left on {sum('unexplained' in r['named'] for r in rows)}/{n_rec}")

    def pairs(key: str, which: str, pick) -> list[float]:
        return [v for r in rows for m, v in r[f"{key}_{which}"].items() if pick(r, m)]

    whiches = ("before", "after", "forced") if forced else ("before", "after")

    def line(label: str, key: str, pick) -> None:
        for i, which in enumerate(whiches):
            print(f"  {label if i == 0 else '':<46} {which:<6} {_med(pairs(key, which, pick))}")

    if forced:
        print(f"forced: {'+'.join(FORCED)} on every record, whatever the selection chose "
              "(a diagnostic, not what rig mode reports)")
    print("\nheld-out NRMSE, medians (IQR, number of values)")
    for which in whiches:
        print(f"  {'within-record (' + which + ')':<46} "
              f"{_med([r[f'within_{which}'] for r in rows])}")
    line("(a) cross, all ordered pairs of the family", "cross", lambda r, m: True)
    for f in fams:
        line(f"    family {f}", "cross", lambda r, m, f=f: r["fam"] == f)
    line("(b) cross, all ordered pairs of the naming group", "cross",
         lambda r, m: grp[m] == r["grp"])
    for g in ("N", "N.1", "N.2", "N.2.2"):
        line(f"    group {g}", "cross", lambda r, m, g=g: r["grp"] == g and grp[m] == g)
    line("(c) cross, next record of the family and rate", "cross", lambda r, m: m == r["next"])
    print("\nwith one force scale re-estimated per validation record (not a prediction):")
    line("(a) scaled, all ordered pairs of the family", "scaled", lambda r, m: True)
    line("(b) scaled, all ordered pairs of the naming group", "scaled",
         lambda r, m: grp[m] == r["grp"])
    print("\nparameter spread (after; records whose chosen model has the parameter):")
    for label, pick in ([(f"family {f}", lambda r, f=f: r["fam"] == f) for f in fams]
                        + [(f"group {g}", lambda r, g=g: r["grp"] == g)
                           for g in ("N", "N.1", "N.2", "N.2.2")]):
        sel = [r for r in rows if pick(r)]
        keys = sorted({k for r in sel for k in r["params"]})
        print(f"  {label} ({len(sel)} records)")
        for k in keys:
            print(f"    {k:>52}: {_spread([r['params'].get(k, np.nan) for r in sel])}")
    print(f"time per record (after): median {np.median([r['secs'] for r in rows]):.1f} s, "
          f"max {max(r['secs'] for r in rows):.1f} s")


def run_mr_evidence() -> None:
    """Does the MR damper's loop depend on where the stroke turned? Per naming group, the
    loop height (force on the extending branch minus force on the compressing branch) at
    4-6 mm of displacement, against the stroke and the speed there; a least-squares line
    ``height = h0 + a stroke + b speed`` over the group's records separates the two. A
    spring, or a friction level that depends on the position, gives the same height at the
    same place and speed whatever the stroke (``a`` = 0); a force that builds up with the
    travel since the reversal gives ``a`` > 0."""
    files = sorted(MR_DIR.glob("*.csv"))
    print("\n== MR damper: loop height at 4-6 mm against stroke and speed ==")
    by_group: dict[str, list[tuple[str, float, float, float]]] = {}
    for p in files:
        d = load_mr(p)
        x_mm = 1e3 * d.displacement
        at = (x_mm > 4.0) & (x_mm < 6.0)
        up, down = at & (d.velocity > 0), at & (d.velocity < 0)
        if up.sum() < 5 or down.sum() < 5:
            continue
        height = float(np.median(d.force[up]) - np.median(d.force[down]))
        speed = 1e3 * float(np.median(d.velocity[up]) - np.median(d.velocity[down])) / 2
        by_group.setdefault(_naming_group(p.stem), []).append(
            (p.stem, float(np.ptp(x_mm)), speed, height))
    for g, rows in sorted(by_group.items()):
        rows.sort(key=lambda r: r[1])
        st, sp, h = (np.array([r[i] for r in rows]) for i in (1, 2, 3))
        a = np.column_stack([np.ones_like(st), st, sp])
        coef, *_ = np.linalg.lstsq(a, h, rcond=None)
        print(f"  group {g:5} ({len(rows)} records): height = {coef[0]:.0f} N + {coef[1]:.2f} N "
              f"per mm of stroke + {coef[2]:.2f} N per mm/s of speed")
        print("    " + ", ".join(f"{n} {s_:.0f} mm {v:.0f} mm/s {hh:.0f} N"
                                  for n, s_, v, hh in rows))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=None, help="repeat a run (default: fresh)")
    ap.add_argument("--cases", type=int, default=6, help="Duffing cases at 610 Hz/60 Hz")
    ap.add_argument("--per-ratio", type=int, default=2, help="cases per fs/f_res ratio")
    ap.add_argument("--skip-mr", action="store_true")
    ap.add_argument("--only-mr", action="store_true")
    ap.add_argument("--evidence", action="store_true",
                    help="MR records: loop height against stroke and speed, then stop")
    ap.add_argument("--forced", action="store_true",
                    help="MR records: also score coulomb + build-up hysteresis on every record")
    a = ap.parse_args(argv)
    seed = a.seed if a.seed is not None else int.from_bytes(os.urandom(4), "little")
    print(f"bench_rig: master seed {seed} (repeat with --seed {seed})")
    rng = np.random.default_rng(seed)
    t0 = time.perf_counter()
    if not a.only_mr:
        run_duffing(rng, a.cases)
        run_ratios(rng, a.per_ratio)
    if a.evidence:
        run_mr_evidence()
    elif not a.skip_mr:
        run_mr(a.forced)
    print(f"\ntotal {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
