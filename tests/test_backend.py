"""The ``gtsam_pose_graph`` back end: PnP verification, the RelativePose seam, odometry
sources, iSAM2, a whole synthetic SLAM run, and its evaluation and log."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from slamfront import Camera, DataError, Frame, PluginError, StageInputs
from slamfront.core import geometry
from slamfront.core.alignment import ate_rmse
from slamfront.formats.poses import Trajectory as PoseFile
from slamfront.formats.poses import read_tum, write_tum
from slamfront.imageio import read_depth, read_image
from slamfront.local_features import LocalFeatureExtractor
from slamfront.matching import Matcher, resolve_max_distance
from slamfront.mcaplog.diff import diff_logs
from slamfront.mcaplog.reader import read_messages, summarize
from slamfront.messages import LoopResult, RelativePose, Trajectory
from slamfront.recipe import build_pipeline, load_recipe
from slamfront.replay import replay_log
from slamfront.runtime import run_pipeline
from slamfront_plugins.backends.gtsam_pose_graph import GtsamPoseGraph
from slamfront_plugins.backends.messages import LoopConstraint, PoseGraphState
from slamfront_plugins.backends.pnp_verification import FrameFeatures, PnPConfig, lift, verify
from slamfront_plugins.sources.synthetic import SyntheticWorld
from tests.posegraph_fixtures import ring_truth

# --- PnP verification -------------------------------------------------------------------


def _features(image: np.ndarray, depth: np.ndarray | None, camera: Camera) -> FrameFeatures:
    features = LocalFeatureExtractor("orb", max_features=1000).extract(cv2.cvtColor(image, cv2.COLOR_RGB2GRAY))
    return FrameFeatures(features.keypoints, features.descriptors, lift(features.keypoints, depth, camera))


def _verify(reference: FrameFeatures, query: FrameFeatures, camera: Camera):  # type: ignore[no-untyped-def]
    config = PnPConfig()
    matcher = Matcher(config.matching, "hamming", resolve_max_distance(config.matching, "orb"))
    return verify(reference, query, camera, matcher, config)


def _error(estimate: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    difference = geometry.relative(truth, estimate)
    return float(np.linalg.norm(difference[:3, 3])), geometry.rotation_angle_deg(difference)


def test_pnp_on_real_rgbd_frames(shared_data: Path) -> None:
    root = shared_data / "rgbd/redwood_sample"
    camera = Camera(fx=525.0, fy=525.0, cx=319.5, cy=239.5, width=640, height=480)
    rows = [line.split() for line in (root / "trajectory.log").read_text().splitlines()]
    poses = np.array([np.array(rows[k + 1 : k + 5], dtype=float) for k in range(0, len(rows), 5)])
    frames = [
        _features(read_image(root / f"color/{i:05d}.jpg"), read_depth(root / f"depth/{i:05d}.png", 1000.0), camera)
        for i in (0, 4)
    ]
    result = _verify(frames[0], frames[1], camera)
    assert result.transform is not None and result.inliers > 100, result.reason
    translation, rotation = _error(result.transform, geometry.relative(poses[0], poses[4]))
    assert translation < 0.01 and rotation < 0.5  # the true motion is 10 cm and 3 degrees


def test_pnp_on_synthetic_revisits_and_refuses_a_wrong_place() -> None:
    source = SyntheticWorld(SyntheticWorld.Config(
        mode="stream", laps=2, frames_per_traversal=12, route_length_m=36, image_width=320, image_height=240,
    ))
    frames = {f.index: f for f in source.frames() if f.index in (9, 21, 3)}
    features = {k: _features(f.image, f.depth, f.camera) for k, f in frames.items()}
    result = _verify(features[9], features[21], source.camera)
    assert result.transform is not None, result.reason
    translation, rotation = _error(result.transform, geometry.relative(frames[9].pose, frames[21].pose))
    assert translation < 0.1 and rotation < 2.0  # lap 2 drives 0.3 m to the side, turned 2 degrees
    wrong = _verify(features[3], features[21], source.camera)
    assert wrong.transform is None and "matches" in wrong.reason


# --- the plugin, driven frame by frame ------------------------------------------------------


def _ring_frames() -> list[Frame]:
    poses = geometry.planar_to_spatial(ring_truth())
    image = np.zeros((8, 8, 3), dtype=np.uint8)
    return [Frame(index=k, timestamp=0.1 * k, image=image, pose=pose) for k, pose in enumerate(poses)]


def _drive(backend: GtsamPoseGraph, frames: list[Frame], extra=lambda frame: {}) -> list:  # type: ignore[no-untyped-def]
    produced = []
    for frame in frames:
        produced += backend.process(StageInputs(frame=frame, outputs=extra(frame)))
    return produced + list(backend.finish())


def _loop_inputs(frame: Frame, with_pose: bool) -> dict[str, list]:
    if frame.index < 60:
        return {}
    match = frame.index - 60
    outputs: dict[str, list] = {"loop_detector": [LoopResult(frame=frame.index, match=match, confidence=0.9, accepted=True)]}
    if with_pose:
        truth = geometry.planar_to_spatial(ring_truth())
        outputs["registration"] = [
            RelativePose(frame_from=match, frame_to=frame.index, transform=geometry.relative(truth[match], truth[frame.index]),
                         method="icp", inliers=99)
        ]
    return outputs


def _ate(messages: list, label: str) -> float:
    trajectory = next(m for m in messages if isinstance(m, Trajectory) and m.label == label)
    truth = geometry.planar_to_spatial(ring_truth())[trajectory.frames, :3, 3]
    return ate_rmse(trajectory.poses[:, :3, 3], truth)


@pytest.mark.parametrize("mode", ["batch", "isam2"])
def test_stage_relative_poses_close_the_loops(mode: str) -> None:
    backend = GtsamPoseGraph(GtsamPoseGraph.Config(solver={"mode": mode}, seed=3))
    messages = _drive(backend, _ring_frames(), lambda f: _loop_inputs(f, with_pose=True))
    constraints = [m for m in messages if isinstance(m, LoopConstraint)]
    assert len(constraints) == 60 and all(c.added and c.reason == "icp relative pose" for c in constraints)
    assert _ate(messages, "optimised") < 0.3 * _ate(messages, "odometry")
    state = next(m for m in messages if isinstance(m, PoseGraphState))
    assert state.sources.shape == (119 + 60,) and state.loop_segments().shape == (60, 2, 3)
    stats = backend.statistics()
    assert stats["n_loop_closures_added"] == 60 and stats["cost_after"] < stats["cost_before"]
    if mode == "isam2":
        assert sum(isinstance(m, Trajectory) and m.label == "isam2" for m in messages) == 60


def test_a_closure_without_a_verified_pose_is_skipped_never_identity() -> None:
    backend = GtsamPoseGraph(GtsamPoseGraph.Config(loop_pose="stages"))
    messages = _drive(backend, _ring_frames(), lambda f: _loop_inputs(f, with_pose=False))
    constraints = [m for m in messages if isinstance(m, LoopConstraint)]
    assert len(constraints) == 60 and not any(c.added for c in constraints)
    assert constraints[0].reason == "not verified: no earlier stage gave a relative pose"
    state = next(m for m in messages if isinstance(m, PoseGraphState))
    assert state.sources.shape == (119,)  # odometry only
    suffix, log = constraints[0].foxglove(0)[0]
    assert suffix == "log" and "skipped" in log.message
    # with PnP allowed but frames without depth or camera, the reason says so
    pnp = GtsamPoseGraph(GtsamPoseGraph.Config(loop_pose="auto"))
    reasons = {m.reason for m in _drive(pnp, _ring_frames(), lambda f: _loop_inputs(f, False)) if isinstance(m, LoopConstraint)}
    assert len(reasons) == 60 and all(r.endswith("has no features and depth for PnP") for r in reasons)


def test_odometry_from_a_file_and_from_stages(tmp_path: Path) -> None:
    frames = _ring_frames()
    poses = np.array([f.pose for f in frames])
    trajectory = tmp_path / "odometry.tum"
    write_tum(trajectory, PoseFile(np.array([f.timestamp for f in frames]), poses))
    from_file = GtsamPoseGraph(GtsamPoseGraph.Config(odometry="file", odometry_file=trajectory))
    messages = _drive(from_file, frames)
    assert _ate(messages, "odometry") < 1e-6  # exact odometry: the composed path is the truth

    def registration(frame: Frame) -> dict[str, list]:
        if frame.index == 0:
            return {}
        motion = geometry.relative(poses[frame.index - 1], poses[frame.index])
        return {"registration": [RelativePose(frame_from=frame.index - 1, frame_to=frame.index, transform=motion)]}

    from_stages = GtsamPoseGraph(GtsamPoseGraph.Config(odometry="stages"))
    assert _ate(_drive(from_stages, frames, registration), "odometry") < 1e-6
    missing = GtsamPoseGraph(GtsamPoseGraph.Config(odometry="stages"))
    with pytest.raises(DataError, match="frame 1: odometry: stages, but no earlier stage gave a RelativePose"):
        _drive(missing, frames[:3])
    no_truth = GtsamPoseGraph()
    with pytest.raises(DataError, match="frame 1 has no ground-truth pose"):
        _drive(no_truth, [Frame(index=k, timestamp=k, image=frames[0].image) for k in range(2)])


def test_odometry_from_the_images_and_a_late_answer_verified_on_its_own_frame() -> None:
    """odometry: pnp measures each motion from the images; a sequence detector answering
    frame 42 while frame 45 is processed gets frame 42's closure checked, not frame 45's."""
    source = SyntheticWorld(SyntheticWorld.Config(
        mode="stream", laps=2, frames_per_traversal=24, route_length_m=36, image_width=320, image_height=240,
    ))
    frames = list(source.frames())
    backend = GtsamPoseGraph(GtsamPoseGraph.Config(odometry="pnp", loop_pose="pnp"))
    assert GtsamPoseGraph.reads_pixels_with(GtsamPoseGraph.Config(odometry="pnp", loop_pose="stages"))

    def late_answer(frame: Frame) -> dict[str, list]:
        if frame.index != 45:
            return {}
        return {"loop_detector": [LoopResult(frame=42, match=18, confidence=0.9, accepted=True)]}

    messages = _drive(backend, frames, late_answer)
    odometry = [m for m in messages if isinstance(m, RelativePose)]
    assert [(m.frame_from, m.frame_to) for m in odometry] == [(k - 1, k) for k in range(1, 48)]
    measured = [m for m in odometry if m.method == "pnp odometry"]
    # Bounds from the spread over +-1-ulp perturbations of every depth pixel (what another CPU's
    # rounding could do; benchmarks/results/machine_spread.md): 29-30 frames measured, median
    # error 0.13-0.18 m, largest 0.46-0.57 m, 1.5 m between frames. Corners of a 36 m block: not all.
    assert len(measured) >= 25 and all(m.inliers >= 20 for m in measured)
    translations = [
        _error(m.transform, geometry.relative(frames[m.frame_from].pose, frames[m.frame_to].pose))[0] for m in measured
    ]
    assert np.median(translations) < 0.3 and max(translations) < 0.8, translations
    assert backend.statistics()["n_odometry_fallbacks"] == 47 - len(measured)
    (constraint,) = [m for m in messages if isinstance(m, LoopConstraint)]
    assert (constraint.frame, constraint.match) == (42, 18) and constraint.added, constraint.reason
    state = next(m for m in messages if isinstance(m, PoseGraphState))
    assert (18, 42) in set(zip(state.sources.tolist(), state.targets.tolist()))
    assert _ate_against(messages, frames, "optimised") < _ate_against(messages, frames, "odometry")


def _ate_against(messages: list, frames: list[Frame], label: str) -> float:
    trajectory = next(m for m in messages if isinstance(m, Trajectory) and m.label == label)
    truth = np.array([frames[k].pose[:3, 3] for k in trajectory.frames])
    return ate_rmse(trajectory.poses[:, :3, 3], truth)


def test_bad_backend_configs_fail_before_the_first_frame(cli, write_recipe, tmp_path: Path) -> None:
    from tests.helpers import small_synthetic_recipe
    from tests.test_cli import _one_line_error

    recipe = small_synthetic_recipe()
    recipe["backend"] = {"plugin": "gtsam_pose_graph", "params": {"odometry": "file"}}
    assert "odometry: file needs odometry_file" in _one_line_error(*cli("run", write_recipe(recipe))[::2])
    recipe["backend"]["params"]["odometry_file"] = str(tmp_path / "missing.tum")
    assert "missing.tum: no such file" in _one_line_error(*cli("run", write_recipe(recipe))[::2])
    recipe["backend"]["params"] = {"odometry": "stages"}
    with pytest.raises(PluginError, match="needs a registration or localizer stage"):
        GtsamPoseGraph(GtsamPoseGraph.Config(odometry="stages")).check({})
    recipe["backend"]["params"] = {"solver": {"kernel": "gnc", "mode": "isam2"}}
    assert "kernel gnc needs mode batch" in _one_line_error(*cli("run", write_recipe(recipe))[::2])


# --- a whole run ----------------------------------------------------------------------------


def test_synthetic_slam_run_reduces_ate_and_logs_for_foxglove(cli, tmp_path: Path) -> None:
    out = tmp_path / "run"
    recipe, path = load_recipe("synthetic_slam", [
        "source.params.frames_per_traversal=40", "source.params.route_length_m=100",
        "source.params.image_width=240", "source.params.image_height=180",
        "loop_detector.params.exclude_recent=20", "log.image_format=png", "log.image_max_width=240",
        "log.depth=true", "log.depth_encoding=32FC1",
    ])
    result = run_pipeline(build_pipeline(recipe, str(path)), str(path), out, progress=False)
    metrics = result.metrics
    # 4 since PnP takes correspondences one-to-one (a reference point matched by several
    # pixels, or two keypoints lifted to one 3-D point, counts once): a 5th loop no longer
    # reaches its inlier ratio
    assert metrics["n_loop_constraints_added"] >= 4
    assert metrics["n_loop_constraints_added_false"] == 0
    assert metrics["ate_rmse_after_m"] < 0.5 * metrics["ate_rmse_before_m"]
    assert (out / "backend.png").exists() and "Pose-graph back end" in (out / "report.md").read_text()
    summary = summarize(result.log_path)
    schemas = {t.topic: t.schema_name for t in summary.topics}
    assert schemas["/backend/trajectory/optimised"] == "foxglove.PosesInFrame"
    assert schemas["/backend/loop_closures"] == "foxglove.SceneUpdate"
    assert schemas["/backend/pose_graph_state"] == "slamfront.PoseGraphState"
    scene = next(read_messages(result.log_path, topics=["/backend/loop_closures"])).decoded
    assert len(scene.entities[0].lines[0].points) == 2 * metrics["n_graph_loop_closures"]
    # the logged graph re-optimises with `slamfront optimize LOG.mcap`, ground truth included
    code, stdout, err = cli("optimize", result.log_path, "-o", tmp_path / "again", "--no-plots", "--kernel", "gnc")
    assert code == 0, err
    again = json.loads((tmp_path / "again" / "metrics.json").read_text())
    assert again["ate_rmse_after_m"] == pytest.approx(metrics["ate_rmse_after_m"], rel=0.05)
    assert again["ground_truth"] == "from the log"
    # ... stamped with the frames' own times (not vertex ids), as the run's own TUM files are
    gt, optimised = read_tum(out / "groundtruth.tum"), read_tum(out / "optimised.tum")
    assert np.array_equal(read_tum(tmp_path / "again" / "trajectory.tum").timestamps, optimised.timestamps)
    assert np.isin(optimised.timestamps, gt.timestamps).all() and len(optimised) == metrics["n_frames"]
    # the back end reads pixels (PnP on depth): with exact pixels logged, a replay re-runs it bit for bit
    replay = replay_log(result.log_path, tmp_path / "replay", from_kind="backend", progress=False)
    assert summarize(replay.log_path).metadata["replay"]["recorded_stages"] == "descriptor,loop_detector"
    difference = diff_logs(result.log_path, replay.log_path)
    assert difference.identical, [d.describe() for d in difference.differences]
    assert replay.metrics["ate_rmse_after_m"] == metrics["ate_rmse_after_m"]
