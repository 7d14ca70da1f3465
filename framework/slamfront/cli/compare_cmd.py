"""``slamfront compare RECIPE... [-o DIR] [--set k=v]...``"""

from __future__ import annotations

import argparse
from pathlib import Path

from slamfront.cli.arguments import frame_count
from slamfront.cli.completion import complete_recipes


def add_parser(commands: argparse._SubParsersAction) -> None:
    parser = commands.add_parser(
        "compare",
        help="run several loop-closure recipes through one harness and compare them",
        description=(
            "Run each recipe (a campaign: parallel, resumable, each run with its own log in DIR/runs/) "
            "and write DIR/comparison.md and DIR/comparison.html (a page linking every run's report): recall at 100 % precision and AUC-PR (zeta 3 and 1), search "
            "space and speed per method, all PR curves on one plot (pr_all.png), each method's match plot."
        ),
    )
    recipe_arg = parser.add_argument("recipes", nargs="+", help="recipe files or shipped recipe names")
    recipe_arg.completer = complete_recipes  # type: ignore[attr-defined]
    parser.add_argument("-o", "--out", type=Path, default=Path("logs/compare"), help="output folder")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help="override applied to every recipe (repeatable)")
    parser.add_argument("--workers", type=int, metavar="N", help="parallel runs (default: the CPU count)")
    parser.add_argument("--max-frames", type=frame_count, metavar="N", help="stop every run after N frames")
    parser.add_argument("--force", action="store_true", help="run again even the runs already finished in DIR")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from slamfront.campaign import LocalBackend
    from slamfront.compare import compare

    result = compare(
        args.recipes, args.out, LocalBackend(args.workers), args.overrides, max_frames=args.max_frames,
        progress=False if args.quiet else None, force=args.force,
    )
    print(f"comparison: {result.report_path.with_suffix('.html')}")
    print(f"results:    {result.campaign.results_csv}")
    failed = result.campaign.count("failed")
    return 1 if failed else 0
