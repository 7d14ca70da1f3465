"""``slamfront outliers GRAPH... [--ground-truth FILE]... [--rates ...] [--methods ...] [-o DIR]``"""

from __future__ import annotations

import argparse
from pathlib import Path

from slamfront.errors import SlamfrontError
from slamfront.posegraph.kernels import METHODS, RATES


def add_parser(commands: argparse._SubParsersAction) -> None:
    parser = commands.add_parser(
        "outliers",
        help="outlier study: add false loop closures, compare robust kernels and GNC",
        description=(
            "Add random false loop closures to each graph (rate = share of all loop closures that are false) and "
            "optimise with each method. Writes DIR/outliers.md (one table), DIR/outliers.json and "
            "DIR/outliers.png. Methods: " + ", ".join(METHODS) + "."
        ),
    )
    parser.add_argument("graphs", type=Path, nargs="+", metavar="GRAPH", help="g2o or iSAM pose graphs")
    parser.add_argument("--ground-truth", type=Path, action="append", default=[], metavar="FILE",
                        help="ground truth of each graph, in the same order (repeat per graph)")
    parser.add_argument("--rates", type=float, nargs="+", default=list(RATES), metavar="RATE",
                        help="outlier rates in [0, 1) (default: 0 0.1 0.2 0.5)")
    parser.add_argument("--methods", nargs="+", default=list(METHODS), choices=list(METHODS),
                        metavar="METHOD", help="methods to compare (default: all)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the false closures")
    parser.add_argument("-o", "--out", type=Path, default=Path("logs") / "outliers", help="output folder")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from slamfront.posegraph import study

    if args.ground_truth and len(args.ground_truth) != len(args.graphs):
        raise SlamfrontError(
            f"--ground-truth: {len(args.ground_truth)} files for {len(args.graphs)} graphs; give one per graph or none"
        )
    bad = [r for r in args.rates if not 0.0 <= r < 1.0]
    if bad:
        raise SlamfrontError(f"--rates: {bad[0]} is not in [0, 1)")
    if 0.0 not in args.rates:
        args.rates = [0.0, *args.rates]  # the clean run is the reference of every other
    graphs = study.load(args.graphs, args.ground_truth)
    done: list[study.StudyRow] = []

    def keep(row: study.StudyRow) -> None:
        # a long study keeps its finished rows on disk, so stopping it loses nothing done
        done.append(row)
        study.write(done, args.out, plots=False)

    rows = study.run_study(graphs, args.rates, args.methods, args.seed, False if args.quiet else None, keep)
    files = study.write(rows, args.out)
    print(study.table(rows))
    for path in files:
        print(f"wrote {path}")
    return 0
