"""``fielddiag fit``: grey-box fit of the body equation to one or more sessions.

    fielddiag fit before.h5 after.h5 --added-mass 80 --json fit.json
    fielddiag fit drive.h5 --terms coulomb_friction --band 0.5 30

The body is simulated driven by the measured (integrated) wheel motion from static
equilibrium, and stiffness, damping (and any effect terms) are fitted to the measured body
acceleration by Levenberg-Marquardt with the Jacobian from the sensitivity equations.
One session, or sessions all with the same added mass, give values per unit sprung mass;
two different added masses give absolute values and the sprung mass. Every parameter comes
with its standard deviation (honest for autocorrelated residuals) and relative standard
deviation, the correlation matrix, and the NRMSE of the body acceleration on the fit data
and on held-out data (the last quarter of each session by default, or other drives).
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import TYPE_CHECKING

from fielddiag.errors import FieldDiagError
from fielddiag.validate import arg_int, arg_number, band_hz, existing_file, finite_session

if TYPE_CHECKING:
    from fielddiag.identify.terms import ForceModel

#: The effect terms ``--terms`` takes (fielddiag.identify.terms.TERMS without the linear
#: spring and damper; named here so that parsing the options does not import the numerics).
EFFECT_TERMS = ("coupling_spring", "coulomb_friction", "cubic_stiffness", "bump_stop",
                "asymmetric_damping")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "fit",
        help="grey-box fit (sensitivity equations + Levenberg-Marquardt) with uncertainty",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("sessions", nargs="+", metavar="SESSION.h5",
                   help="session files fitted together (wheel and body channels by role)")
    p.add_argument("--added-mass", type=arg_number("--added-mass", "added_mass"),
                   metavar="KG", default=None,
                   help="mass added on the body in every session after the first (the first "
                        "is taken without); default: each session's added_mass_kg attribute")
    p.add_argument("--terms", metavar="NAME[,NAME...]", default="",
                   help="effect terms added to the linear spring and damper: "
                        + ", ".join(EFFECT_TERMS))
    p.add_argument("--band", nargs=2, type=arg_number("--band", "frequency"),
                   metavar=("LOW_HZ", "HIGH_HZ"), default=None,
                   help="band of integration and comparison (default 0.5-30 Hz)")
    p.add_argument("--start", type=arg_number("--start", "time_s"), default=None, metavar="S",
                   help="use data from this session time on")
    p.add_argument("--end", type=arg_number("--end", "time_s"), default=None, metavar="S",
                   help="use data up to this session time")
    p.add_argument("--holdout", type=arg_number("--holdout", "holdout"), default=0.25,
                   metavar="FRACTION",
                   help="fraction at the end of each session kept out of the fit for "
                        "validation (default 0.25; 0 uses everything for the fit)")
    p.add_argument("--validate", action="append", default=[], metavar="SESSION.h5",
                   help="another drive to validate on (repeatable; same added-mass rule)")
    p.add_argument("--body-mass", type=arg_number("--body-mass", "body_mass"), default=None,
                   metavar="KG",
                   help="sprung-mass guess (start value of an absolute fit)")
    p.add_argument("--max-iterations", default=50, metavar="N",
                   type=arg_int("--max-iterations", 1, 10000, "the most iterations"))
    p.add_argument("--json", metavar="OUT", default=None,
                   help="write the result as JSON to OUT ('-' for standard output)")
    p.set_defaults(func=run)


def build_model(terms: str) -> ForceModel:
    """Linear spring + damper plus the comma-separated effect terms."""
    names = [t.strip() for t in terms.split(",") if t.strip()]
    for name in names:
        if name not in (*EFFECT_TERMS, "linear_spring", "linear_damper"):
            raise FieldDiagError(f"--terms {name}: unknown term; choose from "
                                 f"{', '.join(EFFECT_TERMS)}")
    from fielddiag.identify.terms import make_term

    model = make_term("linear_spring") + make_term("linear_damper")
    for name in names:
        if name in ("linear_spring", "linear_damper"):
            continue
        model = model + make_term(name)
    return model


def run(args: argparse.Namespace) -> int:
    from fielddiag.outputs import check_target

    for path in [*args.sessions, *args.validate]:
        existing_file(path)
    if args.start is not None and args.end is not None and not args.end > args.start:
        raise FieldDiagError(f"--end {args.end:g} is not after --start {args.start:g}: give "
                             "an end time later than the start, in s")
    band = band_hz(args.band)
    if args.json and args.json != "-":
        check_target(args.json, overwrite=True, flag="--json")
    for path in [*args.sessions, *args.validate]:
        finite_session(path)
    model = build_model(args.terms)

    from fielddiag.identify.greybox import GreyBoxData, fit_greybox

    def load(path: str, index: int) -> GreyBoxData:
        dm = None
        if args.added_mass is not None:
            dm = 0.0 if index == 0 else args.added_mass
        return GreyBoxData.from_session(path, start_s=args.start, end_s=args.end,
                                        band_hz=band, added_mass_kg=dm)

    fit_data, val_data = [], []
    for i, path in enumerate(args.sessions):
        d = load(path, i)
        if args.holdout > 0:
            f, v = d.split(1.0 - args.holdout)
            fit_data.append(f)
            val_data.append(v)
        else:
            fit_data.append(d)
    for path in args.validate:
        val_data.append(load(path, 1 if args.added_mass is not None else 0))
    result = fit_greybox(fit_data, model, body_mass_kg=args.body_mass, validation=val_data,
                         max_iterations=args.max_iterations)
    print(result.summary(), file=sys.stderr if args.json == "-" else sys.stdout)
    if args.json:
        text = json.dumps(result.to_dict(), indent=2)
        if args.json == "-":
            print(text)
        else:
            from fielddiag.outputs import write_text

            write_text(args.json, text + "\n")
    return 0
