"""What logging costs: write overhead as a fraction of run time, log size per frame, and
the speed of replay and of the log tools, for any recipe.

Run: .venv/bin/python benchmarks/bench_logging.py [RECIPE] [--max-frames N] [--set k=v ...]
[--variants default,no-images,...] [--repeat N] (default: the demo recipe, `make run`'s, and
every variant, once; for the demo's exact pixels against the JPEGs it logged before:
`demo --variants default,jpeg --repeat 3`, run interleaved; for the Nordland hierarchical run:
`nordland_hsl --variants default,no-images`).
Writes results/logging.md (results/logging_<recipe>.md for another recipe).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import publish, table  # noqa: E402

from slamfront.mcaplog.diff import diff_logs  # noqa: E402
from slamfront.mcaplog.reader import summarize  # noqa: E402
from slamfront.mcaplog.recover import recover_log  # noqa: E402
from slamfront.mcaplog.validate import validate_log  # noqa: E402
from slamfront.recipe import build_pipeline, load_recipe  # noqa: E402
from slamfront.replay import replay_log  # noqa: E402
from slamfront.runtime import RunResult, run_pipeline  # noqa: E402

VARIANTS: dict[str, tuple[str, list[str]]] = {
    "default": ("the recipe's log settings (slamfront default: JPEG 320 px, zstd, 1 MiB chunks, fsync every 5 s; "
                "the demo: PNG at full width and float32 depth)", []),
    "jpeg": ("JPEG 320 px, no depth (what the demo logged before it kept exact pixels)",
             ["log.image_format=jpeg", "log.image_max_width=320", "log.depth=false", "log.depth_encoding=16UC1"]),
    "no-images": ("no images, no scene", ["log.images=false", "log.scene=false"]),
    "png": ("PNG at full width (replayable from the descriptor)", ["log.image_format=png", "log.image_max_width=100000"]),
    "lz4": ("lz4 chunks", ["log.compression=lz4"]),
    "uncompressed": ("uncompressed chunks", ["log.compression=none"]),
    "chunk64k": ("64 KiB chunks", ["log.chunk_size=65536"]),
    "sync0.5": ("fsync every 0.5 s", ["log.sync_seconds=0.5"]),
    "nosync": ("never fsync before the end", ["log.sync_seconds=null"]),
}


def run_variant(recipe: str, overrides: Sequence[str], max_frames: int | None, out: Path) -> RunResult:
    loaded, path = load_recipe(recipe, overrides)
    return run_pipeline(build_pipeline(loaded, str(path)), str(path), out, progress=False, max_frames=max_frames)


def settings_label(recipe: str, overrides: Sequence[str]) -> str:
    """The default row's label: the log settings this recipe actually runs with."""
    options = load_recipe(recipe, overrides)[0].log
    images = f"{options.image_format.upper()} at {options.image_max_width} px" if options.images else "no images"
    images += f", depth {options.depth_encoding}" if options.depth else ""
    sync = "never before the end" if options.sync_seconds is None else f"every {options.sync_seconds:g} s"
    return (f"the recipe's log settings ({images}, {options.compression}, {options.chunk_size / 2**20:g} MiB chunks, "
            f"fsync {sync})")


def timed(work) -> float:  # type: ignore[no-untyped-def]
    start = time.perf_counter()
    work()
    return time.perf_counter() - start


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recipe", nargs="?", default="demo")
    parser.add_argument("--max-frames", type=int)
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument(
        "--variants", default=",".join(VARIANTS),
        help=f"comma-separated subset of {', '.join(VARIANTS)} (default: all; 'default' always runs first)",
    )
    parser.add_argument("--repeat", type=int, default=1,
                        help="run the variants this many times, interleaved (A B A B); rows show medians")
    args = parser.parse_args(argv)
    chosen = ["default", *(v for v in args.variants.split(",") if v and v != "default")]
    unknown = [v for v in chosen if v not in VARIANTS]
    if unknown:
        parser.error(f"unknown variants {unknown}; choose from {', '.join(VARIANTS)}")
    rows, tools = [], []
    with tempfile.TemporaryDirectory() as scratch:
        root = Path(scratch)
        results: dict[str, RunResult] = {}
        wall: dict[str, float] = {}
        samples: dict[str, list[dict]] = {key: [] for key in chosen}
        for repeat in range(args.repeat):
            for key in chosen:
                overrides = VARIANTS[key][1]
                start = time.perf_counter()
                result = run_variant(args.recipe, [*args.overrides, *overrides], args.max_frames, root / f"{key}{repeat}")
                wall.setdefault(key, time.perf_counter() - start)
                results.setdefault(key, result)
                samples[key].append(result.metrics)
        for key in chosen:
            median = {name: statistics.median(m[name] for m in samples[key]) for name in (
                "seconds", "frames_per_second", "log_write_seconds", "log_write_fraction", "log_bytes_per_frame",
                "log_write_mb_per_s", "log_syncs", "log_bytes")}
            rows.append([
                settings_label(args.recipe, args.overrides) if key == "default" else VARIANTS[key][0], median["seconds"], median["frames_per_second"], median["log_write_seconds"],
                100 * median["log_write_fraction"], median["log_bytes_per_frame"] / 1024, median["log_bytes"] / 1e6,
                median["log_write_mb_per_s"], median["log_syncs"],
            ])
        default = results["default"]
        log = default.log_path
        replay_seconds = timed(lambda: replay_log(log, root / "replay", progress=False))
        replayed = root / "replay" / "run.mcap"
        # both end to end (set-up, every stage, evaluation, report): metrics["seconds"] covers the
        # frame loop only, which would flatter the run against a replay that also evaluates
        baseline = wall["default"]
        tools = [
            ["original run (end to end, with evaluation and report)", baseline, 1.0],
            ["replay with the embedded recipe (end to end)", replay_seconds, replay_seconds / baseline],
        ]
        for name, work in (
            ("inspect", lambda: summarize(log)),
            ("inspect --validate (decode every message)", lambda: validate_log(log)),
            ("diff original vs replay", lambda: diff_logs(log, replayed)),
            ("recover (rewrite the whole log)", lambda: recover_log(log, root / "recovered.mcap")),
        ):
            seconds = timed(work)
            tools.append([name, seconds, seconds / baseline])
        n_frames = default.metrics["n_frames"]
        size_mb = log.stat().st_size / 1e6
    body = "\n\n".join([
        f"Recipe `{args.recipe}`{' ' + ' '.join(args.overrides) if args.overrides else ''}, {n_frames} frames, "
        f"each setting run {args.repeat} time(s), interleaved (medians). Write time is "
        "measured inside the run: encoding images, serialising every message, chunk compression, fsync and "
        "closing the file.",
        "## Log options: write overhead and size",
        table(
            ["log setting", "run s", "frames/s", "log write s", "write % of run", "KiB/frame", "log MB", "write MB/s",
             "fsyncs"],
            rows,
        ),
        "Runs share the machine with other work, so compare the write share within a row (both parts of the "
        "ratio are measured in the same run), not run times across rows. KiB/frame does not depend on load.",
        f"## Replay and the log tools (default log, {size_mb:.2f} MB)",
        table(["operation", "seconds", "vs the original run"], tools),
        "A replay re-runs every stage from the first one whose inputs the log does not keep exactly "
        "(`slamfront replay --help`): where the log keeps exact pixels (PNG at full width and float32 depth, as "
        "the demo and the Nordland recipes log them) that is the descriptor, so the replay costs about what the "
        "run did.",
    ])
    name = "logging" if args.recipe == "demo" else f"logging_{Path(args.recipe).stem}"
    publish(name, f"Logging benchmark ({args.recipe})", body)


if __name__ == "__main__":
    main()
