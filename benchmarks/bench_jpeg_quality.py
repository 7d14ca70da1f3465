"""The demo stream as a ROS 1 bag with JPEG images at several qualities: ATE after optimisation.

Writes the demo's synthetic stream (``recipes/demo.yaml``) into ROS 1 bags (JPEG
``CompressedImage`` at each quality, ``compressedDepth`` depth, ``CameraInfo``, ``/tf``
poses), runs the demo recipe on each with only its source swapped to ``ros_bag``, and
prints a table against the raw synthetic run, with the odometry fallbacks and the loop
closures added.

    nice -n 10 .venv/bin/python -m benchmarks.bench_jpeg_quality --qualities 60 70 80 90 95 100
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

from slamfront.recipe import Recipe, build_pipeline, load_recipe
from slamfront.runtime import run_pipeline
from slamfront_plugins.sources.synthetic import SyntheticWorld
from tests.recordings import BagSpec, BagWriter

RADIUS_M = 3.1  # as tests/test_ros_bag_demo.py: the second lap drives 0.3 m aside


def _metrics(recipe: Recipe, out: Path) -> dict[str, float]:
    result = run_pipeline(build_pipeline(recipe, "demo"), "demo", out, progress=False)
    return result.metrics


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--qualities", type=int, nargs="+", default=[60, 70, 80, 90, 95, 100])
    parser.add_argument("--set", action="append", default=[], help="recipe overrides, as `slamfront run --set`")
    args = parser.parse_args(argv)
    demo, _ = load_recipe("demo", ["eval.plots=false", "log.images=false", *args.set])
    world = SyntheticWorld(SyntheticWorld.Config(**demo.source.params))
    root = Path(tempfile.mkdtemp(prefix="bench_jpeg_"))
    try:
        start = time.monotonic()
        raw = _metrics(demo, root / "raw")
        print(f"raw: ATE after {raw['ate_rmse_after_m']:.3f} m, before {raw['ate_rmse_before_m']:.3f} m, "
              f"fallbacks {raw.get('n_odometry_fallbacks')} ({time.monotonic() - start:.0f} s)", file=sys.stderr)
        rows = [("raw stream", raw)]
        dumped = demo.model_dump(mode="json", exclude_none=True)
        for quality in args.qualities:
            spec = BagSpec(ros=1, image="jpeg", depth="compressedDepth", pose="tf", jpeg_quality=quality)
            bag = root / f"q{quality}.bag"
            with BagWriter(bag, spec) as writer:
                for frame in world.frames():
                    writer.write_frame(frame)
            params = {**spec.source_params(bag), "revisit_radius_m": RADIUS_M}
            recipe = Recipe.model_validate({**dumped, "source": {"plugin": "ros_bag", "params": params}})
            metrics = _metrics(recipe, root / f"q{quality}")
            rows.append((f"JPEG quality {quality}", metrics))
            print(f"q{quality}: ATE after {metrics['ate_rmse_after_m']:.3f} m "
                  f"({metrics['ate_rmse_after_m'] / raw['ate_rmse_after_m']:.2f}x), "
                  f"fallbacks {metrics.get('n_odometry_fallbacks')} ({time.monotonic() - start:.0f} s)", file=sys.stderr)
        print("| stream | ATE after (m) | ratio to raw | ATE before (m) | odometry fallbacks | loop closures added |")
        print("| --- | --- | --- | --- | --- | --- |")
        for name, m in rows:
            print(f"| {name} | {m['ate_rmse_after_m']:.3f} | {m['ate_rmse_after_m'] / raw['ate_rmse_after_m']:.2f} | "
                  f"{m['ate_rmse_before_m']:.3f} | {m.get('n_odometry_fallbacks')} | {m.get('n_loop_constraints_added')} |")
    finally:
        shutil.rmtree(root, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
