"""fielddiag's mismatch diagnosis against pysindy (sparse regression), same cases, same scores.

Method
------
Cases: the scenario catalogue (fielddiag.scenarios), each a before/after pair of simulated
drives of one car corner with known effects. fielddiag's side is ``run(name)`` of
benchmarks/bench_diagnose.py, unchanged (it simulates the pair from its seed and calls
fielddiag.diagnose.engine.diagnose_drives). The peer side simulates the same pair from the
same seed (identical arrays: the checksum is compared with a second simulation) and is
scored by the same rules.

Peer (pysindy 2.x STLSQ, set up as a competent user would):

1. Same inputs as fielddiag: ``fielddiag.dsp.integrate_pair`` in the band 0.5-30 Hz at
   125 Hz; r = x_body - x_wheel, rdot = v_body - v_wheel, x2 = x_body, a2 = band-limited
   body acceleration. The last 30 % of every drive is held out for validation.
2. One equation for both drives: (M + dM) a2 + dM g = F(r - dM s, rdot, x2), F the library
   below, s the static sag per added kg (the loaded drive sits lower; nonlinear terms must
   see the travel where they act). Per unit M the target is a2 + dM (a2 + g) / M, so for a
   given s the library is fixed and M enters through one known column: M is found by a
   1-D search of the least-squares misfit (full library, fit part, a2 units) and s on a
   grid around the linear sag dM g / K (K from a first linear least-squares fit of the
   first drive), kept within 0.3-1.1 of it (every effect of the library stiffens the
   suspension in compression or leaves the sag alone; unbounded, shifted bump-stop ramps
   mimic other terms). (The ratio of per-drive linear stiffnesses, K/M over K/(M + dM),
   was tried first: nonlinear effects bias it, e.g. M = 2777 kg on bump_stop_1.)
3. Sparse regression on both drives stacked (pysindy's multiple trajectories): state v2,
   target x_dot = a2 (M+dM)/M + dM g/M, controls u = (r - dM s, rdot, x2);
   GeneralizedLibrary of CustomLibraries: constant, r, r^3, max(-r-g, 0) for g = 20, 25,
   ..., 80 mm (a bump-stop grid; gaps passed by fewer than 10 samples dropped: all-zero
   columns break column normalisation) on r; rdot, tanh(rdot / 0.01 m/s) (dry friction,
   the simulator's smoothing), rdot [rdot < 0] (compression damping) on rdot; x2 (coupling).
   STLSQ on normalised columns (the threshold is then the smallest contribution a term may
   make, relative to the target's norm), swept over 13 thresholds from 3e-4 to 0.3, plus
   the linear model (the linear terms by least squares). Kept: the model with the fewest
   terms whose held-out NRMSE is within 1 % of the best (the knee of the Pareto curve).
4. Naming: an effect is named when one of its terms is kept with a physical sign
   (friction > 0, k3 > 0, bump stiffness > 0, both damper rates > 0) and dropping its
   terms (least-squares refit of the other kept terms on the fit part) raises the
   held-out NRMSE by more than 1 %; ranked by that rise (first = top-1). "unexplained" is
   added when the kept model beats the linear + named terms by more than 1 % on the held-
   out part (kept terms that matter but are not physical; a user's reading, not pysindy's).
   Parameters in fielddiag's SI names, times M: friction_force_n = -coef M;
   cubic_stiffness_n_per_m3 = -coef M; bump stop: the kept ramps sum to one ramp of
   stiffness sum(k_i) and gap sum(k_i g_i) / sum(k_i); asymmetric_damping: rebound =
   -coef(rdot) M, compression = rebound - coef(rdot [rdot<0]) M. Verdict missing_physics
   when anything is named, else adequate.
5. pysindy has no data checks: it is scored 0 on sensor problems.

Scores (for both tools, the rules of bench_diagnose.py): top-1 effect correct, all effects of
a case named (and the two-effect cases alone), false alarms on linear cases (verdict not
adequate), parameter error |estimate/true - 1| over the true effects' parameters (median,
worst), outside the library -> unexplained, sensor problems flagged, wall time (diagnosis
only, simulation excluded; the peer's includes its integration). Also shown: effects named
on the sensor-problem cases (a clean suspension; such names are spurious). Each tool runs
each case in a forked child limited to TIME_LIMIT_S (600 s); a hang or an exception is
"no answer" (no effects, no warnings, not a false alarm).

Usage: python benchmarks/bench_peer_pysindy.py [NAME ...]
"""

from __future__ import annotations

import hashlib
import multiprocessing
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from scipy import optimize

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_diagnose import run as run_fielddiag  # noqa: E402

from fielddiag import dsp  # noqa: E402
from fielddiag.scenarios import SCENARIOS, simulate_scenario  # noqa: E402

try:
    import pysindy as ps
except ImportError:  # pragma: no cover - depends on the machine
    ps = None

GRAVITY_MPS2 = dsp.GRAVITY_MPS2
BAND_HZ = (0.5, 30.0)
ANALYSIS_RATE_HZ = 125.0
HOLDOUT_FRACTION = 0.3
# the simulator's tanh smoothing (fielddiag's friction term fits its own, effective one: a
# sparse regression needs the column fixed)
SMOOTHING_VELOCITY_MPS = 0.01
GAPS_M = tuple(round(0.02 + 0.005 * i, 3) for i in range(13))  # 20 ... 80 mm
MASS_RANGE_KG = (100.0, 3000.0)  # search range of the sprung mass
# static sag of the loaded drive / the linear dM g / K: every effect of the library stiffens
# the suspension in compression or leaves the sag alone, so at most 1 (+10 % for K's error)
SAG_FACTOR_RANGE = (0.3, 1.1)
MIN_ACTIVE = 10  # a bump-stop ramp must act on at least this many samples to be a column
THRESHOLDS = np.logspace(-3.5, -0.5, 13)  # STLSQ threshold / norm of the target
KNEE_TOLERANCE = 0.01  # sparsest model within 1 % of the best held-out NRMSE
NAMING_RISE = 0.01  # held-out NRMSE must rise > 1 % when the effect is dropped
TIME_LIMIT_S = 600.0  # per tool and case; beyond it the case counts as no answer


# ----------------------------------------------------------------------------- peer
def _fingerprint(*arrays: np.ndarray) -> str:
    h = hashlib.sha1()
    for a in arrays:
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def _ramp(gap_m: float):
    """max(-r - gap, 0) and its name (one-argument closures: pysindy counts arguments)."""

    def func(x):
        return np.maximum(-x - gap_m, 0.0)

    def name(x):
        return f"max(-{x}-{gap_m:.3f},0)"

    return func, name


def _library(gaps_m: tuple[float, ...]) -> tuple[Any, list[str]]:
    """pysindy library on (v2 | r, rdot, x2) and the effect each feature belongs to."""
    r_funcs = [lambda x: x, lambda x: x**3]
    r_names = [lambda x: x, lambda x: f"{x}^3"]
    r_family = ["linear", "cubic_stiffness"]
    for g in gaps_m:
        f, n = _ramp(g)
        r_funcs.append(f)
        r_names.append(n)
        r_family.append("bump_stop")
    v_funcs = [
        lambda x: x,
        lambda x: np.tanh(x / SMOOTHING_VELOCITY_MPS),
        lambda x: x * (x < 0.0),
    ]
    v_names = [lambda x: x, lambda x: f"tanh({x}/0.01)", lambda x: f"{x}[{x}<0]"]
    v_family = ["linear", "coulomb_friction", "asymmetric_damping"]
    lib_r = ps.CustomLibrary(r_funcs, r_names, include_bias=True)
    lib_v = ps.CustomLibrary(v_funcs, v_names)
    lib_x = ps.CustomLibrary([lambda x: x], [lambda x: x])
    lib = ps.GeneralizedLibrary([lib_r, lib_v, lib_x], inputs_per_library=[[1], [2], [3]])
    families = ["linear", *r_family, *v_family, "linear"]  # bias first, then r, rdot, x2
    return lib, families


def _nrmse(pred: np.ndarray, meas: np.ndarray) -> float:
    return float(np.sqrt(np.mean((pred - meas) ** 2) / np.mean(meas**2)))


def _states(before, after) -> list[dict[str, np.ndarray | float]]:
    out = []
    for d in (before, after):
        w, b = dsp.integrate_pair(
            d.wheel_accel_mps2,
            d.body_accel_mps2,
            d.sample_rate_hz,
            band_hz=BAND_HZ,
            output_rate_hz=ANALYSIS_RATE_HZ,
        )
        out.append(
            {
                "r": b.displacement_m - w.displacement_m,
                "rdot": b.velocity_mps - w.velocity_mps,
                "x2": b.displacement_m,
                "v2": b.velocity_mps,
                "a2": b.acceleration_mps2,
                "dm": float(d.added_mass_kg),
                "fs": w.sample_rate_hz,
                "cut": int(round((1.0 - HOLDOUT_FRACTION) * w.displacement_m.size)),
            }
        )
    return out


def _stiffness_per_kg(states) -> float:
    """K/(M + dM) of the first drive from an ordinary least-squares linear fit."""
    s = states[0]
    c = s["cut"]
    a = np.column_stack([s["r"][:c], s["rdot"][:c], s["x2"][:c], np.ones(c)])
    return -float(np.linalg.lstsq(a, s["a2"][:c], rcond=None)[0][0])


def _design(states, mass_kg: float, sag_m_per_kg: float) -> dict[str, dict[str, list]]:
    """pysindy inputs per drive and part: x = v2, u = (r + r0, rdot, x2), target x_dot.

    Target (M + dM) a2 / M + dM g / M: with it one set of per-unit-M coefficients explains
    every drive; r0 = -dM sag is the static sag of a drive with added mass dM.
    """
    parts: dict[str, dict[str, list]] = {"fit": {}, "val": {}}
    for s in states:
        u = np.column_stack([s["r"] - s["dm"] * sag_m_per_kg, s["rdot"], s["x2"]])
        y = s["a2"] * (mass_kg + s["dm"]) / mass_kg + s["dm"] * GRAVITY_MPS2 / mass_kg
        c = s["cut"]
        for part, sl in (("fit", slice(None, c)), ("val", slice(c, None))):
            p = parts[part]
            p.setdefault("x", []).append(s["v2"][sl, None])
            p.setdefault("u", []).append(u[sl])
            p.setdefault("y", []).append(y[sl, None])
    return parts


def _theta(lib, part: dict[str, list]) -> np.ndarray:
    return np.concatenate(
        [np.asarray(lib.transform(np.column_stack([x, u])))
         for x, u in zip(part["x"], part["u"], strict=True)]
    )


def _profile_mass(states, kappa: float) -> tuple[float, float]:
    """M and static sag minimising the least-squares misfit of the full library (fit part).

    (M + dM) a2 + dM g = Theta(r - dM sag, rdot, x2) w: for a given sag the library matrix
    is fixed and the target is a2 + dM (a2 + g) / M, so the residual after projection is
    e_a + e_c / M, minimised over M (in a2 units, e (M / (M + dM))); the sag is searched on
    a grid and refined (variable projection). The sag is kept within 0.3-1.1 times the
    linear dM g / K (K = kappa (M + dM_first) from the first linear fit): every effect of
    the library stiffens the suspension in compression or leaves the sag alone, and the
    bound keeps the search out of spurious minima where shifted ramps mimic other terms.
    """
    lib, _ = _library(GAPS_M)
    dm_first = states[0]["dm"]
    zero = _design(states, 380.0, 0.0)["fit"]
    lib.fit(np.column_stack([zero["x"][0], zero["u"][0]]))
    a2 = np.concatenate([s["a2"][: s["cut"]] for s in states])
    dm = np.concatenate([np.full(s["cut"], s["dm"]) for s in states])
    col = dm * (a2 + GRAVITY_MPS2)
    log_m = np.linspace(np.log(MASS_RANGE_KG[0]), np.log(MASS_RANGE_KG[1]), 41)

    def inner(sag: float) -> tuple[float, float]:
        th = _theta(lib, _design(states, 380.0, sag)["fit"])
        norms = np.linalg.norm(th, axis=0)
        q, _ = np.linalg.qr(th[:, norms > 0] / norms[norms > 0])
        ea, ec = a2 - q @ (q.T @ a2), col - q @ (q.T @ col)

        def cost(lm: float) -> float:
            m = np.exp(lm)
            return float(np.sum(((ea + ec / m) * (m / (m + dm))) ** 2))

        k = int(np.argmin([cost(v) for v in log_m]))
        res = optimize.minimize_scalar(
            cost, bounds=(log_m[max(k - 1, 0)], log_m[min(k + 1, log_m.size - 1)]),
            method="bounded", options={"xatol": 1e-4},
        )
        return float(res.fun), float(np.exp(res.x))

    def factor(sag: float, mass: float) -> float:  # sag / the linear dM g / K
        return sag * kappa * (mass + dm_first) / GRAVITY_MPS2

    sag_max = SAG_FACTOR_RANGE[1] * GRAVITY_MPS2 / (kappa * (MASS_RANGE_KG[0] + dm_first))
    grid = np.linspace(0.0, sag_max, 81)
    found = [(sag, *inner(sag)) for sag in grid]
    ok = [f for f in found if SAG_FACTOR_RANGE[0] <= factor(f[0], f[2]) <= SAG_FACTOR_RANGE[1]]
    if not ok:  # no physical sag: take the linear one at the best mass
        ok = found
    best = min(ok, key=lambda f: f[1])
    k = int(np.flatnonzero(grid == best[0])[0])
    res = optimize.minimize_scalar(
        lambda sag: inner(sag)[0], bounds=(grid[max(k - 1, 0)], grid[min(k + 1, grid.size - 1)]),
        method="bounded", options={"xatol": 1e-7},
    )
    sag = float(res.x) if res.fun <= best[1] else best[0]
    return inner(sag)[1], sag


def _findings(
    coef: np.ndarray, names: list[str], families: list[str], mass: float
) -> dict[str, dict[str, float]]:
    """Physical effects among the kept terms, with parameters in fielddiag's SI names."""
    m = float(mass)
    c = {n: float(v) for n, v in zip(names, coef, strict=True)}
    out: dict[str, dict[str, float]] = {}
    f = c.get("tanh(rdot/0.01)", 0.0)
    if f < 0:
        out["coulomb_friction"] = {"friction_force_n": -f * m}
    k3 = c.get("r^3", 0.0)
    if k3 < 0:
        out["cubic_stiffness"] = {"cubic_stiffness_n_per_m3": -k3 * m}
    gaps = _gap_of(names)
    ramps = [
        (gaps[i], float(coef[i]))
        for i, fam in enumerate(families)
        if fam == "bump_stop" and coef[i] != 0.0
    ]
    kb = sum(k for _, k in ramps)
    if ramps and kb > 0:
        out["bump_stop"] = {
            "gap_m": sum(g * k for g, k in ramps) / kb,
            "stiffness_n_per_m": kb * m,
        }
    dc = c.get("rdot[rdot<0]", 0.0)
    reb = -c.get("rdot", 0.0)
    comp = reb - dc
    if dc != 0.0 and reb > 0 and comp > 0:
        out["asymmetric_damping"] = {
            "compression_damping_ns_per_m": comp * m,
            "rebound_damping_ns_per_m": reb * m,
        }
    return out


def _gap_of(names: list[str]) -> list[float]:
    gaps = []
    for n in names:
        gaps.append(float(n.split("-")[2].split(",")[0]) if n.startswith("max(") else np.nan)
    return gaps


def run_peer(name: str) -> dict:
    """pysindy's diagnosis of one scenario, in the result shape of bench_diagnose.run."""
    sc = SCENARIOS[name]
    before, after = simulate_scenario(sc)
    fingerprint = _fingerprint(before.wheel_accel_mps2, before.body_accel_mps2,
                               after.wheel_accel_mps2, after.body_accel_mps2)
    t0 = time.perf_counter()
    states = _states(before, after)
    kappa = _stiffness_per_kg(states)
    mass, sag = _profile_mass(states, kappa)
    stiff = kappa * (mass + states[0]["dm"])
    sag_factor = sag * stiff / GRAVITY_MPS2
    parts = _design(states, mass, sag)
    # ramps that never act in the fit part are all-zero columns (pysindy's column
    # normalisation divides by their norm): keep the gaps passed at least MIN_ACTIVE times
    compression = -np.concatenate(parts["fit"]["u"])[:, 0]
    gaps = tuple(g for g in GAPS_M if np.count_nonzero(compression > g) >= MIN_ACTIVE)
    lib, families = _library(gaps)
    dt = 1.0 / states[0]["fs"]
    y_fit, y_val = (np.concatenate(parts[p]["y"])[:, 0] for p in ("fit", "val"))
    norm_y = float(np.linalg.norm(y_fit))

    sweep = []
    for tau in THRESHOLDS:
        model = ps.SINDy(
            optimizer=ps.STLSQ(threshold=tau * norm_y, normalize_columns=True),
            feature_library=lib,
        )
        model.fit(parts["fit"]["x"], t=dt, x_dot=parts["fit"]["y"], u=parts["fit"]["u"],
                  feature_names=["v2", "r", "rdot", "x2"])
        pred = np.concatenate(
            [model.predict(x, u=u)[:, 0] for x, u in zip(parts["val"]["x"], parts["val"]["u"],
                                                          strict=True)]
        )
        sweep.append((float(tau), model.coefficients()[0].copy(), _nrmse(pred, y_val)))
    names = model.get_feature_names()
    if len(names) != len(families):
        raise RuntimeError(f"library has {len(names)} features, expected {len(families)}")
    fam = np.array(families)
    theta_fit, theta_val = _theta(lib, parts["fit"]), _theta(lib, parts["val"])

    def refit(keep: np.ndarray) -> tuple[np.ndarray, float]:
        """Least squares on the terms ``keep`` (fit part), held-out NRMSE."""
        w = np.zeros(keep.size)
        w[keep] = np.linalg.lstsq(theta_fit[:, keep], y_fit, rcond=None)[0]
        return w, _nrmse(theta_val @ w, y_val)

    # the linear model (the library's linear terms) is a candidate too
    lin_coef, lin_err = refit(fam == "linear")
    sweep.append((float("inf"), lin_coef, lin_err))
    best = min(e for _, _, e in sweep)
    tau, coef, err = min(
        (s for s in sweep if s[2] <= best * (1 + KNEE_TOLERANCE)),
        key=lambda s: (np.count_nonzero(s[1]), s[2]),
    )

    # Naming by ablation on the held-out part (least-squares refit of the remaining terms).
    kept = coef != 0.0
    physical = _findings(coef, names, families, mass)
    rises = {}
    for effect in physical:
        rises[effect] = refit(kept & (fam != effect))[1] / err - 1.0
    named = sorted((e for e in physical if rises[e] > NAMING_RISE), key=lambda e: -rises[e])
    # what the kept terms explain beyond the linear and the named effects' terms
    named_err = refit(kept & np.isin(fam, ["linear", *named]))[1]
    if named_err > err * (1.0 + NAMING_RISE):
        named.append("unexplained")
    wall = time.perf_counter() - t0

    out = {
        "verdict": "missing_physics" if named else "adequate",
        "findings": [{"effect": e, "parameters": physical.get(e, {})} for e in named],
        "warnings": [],
        "sprung_mass_kg": mass,
        "suspension_stiffness_n_per_m": stiff,
        "sag_factor": sag_factor,
        "threshold": tau,
        "kept_terms": [n for n, k in zip(names, kept, strict=True) if k],
        "nrmse_linear": lin_err,
        "nrmse_named": named_err,
        "nrmse_chosen": err,
        "rises": rises,
        "fingerprint": fingerprint,
    }
    return {
        "name": name,
        "sc": sc,
        "out": out,
        "named": named,
        "errors": _param_errors(sc, out["findings"]),
        "warnings": [],
        "wall": wall,
    }


def _param_errors(sc, findings: list[dict]) -> list[float]:
    """|estimate/true - 1| for every parameter of the true effects (bench_diagnose's rule)."""
    errors = []
    for eff, params in sc.effects:
        f = next((f for f in findings if f["effect"] == eff), None)
        for key, true in params.items():
            if f is not None and key in f["parameters"]:
                errors.append(abs(f["parameters"][key] / true - 1.0))
    return errors


# ----------------------------------------------------------------------------- scores
def score(rows: list[dict]) -> dict[str, Any]:
    """The scores of bench_diagnose.py (plus pairs and spurious names on sensor cases)."""
    effect_cases = [
        r for r in rows if r["sc"].expected_effects and r["sc"].expected_effects != ("unexplained",)
    ]
    pairs = [r for r in effect_cases if len(r["sc"].expected_effects) > 1]
    linear = [
        r
        for r in rows
        if not r["sc"].expected_effects
        and not r["sc"].expected_warnings
        or r["name"] == "linear_bias_drift"
    ]
    outside = [r for r in rows if r["sc"].expected_effects == ("unexplained",)]
    sensors = [r for r in rows if r["sc"].expected_warnings]
    sensor_only = [r for r in sensors if not r["sc"].expected_effects]
    errs = sorted(e for r in effect_cases for e in r["errors"])

    def all_named(r: dict) -> bool:
        return set(r["sc"].expected_effects) <= set(r["named"])

    return {
        "top1": (
            sum(bool(r["named"]) and r["named"][0] in r["sc"].expected_effects
                for r in effect_cases),
            len(effect_cases),
        ),
        "all_named": (sum(all_named(r) for r in effect_cases), len(effect_cases)),
        "pairs_named": (sum(all_named(r) for r in pairs), len(pairs)),
        "false_alarms": (
            sum(r["out"]["verdict"] == "missing_physics" for r in linear),
            len(linear),
        ),
        "no_answer": (
            sum(r["out"]["verdict"] in ("timeout", "error") for r in rows),
            len(rows),
        ),
        "err_median": errs[len(errs) // 2] if errs else float("nan"),
        "err_worst": errs[-1] if errs else float("nan"),
        "n_errs": len(errs),
        "unexplained": (sum("unexplained" in r["named"] for r in outside), len(outside)),
        "sensors": (
            sum(set(r["sc"].expected_warnings) <= set(r["warnings"]) for r in sensors),
            len(sensors),
        ),
        "sensor_spurious": (sum(bool(r["named"]) for r in sensor_only), len(sensor_only)),
        "wall": sum(r["wall"] for r in rows),
    }


def _child(func, name: str, conn) -> None:
    try:
        conn.send(func(name))
    except Exception as exc:  # reported as no answer, the run goes on
        conn.send({"error": f"{type(exc).__name__}: {exc}"})


def _no_answer(name: str, verdict: str, wall: float) -> dict:
    out = {"verdict": verdict, "findings": [], "warnings": []}
    return {"name": name, "sc": SCENARIOS[name], "out": out, "named": [], "errors": [],
            "warnings": [], "wall": wall}


def run_limited(func, name: str, limit_s: float = TIME_LIMIT_S) -> dict:
    """``func(name)`` in a forked child, killed after ``limit_s`` (a hang is no answer)."""
    ctx = multiprocessing.get_context("fork")
    recv, send = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_child, args=(func, name, send), daemon=True)
    t0 = time.perf_counter()
    proc.start()
    send.close()
    try:
        result = recv.recv() if recv.poll(limit_s) else None
    except EOFError:  # the child died
        result = {"error": f"exit code {proc.exitcode}"}
    if result is None:
        proc.kill()
        proc.join()
        return _no_answer(name, "timeout", time.perf_counter() - t0)
    proc.join()
    if "error" in result:
        print(f"  ({func.__name__} failed on {name}: {result['error']})")
        return _no_answer(name, "error", time.perf_counter() - t0)
    return result


def _case_line(tool: str, r: dict) -> str:
    err = r["errors"]
    e = f"{100 * max(err):.1f} %" if err else "-"
    warn = ",".join(dict.fromkeys(w for w in r["warnings"] if w != "findings_withheld")) or "-"
    return (
        f"  {tool:<10} {r['out']['verdict']:<16} named {','.join(r['named']) or '-':<42} "
        f"param err {e:>8}  warn {warn:<34} {r['wall']:5.1f} s"
    )


def _frac(x: tuple[int, int]) -> str:
    return f"{x[0]}/{x[1]}"


def main() -> None:
    names = sys.argv[1:] or list(SCENARIOS)
    print(__doc__)
    if ps is None:
        print("pysindy is not installed (pip install pysindy); the comparison cannot run.")
        return
    print(f"pysindy {ps.__version__}, numpy {np.__version__}\n")
    ours, peer = [], []
    for name in names:
        sc = SCENARIOS[name]
        p = run_limited(run_peer, name)
        f = run_limited(run_fielddiag, name)
        again = simulate_scenario(sc)
        same = _fingerprint(again[0].wheel_accel_mps2, again[0].body_accel_mps2,
                            again[1].wheel_accel_mps2, again[1].body_accel_mps2)
        if p["out"].get("fingerprint", same) != same:
            raise RuntimeError(f"{name}: the simulation is not reproducible; no fair comparison")
        ours.append(f)
        peer.append(p)
        po = p["out"]
        print(
            f"{name:<24} expected {','.join(sc.expected_effects) or '-'}"
            f" / warn {','.join(sc.expected_warnings) or '-'}",
        )
        print(_case_line("fielddiag", f))
        print(_case_line("pysindy", p), flush=True)
        if "threshold" not in po:
            continue
        thr = "- (linear LS)" if np.isinf(po["threshold"]) else f"{po['threshold']:.2g}"
        print(
            f"  {'':<10} pysindy: M {po['sprung_mass_kg']:.0f} kg (true {sc.car.body_mass_kg:g}),"
            f" sag {po['sag_factor']:.2f} x linear, threshold {thr}, held-out NRMSE linear "
            f"{po['nrmse_linear']:.3f} / named {po['nrmse_named']:.3f} / kept "
            f"{po['nrmse_chosen']:.3f}, kept {', '.join(po['kept_terms'])}",
            flush=True,
        )
    s_f, s_p = score(ours), score(peer)
    rows = [
        ("top-1 effect correct", _frac(s_f["top1"]), _frac(s_p["top1"])),
        ("all effects of a case named", _frac(s_f["all_named"]), _frac(s_p["all_named"])),
        ("  of which two-effect cases", _frac(s_f["pairs_named"]), _frac(s_p["pairs_named"])),
        ("false alarms (linear)", _frac(s_f["false_alarms"]), _frac(s_p["false_alarms"])),
        (
            "parameter error median",
            f"{100 * s_f['err_median']:.1f} % (n={s_f['n_errs']})",
            f"{100 * s_p['err_median']:.1f} % (n={s_p['n_errs']})",
        ),
        (
            "parameter error worst",
            f"{100 * s_f['err_worst']:.1f} %",
            f"{100 * s_p['err_worst']:.1f} %",
        ),
        ("outside the library -> unexplained", _frac(s_f["unexplained"]),
         _frac(s_p["unexplained"])),
        ("sensor problems flagged", _frac(s_f["sensors"]), _frac(s_p["sensors"]) + " (no checks)"),
        ("effects named on sensor cases", _frac(s_f["sensor_spurious"]),
         _frac(s_p["sensor_spurious"])),
        ("no answer (timeout / error)", _frac(s_f["no_answer"]), _frac(s_p["no_answer"])),
        ("wall time", f"{s_f['wall']:.0f} s", f"{s_p['wall']:.0f} s"),
    ]
    print(f"\n{'score':<36} {'fielddiag':>18} {'pysindy':>24}")
    for label, a, b in rows:
        print(f"{label:<36} {a:>18} {b:>24}")
    print(f"({len(names)} cases)")


if __name__ == "__main__":
    main()
