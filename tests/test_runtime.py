"""A whole run: outputs, log contents, bit-exact arrays, evaluation."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from slamfront.mcaplog.reader import read_attachment, read_messages, summarize
from slamfront.messages import Features, FrameInfo, LoopResult
from slamfront.recipe import build_pipeline, parse_recipe
from slamfront.runtime import run_pipeline
from slamfront_plugins.descriptors.downsampled import DownsampledImage
from slamfront_plugins.sources.synthetic import SyntheticWorld
from tests.helpers import small_synthetic_recipe

CONTRACT_KEYS = {
    "recall_at_100p", "auc_pr", "n_queries", "n_searches", "n_places_reference", "n_places_query",
    "seconds", "frames_per_second",
}


@pytest.fixture(scope="module")
def small_run(tmp_path_factory: pytest.TempPathFactory):
    out = tmp_path_factory.mktemp("run")
    raw = small_synthetic_recipe()
    raw["eval"]["plots"] = True
    recipe = parse_recipe(raw, "small.yaml")
    pipeline = build_pipeline(recipe, "small.yaml")
    return run_pipeline(pipeline, "small.yaml", out, progress=False), pipeline


def test_run_writes_log_metrics_and_report(small_run) -> None:
    result, _ = small_run
    metrics = json.loads(result.metrics_path.read_text())
    assert CONTRACT_KEYS <= metrics.keys()
    assert metrics["n_queries"] == 40 and metrics["n_frames"] == 80
    assert {"descriptor", "loop_detector"} <= metrics["timing"].keys()
    report = result.report_path.read_text()
    assert "## Loop closure" in report and "pr.png" in report
    for png in ("pr.png", "matches.png", "trajectory.png"):
        assert (result.out_dir / png).stat().st_size > 1000


def test_log_has_a_topic_per_stage_and_foxglove_schemas(small_run) -> None:
    result, _ = small_run
    summary = summarize(result.log_path)
    assert summary.complete
    schemas = {t.topic: t.schema_name for t in summary.topics}
    assert schemas["/descriptor/features"] == "slamfront.Features"
    assert schemas["/loop_detector/loop_result"] == "slamfront.LoopResult"
    assert schemas["/camera/image"] == "foxglove.CompressedImage"
    assert schemas["/ground_truth/pose"] == "foxglove.PoseInFrame"
    assert schemas["/tf"] == "foxglove.FrameTransforms"
    assert schemas["/camera/calibration"] == "foxglove.CameraCalibration"
    assert summary.topic("/frames").count == 80
    assert {"slamfront", "plugins", "params.source"} <= summary.metadata.keys()
    assert b"nearest_neighbour" in read_attachment(result.log_path, "recipe.yaml")


def test_logged_arrays_equal_what_the_stages_produced(small_run) -> None:
    result, pipeline = small_run
    # recompute every descriptor independently and compare bit for bit with the log
    source = SyntheticWorld(pipeline.source.config)
    describe = DownsampledImage(pipeline.plugins["descriptor"].config).describe
    expected = {frame.index: describe(frame.image) for frame in source.frames()}
    logged = [m.decoded for m in read_messages(result.log_path, ["/descriptor/features"])]
    assert len(logged) == len(expected)
    for features in logged:
        assert isinstance(features, Features)
        assert features.vector.dtype == np.float32
        assert features.vector.tobytes() == expected[features.frame].tobytes()
    poses = {m.decoded.frame: m.decoded.pose for m in read_messages(result.log_path, ["/frames"])}
    for frame in source.frames():
        assert poses[frame.index].tobytes() == frame.pose.tobytes()


def test_every_query_gets_a_loop_result(small_run) -> None:
    result, _ = small_run
    results = [m.decoded for m in read_messages(result.log_path, ["/loop_detector/loop_result"])]
    assert all(isinstance(r, LoopResult) for r in results)
    assert sorted(r.frame for r in results) == list(range(40, 80))
    infos = [m.decoded for m in read_messages(result.log_path, ["/frames"])]
    assert all(isinstance(i, FrameInfo) for i in infos)


def test_stream_mode_evaluates_revisits(tmp_path: Path) -> None:
    raw = small_synthetic_recipe(mode="stream", laps=2)
    raw["loop_detector"]["params"] = {"exclude_recent": 10}
    recipe = parse_recipe(raw, "s.yaml")
    result = run_pipeline(build_pipeline(recipe, "s.yaml"), "s.yaml", tmp_path, progress=False)
    assert result.metrics["n_queries"] == 80
    # the second lap, and the last frame of the first (the closed route is back at its start)
    assert result.metrics["n_queries_with_true_match"] == 41


def test_a_stream_run_reports_its_stream_not_an_empty_reference(tmp_path) -> None:  # type: ignore[no-untyped-def]
    # a stream has no reference and query halves: no `n_places_reference 0`, no `0 / 40` frames
    raw = small_synthetic_recipe(mode="stream", laps=2, frames_per_traversal=20)
    recipe = parse_recipe(raw, "stream.yaml")
    result = run_pipeline(build_pipeline(recipe, "stream.yaml"), "stream.yaml", tmp_path, progress=False)
    metrics = json.loads(result.metrics_path.read_text())
    assert metrics["n_frames_stream"] == 40 and metrics["n_places_stream"] > 0
    assert metrics.get("n_places_reference") != 0 and metrics.get("n_frames_reference") != 0
    report = result.report_path.read_text()
    assert "| frames in the stream | places | searches for a loop |" in report and "0 / 40" not in report
