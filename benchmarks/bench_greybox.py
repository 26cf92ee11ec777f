"""Grey-box fit and on-line estimator: accuracy, speed, honest uncertainty (prints figures).

Method
------
1. Perfect data: fielddiag.sim drives (ISO 8608 class C road, 30 s, 500 Hz; car K2 = 24 kN/m,
   C2 = 1.8 kN s/m, K3 = 3 kN/m, M2 = 380 kg); the model is driven by the simulator's true
   wheel motion and fitted to its true body acceleration (full band). Starts 5x off in
   every combination of directions (per unit mass: 8 starts; two sessions with an 80 kg
   added mass, absolute values and mass: 16 starts). Reported: worst relative error of
   the parameters and the most iterations, with the default continuation (equation error,
   0.2 s and 2 s horizons, then the plain simulation) and with the plain simulation from
   static equilibrium only (Serban & Freeman's procedure).
2. Sensitivity equations vs finite differences: on the same noisy drives (sensor noise
   0.05 m/s2, integrated in 0.5-30 Hz like a recording; one session per unit mass, and a
   two-session absolute fit) and from the same start (stiffness x1.5, damping x0.7, mass
   x1.2), this module's Levenberg-Marquardt with the Jacobian from the sensitivity
   equations vs scipy.optimize.least_squares (trf, bounds, x_scale="jac", '2-point' and
   '3-point' finite differences) on the same residual function, with the same stopping
   tolerances (xtol, ftol, gtol of our fit). Both without continuation. Reported: calls of
   the residual function (a finite-difference Jacobian costs n or 2n of them), optimiser
   time, final cost relative to ours (the proof of equal accuracy) and the difference of
   the estimates in units of their standard deviation; and the speed-up at matched cost:
   the time each method needs to first get down to the higher of the two final costs
   (+1e-9 relative).
3. Monte Carlo: 100 random drive pairs drawn like benchmarks/bench_identify.py (car, road
   B/C, 120-300 s, 200/500/1000 Hz, SNR 25-40 dB, bias with drift, added mass 8-30 %).
   Two passes per pair: the first drive alone per unit mass, and both drives with the
   added mass (absolute K2, C2 and M2, as ``fielddiag fit S1 S2 --added-mass KG``).
   Coverage = fraction of drives with the truth within 1, 2 and 3 std per parameter (and
   all jointly); std(z) should be ~1 where z = (estimate - truth) / std.
4. On-line estimator: 10 drives (120 s, noise 0.05 m/s2, a car unlike the prior), replayed
   in 0.1 s blocks; real-time factor of the estimator alone and of the whole replay, and
   the time until both estimates stay within 5 % of the off-line fit of the same drive.

Run: ``python benchmarks/bench_greybox.py [--quick] [--only perfect,fd,mc,online] [--mc N]``.
"""

from __future__ import annotations

import argparse
import contextlib
import inspect
import itertools
import math
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
from scipy import optimize

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_identify import draw_case  # noqa: E402  (the same random cases as identify)

from fielddiag.errors import FieldDiagError
from fielddiag.identify.greybox import (
    GreyBoxData,
    GreyBoxProblem,
    fit_greybox,
    levenberg_marquardt,
)
from fielddiag.identify.online import OnlineEstimator, convergence_time, replay
from fielddiag.identify.terms import linear_model
from fielddiag.sim import QuarterCarParams, SensorModel, simulate, simulate_pair

CAR = QuarterCarParams(coupling_stiffness_n_per_m=3000.0)
ABS = {"suspension_stiffness_n_per_m": 24e3, "suspension_damping_ns_per_m": 1800.0,
       "coupling_stiffness_n_per_m": 3000.0}
PER_KG = {k: v / 380.0 for k, v in ABS.items()}


def perfect_data(n_drives: int) -> None:
    print("\n1. Perfect data (simulator truth), starts 5x off")
    model = linear_model(coupling=True)
    for horizons, label in (((0.0, 0.2, 2.0), "continuation + simulation"),
                            (None, "plain simulation only")):
        worst, iters, fails = 0.0, [], 0
        for seed in range(n_drives):
            data = GreyBoxData.from_drive(simulate(CAR, duration_s=30.0, seed=seed), truth=True)
            for fac in itertools.product((5.0, 0.2), repeat=3):
                start = {k: v * f for (k, v), f in zip(PER_KG.items(), fac, strict=True)}
                res = fit_greybox(data, model, initial=start, horizons_s=horizons)
                err = max(abs(res.value(k) / v - 1) for k, v in PER_KG.items())
                if err > 1e-6:
                    fails += 1
                else:
                    worst = max(worst, err)
                    iters.append(res.iterations)
        print(f"   per unit mass, {label:<27}: {8 * n_drives - fails}/{8 * n_drives} starts "
              f"reach 1e-6; worst error {worst:.1e}, iterations max {max(iters)} "
              f"(median {int(np.median(iters))})")
    truth = {**ABS, "body_mass_kg": 380.0}
    worst, iters, fails = 0.0, [], 0
    for seed in range(n_drives):
        pair = simulate_pair(CAR, added_mass_kg=80.0, seed=seed, duration_s=30.0)
        data = [GreyBoxData.from_drive(d, truth=True) for d in pair]
        for fac in itertools.product((5.0, 0.2), repeat=4):
            start = {k: v * f for (k, v), f in zip(truth.items(), fac, strict=True)}
            res = fit_greybox(data, model, initial=start)
            err = max(abs(res.value(k) / v - 1) for k, v in truth.items())
            if err > 1e-6:
                fails += 1
            else:
                worst = max(worst, err)
                iters.append(res.iterations)
    print(f"   absolute (2 sessions, 80 kg), continuation: {16 * n_drives - fails}/"
          f"{16 * n_drives} starts reach 1e-6; worst error {worst:.1e}, iterations max "
          f"{max(iters)} (median {int(np.median(iters))})")


def _tolerances() -> dict[str, float]:
    """The stopping tolerances of our fit (fit_greybox's xtol, levenberg_marquardt's others)."""
    lm = inspect.signature(levenberg_marquardt).parameters
    return {"xtol": inspect.signature(fit_greybox).parameters["xtol"].default,
            "ftol": lm["ftol"].default, "gtol": lm["gtol"].default}


class _Trace:
    """Cost and time of every call of a residual function (times from the first call's start)."""

    def __init__(self) -> None:
        self.costs: list[float] = []
        self.ends: list[float] = []
        self.t0: float | None = None

    def record(self, t_start: float, r: np.ndarray) -> None:
        if self.t0 is None:
            self.t0 = t_start
        self.costs.append(0.5 * float(r @ r))
        self.ends.append(time.perf_counter() - self.t0)

    @property
    def seconds(self) -> float:
        """Optimiser time: from the first call's start to the last call's end."""
        return self.ends[-1]

    def first_reaching(self, target_cost: float) -> tuple[int | None, float | None]:
        """Calls and seconds until the cost first got down to ``target_cost``."""
        for i, c in enumerate(self.costs):
            if c <= target_cost:
                return i + 1, self.ends[i]
        return None, None


@contextlib.contextmanager
def _traced_sensitivity_calls() -> Iterator[_Trace]:
    """Trace GreyBoxProblem.residual_and_jacobian (what our fit calls) while inside."""
    trace = _Trace()
    original = GreyBoxProblem.residual_and_jacobian

    def traced(self: GreyBoxProblem, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        t = time.perf_counter()
        r, j = original(self, z)
        trace.record(t, r)
        return r, j

    GreyBoxProblem.residual_and_jacobian = traced
    try:
        yield trace
    finally:
        GreyBoxProblem.residual_and_jacobian = original


def _scipy_fit(prob: GreyBoxProblem, z0: np.ndarray, jac: str
               ) -> tuple[np.ndarray, float, _Trace]:
    """scipy's least_squares on our residual function: solution, its cost, the trace."""
    lo, hi = prob.bounds()
    scale = np.abs(z0)
    scale[prob.nuis_index:] = np.tile([1e-3, 1e-2], len(prob.data))
    trace = _Trace()

    def fun(q: np.ndarray) -> np.ndarray:
        t = time.perf_counter()
        r = prob.residual(q * scale)
        trace.record(t, r)
        return r

    sol = optimize.least_squares(fun, z0 / scale, bounds=(lo / scale, hi / scale), jac=jac,
                                 method="trf", x_scale="jac", max_nfev=2000, **_tolerances())
    return sol.x * scale, float(sol.cost), trace


MATCH_RTOL = 1e-9  # cost within 1e-9 (relative): ~0.01 std of the parameters at 30k samples


def sensitivity_vs_fd(n_drives: int) -> None:
    print("\n2. Sensitivity equations vs scipy least_squares with finite differences")
    tol = _tolerances()
    tol_txt = ", ".join(f"{k}={v:g}" for k, v in tol.items())
    print(f"   ours: fit_greybox(horizons_s=None) = levenberg_marquardt, Jacobian from the "
          f"sensitivity equations, {tol_txt}")
    print(f"   FD:   scipy.optimize.least_squares(method='trf', jac='2-point' | '3-point', "
          f"x_scale='jac', bounds, {tol_txt})")
    print("   'evals' = calls of the residual function (all sessions; ours each with "
          "sensitivities); 'time' = optimiser time, first call to last (ours without the "
          "setup and the uncertainty, 'fit' = its whole fit_greybox call); 'match' = first "
          f"call with a cost <= max(ours, FD final cost) x (1 + {MATCH_RTOL:g}), for FD and "
          "for ours ('ours@match'; FD's Jacobian probes count too: a lower bound of its "
          "effort)")
    model = linear_model()
    truth_abs = {"suspension_stiffness_n_per_m": 24e3, "suspension_damping_ns_per_m": 1800.0}
    rows = []
    for seed in range(n_drives):
        car = QuarterCarParams()
        sens = SensorModel(noise_std_mps2=0.05)
        for mode in ("per_unit_mass", "absolute"):
            if mode == "per_unit_mass":
                data = [GreyBoxData.from_drive(simulate(car, duration_s=60.0, seed=seed,
                                                        sensor=sens))]
                start = {"suspension_stiffness_n_per_m": 1.5 * 24e3 / 380,
                         "suspension_damping_ns_per_m": 0.7 * 1800 / 380}
            else:
                pair = simulate_pair(car, added_mass_kg=80.0, seed=seed, duration_s=60.0,
                                     sensor=sens)
                data = [GreyBoxData.from_drive(d) for d in pair]
                start = {"suspension_stiffness_n_per_m": 1.5 * 24e3,
                         "suspension_damping_ns_per_m": 0.7 * 1800, "body_mass_kg": 1.2 * 380}
            t0 = time.perf_counter()
            with _traced_sensitivity_calls() as ours_trace:
                ours = fit_greybox(data, model, initial=start, horizons_s=None)
            t_fit = time.perf_counter() - t0
            cost_ours = ours.cost_history[-1]
            err = max(abs(ours.value(k) / (v if mode == "absolute" else v / 380) - 1)
                      for k, v in truth_abs.items())
            prob = GreyBoxProblem(model, data)
            mass = start.get("body_mass_kg")
            th0 = model.vector({k: (v / mass if mass else v) for k, v in start.items()
                                if k != "body_mass_kg"})
            z0 = prob.pack(th0, mass)
            fd = {}
            for jac in ("2-point", "3-point"):
                z, cost_fd, trace = _scipy_fit(prob, z0, jac)
                th, m, _ = prob.unpack(z)
                diff = [abs(th[i] * (m if m else 1.0) - p.value) / p.std
                        for i, p in enumerate(ours.parameters[:model.n_params])]
                if m is not None:
                    diff.append(abs(m - ours.body_mass_kg) / ours.parameter("body_mass_kg").std)
                fd[jac] = (trace, cost_fd, max(diff))
            rows.append(dict(seed=seed, mode=mode, method="ours (sens.)", trace=ours_trace,
                             cost=0.0, n_match=None, t_match=None, ours_match=None,
                             speed_up=None, diff=None, fit=t_fit, err=err))
            for jac, (trace, cost_fd, diff) in fd.items():
                # equal accuracy: both down to the higher of the two final costs
                target = max(cost_ours, cost_fd) * (1 + MATCH_RTOL)
                n_m, t_m = trace.first_reaching(target)
                ours_m = ours_trace.first_reaching(target)[1]
                rows.append(dict(seed=seed, mode=mode, method=f"FD {jac}", trace=trace,
                                 cost=cost_fd / cost_ours - 1, n_match=n_m,
                                 t_match=t_m, ours_match=ours_m,
                                 speed_up=None if t_m is None or not ours_m else t_m / ours_m,
                                 diff=diff, fit=None, err=None))
    print(f"   {'seed':>4} {'mode':<14} {'method':<13} {'evals':>5} {'time':>6} {'fit':>6} "
          f"{'cost/ours-1':>11} {'evals@match':>11} {'time@match':>10} {'ours@match':>10} "
          f"{'speed-up@match':>14} {'|diff|/std':>10}")
    for r in rows:
        print(f"   {r['seed']:>4} {r['mode']:<14} {r['method']:<13} {len(r['trace'].costs):>5d} "
              f"{r['trace'].seconds:>5.2f}s {_fmt(r['fit'], '{:.2f}s'):>6} {r['cost']:>+11.1e} "
              f"{_fmt(r['n_match'], '{}', '-' if r['fit'] else 'never'):>11} "
              f"{_fmt(r['t_match'], '{:.2f}s'):>10} {_fmt(r['ours_match'], '{:.2f}s'):>10} "
              f"{_fmt(r['speed_up'], '{:.1f}x'):>14} {_fmt(r['diff'], '{:.3f}'):>10}")
    for mode in ("per_unit_mass", "absolute"):
        for meth in ("FD 2-point", "FD 3-point"):
            sel = [r for r in rows if r["mode"] == mode and r["method"] == meth]
            ours_t = {r["seed"]: r["trace"].seconds for r in rows
                      if r["mode"] == mode and r["fit"] is not None}
            full = np.median([r["trace"].seconds / ours_t[r["seed"]] for r in sel])
            match = [r["speed_up"] for r in sel if r["speed_up"] is not None]
            worst = max(abs(r["cost"]) for r in sel)
            worst_diff = max(r["diff"] for r in sel)
            print(f"   median speed-up {mode} vs {meth}: {full:.1f}x to the end, "
                  f"{np.median(match) if match else math.nan:.1f}x at matched cost "
                  f"({len(match)}/{len(sel)} matched); final |cost/ours - 1| <= {worst:.1e}, "
                  f"|diff| <= {worst_diff:.3f} std; goal >= 3x at equal accuracy")
    errs = {mode: max(r["err"] for r in rows if r["mode"] == mode and r["err"] is not None)
            for mode in ("per_unit_mass", "absolute")}
    print(f"   our error vs truth (noise, not the optimiser): per unit mass max "
          f"{errs['per_unit_mass']:.1e}, absolute max {errs['absolute']:.1e}")


def _fmt(x: float | None, fmt: str, missing: str = "-") -> str:
    return missing if x is None else fmt.format(x)


_TRUTH_UNIT = {"suspension_stiffness_n_per_m": "suspension_stiffness_n_per_m_per_kg",
               "suspension_damping_ns_per_m": "suspension_damping_ns_per_m_per_kg"}


def _mc_case(case: dict, model: Any) -> dict[str, tuple[float, float, float]]:
    """Simulate one pair, fit the first drive per unit mass and both absolutely.

    Returns ``{pass:parameter: (estimate, std, truth)}``.
    """
    before, after = simulate_pair(case["params"], added_mass_kg=case["dm"], seed=case["seed"],
                                  duration_s=case["duration_s"], road_class=case["road"],
                                  sensor=case["sensor"])
    truth = case["params"].to_dict()
    b, a = GreyBoxData.from_drive(before), GreyBoxData.from_drive(after)
    out = {}
    res = fit_greybox(b, model)
    for key, name in _TRUTH_UNIT.items():
        p = res.parameter(name)
        out[f"per unit mass:{name}"] = (p.value, p.std, truth[key] / truth["body_mass_kg"])
    res = fit_greybox([b, a], model)
    for key in (*_TRUTH_UNIT, "body_mass_kg"):
        p = res.parameter(key)
        out[f"absolute:{key}"] = (p.value, p.std, truth[key])
    return out


def monte_carlo(n_drives: int, max_duration_s: float | None) -> None:
    print(f"\n3. Monte Carlo coverage, {n_drives} random drive pairs (bench_identify.draw_case: "
          "M2 250-550 kg, K2 15-40 kN/m, damping ratio 0.15-0.45, road B/C, 120-300 s, "
          "200/500/1000 Hz, SNR 25-40 dB, bias +-0.5 m/s2 with drift, added mass 8-30 %)")
    if max_duration_s is not None:
        print(f"   (--quick: durations cut to at most {max_duration_s:g} s)")
    print("   per unit mass: the first drive alone; absolute: both drives with the added "
          "mass (like `fielddiag fit S1 S2 --added-mass KG`)")
    rng = np.random.default_rng(2025)
    model = linear_model()
    results, refused = [], 0
    t0 = time.perf_counter()
    for i in range(n_drives):
        case = draw_case(rng)
        if max_duration_s is not None:
            case["duration_s"] = min(case["duration_s"], max_duration_s)
        try:
            results.append(_mc_case(case, model))
        except FieldDiagError as exc:
            refused += 1
            print(f"   case {i} refused: {exc}")
        if (i + 1) % 10 == 0:
            print(f"   {i + 1}/{n_drives} done, {time.perf_counter() - t0:.0f} s", flush=True)
    per_pair = (time.perf_counter() - t0) / n_drives
    print(f"   {len(results)} fitted, {refused} refused; {per_pair:.2f} s per pair (simulate + "
          "integrate + 2 fits)")
    print(f"   {'pass:parameter':<48} {'within 1 / 2 / 3 std':>21} {'std(z)':>7} {'mean(z)':>8} "
          f"{'rms err':>8} {'mean rel std':>12}")
    inside3 = []
    for key in results[0]:
        v, s, t = (np.array(x) for x in zip(*[r[key] for r in results], strict=True))
        z = (v - t) / s
        inside3.append(np.abs(z) <= 3)
        cover = [100 * np.mean(np.abs(z) <= k) for k in (1, 2, 3)]
        print(f"   {key:<48} {cover[0]:5.0f} /{cover[1]:4.0f} /{cover[2]:4.0f} % "
              f"{z.std():>7.2f} {z.mean():>+8.2f} {100 * np.sqrt(np.mean((v / t - 1) ** 2)):>7.2f}%"
              f" {100 * np.mean(s / np.abs(v)):>11.2f}%")
    both = 100 * np.mean(np.all(inside3, axis=0))
    print(f"   (Gaussian: 68 / 95 / 99.7 %; std(z) 1 = honest). All parameters of both passes "
          f"within 3 std jointly: {both:.0f} %; goal >= 95 % within 3 std per parameter")


def online(n_drives: int) -> None:
    print(f"\n4. On-line estimator, {n_drives} drives of 120 s at 500 Hz")
    car = QuarterCarParams(body_mass_kg=300.0, suspension_stiffness_n_per_m=30e3,
                           suspension_damping_ns_per_m=2500.0)
    rt_est, rt_all, conv, dev = [], [], [], []
    for seed in range(n_drives):
        d = simulate(car, duration_s=120.0, seed=500 + seed,
                     sensor=SensorModel(noise_std_mps2=0.05))
        off = fit_greybox(GreyBoxData.from_drive(d), linear_model())
        est = OnlineEstimator(d.sample_rate_hz).warm_up()
        t0 = time.perf_counter()
        snaps = replay(est, d.time_s, d.wheel_accel_mps2, d.body_accel_mps2, block_s=0.1,
                       every_s=0.5)
        wall = time.perf_counter() - t0
        rt_all.append(120.0 / wall)
        rt_est.append(snaps[-1]["realtime_factor"])
        conv.append(convergence_time(snaps, off.per_unit_mass, 0.05))
        final = {p["key"]: p["value"] for p in snaps[-1]["parameters"]}
        dev.append(max(abs(final[k] / v - 1) for k, v in off.per_unit_mass.items()))
    c = [x for x in conv if x is not None]
    print(f"   real-time factor: estimator {np.median(rt_est):.0f}x (min {np.min(rt_est):.0f}x), "
          f"replay with status snapshots every 0.5 s {np.median(rt_all):.0f}x "
          f"(min {np.min(rt_all):.0f}x); goal >= 20x")
    print(f"   time to stay within 5 % of the off-line fit: median {np.median(c):.1f} s, max "
          f"{np.max(c):.1f} s of data ({len(c)}/{n_drives} converged); final deviation from "
          f"the off-line fit max {100 * max(dev):.2f} %")


SECTIONS = ("perfect", "fd", "mc", "online")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true",
                    help="fewer drives (Monte Carlo: 5 pairs of at most 60 s)")
    ap.add_argument("--only", default=",".join(SECTIONS), metavar="NAME[,NAME...]",
                    help=f"sections to run, from {', '.join(SECTIONS)}")
    ap.add_argument("--mc", type=int, default=None, metavar="N",
                    help="Monte Carlo drive pairs (default 100, 5 with --quick)")
    args = ap.parse_args()
    only = {x.strip() for x in args.only.split(",") if x.strip()}
    if not only <= set(SECTIONS):
        ap.error(f"--only: unknown section(s) {sorted(only - set(SECTIONS))}")
    print(__doc__)
    q = args.quick
    t0 = time.perf_counter()
    if "perfect" in only:
        perfect_data(1 if q else 3)
    if "fd" in only:
        sensitivity_vs_fd(2 if q else 4)
    if "mc" in only:
        monte_carlo(args.mc or (5 if q else 100), 60.0 if q else None)
    if "online" in only:
        online(3 if q else 10)
    print(f"\ntotal {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
