"""Grey-box optimiser: the hand-written Levenberg-Marquardt vs scipy's least_squares (prints).

Method: the fits a diagnosis makes. For scenarios of fielddiag.scenarios (before/after
pairs, 2 drives, prepared like fielddiag.diagnose.engine: integrated in the default band,
resampled to 125 Hz, first 70 % fitted, last 30 % held out), the linear model and the
model with the scenario's true effect(s) are fitted with fit_greybox exactly as the
diagnosis does (continuation 0 / 0.2 / 2 s, max 40 iterations, 2 RK4 substeps) by

* ``lm``: fielddiag.identify.greybox_solver.levenberg_marquardt (bounded LM, QR + BVLS
  steps, Marquardt scaling, Nielsen's damping update);
* ``trf``: scipy.optimize.least_squares(method="trf", x_scale=1 on the same normalised
  parameters, same xtol/ftol/gtol, max_nfev = the iteration limit) with the *same*
  analytic Jacobian from the sensitivity equations (each residual call computes it; scipy
  asks for it only at accepted points and gets the cached one).

The model's numba kernels are compiled by a warm-up fit before either is timed. Printed
per fit: residual evaluations (each one simulation with sensitivities), wall time,
final cost relative to LM's, held-out NRMSE. Then the medians. Run:
``python benchmarks/bench_greybox_solver.py [SCENARIO ...]``.
"""

from __future__ import annotations

import statistics
import sys
import time

import numpy as np

from fielddiag.diagnose.engine import Drive, _band_and_rate, _model, _prepare
from fielddiag.identify.greybox import fit_greybox, validation_runs
from fielddiag.identify.greybox_results import nrmse
from fielddiag.scenarios import SCENARIOS, simulate_scenario

DEFAULT = ["friction_2", "cubic_2", "bump_stop_2", "asymmetric_2", "friction_and_asymmetric",
           "linear_plain"]


def main(names: list[str]) -> None:
    print(__doc__)
    rows = []
    for name in names:
        sc = SCENARIOS[name]
        before, after = simulate_scenario(sc)
        drives = [Drive(d.wheel_accel_mps2, d.body_accel_mps2, d.sample_rate_hz,
                        added_mass_kg=d.added_mass_kg, label=lab, name=name)
                  for lab, d in (("before", before), ("after", after))]
        band, rate = _band_and_rate(drives, None, 0.3, 125.0)
        prep = [_prepare(d, band, rate, 0.3) for d in drives]
        effects = tuple(e for e, _ in sc.effects)
        for combo in {(), effects}:
            model = _model(combo, True)
            res = {}
            # warm-up: compile the model's kernels before timing anything
            fit_greybox([p.fit for p in prep], model, substeps=2, max_iterations=1,
                        horizons_s=None)
            for solver in ("lm", "trf"):
                t0 = time.perf_counter()
                with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
                    r = fit_greybox([p.fit for p in prep], model, substeps=2,
                                    max_iterations=40, solver=solver)
                wall = time.perf_counter() - t0
                runs = validation_runs(r, [p.val for p in prep], substeps=2)
                nv = nrmse(np.concatenate([x[2] for x in runs]),
                           np.concatenate([x[1] for x in runs]))
                res[solver] = (r.model_evaluations, wall, r.cost_history[-1], nv)
            c_lm = res["lm"][2]
            for solver, (ev, wall, cost, nv) in res.items():
                label = "+".join(combo) or "linear"
                print(f"  {name:24s} {label:40s} {solver:4s} evals {ev:4d}  time {wall:6.2f} s"
                      f"  cost/LM-1 {cost / c_lm - 1:+.1e}  held-out NRMSE {nv:.4f}",
                      flush=True)
                rows.append((solver, ev, wall, cost / c_lm - 1, nv))
    for solver in ("lm", "trf"):
        sel = [r for r in rows if r[0] == solver]
        print(f"median {solver}: evals {statistics.median(r[1] for r in sel):.0f}, time "
              f"{statistics.median(r[2] for r in sel):.2f} s, total time "
              f"{sum(r[2] for r in sel):.1f} s, worst cost/LM-1 "
              f"{max(r[3] for r in sel):+.1e}")


if __name__ == "__main__":
    main(sys.argv[1:] or DEFAULT)
