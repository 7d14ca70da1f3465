"""The demo's stream, recorded as a robot would record it, gives the demo's results.

The synthetic world of ``recipes/demo.yaml`` (seed 0, two laps, 320x240, depth,
intrinsics, ground-truth pose) is written into a ROS 2 bag (MCAP: raw ``rgb8``, ``16UC1``
depth in millimetres, ``CameraInfo``, ``PoseStamped``) and a ROS 1 bag (JPEG
``CompressedImage``, ``compressedDepth`` PNG depth, ``CameraInfo``, the pose through the
``/tf`` tree), and the demo recipe runs on each with only its source swapped to
``ros_bag``. Each bag run is compared with the synthetic run made here, in the same
process on the same machine (the demo's numbers vary slightly across CPUs).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from slamfront.formats.poses import read_tum
from slamfront.recipe import Recipe, build_pipeline, load_recipe
from slamfront.runtime import RunResult, run_pipeline
from slamfront_plugins.sources.ros_bag import RosBag
from slamfront_plugins.sources.synthetic import SyntheticWorld
from tests.recordings import BagSpec, BagWriter

ROS2 = BagSpec(ros=2, storage="mcap", image="rgb8", depth="16UC1", pose="PoseStamped")
ROS1 = BagSpec(ros=1, image="jpeg", depth="compressedDepth", pose="tf", jpeg_quality=80)
# The second lap drives 0.3 m aside, so a return two frames (3.0 m along the road) from
# a first-lap frame is 3.015 m from it: the synthetic world counts it (its radius is along
# the route), a radius in space must be a little larger to count the same frames.
RADIUS_M = 3.1


def _run(recipe: Recipe, out: Path) -> RunResult:
    return run_pipeline(build_pipeline(recipe, "demo"), "demo", out, progress=False)


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    root = tmp_path_factory.mktemp("demo_bags")
    demo, _ = load_recipe("demo", ["eval.plots=false"])
    world = SyntheticWorld(SyntheticWorld.Config(**demo.source.params))
    bags = {"ros2": root / "demo_ros2", "ros1": root / "demo_ros1.bag"}
    with BagWriter(bags["ros2"], ROS2) as ros2, BagWriter(bags["ros1"], ROS1) as ros1:
        for frame in world.frames():
            ros2.write_frame(frame)
            ros1.write_frame(frame)
    results: dict[str, Any] = {"synthetic": _run(demo, root / "synthetic"), "bags": bags}
    raw = demo.model_dump(mode="json", exclude_none=True)
    for name, spec in (("ros2", ROS2), ("ros1", ROS1)):
        params = {**spec.source_params(bags[name]), "revisit_radius_m": RADIUS_M}
        swapped = Recipe.model_validate({**raw, "source": {"plugin": "ros_bag", "params": params}})
        results[name] = _run(swapped, root / name)
    yield results
    shutil.rmtree(root, ignore_errors=True)


@pytest.mark.parametrize("bag, recall_within, ate_ratio", [("ros2", 0.02, 1.10), ("ros1", 0.05, 1.25)])
def test_a_bag_of_the_demo_stream_gives_the_demo_results(
    runs: dict[str, Any], bag: str, recall_within: float, ate_ratio: float
) -> None:
    synthetic, recorded = runs["synthetic"].metrics, runs[bag].metrics
    print(f"\n{bag}: recall@100%P {recorded['recall_at_100p']:.4f} (synthetic {synthetic['recall_at_100p']:.4f}), "
          f"ATE after {recorded['ate_rmse_after_m']:.4f} m (synthetic {synthetic['ate_rmse_after_m']:.4f} m, "
          f"ratio {recorded['ate_rmse_after_m'] / synthetic['ate_rmse_after_m']:.3f})")
    assert recorded["n_frames"] == 400 and recorded["n_frames_dropped"] == 0 and recorded["n_images_read"] == 400
    assert abs(recorded["recall_at_100p"] - synthetic["recall_at_100p"]) <= recall_within, (
        recorded["recall_at_100p"], synthetic["recall_at_100p"])
    assert recorded["ate_rmse_after_m"] <= ate_ratio * synthetic["ate_rmse_after_m"], (
        recorded["ate_rmse_after_m"], synthetic["ate_rmse_after_m"])
    # the loop closures are real ones: the bag's truth (from its poses) is the world's
    assert recorded["recall_at_100p"] > 0.5 and recorded["n_loop_constraints_added"] > 50


def test_the_loop_truth_from_the_bag_poses_is_the_synthetic_worlds(runs: dict[str, Any]) -> None:
    demo, _ = load_recipe("demo")
    world = SyntheticWorld(SyntheticWorld.Config(**demo.source.params)).loop_ground_truth()
    from_poses = RosBag(RosBag.Config(**ROS2.source_params(runs["bags"]["ros2"]), revisit_radius_m=RADIUS_M))
    truth = from_poses.loop_ground_truth()  # read from the bag's poses alone (no frame was streamed)
    assert truth is not None
    for field in ("queries", "indptr", "matches"):
        assert np.array_equal(getattr(truth, field), getattr(world, field)), field


@pytest.mark.parametrize("bag", ["ros2", "ros1"])
def test_the_run_writes_trajectories_evo_scores_as_the_run_did(
    runs: dict[str, Any], bag: str, tmp_path: Path
) -> None:
    result: RunResult = runs[bag]
    out = result.out_dir
    truth = read_tum(out / "groundtruth.tum")
    frames = read_tum(out / "optimised.tum")
    assert len(truth) == len(frames) == 400
    # the frames' own timestamps: the synthetic clock, as the bag's header stamps carried it
    assert np.allclose(truth.timestamps, read_tum(runs["synthetic"].out_dir / "groundtruth.tum").timestamps, atol=1e-9)
    evo_ape = Path(sys.executable).parent / "evo_ape"
    for estimate, key in (("optimised.tum", "ate_rmse_after_m"), ("odometry.tum", "ate_rmse_before_m")):
        done = subprocess.run(
            [str(evo_ape), "tum", str(out / "groundtruth.tum"), str(out / estimate), "-a"],
            capture_output=True, text=True, env={**os.environ, "HOME": str(tmp_path)}, check=True,
        )
        rmse = float(next(line.split()[-1] for line in done.stdout.splitlines() if line.strip().startswith("rmse")))
        assert rmse == pytest.approx(result.metrics[key], rel=1e-3), (estimate, done.stdout)
