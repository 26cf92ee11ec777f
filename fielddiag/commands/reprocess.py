"""``fielddiag reprocess DIR_OR_GLOB ... [--scheduler tcp://HOST:PORT] [--workers N]
[--force]``: identify and diagnose every before/after pair of a fleet's sessions."""

from __future__ import annotations

import argparse
import sys

from fielddiag.errors import FieldDiagError
from fielddiag.validate import arg_int, arg_number


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "reprocess",
        help="identify and diagnose every before/after pair under folders, on a dask cluster",
        description=(
            "Find the sessions under the folders, files or glob patterns given, pair each "
            "drive with added mass with the drive as the car is (same vehicle and corner, "
            "closest in time; or as a manifest CSV fielddiag-manifest.csv with columns "
            "before,after[,added_mass_kg] says), run identification and diagnosis on every "
            "pair on dask.distributed (a local cluster of process workers by default), and "
            "store the results as JSON beside the before session and in the SQLite catalog "
            "fielddiag-catalog.sqlite that the dashboard reads. Up-to-date results are "
            "skipped; a failing pair fails alone. Exit status 1 when any pair failed."
        ),
    )
    p.add_argument("inputs", nargs="+", metavar="DIR_OR_GLOB",
                   help="folders (searched recursively), session files or glob patterns "
                   "(quote them: 'fleet/**/*.h5')")
    p.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                   help="run on this existing dask cluster (its workers must see the session "
                   "files at the same paths); default: a local cluster")
    p.add_argument("--workers", type=arg_int("--workers", 1, 1024, "worker processes"),
                   metavar="N", default=None,
                   help="worker processes of the local cluster (default: one per core)")
    p.add_argument("--force", action="store_true",
                   help="reprocess pairs whose results are up to date")
    p.add_argument("--steps", default="identify,diagnose", metavar="STEPS",
                   help="what to run per pair, comma-separated (default: identify,diagnose)")
    p.add_argument("--manifest", metavar="FILE.csv",
                   help="pair as this CSV says (columns before,after[,added_mass_kg], paths "
                   "relative to the CSV)")
    p.add_argument("--catalog", metavar="FILE.sqlite",
                   help="catalog file (default: fielddiag-catalog.sqlite in the common folder "
                   "of the inputs, where `fielddiag serve --root` on that folder finds it)")
    p.add_argument("--max-apart-h", type=arg_number("--max-apart-h", "max_apart"),
                   default=24.0, metavar="H",
                   help="pair drives by metadata only when recorded at most H hours apart "
                   "(default 24)")
    p.add_argument("--dry-run", action="store_true",
                   help="show the pairs and what would run, run nothing")
    p.set_defaults(func=run)


def _n(count: int, noun: str) -> str:
    return f"{count} {noun}{'' if count == 1 else 's'}"


def run(args: argparse.Namespace) -> int:
    from fielddiag.batch.report import Progress, format_table, short_path
    from fielddiag.batch.reprocess import plan, reprocess

    if args.workers is not None and args.workers < 1:
        raise FieldDiagError(f"--workers must be at least 1 (got {args.workers})")
    if args.scheduler and args.workers is not None:
        raise FieldDiagError("--workers sizes a local cluster; it cannot be combined with "
                             "--scheduler (size a remote cluster where it runs)")
    steps = [s.strip() for s in args.steps.split(",") if s.strip()]
    batch = plan(args.inputs, steps=steps, force=args.force, manifest=args.manifest,
                 catalog_path=args.catalog, max_apart_h=args.max_apart_h)
    root = batch.root
    n_pairs = len(batch.pairing.pairs)
    print(f"{_n(n_pairs, 'pair')} under {root}: {len(batch.jobs)} to run, "
          f"{n_pairs - len(batch.jobs)} up to date; "
          f"{_n(len(batch.pairing.unpaired), 'session')} not paired, "
          f"{len(batch.pairing.unreadable)} unreadable")
    if args.dry_run:
        for job in batch.jobs:
            print(f"  would run {'+'.join(job.steps)}: {short_path(job.before, root)} + "
                  f"{short_path(job.after, root)} (+{job.added_mass_kg:g} kg)")
        for path, why in [*batch.pairing.unreadable, *batch.pairing.unpaired]:
            print(f"  left out {short_path(path, root)}: {why}")
        return 0

    progress = Progress(len(batch.jobs), root)

    def started(info) -> None:
        where = "local cluster" if info.local else "cluster"
        progress.start(f"running on a {where} at {info.address} with {info.n_workers} "
                       f"workers ({info.threads} threads)")

    try:
        report = reprocess(batch, scheduler=args.scheduler, workers=args.workers,
                           on_done=progress.update, on_start=started)
    except KeyboardInterrupt:
        print("\ninterrupted: the pairs finished so far are stored; run the same command "
              "again to resume", file=sys.stderr)
        return 130
    progress.finish()
    print()
    print(format_table(report.outcomes, root, batch.pairing.unpaired, batch.pairing.unreadable))
    print()
    done = sum(o.status == "done" for o in report.outcomes)
    print(f"{done} processed, {sum(o.status == 'skipped' for o in report.outcomes)} up to date, "
          f"{report.n_failed} failed in {report.wall_s:.1f} s; catalog {batch.catalog_path}")
    return 1 if report.n_failed else 0
