"""The keyframe localizer: kidnapped robot on the synthetic world, the real RGB-D samples,
and what a run reports."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from slamfront.formats.poses import read_tum
from slamfront.mcaplog.reader import read_messages, summarize
from slamfront.recipe import build_pipeline, load_recipe, parse_recipe
from slamfront.runtime import RunResult, run_pipeline


def kidnapped_recipe(shuffle: bool = True, **localizer: Any) -> dict[str, Any]:
    """A reference drive and a second drive (0.3 m aside, turned 2°, occluders) given in random order.

    As ``recipes/synthetic_localize.yaml``, shorter: 50 places 3 m apart.
    """
    return {
        "name": "kidnapped",
        "source": {"plugin": "synthetic", "params": {
            "mode": "paired", "frames_per_traversal": 50, "route_length_m": 150, "image_width": 320,
            "image_height": 240, "query_illumination": "day", "shuffle": shuffle, "shuffle_seed": 3,
        }},
        "descriptor": {"plugin": "local_features", "params": {"descriptor": "orb", "max_features": 500}},
        "localizer": {"plugin": "keyframe", "params": {
            "matching": {"ratio": 0.8}, "pnp_refinement": True, **localizer}},
        "log": {"images": False},
    }


def _run(raw: dict[str, Any], out: Path) -> RunResult:
    return run_pipeline(build_pipeline(parse_recipe(raw, "test"), "test"), "test", out, progress=False)


@pytest.fixture(scope="module")
def kidnapped(tmp_path_factory: pytest.TempPathFactory) -> RunResult:
    return _run(kidnapped_recipe(), tmp_path_factory.mktemp("kidnapped"))


def test_kidnapped_robot_every_frame_finds_its_region(kidnapped: RunResult) -> None:
    m = kidnapped.metrics
    assert m["n_localization_queries"] == 50
    assert m["n_frames_localized"] == 50
    assert m["fraction_correct_keyframe_region"] == 1.0
    assert 5 <= m["n_keyframes"] < 50
    # PnP from the keyframe's depth makes the keyframe's pose metric
    assert m["n_refined"] > 25
    assert m["ate_rmse_m"] < m["ate_rmse_keyframe_pose_m"]
    assert np.isfinite(m["rpe_rmse_m"]) and m["localization_latency_median_ms"] > 0


def test_run_outputs_metrics_log_report_and_trajectories(kidnapped: RunResult) -> None:
    metrics = json.loads(kidnapped.metrics_path.read_text())
    for key in ("ate_rmse_m", "rpe_rmse_m", "n_keyframes", "n_frames_localized", "localization_latency_median_ms",
                "localization_latency_p99_ms", "ate_rmse_unaligned_m"):
        assert key in metrics, key
    report = kidnapped.report_path.read_text()
    assert "## Localization" in report and "localization.png" in report
    assert (kidnapped.out_dir / "localization.png").stat().st_size > 10_000
    summary = summarize(kidnapped.log_path)
    assert summary.topic("/localizer/pose_estimate").count == 50
    assert summary.topic("/localizer/pose").count == 50  # foxglove.PoseInFrame
    assert summary.topic("/localizer/keyframe_added").count == metrics["n_keyframes"]
    assert summary.topic("/localizer/keyframes").count == 1  # foxglove.PosesInFrame of the map
    # the TUM files the evaluation writes give the same ATE through `eval traj`'s functions
    from slamfront.core.trajectory import evaluate_trajectories

    gt = read_tum(kidnapped.out_dir / "groundtruth_tum.txt")
    est = read_tum(kidnapped.out_dir / "estimated_tum.txt")
    again = evaluate_trajectories(gt.timestamps, gt.poses, est.timestamps, est.poses, 1e-6)
    assert again.ate.statistics.rmse == pytest.approx(metrics["ate_rmse_m"], abs=1e-9)


def test_localization_does_not_depend_on_the_order_frames_come_in(tmp_path: Path) -> None:
    """Global localization: the same keyframe for every place whether the drive is shuffled or not."""

    def answers(shuffle: bool) -> dict[int, tuple[int, int]]:
        raw = kidnapped_recipe(shuffle, pnp_refinement=False)
        raw["source"]["params"].update(frames_per_traversal=30, image_width=240, image_height=180)
        raw["eval"] = {"plots": False}
        result = _run(raw, tmp_path / str(shuffle))
        places = {m.decoded.frame: m.decoded.sequence_index for m in read_messages(result.log_path, ["/frames"])}
        return {places[m.decoded.frame]: (m.decoded.keyframe, m.decoded.inliers)
                for m in read_messages(result.log_path, ["/localizer/pose_estimate"])}

    ordered, shuffled = answers(False), answers(True)
    assert len(ordered) == 30 and ordered == shuffled


def test_preselection_finds_the_same_keyframes_with_fewer_comparisons(kidnapped: RunResult, tmp_path: Path) -> None:
    fast = _run(kidnapped_recipe(preselection="thumbnail", candidates=5), tmp_path)
    assert fast.metrics["fraction_correct_keyframe_region"] == 1.0
    assert fast.metrics["n_two_view_matches"] < kidnapped.metrics["n_two_view_matches"]


@pytest.mark.parametrize("name", ["redwood_localize", "room_localize", "icl_localize"])
def test_real_samples_localize_every_frame(name: str, tmp_path: Path, shared_data: Path) -> None:
    recipe, path = load_recipe(name, ["log.images=false", "eval.plots=false"])
    m = run_pipeline(build_pipeline(recipe, str(path)), str(path), tmp_path, progress=False).metrics
    assert m["n_localization_queries"] == 5 and m["n_frames_localized"] == 5
    assert m["n_keyframes"] >= 1
    # frames that are keyframes find themselves; the others their keyframe (PnP makes it metric)
    assert m["ate_rmse_unaligned_m"] < {"redwood_localize": 0.01, "room_localize": 0.02, "icl_localize": 0.8}[name]


def test_leave_one_out_on_the_room_sample(tmp_path: Path, shared_data: Path) -> None:
    """Each keyframe localized against the others only: PnP recovers most of the pose."""
    recipe, path = load_recipe("room_localize", ["localizer.params.exclude_self=true", "log.images=false"])
    m = run_pipeline(build_pipeline(recipe, str(path)), str(path), tmp_path, progress=False).metrics
    assert m["n_frames_localized"] == 5 and m["n_refined"] >= 3
    assert m["ate_rmse_unaligned_m"] < 0.5 * m["ate_rmse_keyframe_pose_unaligned_m"]


def test_icl_poses_agree_with_the_images_only_after_the_y_flip(shared_data: Path) -> None:
    """PnP between the two overlapping ICL frames matches the flipped ground truth to 2 cm."""
    from slamfront.core.geometry import invert
    from slamfront.core.pnp import backproject, pnp_ransac
    from slamfront.local_features import LocalFeatureExtractor
    from slamfront.matching import Matcher, MatchingConfig
    from slamfront_plugins.sources.rgbd import RgbdFolder

    def frames(flip: bool) -> list:
        config = RgbdFolder.Config.model_validate({
            "root": shared_data / "rgbd/icl_livingroom_sample", "poses": "pose.txt", "camera": "icl_nuim",
            "depth_scale": 5000, "flip_y": flip, "limit": 3,
        })
        return list(RgbdFolder(config).frames())

    flipped, plain = frames(True), frames(False)
    extractor = LocalFeatureExtractor("sift", max_features=2000)
    a, b = (extractor.extract(flipped[i].gray()) for i in (0, 2))
    match = Matcher(MatchingConfig(ratio=0.8), "l2", 300).match(b.keypoints, b.descriptors, a.keypoints, a.descriptors)
    points = backproject(a.keypoints, flipped[0].depth, flipped[0].camera.matrix)
    solution = pnp_ransac(points[match.pairs[:, 1]], b.keypoints[match.pairs[:, 0]], flipped[2].camera.matrix)
    for source, expected in ((flipped, True), (plain, False)):
        truth = invert(source[2].pose) @ source[0].pose
        agrees = np.linalg.norm(truth[:3, 3] - solution.transform[:3, 3]) < 0.02
        assert agrees == expected


def test_a_localization_run_replays_bit_for_bit(cli, tmp_path: Path, shared_data: Path) -> None:
    """Wall times stay out of the messages, so replaying the localizer reproduces every one."""
    exact = ["--set", "log.image_format=png", "--set", "log.image_max_width=640", "--set", "log.depth=true",
             "--set", "log.depth_encoding=32FC1"]
    assert cli("run", "room_localize", "-o", tmp_path / "run", "-q", *exact)[0] == 0
    code, _, err = cli("replay", tmp_path / "run", "--from", "localizer", "-o", tmp_path / "replay", "-q")
    assert code == 0, err
    code, out, _ = cli("diff", tmp_path / "run/run.mcap", tmp_path / "replay/run.mcap")
    assert code == 0 and out.startswith("identical"), out
    first, again = (json.loads((tmp_path / d / "metrics.json").read_text()) for d in ("run", "replay"))
    assert again["ate_rmse_m"] == first["ate_rmse_m"] and again["n_keyframes"] == first["n_keyframes"]


def test_loop10_revisits_found_without_poses(tmp_path: Path, shared_data: Path) -> None:
    """images/loop10 (no poses): leave-one-out, each revisit finds its twin (10.png <-> 1.png,
    5.png <-> 6.png); the run reports the localization and says there is nothing to score."""
    raw = {
        "name": "loop10", "source": {"plugin": "image_folder", "params": {"folder": "images/loop10"}},
        "descriptor": {"plugin": "local_features", "params": {"descriptor": "orb", "max_features": 1000}},
        "localizer": {"plugin": "keyframe", "params": {"exclude_self": True}}, "eval": {"plots": False},
    }
    result = _run(raw, tmp_path)
    chosen = {m.decoded.frame: m.decoded.keyframe for m in read_messages(result.log_path, ["/localizer/pose_estimate"])}
    assert (chosen[9], chosen[0], chosen[4], chosen[5]) == (0, 9, 5, 4)
    assert result.metrics["n_frames_localized"] == 10 and "ate_rmse_m" not in result.metrics
    assert "No localized frame has a ground-truth pose" in result.report_path.read_text()
