"""Speed of the diagnosis with the whole effect library: a 2 x 300 s pair at 500 Hz.

Method: the default car (fielddiag.sim.QuarterCarParams()) on an ISO 8608 class C road,
two 300 s drives at 500 Hz (the second with 60 kg added), 35 dB SNR, simulated once per
case; ``diagnose_drives`` is timed from the recorded accelerations to the JSON (all of:
data checks, frequency-domain start, linear fit, screening of every library effect, full
fits, pairs, data hypotheses, ride height, shape model), after one warm-up diagnosis so
that numba's compiled kernels come from the on-disk cache as they do for a user. The
machine's load average is printed beside each time: the figure is only comparable on an
otherwise idle machine (2 cores).

With ``--steps`` the diagnosis's progress lines are printed with the time each began (where
the time goes: screening, single fits, pairs, data hypotheses, ride height). Grey-box fits
of effects with internal states take their Jacobian from the states' sensitivity
equations (one run per iteration), a pair with one is fitted where its signature adds to
its better single's (docs/diagnosis.md, step 4).

Usage: python benchmarks/bench_diagnose_speed.py [--cases linear,coulomb_friction,bouc_wen]
                                                 [--steps]
"""

from __future__ import annotations

import argparse
import os
import sys
import time

#: Target of issue 17: a 2 x 300 s pair at 500 Hz diagnosed in under this [s].
TARGET_S = 60.0

CASES = {
    "linear": (),
    "coulomb_friction": (("coulomb_friction", {"friction_force_n": 80.0}),),
    "bouc_wen": (("bouc_wen", {"hysteretic_force_n": 120.0, "yield_displacement_m": 1e-3,
                                "yield_exponent": 2.0}),),
    "series_top_mount": (("series_top_mount", {"suspension_damping_ns_per_m": 1800.0,
                                               "mount_stiffness_n_per_m": 6e4}),),
}


def _drives(effects):
    from fielddiag import sim
    from fielddiag.diagnose.engine import Drive

    sensor = sim.SensorModel(output_rate_hz=500.0, snr_db=35.0)
    pair = sim.simulate_pair(sim.QuarterCarParams(), added_mass_kg=60.0, seed=17,
                             duration_s=300.0, road_class="C",
                             effects=[sim.make_effect(n, **p) for n, p in effects],
                             wheel_sensor=sensor, body_sensor=sensor)
    return [Drive(wheel_accel_mps2=d.wheel_accel_mps2, body_accel_mps2=d.body_accel_mps2,
                  sample_rate_hz=d.sample_rate_hz, added_mass_kg=d.added_mass_kg,
                  label=label, name="speed", start_s=0.0)
            for label, d in zip(("before", "after"), pair, strict=True)]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--steps", action="store_true",
                    help="print each step of the diagnosis with the time it began")
    args = ap.parse_args(argv)
    from fielddiag.diagnose.engine import diagnose_drives
    from fielddiag.effects import diagnosis_effects

    print(__doc__.split("Usage:")[0].rstrip())
    print(f"library: {', '.join(diagnosis_effects())}")
    warm = _drives(())
    diagnose_drives([_shorten(d) for d in warm])  # kernels compiled / loaded once
    worst = 0.0
    for name in args.cases.split(","):
        drives = _drives(CASES[name])
        load0 = os.getloadavg()[0]
        t0 = time.perf_counter()

        def step(msg: str, _t0: float = t0) -> None:
            print(f"      {time.perf_counter() - _t0:6.1f} s  {msg}", flush=True)

        out = diagnose_drives(drives, progress=step if args.steps else None).to_dict()
        wall = time.perf_counter() - t0
        worst = max(worst, wall)
        named = ", ".join(f["effect"] for f in out["findings"]) or "-"
        print(f"  {name:<18} {wall:6.1f} s   named {named:<30} load average "
              f"{load0:.1f} -> {os.getloadavg()[0]:.1f}", flush=True)
    print(f"worst {worst:.1f} s against the target {TARGET_S:.0f} s: "
          f"{'met' if worst < TARGET_S else 'NOT met'}")
    return 0


def _shorten(d):
    from dataclasses import replace

    n = int(40 * d.sample_rate_hz)
    return replace(d, wheel_accel_mps2=d.wheel_accel_mps2[:n],
                   body_accel_mps2=d.body_accel_mps2[:n])


if __name__ == "__main__":
    sys.exit(main())
