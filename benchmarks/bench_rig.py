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
  diagnosed twice: "before" with the memoryless candidates rig mode had before issue 17
  (friction, cubic, bump stop, asymmetric damping), "after" with today's candidates
  (:data:`fielddiag.diagnose.rig.RIG_EFFECTS`, with Dahl friction: hysteresis). Within:
  the held-out NRMSE on the record's last 30 %. Cross: the chosen model (fitted on the
  first 70 %) scored on the next record of the same coil-voltage family recorded at the
  same sample rate (sorted names, cyclic), with the load-cell offset re-estimated there
  (it differs between files: +100 N in most, -15..0 N in ``exp*``, ``ensaio15/16``); the
  internal states start at rest and warm up on the first 0.5 s of motion, not scored.
  Also printed: the next record of the family at any rate, and all ordered pairs. The
  records at 100 Hz (``ensaioN.1``, ``*a``) and at 50 Hz (``ensaioN``) of the low family
  differ in force level at the same stroke and speed (force std about 91 vs 77 N, friction
  about 66 vs 56 N): another operating point, which no model of one record predicts.
  NRMSE = residual std / force std, both through the validation record's band.
  Parameter spread per family: median, inter-quartile range and range over the records.

Seeds are fresh every run (printed); ``--seed`` repeats a run. Nothing is tuned on them.

Usage: ``python benchmarks/bench_rig.py [--seed S] [--cases N] [--skip-mr]``
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
    stem = name[:-4]
    return "high" if stem.endswith(".2") or stem.endswith(".2.2") else "low"


def load_mr(path: Path):
    with path.open() as fh:
        rows = list(csv.DictReader(fh))
    t = np.array([float(r["time_s"]) for r in rows])
    x = np.array([float(r["displacement_mm"]) for r in rows]) * 1e-3
    f = np.array([float(r["force_N"]) for r in rows])
    fs = 1.0 / float(np.median(np.diff(t)))
    return rig_data_from_displacement(t, f, x, fs)


#: Rig mode's candidates before hysteresis was modelled (memoryless effects only).
BEFORE_EFFECTS = ("coulomb_friction", "cubic_stiffness", "bump_stop", "asymmetric_damping")
#: Effects with an internal state (hysteresis).
HYSTERESIS = {"hysteretic_spring", "dahl_friction", "bouc_wen"}


def _spread(vals) -> str:
    v = np.asarray([x for x in vals if np.isfinite(x)], float)
    if not v.size:
        return "-"
    q1, med, q3 = np.percentile(v, [25, 50, 75])
    return (f"median {med:10.4g}  IQR {q1:10.4g} .. {q3:10.4g}  (IQR/median "
            f"{100 * (q3 - q1) / abs(med):5.1f} %)  range {v.min():.4g} .. {v.max():.4g}  "
            f"n={v.size}")


def run_mr() -> None:
    files = sorted(MR_DIR.glob("*.csv"))
    print(f"\n== real MR damper: {len(files)} records in {MR_DIR} ==")
    if not files:
        print("no records found")
        return
    print("before: rig mode with the memoryless candidates", BEFORE_EFFECTS)
    print("after:  rig mode with", rigmod.RIG_EFFECTS)
    print("within: held-out NRMSE on the record's last 30 % (fitted on the first 70 %)")
    print("cross:  the model fitted (first 70 %) on a record, scored on all of the NEXT record of "
          "its family recorded at the\n        same sample rate (sorted names, cyclic; a record "
          "alone at its rate: the next of its family); load-cell\n        offset re-estimated "
          "there; the states start at rest and warm up on the first 0.5 s of motion, not scored")
    print("cross any rate: the same on the next record of the family regardless of its rate")
    print("all-pairs: the same on every other record of the family (and rate), median over "
          "ordered pairs")
    fams: dict[str, list[Path]] = {}
    for p in files:
        fams.setdefault(_family(p.name), []).append(p)
    data = {p: load_mr(p) for p in files}
    rate = {p: round(data[p].sample_rate_hz) for p in files}

    def same_rate(group: list[Path], p: Path) -> list[Path]:
        g = [q for q in group if rate[q] == rate[p]]
        return g if len(g) > 1 else group
    print(f"{'record':>12} {'fam':>4} {'fs':>5} | {'before first':>16} {'within':>6} "
          f"{'cross':>6} | "
          f"{'after effects':>40} {'within':>6} {'cross':>6} {'s':>5} | validated on "
          "(cross any rate: before -> after)")
    rows = []
    for fam, group in fams.items():
        for i, p in enumerate(group):
            sub = same_rate(group, p)
            other = sub[(sub.index(p) + 1) % len(sub)]
            other_any = group[(i + 1) % len(group)]
            before = diagnose_rig(data[p], effects=BEFORE_EFFECTS)
            t0 = time.perf_counter()
            after = diagnose_rig(data[p])
            secs = time.perf_counter() - t0
            ob, oa = before.to_dict(), after.to_dict()
            fb = ob["findings"][0]["effect"] if ob["findings"] else "-"
            named = [f["effect"] for f in oa["findings"]]
            params = {f["effect"] + "." + k: v for f in oa["findings"]
                      for k, v in {**f.get("parameters", {}), **f.get("shape", {})}.items()}
            params["damping"] = oa["parameters"]["damping"]["value"]
            params["stiffness"] = oa["parameters"]["stiffness"]["value"]
            fc_before = next((f["parameters"]["friction_force_n"] for f in ob["findings"]
                              if f["effect"] == "coulomb_friction"), float("nan"))
            r = {"name": p.stem, "fam": fam, "first_before": fb, "named": named,
                 "within_before": ob["augmented"]["nrmse_validation"],
                 "within_after": oa["augmented"]["nrmse_validation"],
                 "cross_before": cross_nrmse(before.selection.chosen, data[other]),
                 "cross_after": cross_nrmse(after.selection.chosen, data[other]),
                 "any_before": cross_nrmse(before.selection.chosen, data[other_any]),
                 "any_after": cross_nrmse(after.selection.chosen, data[other_any]),
                 "pairs_before": [cross_nrmse(before.selection.chosen, data[q])
                                  for q in group if q != p],
                 "pairs_after": [cross_nrmse(after.selection.chosen, data[q])
                                 for q in group if q != p],
                 "rpairs_before": [cross_nrmse(before.selection.chosen, data[q])
                                   for q in sub if q != p],
                 "rpairs_after": [cross_nrmse(after.selection.chosen, data[q])
                                  for q in sub if q != p],
                 "params": params, "fc_before": fc_before, "secs": secs}
            rows.append(r)
            print(f"{p.stem:>12} {fam:>4} {data[p].sample_rate_hz:5.1f} | {fb:>16} "
                  f"{r['within_before']:6.4f} {r['cross_before']:6.4f} | "
                  f"{'+'.join(named):>40} {r['within_after']:6.4f} {r['cross_after']:6.4f} "
                  f"{secs:5.1f} | {other.stem} (any rate: {other_any.stem} "
                  f"{r['any_before']:.4f} -> {r['any_after']:.4f})")
    n = len(rows)
    hyst_first = sum(bool(r["named"]) and r["named"][0] in HYSTERESIS for r in rows)
    fric_first = sum(bool(r["named"]) and r["named"][0] == "coulomb_friction" for r in rows)
    hyst_named = sum(any(e in HYSTERESIS for e in r["named"]) for r in rows)
    print(f"\nbefore: friction named first on "
          f"{sum(r['first_before'] == 'coulomb_friction' for r in rows)}/{n} records")
    print(f"after:  hysteresis named on {hyst_named}/{n}; named first: hysteresis "
          f"{hyst_first}/{n}, "
          f"Coulomb friction {fric_first}/{n}; 'unexplained' left on "
          f"{sum('unexplained' in r['named'] for r in rows)}/{n}")
    for fam in [None, *fams]:
        sel = [r for r in rows if fam is None or r["fam"] == fam]
        lab = "all" if fam is None else fam
        for key in ("within", "cross", "any"):
            b = np.array([r[f"{key}_before"] for r in sel])
            a = np.array([r[f"{key}_after"] for r in sel])
            print(f"{lab:>4} {key:>6} NRMSE: before median {np.median(b):.4f} "
                  f"(IQR {np.percentile(b, 25):.4f}-{np.percentile(b, 75):.4f}, max {b.max():.4f})"
                  f" -> after median {np.median(a):.4f} (IQR {np.percentile(a, 25):.4f}-"
                  f"{np.percentile(a, 75):.4f}, max {a.max():.4f})")
        for key, what in (("rpairs", "same family and rate"), ("pairs", "same family")):
            pb = np.concatenate([r[f"{key}_before"] for r in sel])
            pa = np.concatenate([r[f"{key}_after"] for r in sel])
            print(f"{lab:>4} all-pairs NRMSE, {what} ({pa.size} ordered pairs): before median "
                  f"{np.median(pb):.4f} -> after median {np.median(pa):.4f} (IQR "
                  f"{np.percentile(pa, 25):.4f}-{np.percentile(pa, 75):.4f})")
    print("\nparameter spread per family (after; records whose chosen model has the parameter):")
    for fam in fams:
        sel = [r for r in rows if r["fam"] == fam]
        keys = sorted({k for r in sel for k in r["params"]})
        print(f"  family {fam} ({len(sel)} records)")
        print(f"    {'coulomb (before) F_c':>44}: {_spread([r['fc_before'] for r in sel])}")
        for k in keys:
            print(f"    {k:>44}: {_spread([r['params'].get(k, np.nan) for r in sel])}")
    print(f"time per record (after): median {np.median([r['secs'] for r in rows]):.1f} s, "
          f"max {max(r['secs'] for r in rows):.1f} s")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=None, help="repeat a run (default: fresh)")
    ap.add_argument("--cases", type=int, default=6, help="Duffing cases at 610 Hz/60 Hz")
    ap.add_argument("--per-ratio", type=int, default=2, help="cases per fs/f_res ratio")
    ap.add_argument("--skip-mr", action="store_true")
    ap.add_argument("--only-mr", action="store_true")
    a = ap.parse_args(argv)
    seed = a.seed if a.seed is not None else int.from_bytes(os.urandom(4), "little")
    print(f"bench_rig: master seed {seed} (repeat with --seed {seed})")
    rng = np.random.default_rng(seed)
    t0 = time.perf_counter()
    if not a.only_mr:
        run_duffing(rng, a.cases)
        run_ratios(rng, a.per_ratio)
    if not a.skip_mr:
        run_mr()
    print(f"\ntotal {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
