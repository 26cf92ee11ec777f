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
   equations vs scipy.optimize.least_squares (trf, bounds, 2-point finite differences,
   x_scale="jac") on the same residual function. Both without continuation. Reported:
   model evaluations (simulations; a finite-difference Jacobian costs n_params of them),
   wall time, the difference of the final estimates in units of their standard deviation,
   and the final cost.
3. Monte Carlo: 100 noisy drives (60 s, random speed profile, class C road, noise 0.05
   m/s2), fit per unit mass; coverage = fraction of drives with the truth within 3 std
   (per parameter and jointly); std(z) should be ~1 where z = (estimate - truth) / std.
4. On-line estimator: 10 drives (120 s, noise 0.05 m/s2, a car unlike the prior), replayed
   in 0.1 s blocks; real-time factor of the estimator alone and of the whole replay, and
   the time until both estimates stay within 5 % of the off-line fit of the same drive.

Run: ``python benchmarks/bench_greybox.py [--quick]``.
"""

from __future__ import annotations

import argparse
import itertools
import time

import numpy as np
from scipy import optimize

from fielddiag.identify.greybox import GreyBoxData, GreyBoxProblem, fit_greybox
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


def _scipy_fit(prob: GreyBoxProblem, z0: np.ndarray) -> tuple[np.ndarray, int, float]:
    lo, hi = prob.bounds()
    scale = np.abs(z0)
    scale[prob.nuis_index:] = np.tile([1e-3, 1e-2], len(prob.data))

    def fun(q: np.ndarray) -> np.ndarray:
        return prob.residual(q * scale)

    before = prob.evaluations
    t0 = time.perf_counter()
    sol = optimize.least_squares(fun, z0 / scale, bounds=(lo / scale, hi / scale),
                                 jac="2-point", method="trf", x_scale="jac", xtol=1e-10,
                                 ftol=1e-10, gtol=1e-10, max_nfev=2000)
    return sol.x * scale, prob.evaluations - before, time.perf_counter() - t0


def sensitivity_vs_fd(n_drives: int) -> None:
    print("\n2. Sensitivity equations vs scipy least_squares with finite differences")
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
            ours = fit_greybox(data, model, initial=start, horizons_s=None)
            t_ours = time.perf_counter() - t0
            prob = GreyBoxProblem(model, data)
            mass = start.get("body_mass_kg")
            th0 = model.vector({k: (v / mass if mass else v) for k, v in start.items()
                                if k != "body_mass_kg"})
            z0 = prob.pack(th0, mass)
            z, n_fd, t_fd = _scipy_fit(prob, z0)
            th, m, _ = prob.unpack(z)
            diff = []
            for i in range(model.n_params):
                p = ours.parameters[i]
                v = th[i] * (m if m else 1.0)
                diff.append(abs(v - p.value) / p.std)
            if m is not None:
                diff.append(abs(m - ours.body_mass_kg) / ours.parameter("body_mass_kg").std)
            r = prob.residual(z)
            cost_fd = 0.5 * float(r @ r)
            cost_ours = ours.cost_history[-1]
            err = max(abs(ours.value(k) / (v if mode == "absolute" else v / 380) - 1)
                      for k, v in truth_abs.items())
            rows.append((mode, ours.model_evaluations, t_ours, n_fd, t_fd, max(diff),
                         cost_fd / cost_ours - 1, err))
    print(f"   {'mode':<14} {'sims ours':>9} {'time ours':>10} {'sims FD':>8} {'time FD':>8} "
          f"{'speed-up':>8} {'|diff|/std':>10} {'cost FD/ours-1':>14} {'err vs truth':>12}")
    for mode, n1, t1, n2, t2, d, c, e in rows:
        print(f"   {mode:<14} {n1:>9d} {t1:>9.2f}s {n2:>8d} {t2:>7.2f}s {t2 / t1:>7.1f}x "
              f"{d:>10.3f} {c:>14.1e} {e:>12.1e}")
    for mode in ("per_unit_mass", "absolute"):
        sel = [r for r in rows if r[0] == mode]
        sp = np.median([r[4] / r[2] for r in sel])
        print(f"   median speed-up {mode}: {sp:.1f}x (goal >= 3x at equal accuracy)")


def monte_carlo(n_drives: int) -> None:
    print(f"\n3. Monte Carlo coverage, {n_drives} noisy drives (per unit mass)")
    car = QuarterCarParams()
    model = linear_model()
    truth = np.array([24e3 / 380, 1800 / 380])
    z, rel = [], []
    t0 = time.perf_counter()
    for seed in range(n_drives):
        d = simulate(car, duration_s=60.0, seed=1000 + seed,
                     sensor=SensorModel(noise_std_mps2=0.05))
        res = fit_greybox(GreyBoxData.from_drive(d), model)
        v = np.array([res.parameters[i].value for i in range(2)])
        s = np.array([res.parameters[i].std for i in range(2)])
        z.append((v - truth) / s)
        rel.append(s / v * 100)
    z = np.array(z)
    cover = (np.abs(z) < 3).mean(axis=0)
    print(f"   truth within 3 std: stiffness {100 * cover[0]:.0f} %, damping "
          f"{100 * cover[1]:.0f} %, both {100 * (np.abs(z) < 3).all(axis=1).mean():.0f} % "
          "(goal >= 95 %)")
    print(f"   std(z): stiffness {z[:, 0].std():.2f}, damping {z[:, 1].std():.2f} "
          f"(1 = honest); mean(z) {z[:, 0].mean():+.2f}, {z[:, 1].mean():+.2f}")
    print(f"   mean relative std: stiffness {np.mean(rel, axis=0)[0]:.3f} %, damping "
          f"{np.mean(rel, axis=0)[1]:.3f} %; {(time.perf_counter() - t0) / n_drives:.2f} s "
          "per drive (simulate + integrate + fit)")


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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true", help="fewer drives")
    args = ap.parse_args()
    print(__doc__)
    q = args.quick
    t0 = time.perf_counter()
    perfect_data(1 if q else 3)
    sensitivity_vs_fd(2 if q else 4)
    monte_carlo(20 if q else 100)
    online(3 if q else 10)
    print(f"\ntotal {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
