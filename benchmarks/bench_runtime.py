"""Runtime costs: rendering the synthetic world, the paired_demo pipeline, and logging.

Run: .venv/bin/python benchmarks/bench_runtime.py
"""

from __future__ import annotations

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
    for width, height in ((160, 120), (320, 240), (640, 480)):
        source = SyntheticWorld(SyntheticWorld.Config(frames_per_traversal=40, image_width=width, image_height=height))
        frames = source.frames()
        next(frames)  # build the world outside the timing
        seconds = best_of(1, lambda frames=frames: [next(frames) for _ in range(30)])
        rate = 30 / seconds
        base = base or rate
        rows.append([f"{width}x{height}", rate, 1000 / rate, base / rate])
    return rows


def pipeline_runs() -> tuple[list[list[object]], dict[str, float]]:
    rows = []
    timings = {}
    for label, overrides in (
        ("images off", ["log.images=false"]),
        ("images on (jpeg, 320 px)", []),
        ("images on (png, lossless)", ["log.image_format=png"]),
    ):
        recipe, path = load_recipe("paired_demo", overrides)
        with tempfile.TemporaryDirectory() as out:
            result = run_pipeline(build_pipeline(recipe, str(path)), str(path), Path(out), progress=False)
            metrics = result.metrics
        timings[label] = metrics["seconds"]
        rows.append([
            label, metrics["seconds"], metrics["frames_per_second"], metrics["log_bytes"] / metrics["n_frames"] / 1024,
        ])
    base = timings["images off"]
    for row in rows:
        row.append(row[1] / base)
    stage_rows = [
        [kind, t["median_ms"], t["p99_ms"], t["total_s"]] for kind, t in metrics["timing"].items()
    ]
    return rows, {"stages": stage_rows}


def main() -> None:
    render = render_rates()
    runs, extra = pipeline_runs()
    body = "\n\n".join([
        "## Synthetic world rendering (one core for shading, Open3D ray casting on all)",
        table(["image", "frames/s", "ms/frame", "time vs 160x120"], render),
        "## paired_demo recipe (400 + 400 frames), whole run incl. rendering",
        table(["log setting", "seconds", "frames/s", "log KiB/frame", "time vs images off"], runs),
        "## Per-stage latency (last run)",
        table(["stage", "median ms", "p99 ms", "total s"], extra["stages"]),
    ])
    publish("runtime", "Runtime benchmark", body)


if __name__ == "__main__":
    main()
