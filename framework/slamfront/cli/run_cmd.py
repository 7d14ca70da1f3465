"""``slamfront run RECIPE [-o DIR] [--set k=v]...``"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from slamfront.cli.completion import complete_overrides, complete_recipes
from slamfront.outputs import safe_name
from slamfront.report.headline import headline
from slamfront.text import shorten

if TYPE_CHECKING:
    from slamfront.runtime import RunResult


def add_parser(commands: argparse._SubParsersAction) -> None:
    parser = commands.add_parser(
        "run",
        help="run a recipe: writes run.mcap, metrics.json, report.md and report.html",
        description="Run a recipe. Writes DIR/run.mcap, DIR/metrics.json, DIR/report.md, DIR/report.html "
        "(one page with the plots inside: open it in a browser) and the plots.",
    )
    recipe_arg = parser.add_argument("recipe", help="recipe file, or the name of a shipped recipe (see `slamfront recipes`)")
    recipe_arg.completer = complete_recipes  # type: ignore[attr-defined]
    parser.add_argument("-o", "--out", type=Path, help="output folder (default: logs/<recipe name>/)")
    parser.add_argument(
        "--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
        help="override a recipe field, e.g. --set loop_detector.params.threshold=0.3 (repeatable); "
        "--set STAGE.plugin=X starts X from its own defaults",
    ).completer = complete_overrides  # type: ignore[attr-defined]
    parser.add_argument("-p", "--plugin-module", action="append", default=[], metavar="MODULE",
                        help="register an extra plugin module (importable name; repeatable)")
    parser.add_argument("--max-frames", type=int, metavar="N", help="stop after N frames (a quick smoke run)")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from slamfront.recipe import build_pipeline, load_recipe
    from slamfront.runtime import run_pipeline

    recipe, path = load_recipe(args.recipe, args.overrides)
    if args.plugin_module:
        recipe = recipe.model_copy(update={"plugin_modules": [*recipe.plugin_modules, *args.plugin_module]})
    pipeline = build_pipeline(recipe, str(path))
    out_dir = args.out or Path("logs") / safe_name(recipe.name)
    result = run_pipeline(
        pipeline, str(path), out_dir, progress=False if args.quiet else None, max_frames=args.max_frames
    )
    print_outcome(result)
    return 0


def print_outcome(result: RunResult) -> None:
    """Where the outputs are and the headline metrics."""
    metrics = result.metrics
    for note in result.notes:
        print(f"warning: {shorten(note, 2000)}")
    print(f"log:     {result.log_path}")
    print(f"report:  {result.html_path or result.report_path}")
    print(f"metrics: {result.metrics_path}")
    for sentence in headline(metrics):
        print(f"  {sentence}")
