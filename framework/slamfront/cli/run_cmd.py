"""``slamfront run RECIPE [-o DIR] [--set k=v]...``"""

from __future__ import annotations

import argparse
import contextlib
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from slamfront.cli.arguments import frame_count
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
        epilog="Ctrl-C and SIGTERM finalise the log. A SIGKILL (or a power cut) cannot: the log is fsynced every "
        "log.sync_seconds (5 s by default), so up to that much of the run's end is lost; `slamfront recover "
        "DIR/run.mcap -o FIXED` turns what reached the disk into a finalised log. One run at a time per DIR: a "
        "rerun replaces only files the previous run wrote and that are unchanged since.",
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
    parser.add_argument("--max-frames", type=frame_count, metavar="N", help="stop after N frames (a quick smoke run)")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    parser.add_argument(
        "--live", nargs="?", type=int, const=8765, metavar="PORT",
        help="also serve the run to Foxglove as it happens (Foxglove WebSocket, default port 8765; "
        "in Foxglove: Open connection -> Foxglove WebSocket -> ws://localhost:PORT); the log is still written",
    )
    parser.add_argument("--live-host", default="127.0.0.1", metavar="HOST",
                        help="address --live listens on (default 127.0.0.1: this machine only; 0.0.0.0: all)")
    parser.add_argument("--live-wait", type=float, default=0.0, metavar="SECONDS",
                        help="with --live, wait up to SECONDS for Foxglove to connect before the first frame")
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from slamfront.recipe import build_pipeline, load_recipe
    from slamfront.runtime import run_pipeline

    recipe, path = load_recipe(args.recipe, args.overrides)
    if args.plugin_module:
        recipe = recipe.model_copy(update={"plugin_modules": [*recipe.plugin_modules, *args.plugin_module]})
    pipeline = build_pipeline(recipe, str(path))
    out_dir = args.out or Path("logs") / safe_name(recipe.name)
    with contextlib.ExitStack() as stack:
        sinks = []
        if args.live is not None:
            from slamfront.mcaplog.live import LiveView

            live = stack.enter_context(LiveView(args.live, args.live_host, args.live_wait))
            print(f"live: {live.url} (Foxglove: Open connection -> Foxglove WebSocket)", file=sys.stderr, flush=True)
            sinks.append(live)
        result = run_pipeline(
            pipeline, str(path), out_dir, progress=False if args.quiet else None, max_frames=args.max_frames,
            sinks=sinks,
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
