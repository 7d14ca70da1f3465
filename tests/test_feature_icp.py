"""The feature_icp registration on the real RGB-D samples, its log, model and bad input."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import open3d as o3d
import pytest

from slamfront import DataError, Frame, StageInputs
from slamfront.mcaplog.diff import diff_logs
from slamfront.mcaplog.reader import read_messages, summarize
from slamfront.messages import LoopResult, PointCloud, RelativePose
from slamfront.recipe import build_pipeline, load_recipe
from slamfront.replay import replay_log
from slamfront.runtime import run_pipeline
from slamfront_plugins.registrations.config import FeatureIcpConfig
from slamfront_plugins.registrations.feature_icp import FeatureIcp
from slamfront_plugins.registrations.messages import CloudRegistration, RegisteredTrajectory
from slamfront_plugins.sources.rgbd import RgbdFolder
from tests.helpers import stage_topic_bytes

FAST = ["log.images=false"]
"""Images are not needed in these logs."""


def _run(recipe_name: str, out: Path, *overrides: str, plots: bool = False):
    recipe, path = load_recipe(recipe_name, [*FAST, f"eval.plots={str(plots).lower()}", *overrides])
    return run_pipeline(build_pipeline(recipe, str(path)), str(path), out, progress=False)


@pytest.fixture(scope="module")
def redwood_run(tmp_path_factory: pytest.TempPathFactory, shared_data: Path):
    return _run("redwood_register", tmp_path_factory.mktemp("redwood"), plots=True)


def test_redwood_registration_matches_the_given_poses(redwood_run) -> None:
    metrics = redwood_run.metrics
    assert metrics["n_clouds"] == 5 and metrics["n_aligned"] == 4 and metrics["n_failed"] == 0
    assert metrics["rpe_rmse_m"] < 0.01  # the poses agree to millimetres (measured: 1.6 mm)
    assert metrics["rpe_rot_rmse_deg"] < 0.5
    assert metrics["fitness_mean"] > 0.9
    for key in ("seconds", "seconds_preprocess", "seconds_features", "seconds_initial_alignment", "seconds_icp"):
        assert metrics[key] > 0, key


@pytest.mark.parametrize(
    "configuration",
    [["registration.params.feature=none", "registration.params.initial_alignment=none"],
     ["registration.params.feature=pfh", "registration.params.feature_max_nn=40", "registration.params.voxel_size_m=0.08"]],
    ids=["icp-alone", "pfh+ransac+icp"],
)
def test_the_papers_other_configurations_report_rpe_per_pair(tmp_path: Path, shared_data: Path, configuration) -> None:
    """ICP alone and PFH + RANSAC + ICP (FPFH is the recipe's default, above) on three Redwood frames."""
    run = _run("redwood_register", tmp_path, "source.params.limit=3", *configuration)
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["n_clouds"] == 3 and metrics["n_rpe_pairs"] == 2
    assert metrics["rpe_rmse_m"] < 0.01  # measured: 1.6 mm for both
    assert metrics["seconds"] > 0 and (metrics["seconds_features"] > 0.1) == ("feature=pfh" in configuration[0])
    rows = [line for line in (tmp_path / "report.md").read_text().splitlines() if line.startswith(("| 1 | 0 |", "| 2 | 1 |"))]
    assert len(rows) == 2  # one row per pair, with its error
    assert run.metrics["n_aligned"] == 2


def test_redwood_model_is_written_and_matches_the_logged_model(redwood_run) -> None:
    out = redwood_run.out_dir
    model = o3d.io.read_point_cloud(str(out / "model.ply"))
    assert len(model.points) == redwood_run.metrics["model_points"] > 10_000
    assert model.has_colors()
    logged = [m.decoded for m in read_messages(redwood_run.log_path, topics=["/registration/point_cloud"])]
    final = [m for m in logged if m.role == "model"]
    assert len(final) == 1 and len(logged) == 6  # five aligned clouds and the model
    np.testing.assert_allclose(np.asarray(model.points), final[0].points, atol=1e-6)
    report = (out / "report.md").read_text()
    assert "Time per step" in report and "features (FPFH)" in report and "initial alignment (RANSAC)" in report
    for figure in ("model.png", "registration_errors.png", "registration_seconds.png", "registration_trajectory.png"):
        assert (out / figure).stat().st_size > 1000 and f"]({figure})" in report


def test_redwood_log_has_clouds_poses_and_trajectory_for_foxglove(redwood_run) -> None:
    summary = summarize(redwood_run.log_path)
    topics = {t.topic: t for t in summary.topics}
    assert topics["/registration/aligned_cloud"].schema_name == "foxglove.PointCloud"
    assert topics["/registration/aligned_cloud"].count == 5
    assert topics["/registration/model_cloud"].schema_name == "foxglove.PointCloud"
    assert topics["/registration/pose"].schema_name == "foxglove.PoseInFrame"
    assert topics["/registration/trajectory"].schema_name == "foxglove.PosesInFrame"
    steps = [m.decoded for m in read_messages(redwood_run.log_path, topics=["/registration/cloud_registration"])]
    assert [s.outcome for s in steps] == ["first", "aligned", "aligned", "aligned", "aligned"]
    assert all(s.target == s.frame - 1 for s in steps[1:])
    assert all({"cloud", "downsample", "normals", "features"} <= set(s.seconds) for s in steps)
    trajectory = next(read_messages(redwood_run.log_path, topics=["/registration/registered_trajectory"])).decoded
    np.testing.assert_array_equal(trajectory.poses[-1], steps[-1].pose)
    # the Foxglove cloud carries the same points as slamfront's own message
    fox = next(read_messages(redwood_run.log_path, topics=["/registration/aligned_cloud"])).decoded
    packed = np.frombuffer(fox.data, dtype=np.uint8).reshape(-1, fox.point_stride)
    xyz = packed[:, :12].copy().view("<f4").reshape(-1, 3)
    first = next(read_messages(redwood_run.log_path, topics=["/registration/point_cloud"])).decoded
    np.testing.assert_array_equal(xyz, first.points)
    np.testing.assert_array_equal(packed[:, 12:15], first.colors)


def test_icl_poses_are_mirrored_into_the_y_down_camera(tmp_path: Path, shared_data: Path) -> None:
    """ICL-NUIM poses are for a y-up camera: mirrored, they agree with the clouds."""
    mirrored = _run("icl_register", tmp_path / "a", "source.params.limit=2")
    assert mirrored.metrics["rpe_rmse_m"] < 0.02  # measured: 8 mm
    raw = _run("icl_register", tmp_path / "b", "source.params.limit=2", "source.params.flip_y=false")
    assert raw.metrics["rpe_rot_rmse_deg"] > 20  # read as y-down they contradict the clouds


def _redwood_frames(shared_data: Path, limit: int = 5) -> list[Frame]:
    source = RgbdFolder(RgbdFolder.Config(
        root=shared_data / "rgbd/redwood_sample", match_file="rgbd.match", poses="trajectory.log",
        pose_format="redwood_log", intrinsics_file="camera_primesense.json", limit=limit,
    ))
    return list(source.frames())


def _with_depth(frame: Frame, depth: np.ndarray) -> Frame:
    return Frame(index=frame.index, timestamp=frame.timestamp, image=frame.image, name=frame.name, depth=depth,
                 camera=frame.camera, pose=frame.pose)


def test_unusable_frames_are_reported_not_fatal(shared_data: Path) -> None:
    frames = _redwood_frames(shared_data)
    few = np.zeros_like(frames[3].depth)
    few[200:205, 300:305] = 1.5  # 25 pixels: too few points to register
    frames[2] = _with_depth(frames[2], np.zeros_like(frames[2].depth))
    frames[3] = _with_depth(frames[3], few)
    plugin = FeatureIcp(FeatureIcpConfig(voxel_size_m=0.05))
    outputs = [plugin.process(StageInputs(frame=f)) for f in frames]
    steps = [out[0] for out in outputs]
    assert [s.outcome for s in steps] == ["first", "aligned", "failed", "failed", "aligned"]
    # a back end gets every frame's motion from the previous one: measured, or the prior with little weight
    relatives = [[m for m in out if isinstance(m, RelativePose)] for out in outputs]
    assert [[(r.frame_from, r.frame_to) for r in rs] for rs in relatives] == [[], [(0, 1)], [(1, 2)], [(2, 3)],
                                                                            [(3, 4), (1, 4)]]
    assert relatives[1][0].information is None and relatives[1][0].method.startswith("registration")
    assert relatives[2][0].information is not None and relatives[2][0].information.max() <= 0.1
    np.testing.assert_array_equal(relatives[4][1].transform, steps[4].transform)
    assert "depth is all zero" in steps[2].reason and "00002.jpg" in steps[2].reason
    assert "only 25 pixels with depth" in steps[3].reason
    assert steps[4].target == 1  # aligned to the last usable cloud
    assert steps[4].fitness > 0.9
    trajectory, model = plugin.finish()
    assert isinstance(trajectory, RegisteredTrajectory) and trajectory.frames.tolist() == [0, 1, 2, 3, 4]
    assert isinstance(model, PointCloud) and model.role == "model" and len(model.points) > 1000


def test_a_cloud_too_small_after_filtering_is_reported(shared_data: Path) -> None:
    frame = _redwood_frames(shared_data, limit=1)[0]
    plugin = FeatureIcp(FeatureIcpConfig(voxel_size_m=1.0))  # a 1 m grid leaves a handful of points
    step = plugin.process(StageInputs(frame=frame))[0]
    assert isinstance(step, CloudRegistration) and step.outcome == "failed"
    assert "too few points after filtering" in step.reason and "min_points 100" in step.reason


def test_wrong_depth_scale_gets_a_hint(shared_data: Path) -> None:
    frame = _redwood_frames(shared_data, limit=1)[0]
    metres_as_millimetres = _with_depth(frame, frame.depth * 1000.0)
    step = FeatureIcp(FeatureIcpConfig()).process(StageInputs(frame=metres_as_millimetres))[0]
    assert step.outcome == "failed" and "check the source's depth_scale" in step.reason


def test_wrong_size_depth_in_a_frame_names_the_frame_and_field(shared_data: Path) -> None:
    frame = _redwood_frames(shared_data, limit=1)[0]
    half = _with_depth(frame, frame.depth[::2, ::2])
    with pytest.raises(DataError, match=r"frame 0 \(00000.jpg\): depth: 320x240 but the image is 640x480"):
        FeatureIcp(FeatureIcpConfig()).process(StageInputs(frame=half))
    no_depth = _with_depth(frame, None)
    with pytest.raises(DataError, match="depth: the source gives no depth image"):
        FeatureIcp(FeatureIcpConfig()).process(StageInputs(frame=no_depth))


def test_wrong_size_depth_file_stops_the_run_with_one_line(tmp_path: Path, shared_data: Path, cli) -> None:
    sample = tmp_path / "redwood"
    shutil.copytree(shared_data / "rgbd/redwood_sample", sample)
    bad = sample / "depth/00002.png"
    bad.chmod(0o644)
    depth = cv2.imread(str(bad), cv2.IMREAD_ANYDEPTH)
    cv2.imwrite(str(bad), cv2.resize(depth, (320, 240), interpolation=cv2.INTER_NEAREST))
    code, _, err = cli("run", "redwood_register", "-o", tmp_path / "out", "-q", "--set", f"source.params.root={sample}",
                       *(x for item in FAST for x in ("--set", item)))
    assert code == 2
    assert err.strip().count("\n") == 0 and "00002.png: depth is 320x240 but the colour image is 640x480" in err
    summary = summarize(tmp_path / "out/run.mcap")
    assert summary.complete  # the log written so far is finalised and readable
    assert {t.topic: t.count for t in summary.topics}["/registration/cloud_registration"] == 2


def test_config_refuses_features_without_an_initial_alignment(write_recipe, cli) -> None:
    path = write_recipe({
        "name": "bad", "source": {"plugin": "synthetic"},
        "registration": {"plugin": "feature_icp", "params": {"feature": "none", "initial_alignment": "ransac"}},
    })
    code, _, err = cli("run", path, "-q")
    assert code == 2 and "registration.params" in err and "needs features" in err


def test_motion_beyond_the_limit_is_rejected_and_kept_out_of_the_model(shared_data: Path) -> None:
    frames = _redwood_frames(shared_data, limit=3)
    plugin = FeatureIcp(FeatureIcpConfig(voxel_size_m=0.05, max_translation_m=0.005))  # the camera moves 2.3 cm
    steps = [plugin.process(StageInputs(frame=f)) for f in frames]
    outcomes = [s[0].outcome for s in steps]
    assert outcomes == ["first", "rejected", "rejected"]
    assert "translation 0.02" in steps[1][0].reason and "max_translation_m 0.005" in steps[1][0].reason
    assert steps[2][0].target == 0  # still aligned to the last accepted cloud
    clouds = [[m for m in s if isinstance(m, PointCloud)] for s in steps]
    assert [len(c) for c in clouds] == [1, 0, 0]  # a rejected frame logs no aligned cloud
    np.testing.assert_array_equal(steps[1][0].pose, steps[0][0].pose)  # identity motion prior
    _, model = plugin.finish()
    first_only = FeatureIcp(FeatureIcpConfig(voxel_size_m=0.05))
    first_only.process(StageInputs(frame=frames[0]))
    assert len(model.points) == len(first_only.finish()[1].points)


def test_pose_graph_run_adds_loop_edges_and_reports_both_errors(tmp_path: Path, shared_data: Path) -> None:
    """Redwood's five frames all see the same corner: frames three apart make loop edges."""
    run = _run("redwood_register", tmp_path, "registration.params.pose_graph=true",
               "registration.params.loop_min_gap=3", "registration.params.loop_radius_m=0.5")
    metrics = run.metrics
    assert metrics["pose_graph_refined"] is True and metrics["n_loop_edges"] >= 2
    assert metrics["rpe_rmse_m"] < 0.01 and metrics["rpe_rmse_m_chain"] < 0.01
    assert metrics["seconds_pose_graph"] > 0
    trajectory = next(read_messages(run.log_path, topics=["/registration/registered_trajectory"])).decoded
    assert trajectory.refined and trajectory.frames.tolist() == [0, 1, 2, 3, 4]
    assert {tuple(edge) for edge in trajectory.loop_edges} <= {(0, 3), (0, 4), (1, 4)}
    assert o3d.io.read_point_cloud(str(tmp_path / "model.ply")).has_points()


def test_without_ground_truth_the_errors_are_null_not_made_up(tmp_path: Path, shared_data: Path) -> None:
    run = _run("redwood_register", tmp_path, "source.params.poses=null", "source.params.limit=3")
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["n_clouds"] == 3 and metrics["rpe_rmse_m"] is None and metrics["end_to_end_error_m"] is None
    assert run.metrics["n_rpe_pairs"] == 0
    assert "| 2 | 1 | aligned |" in (tmp_path / "report.md").read_text()


def test_loop_detector_matches_become_verified_loop_edges(shared_data: Path) -> None:
    frames = _redwood_frames(shared_data, limit=4)
    # pose-based candidates are off (loop_radius_m tiny): only the detector's match is tried
    plugin = FeatureIcp(FeatureIcpConfig(pose_graph=True, loop_radius_m=1e-6, loop_min_gap=2))
    for frame in frames:
        detector = [LoopResult(frame=frame.index, match=0, confidence=0.9, accepted=frame.index == 3)]
        plugin.process(StageInputs(frame=frame, outputs={"loop_detector": detector}))
    trajectory, _ = plugin.finish()
    assert trajectory.refined and trajectory.loop_edges.tolist() == [[0, 3]]


def test_a_registration_run_is_bit_reproducible(redwood_run, tmp_path: Path) -> None:
    """Same recipe, same data: the same registration messages, bit for bit (the replay
    contract; Open3D runs single-threaded while aligning by default for this)."""
    again = _run("redwood_register", tmp_path, plots=True)
    assert stage_topic_bytes(again.log_path, "/registration/") == stage_topic_bytes(redwood_run.log_path, "/registration/")


def test_a_registration_run_replays_bit_for_bit_from_exact_depth(tmp_path: Path, shared_data: Path) -> None:
    """Logged with exact pixels (PNG at full width, depth as 32FC1), the registration is
    re-run by a replay and reproduces every message."""
    exact = ["log.images=true", "log.image_format=png", "log.image_max_width=100000", "log.depth=true",
             "log.depth_encoding=32FC1", "source.params.limit=3"]
    run = _run("redwood_register", tmp_path / "run", *exact)
    replay = replay_log(run.log_path, tmp_path / "replay", progress=False)
    assert summarize(replay.log_path).metadata["replay"]["from"] == "registration"
    result = diff_logs(run.log_path, replay.log_path)
    assert result.identical, [d.describe() for d in result.differences]
    assert stage_topic_bytes(replay.log_path, "/registration/")


def test_registration_is_the_back_ends_odometry(tmp_path: Path, shared_data: Path) -> None:
    """feature_icp's RelativePose messages feed gtsam_pose_graph (odometry: stages)."""
    run = _run("redwood_register", tmp_path, "backend={plugin: gtsam_pose_graph, params: {odometry: stages}}")
    relatives = [m.decoded for m in read_messages(run.log_path, ["/registration/relative_pose"])]
    assert [(r.frame_from, r.frame_to) for r in relatives] == [(k, k + 1) for k in range(4)]
    assert run.metrics["ate_rmse_after_m"] < 0.01  # the registered chain is millimetre-accurate here
