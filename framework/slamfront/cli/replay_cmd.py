"""``slamfront replay LOG [--recipe R] [--from STAGE] [-o DIR] [--set k=v]...``"""

from __future__ import annotations

import argparse
from pathlib import Path

from slamfront.kinds import STAGE_KINDS
from slamfront.outputs import safe_name


def add_parser(commands: argparse._SubParsersAction) -> None:
    parser = commands.add_parser(
        "replay",
        help="re-run stages on the outputs a log recorded (no source data needed)",
        description=(
            "Replay a run from its log: the frames and the outputs of every stage before --from are read "
            "from LOG, and --from and the later stages run again with the recipe given (default: the one "
            "LOG embeds). Writes DIR/run.mcap, DIR/metrics.json and DIR/report.md like `run`."
        ),
    )
    parser.add_argument("log", type=Path, help="a run's .mcap file (or its run folder)")
    parser.add_argument("--recipe", help="replay with this recipe (its stages before --from must match the log's)")
    parser.add_argument(
        "--from", dest="from_kind", choices=(*STAGE_KINDS, "evaluation"), metavar="STAGE",
        help=f"first stage to run again, one of {', '.join(STAGE_KINDS)}, or evaluation to read every stage from "
        "the log and only evaluate again (default: the earliest stage the log can feed, else evaluation)",
    )
    parser.add_argument("-o", "--out", type=Path, help="output folder (default: logs/<recipe name>_replay/)")
    parser.add_argument(
        "--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
        help="override a field of the replay recipe, e.g. --set loop_detector.params.threshold=0.3",
    )
    parser.add_argument(
        "--trust-log", action="store_true",
        help="let the log's recipe import its plugin_modules and read paths outside the data root "
        "(a log is data: without this, such fields are refused)",
    )
    parser.add_argument(
        "--salvage", action="store_true",
        help="replay a damaged log as far as it can be read, saying what was lost (without it, a damaged log is refused)",
    )
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from slamfront.cli.run_cmd import print_outcome
    from slamfront.mcaplog.reader import log_file
    from slamfront.recipe import apply_overrides, load_recipe, parse_recipe
    from slamfront.replay import log_recipe_data, replay_log

    log = log_file(args.log)
    recipe, origin = None, None
    if args.recipe:
        recipe, path = load_recipe(args.recipe, args.overrides)
        origin = str(path)
    elif args.overrides:
        origin = f"{log}:recipe.yaml"
        recipe = parse_recipe(apply_overrides(log_recipe_data(log), args.overrides), origin)
    name = recipe.name if recipe is not None else str(log_recipe_data(log).get("name", "run"))
    out_dir = args.out or Path("logs") / f"{safe_name(name)}_replay"  # the name may come from a stranger's log
    result = replay_log(
        log, out_dir, recipe, origin, args.from_kind, progress=False if args.quiet else None,
        trust_log=args.trust_log, salvage=args.salvage,
    )
    print_outcome(result)
    return 0
