"""Replaying runs from their logs: bit-exact reproduction, swapping stages, refusals."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from slamfront.errors import LogError, PluginError, RecipeError
from slamfront.mcaplog.diff import diff_logs
from slamfront.mcaplog.reader import read_messages, summarize
from slamfront.mcaplog.topics import LOOP_TRUTH_TOPIC
from slamfront.recipe import build_pipeline, parse_recipe
from slamfront.replay import LogRecording, RecordedStage, log_recipe, plan_replay, replay_log
from slamfront.runtime import RunResult, run_pipeline
from slamfront_plugins.descriptors.downsampled import DownsampledImage
from slamfront_plugins.loop_detectors.nearest_neighbour import NearestNeighbour
from tests.helpers import rewrite_log, small_synthetic_recipe, stage_topic_bytes

# The pipelines whose replay must reproduce the original run bit for bit. Each entry is
# the stages of a small synthetic run; add a detector by adding its stages here, e.g.
#   "hierarchical_sequence": {"descriptor": {"plugin": "rst_shelo", ...},
#                             "place_map": {"plugin": "hierarchical", ...},
#                             "loop_detector": {"plugin": "hierarchical_sequence", ...}},
#   "seqslam": {"descriptor": {...}, "loop_detector": {"plugin": "seqslam", ...}},
REPLAYED_PIPELINES: dict[str, dict[str, Any]] = {
    "nearest_neighbour": {
        "descriptor": {"plugin": "downsampled", "params": {"width": 16, "height": 16}},
        "loop_detector": {"plugin": "nearest_neighbour", "params": {"threshold": 0.1}},
    },
    # nu chosen from the reference (auto), frame-level mode: the choice is replayed too
    "hierarchical_sequence": {
        "descriptor": {"plugin": "rst_shelo", "params": {"cells_x": 16, "cells_y": 12}},
        "place_map": {"plugin": "hierarchical"},
        "loop_detector": {"plugin": "hierarchical_sequence", "params": {"rho": 3, "sequence_frames": 12}},
    },
    "hierarchical_faithful": {
        "descriptor": {"plugin": "rst_shelo", "params": {"cells_x": 16, "cells_y": 12}},
        "place_map": {"plugin": "hierarchical", "params": {"similarity_threshold": 0.9}},
        "loop_detector": {"plugin": "hierarchical_faithful", "params": {"rho": 3}},
    },
    # the frame-level detector on the flat place map (one place per frame)
    "hierarchical_sequence_flat": {
        "descriptor": {"plugin": "rst_shelo", "params": {"cells_x": 16, "cells_y": 12}},
        "place_map": {"plugin": "flat"},
        "loop_detector": {"plugin": "hierarchical_sequence", "params": {"rho": 3, "sequence_frames": 12}},
    },
    # a stream: nu from the first 20 frames, held and placed at once
    "hierarchical_sequence_stream": {
        "source_params": {"mode": "stream", "laps": 2, "frames_per_traversal": 30},
        "descriptor": {"plugin": "rst_shelo", "params": {"cells_x": 16, "cells_y": 12}},
        "place_map": {"plugin": "hierarchical", "params": {"calibration_frames": 20}},
        "loop_detector": {"plugin": "hierarchical_sequence",
                          "params": {"rho": 3, "sequence_frames": 12, "exclude_recent_places": 5}},
    },
    "nearest_neighbour_stream": {
        "source_params": {"mode": "stream", "laps": 2, "frames_per_traversal": 30},
        "descriptor": {"plugin": "downsampled", "params": {"width": 16, "height": 12, "patch_size": 4}},
        "loop_detector": {"plugin": "nearest_neighbour", "params": {"exclude_recent": 10}},
    },
    "seqslam": {
        "source_params": {"image_width": 64, "image_height": 32},
        "descriptor": {"plugin": "seqslam_thumbnail"},
        "loop_detector": {"plugin": "seqslam", "params": {"ds": 6}},
    },
    "seqslam_fast_online": {
        "source_params": {"image_width": 64, "image_height": 32},
        "descriptor": {"plugin": "seqslam_thumbnail"},
        "loop_detector": {"plugin": "seqslam_fast", "params": {"ds": 6, "mode": "online", "score_offset": "bound"}},
    },
    # loop poses only from earlier stages: the back end needs no pixels, so it is re-run from a JPEG log
    "gtsam_pose_graph_stage_loops": {
        "source_params": {"mode": "stream", "laps": 2, "frames_per_traversal": 30},
        "descriptor": {"plugin": "downsampled", "params": {"width": 16, "height": 12, "patch_size": 4}},
        "loop_detector": {"plugin": "nearest_neighbour", "params": {"exclude_recent": 10}},
        "backend": {"plugin": "gtsam_pose_graph", "params": {"loop_pose": "stages"}},
    },
    # no time budget: transfers to long-term memory would then depend on the machine's speed
    "bow_bayes_stream": {
        "source_params": {"mode": "stream", "laps": 2, "frames_per_traversal": 30, "image_width": 160, "image_height": 120},
        "descriptor": {"plugin": "local_features", "params": {"descriptor": "orb", "max_features": 200}},
        "loop_detector": {"plugin": "bow_bayes", "params": {"time_budget_s": 0}},
    },
}


def _recipe(stages: dict[str, Any], **log: Any) -> dict[str, Any]:
    raw = small_synthetic_recipe(**stages.get("source_params", {}))
    for kind, spec in stages.items():
        if kind != "source_params":
            raw[kind] = spec
    raw["log"] = log
    return raw


def _run(raw: dict[str, Any], out: Path) -> RunResult:
    recipe = parse_recipe(raw, "replay-test.yaml")
    return run_pipeline(build_pipeline(recipe, "replay-test.yaml"), "replay-test.yaml", out, progress=False)


@pytest.fixture(scope="module", params=sorted(REPLAYED_PIPELINES))
def original(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> RunResult:
    return _run(_recipe(REPLAYED_PIPELINES[request.param]), tmp_path_factory.mktemp(request.param))


def test_replay_with_the_embedded_recipe_reproduces_every_downstream_message(original: RunResult, tmp_path: Path) -> None:
    replay = replay_log(original.log_path, tmp_path / "replay", progress=False)
    result = diff_logs(original.log_path, replay.log_path)
    assert result.identical, [d.describe() for d in result.differences]
    # the comparison covered every stage's topics, message for message
    stages = [kind for kind in ("descriptor", "place_map", "loop_detector", "backend") if kind in original.metrics["timing"]]
    for kind in stages:
        a, b = stage_topic_bytes(original.log_path, f"/{kind}/"), stage_topic_bytes(replay.log_path, f"/{kind}/")
        assert a and a == b
    summary = summarize(replay.log_path)
    first_rerun = stages[1]  # the first stage after the descriptor, which read the (lossy) pixels
    assert summary.metadata["replay"]["from"] == first_rerun
    assert summary.metadata["replay"]["recorded_stages"] == "descriptor"
    for key in ("recall_at_100p", "auc_pr", "n_queries", "n_searches", "n_frames"):
        assert replay.metrics[key] == original.metrics[key]
    # it was read, not run: the log says so where it names each stage's plugin
    assert summary.metadata["plugins"]["descriptor"].endswith(f"read from {original.log_path}")
    last = [m.decoded.message for m in read_messages(replay.log_path, ["/log"])][-1]
    assert "replay of" in last and f"from {first_rerun}" in last


def test_a_replay_can_be_replayed(original: RunResult, tmp_path: Path) -> None:
    first = replay_log(original.log_path, tmp_path / "once", progress=False)
    second = replay_log(first.log_path, tmp_path / "twice", progress=False)
    assert diff_logs(original.log_path, second.log_path).identical


@pytest.fixture(scope="module")
def paired_run(tmp_path_factory: pytest.TempPathFactory) -> RunResult:
    return _run(_recipe(REPLAYED_PIPELINES["nearest_neighbour"]), tmp_path_factory.mktemp("paired"))


def test_replay_from_loop_detector_runs_another_detector_without_the_descriptor(
    paired_run: RunResult, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    other = {"threshold": 0.4, "uniqueness_window": 2, "exclude_recent": 5, "candidates": 3}
    raw = _recipe(REPLAYED_PIPELINES["nearest_neighbour"])
    raw["loop_detector"]["params"] = other
    live = _run(raw, tmp_path / "live")  # what that detector gives on a fresh run

    def not_called(*_args: Any) -> None:
        raise AssertionError("the descriptor ran during a replay --from loop_detector")

    monkeypatch.setattr(DownsampledImage, "process", not_called)
    monkeypatch.setattr(DownsampledImage, "describe", not_called)
    monkeypatch.setattr(DownsampledImage, "finish", not_called)
    recipe = parse_recipe(raw, "other.yaml")
    replay = replay_log(paired_run.log_path, tmp_path / "replay", recipe, "other.yaml", "loop_detector", progress=False)

    results = stage_topic_bytes(replay.log_path, "/loop_detector/loop_result")
    assert results == stage_topic_bytes(live.log_path, "/loop_detector/loop_result")
    assert results != stage_topic_bytes(paired_run.log_path, "/loop_detector/loop_result")
    assert stage_topic_bytes(replay.log_path, "/descriptor/") == stage_topic_bytes(paired_run.log_path, "/descriptor/")
    assert replay.metrics["recall_at_1"] == live.metrics["recall_at_1"]
    assert replay.metrics["auc_pr"] == live.metrics["auc_pr"]


def test_replay_from_the_descriptor_when_the_log_keeps_exact_pixels(tmp_path: Path) -> None:
    stages = REPLAYED_PIPELINES["nearest_neighbour"]
    original = _run(
        _recipe(stages, image_format="png", image_max_width=64, depth=True, depth_encoding="32FC1"), tmp_path / "a"
    )
    replay = replay_log(original.log_path, tmp_path / "b", from_kind="descriptor", progress=False)
    result = diff_logs(original.log_path, replay.log_path)
    assert result.identical, [d.describe() for d in result.differences]
    assert "descriptor" in replay.metrics["timing"]  # this time it ran, on the logged pixels
    # with exact pixels the default is to re-run everything
    assert summarize(replay_log(original.log_path, tmp_path / "c", progress=False).log_path).metadata["replay"][
        "from"
    ] == "descriptor"


def test_replay_refuses_what_the_log_cannot_feed(paired_run: RunResult, cli, tmp_path: Path) -> None:
    log = paired_run.log_path
    with pytest.raises(LogError, match="JPEG"):
        replay_log(log, tmp_path / "x", from_kind="descriptor")
    changed = log_recipe(log).model_dump(mode="json")
    changed["descriptor"]["params"]["width"] = 8
    with pytest.raises(RecipeError, match="descriptor differs from the log's"):
        replay_log(log, tmp_path / "x", parse_recipe(changed, "changed.yaml"), "changed.yaml")
    moved = log_recipe(log).model_dump(mode="json")
    moved["source"]["params"]["seed"] = 5
    with pytest.raises(RecipeError, match="source differs"):
        replay_log(log, tmp_path / "x", parse_recipe(moved, "moved.yaml"), "moved.yaml")
    with pytest.raises(LogError, match="cannot overwrite"):
        replay_log(log, log.parent)
    code, _, err = cli("replay", log, "--from", "place_map", "-o", tmp_path / "y", "-q")
    assert code == 2 and err.count("\n") == 1 and "has no place_map stage" in err


def test_a_stage_read_from_the_log_shows_its_identity_not_its_state(paired_run: RunResult) -> None:
    plan = plan_replay(paired_run.log_path, from_kind="loop_detector")
    make = RecordedStage.substitute(LogRecording(plan))
    stage = make(DownsampledImage, DownsampledImage.Config(width=32))
    assert isinstance(stage, RecordedStage) and type(stage).__name__ == "RecordedDownsampledImage"
    assert stage.name == "downsampled" and stage.kind == "descriptor" and stage.produces_global
    assert stage.config.width == 32 and not hasattr(stage, "describe")  # its identity, not its methods or state


def test_a_later_stage_that_needs_a_stage_read_from_the_log_is_refused_before_the_first_frame(
    tmp_path: Path,
) -> None:
    original = _run(_recipe(REPLAYED_PIPELINES["hierarchical_sequence"]), tmp_path / "a")
    with pytest.raises(PluginError, match=r"loop_detector: .*read from the log: they give their logged messages, "
                                          r"not their state; replay from an earlier stage"):
        replay_log(original.log_path, tmp_path / "b", from_kind="loop_detector")
    assert not (tmp_path / "b" / "run.mcap").exists()


def test_replay_of_a_run_that_failed_leaves_out_its_unfinished_frame(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    process = NearestNeighbour.process

    def failing(self: NearestNeighbour, inputs: Any) -> Any:
        if inputs.frame.index == 50:
            raise RuntimeError("detector crashed")
        return process(self, inputs)

    with monkeypatch.context() as patch:
        patch.setattr(NearestNeighbour, "process", failing)
        with pytest.raises(RuntimeError):
            _run(_recipe(REPLAYED_PIPELINES["nearest_neighbour"]), tmp_path / "crashed")
    replay = replay_log(tmp_path / "crashed" / "run.mcap", tmp_path / "replay", progress=False)
    assert replay.metrics["n_frames"] == 50
    assert summarize(replay.log_path).complete
    last = [m.decoded.message for m in read_messages(replay.log_path, ["/log"])][-1]
    assert "last frame was left out" in last
    results = [m.decoded for m in read_messages(replay.log_path, ["/loop_detector/loop_result"])]
    assert [r.frame for r in results] == list(range(40, 50))


def test_replay_rebuilds_ground_truth_from_the_source_when_the_log_lacks_it(
    paired_run: RunResult, tmp_path: Path
) -> None:
    stripped = tmp_path / "stripped.mcap"
    rewrite_log(paired_run.log_path, stripped, lambda topic, _i, data: None if topic == LOOP_TRUTH_TOPIC else data)
    replay = replay_log(stripped, tmp_path / "replay", progress=False)
    assert replay.metrics["recall_at_100p"] == paired_run.metrics["recall_at_100p"]
    last = [m.decoded.message for m in read_messages(replay.log_path, ["/log"])][-1]
    assert "rebuilt from the recipe's source" in last


def test_replay_cli(paired_run: RunResult, cli, tmp_path: Path) -> None:
    out = tmp_path / "replayed"
    code, stdout, _ = cli(
        "replay", paired_run.out_dir, "-o", out, "-q", "--set", "loop_detector.params.threshold=0.5"
    )
    assert code == 0 and "loop closure: recall " in stdout  # the run's headline sentences
    assert log_recipe(out / "run.mcap").loop_detector.params["threshold"] == 0.5
    code, stdout, _ = cli("diff", paired_run.out_dir, out)
    assert code == 1 and "/loop_detector/loop_result  message 6" in stdout and "accepted: True vs False" in stdout
