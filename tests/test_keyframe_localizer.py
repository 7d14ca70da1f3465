"""The keyframe localizer: kidnapped robot on the synthetic world (the shipped recipe),
unknown places, the real RGB-D samples, a saved map, and what a run reports."""

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
    """The shipped recipe: 200 reference frames, 200 shuffled queries, 50 frames of another world."""
    recipe, path = load_recipe("synthetic_localize", ["log.images=false"])
    return run_pipeline(build_pipeline(recipe, str(path)), str(path), tmp_path_factory.mktemp("kidnapped"),
                        progress=False)


@pytest.fixture(scope="module")
def small(tmp_path_factory: pytest.TempPathFactory) -> RunResult:
    return _run(kidnapped_recipe(), tmp_path_factory.mktemp("small"))


def test_kidnapped_robot_localizes_in_its_region_and_refuses_unknown_places(kidnapped: RunResult) -> None:
    """Every answer right, at least 95 % of the drive localized in its region and of the other
    world's frames answered "unknown place", and a confidence that ranks the right answers
    first (recall at 100 % precision >= 95 %); the threshold was fitted on other worlds."""
    m = kidnapped.metrics
    assert m["n_in_map_queries"] == 200 and m["n_out_of_map_queries"] == 50
    assert m["localization_precision"] == 1.0
    assert m["localization_recall"] >= 0.95  # localized and in the right region, of the 200
    assert m["fraction_out_of_map_refused"] >= 0.95
    assert m["fraction_correct_keyframe_region"] >= 0.99
    assert 0.95 <= m["localization_recall_at_100p"] <= 1.0
    assert 20 <= m["n_keyframes"] < 200
    # PnP from the keyframe's depth makes the keyframe's pose metric
    assert m["n_refined"] > 150
    assert m["ate_rmse_pnp_m"] < m["ate_rmse_m"]  # ate_rmse_m: the keyframe's pose, as Barbosa 2017
    assert np.isfinite(m["rpe_rmse_m"]) and m["localization_latency_median_ms"] > 0


def test_run_outputs_metrics_log_report_and_trajectories(kidnapped: RunResult) -> None:
    metrics = json.loads(kidnapped.metrics_path.read_text())
    for key in ("ate_rmse_m", "rpe_rmse_m", "ate_rmse_pnp_m", "rpe_rmse_pnp_m", "rpe_all_intervals_rmse_m",
                "n_keyframes", "n_frames_localized", "localization_latency_median_ms",
                "localization_latency_p99_ms", "ate_rmse_unaligned_m", "localization_recall_at_100p"):
        assert key in metrics, key
    report = kidnapped.report_path.read_text()
    assert "## Localization" in report and "localization.png" in report and "localization_pr.png" in report
    assert (kidnapped.out_dir / "localization.png").stat().st_size > 10_000
    assert (kidnapped.out_dir / "localization_pr.png").stat().st_size > 10_000
    summary = summarize(kidnapped.log_path)
    assert summary.topic("/localizer/pose_estimate").count == 250
    assert summary.topic("/localizer/pose").count == metrics["n_frames_localized"]  # foxglove.PoseInFrame
    assert summary.topic("/localizer/keyframe_added").count == metrics["n_keyframes"]
    assert summary.topic("/localizer/keyframes").count == 1  # foxglove.PosesInFrame of the map
    # the TUM files the run writes give the same ATE (frames' own timestamps) and RPE (the
    # shuffled drive's route-order files) through `eval traj`'s functions
    from slamfront.core.trajectory import evaluate_trajectories

    keys = ("ate_rmse_m", "rpe_rmse_m", "rpe_all_intervals_rmse_m")
    pnp = ("ate_rmse_pnp_m", "rpe_rmse_pnp_m", "rpe_all_intervals_rmse_pnp_m")
    out = kidnapped.out_dir
    for truth, estimates in (("groundtruth.tum", ("estimated.tum", "estimated_pnp.tum")),
                             ("groundtruth_route.tum", ("estimated_route.tum", "estimated_pnp_route.tum"))):
        gt = read_tum(out / truth)
        for name, theirs in zip(estimates, (keys, pnp)):
            est = read_tum(out / name)
            again = evaluate_trajectories(gt.timestamps, gt.poses, est.timestamps, est.poses, 1e-6,
                                          all_intervals=True).metrics()
            checked = keys if "route" in name else keys[:1]  # RPE is scored along the route
            for key, mine in zip(keys, theirs):
                if key in checked:
                    assert again[key] == pytest.approx(metrics[mine], abs=1e-9), (name, key)


def test_localization_and_its_scores_do_not_depend_on_the_order_frames_come_in(tmp_path: Path) -> None:
    """Global localization: the same keyframe for every place whether the drive is shuffled or
    not, and the same ATE and RPE (scored in route order, not arrival order)."""

    def answers(shuffle: bool) -> tuple[dict[int, tuple[int, int]], dict[str, Any]]:
        raw = kidnapped_recipe(shuffle, pnp_refinement=False)
        raw["source"]["params"].update(frames_per_traversal=30, image_width=240, image_height=180)
        raw["eval"] = {"plots": False}
        result = _run(raw, tmp_path / str(shuffle))
        places = {m.decoded.frame: m.decoded.sequence_index for m in read_messages(result.log_path, ["/frames"])}
        return {places[m.decoded.frame]: (m.decoded.keyframe, m.decoded.inliers)
                for m in read_messages(result.log_path, ["/localizer/pose_estimate"])}, result.metrics

    (ordered, in_order), (shuffled, out_of_order) = answers(False), answers(True)
    assert len(ordered) == 30 and ordered == shuffled
    assert in_order["n_rpe_pairs"] > 20
    for key in ("ate_rmse_m", "rpe_rmse_m", "rpe_max_m", "rpe_all_intervals_rmse_m", "n_rpe_pairs"):
        assert in_order[key] == out_of_order[key], key


def test_preselection_finds_the_same_keyframes_with_fewer_comparisons(small: RunResult, tmp_path: Path) -> None:
    fast = _run(kidnapped_recipe(preselection="thumbnail", candidates=5), tmp_path)
    assert fast.metrics["fraction_correct_keyframe_region"] == 1.0
    assert fast.metrics["n_two_view_matches"] < small.metrics["n_two_view_matches"]


@pytest.mark.parametrize("name", ["redwood_localize", "room_localize", "icl_localize"])
def test_real_samples_localize_every_frame(name: str, tmp_path: Path, shared_data: Path) -> None:
    recipe, path = load_recipe(name, ["log.images=false", "eval.plots=false"])
    m = run_pipeline(build_pipeline(recipe, str(path)), str(path), tmp_path, progress=False).metrics
    assert m["n_in_map_queries"] == 5 and m["n_out_of_map_queries"] == 20
    assert m["n_frames_localized"] == 5 and m["n_out_of_map_localized"] == 0  # every other scene's frame refused
    assert m["localization_precision"] == 1.0 and m["localization_recall_at_100p"] == m["localization_recall"]
    assert m["n_keyframes"] >= 1
    # frames that are keyframes find themselves; the others their keyframe (PnP makes it metric)
    assert m["ate_rmse_pnp_unaligned_m"] < {"redwood_localize": 0.01, "room_localize": 0.02,
                                            "icl_localize": 0.8}[name]


def test_leave_one_out_on_the_room_sample(tmp_path: Path, shared_data: Path) -> None:
    """Each keyframe localized against the others only: PnP recovers most of the pose."""
    recipe, path = load_recipe("room_localize", ["localizer.params.exclude_self=true", "log.images=false"])
    m = run_pipeline(build_pipeline(recipe, str(path)), str(path), tmp_path, progress=False).metrics
    assert m["n_frames_localized"] == 5 and m["n_refined"] >= 3
    assert m["ate_rmse_pnp_unaligned_m"] < 0.5 * m["ate_rmse_unaligned_m"]


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
    5.png <-> 6.png); the other views, of the desk from far-apart viewpoints, match too little
    to be sure of. The run reports the localization and says there is nothing to score."""
    raw = {
        "name": "loop10", "source": {"plugin": "image_folder", "params": {"folder": "images/loop10"}},
        "descriptor": {"plugin": "local_features", "params": {"descriptor": "orb", "max_features": 1000}},
        "localizer": {"plugin": "keyframe", "params": {"exclude_self": True}}, "eval": {"plots": False},
    }
    result = _run(raw, tmp_path)
    chosen = {m.decoded.frame: m.decoded.keyframe for m in read_messages(result.log_path, ["/localizer/pose_estimate"])}
    assert (chosen[9], chosen[0], chosen[4], chosen[5]) == (0, 9, 5, 4)
    assert result.metrics["n_frames_localized"] >= 4 and "ate_rmse_m" not in result.metrics
    assert "has a ground-truth pose: no ATE/RPE" in result.report_path.read_text()


def test_a_saved_map_gives_bit_identical_answers_without_the_reference_drive(small: RunResult, tmp_path: Path) -> None:
    """The run saved its map; a later run localizes against it (reference frames are then only
    queries) and every query of the second drive gets the very same answer, bit for bit."""
    saved = small.out_dir / "keyframe_map.npz"
    assert saved.is_file()
    again = _run(kidnapped_recipe(map=str(saved)), tmp_path)
    first = {m.decoded.frame: m.decoded for m in read_messages(small.log_path, ["/localizer/pose_estimate"])}
    second = {m.decoded.frame: m.decoded for m in read_messages(again.log_path, ["/localizer/pose_estimate"])}
    assert len(first) == 50 and len(second) == 100  # the loaded map is fixed: the reference drive is queried too
    assert all(second[frame].same_as(answer) for frame, answer in first.items())
    assert "/localizer/keyframe_added" not in {t.topic for t in summarize(again.log_path).topics}  # none added
    assert again.metrics["n_keyframes"] == small.metrics["n_keyframes"]
    # the map file is data: numpy reads it without pickle, and it round-trips unchanged
    from slamfront.formats.npz import read_message_npz, write_message_npz
    from slamfront_plugins.localizers.messages import KeyframeMap

    loaded = read_message_npz(saved, KeyframeMap)
    assert loaded.same_as(read_message_npz(write_message_npz(tmp_path / "copy.npz", loaded), KeyframeMap))
    assert loaded.points is not None and loaded.descriptors.dtype == np.uint8 and loaded.descriptor == "orb"


def test_a_saved_map_that_does_not_fit_the_recipe_is_refused(cli, small: RunResult, tmp_path: Path,
                                                             write_recipe) -> None:
    from tests.test_cli import _one_line_error

    raw = kidnapped_recipe(map=str(small.out_dir / "keyframe_map.npz"))
    raw["descriptor"]["params"]["descriptor"] = "sift"
    line = _one_line_error(*cli("run", write_recipe(raw), "-o", tmp_path / "run", "-q")[::2])
    assert "keyframe_map.npz holds orb features" in line and "sift" in line
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    raw = kidnapped_recipe(map=str(tmp_path / "junk.npz"))
    line = _one_line_error(*cli("run", write_recipe(raw, "junk.yaml"), "-o", tmp_path / "run2", "-q")[::2])
    assert "junk.npz: not a readable .npz archive" in line


def _frame_features(paths: list[Path]) -> dict[Path, tuple[Any, list]]:
    from slamfront.frame import Frame
    from slamfront.imageio import read_image
    from slamfront.plugin import StageInputs
    from slamfront_plugins.descriptors.local_features import LocalFeaturesDescriptor

    descriptor = LocalFeaturesDescriptor(LocalFeaturesDescriptor.Config())  # ORB, 1000 features
    out = {}
    for path in paths:
        frame = Frame(0, 0.0, read_image(path))
        out[path] = (frame.image, list(descriptor.process(StageInputs(frame=frame))))
    return out


def test_unrelated_images_are_unknown_places(shared_data: Path) -> None:
    """Acceptance: a map of one loop10 image, a query from an RGB-D sample (and the other way
    round), every pair: the default localizer answers "unknown place" for at least 95 %."""
    from slamfront.frame import Frame
    from slamfront.imageio import list_images
    from slamfront.plugin import StageInputs
    from slamfront_plugins.descriptors.local_features import LocalFeaturesDescriptor
    from slamfront_plugins.localizers.keyframe import KeyframeLocalizer

    loop = list_images(shared_data / "images/loop10")
    samples = [p for s in ("redwood_sample", "room_sample", "icl_livingroom_sample")
               for p in list_images(shared_data / "rgbd" / s / "color")]
    features = _frame_features(loop + samples)
    descriptor = LocalFeaturesDescriptor(LocalFeaturesDescriptor.Config())
    answers = []
    for a in loop:
        for b in samples:
            for keyframe, query in ((a, b), (b, a)):
                localizer = KeyframeLocalizer()
                localizer.check({"descriptor": descriptor})
                image, outputs = features[keyframe]
                localizer.process(StageInputs(frame=Frame(0, 0.0, image, "reference"), outputs={"descriptor": outputs}))
                image, outputs = features[query]
                (answer,) = localizer.process(StageInputs(frame=Frame(1, 1.0, image, "query"),
                                                          outputs={"descriptor": outputs}))
                answers.append(answer)
    assert len(answers) == 300
    unknown = [a for a in answers if a.keyframe < 0]
    assert len(unknown) >= 0.95 * len(answers)
    assert all(a.reason.startswith(("unknown place", "best keyframe has")) for a in unknown)


def test_the_papers_matching_with_sift_runs_to_the_end(tmp_path: Path) -> None:
    """Brute-force matching without the ratio test is many-to-one; PnP on it once crashed (SQPnP)."""
    raw = kidnapped_recipe(matching={"ratio": None})
    raw["descriptor"]["params"]["descriptor"] = "sift"
    raw["source"]["params"].update(frames_per_traversal=40, route_length_m=80)
    result = _run(raw, tmp_path)
    assert result.metrics["n_frames"] == 80 and result.metrics["n_localization_queries"] == 40


def test_tum_sequence_recipe_on_a_fixture_in_the_tum_layout(tmp_path: Path, shared_data: Path) -> None:
    """The fr1/desk recipe reads a TUM-layout folder (here synthetic frames written as TUM
    files) through the tum_rgbd source and localizes every frame in its region."""
    from slamfront_plugins.sources.synthetic import SyntheticWorld
    from tests.helpers import write_tum_layout

    world = SyntheticWorld(SyntheticWorld.Config(mode="stream", laps=1, frames_per_traversal=40, route_length_m=60,
                                                 image_width=320, image_height=240))
    frames = list(world.frames())
    root = write_tum_layout(tmp_path / "tum_fr1_desk", frames)
    camera = world.camera
    recipe, path = load_recipe("tum_fr1_desk_localize", [
        f"source.params.main.params.root={root}", "log.images=false", "eval.plots=false",
        f"source.params.main.params.camera={{fx: {camera.fx}, fy: {camera.fy}, cx: {camera.cx}, cy: {camera.cy}}}",
    ])
    m = run_pipeline(build_pipeline(recipe, str(path)), str(path), tmp_path / "run", progress=False).metrics
    assert m["n_in_map_queries"] == 40 and m["n_out_of_map_queries"] == 15
    assert m["localization_recall"] >= 0.95 and m["n_out_of_map_localized"] == 0
    assert m["ate_rmse_pnp_unaligned_m"] < m["ate_rmse_unaligned_m"]
