"""Runtime costs: rendering the synthetic world, the paired_demo pipeline, and logging.

Run: .venv/bin/python benchmarks/bench_runtime.py [--rounds 3]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import best_of, publish, table  # noqa: E402

from slamfront.recipe import build_pipeline, load_recipe  # noqa: E402
from slamfront.runtime import run_pipeline  # noqa: E402
from slamfront_plugins.sources.synthetic import SyntheticWorld  # noqa: E402


def render_rates() -> list[list[object]]:
    rows = []
    base = None
    warm = SyntheticWorld(SyntheticWorld.Config(frames_per_traversal=40, image_width=160, image_height=120)).frames()
    for _ in range(10):  # untimed: the first frames of a process pay compilation and the ray caster's set-up
        next(warm)
    for width, height in ((160, 120), (320, 240), (640, 480)):
        source = SyntheticWorld(SyntheticWorld.Config(frames_per_traversal=40, image_width=width, image_height=height))
        frames = source.frames()
        next(frames)  # build the world outside the timing
        seconds = best_of(1, lambda frames=frames: [next(frames) for _ in range(30)])
        rate = 30 / seconds
        base = base or rate
        rows.append([f"{width}x{height}", rate, 1000 / rate, base / rate])
    return rows


SETTINGS = (
    ("images off", ["log.images=false"]),
    ("images on (jpeg, 320 px)", []),
    ("images on (png, lossless)", ["log.image_format=png"]),
)


def _run(overrides: list[str]) -> dict:
    recipe, path = load_recipe("paired_demo", overrides)
    with tempfile.TemporaryDirectory() as out:
        return run_pipeline(build_pipeline(recipe, str(path)), str(path), Path(out), progress=False).metrics


def pipeline_runs(rounds: int) -> tuple[list[list[object]], list[list[object]]]:
    """Every setting once per round, interleaved (A B C A B C ...), after one untimed warm-up
    run (the first run in a process pays compilation and the world's caches); seconds are
    medians over rounds, ratios the medians of the round-by-round ratios."""
    _run(["log.images=false"])
    seconds: dict[str, list[float]] = {label: [] for label, _ in SETTINGS}
    metrics: dict[str, dict] = {}
    for _ in range(rounds):
        for label, overrides in SETTINGS:
            metrics[label] = _run(overrides)
            seconds[label].append(metrics[label]["seconds"])
    base = seconds["images off"]
    rows: list[list[object]] = []
    for label, _ in SETTINGS:
        m = metrics[label]
        ratios = [a / b for a, b in zip(seconds[label], base)]
        rows.append([label, statistics.median(seconds[label]), m["n_frames"] / statistics.median(seconds[label]),
                     m["log_bytes"] / m["n_frames"] / 1024, statistics.median(ratios),
                     f"{min(ratios):.3g}-{max(ratios):.3g}"])
    last = metrics[SETTINGS[-1][0]]
    stage_rows: list[list[object]] = [[kind, t["median_ms"], t["p99_ms"], t["total_s"]] for kind, t in last["timing"].items()]
    return rows, stage_rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=3, help="interleaved rounds of the pipeline runs")
    args = parser.parse_args()
    load = os.getloadavg()[0]
    render = render_rates()
    runs, stages = pipeline_runs(args.rounds)
    body = "\n\n".join([
        f"`nice .venv/bin/python benchmarks/bench_runtime.py --rounds {args.rounds}`; load average (1 min) "
        f"{load:.1f} at the start, {os.getloadavg()[0]:.1f} at the end, on a machine shared with other jobs: "
        "compare the ratios.",
        "## Synthetic world rendering (one core for shading, Open3D ray casting on all)",
        table(["image", "frames/s", "ms/frame", "time vs 160x120"], render),
        f"## paired_demo recipe (400 + 400 frames), whole run incl. rendering, {args.rounds} interleaved rounds",
        table(["log setting", "seconds (median)", "frames/s", "log KiB/frame", "time vs images off (median)",
               "[range]"], runs),
        "## Per-stage latency (last run, png)",
        table(["stage", "median ms", "p99 ms", "total s"], stages),
    ])
    publish("runtime", "Runtime benchmark", body)


if __name__ == "__main__":
    main()
