"""Write the concealed-effect drive pairs of fielddiag.scenarios as sessions.

Usage::

    python sample_data/concealed/make_concealed.py            # the small committed set
    python sample_data/concealed/make_concealed.py --all DIR  # every scenario into DIR

Each case gives ``<name>_before.h5``, ``<name>_after.h5`` (no recipe inside, so the
diagnosis cannot peek) and ``<name>_truth.json`` (the car, the effects and their sizes,
and what a correct diagnosis says). The drives are deterministic in the scenario's seed.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from fielddiag.scenarios import SCENARIOS, write_scenario

#: Committed to the repository (small): one concealed effect, a pair, and a linear car.
COMMITTED = ("friction_2", "bump_stop_1", "linear_plain")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--all", metavar="DIR", help="write every scenario into DIR")
    args = p.parse_args()
    if args.all:
        names, folder = list(SCENARIOS), Path(args.all)
    else:
        names, folder = list(COMMITTED), Path(__file__).parent
    for name in names:
        before, after, truth = write_scenario(SCENARIOS[name], folder)
        print(f"{name}: {before.name}, {after.name}, {truth.name} — {SCENARIOS[name].description}")


if __name__ == "__main__":
    main()
