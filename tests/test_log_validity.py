"""Logs Foxglove understands: schemas, decodable messages, time and frames, the layout."""

from __future__ import annotations

import json
from pathlib import Path

import jsonschema
import pytest

from slamfront.mcaplog.reader import read_messages, summarize
from slamfront.mcaplog.validate import foxglove_message_types, validate_log
from slamfront.recipe import build_pipeline, load_recipe, parse_recipe
from slamfront.runtime import RunResult, run_pipeline
from tests.helpers import layout_problems, rewrite_log, small_synthetic_recipe

REPO = Path(__file__).resolve().parents[1]
LAYOUT = REPO / "foxglove" / "slamfront-layout.json"



@pytest.fixture(scope="module")
def full_log(tmp_path_factory: pytest.TempPathFactory) -> RunResult:
    """A run with every log option on: depth (exact), point clouds, lossless images, the scene."""
    raw = small_synthetic_recipe()
    raw["log"] = {"depth": True, "depth_encoding": "32FC1", "points": True, "image_format": "png", "scene_every": 10}
    recipe = parse_recipe(raw, "full.yaml")
    out = tmp_path_factory.mktemp("full")
    return run_pipeline(build_pipeline(recipe, "full.yaml"), "full.yaml", out, progress=False)


def test_every_topic_has_a_known_schema_and_every_message_decodes(full_log: RunResult) -> None:
    validation = validate_log(full_log.log_path)
    assert validation.valid, validation.problems
    summary = summarize(full_log.log_path)
    assert validation.n_messages == summary.n_messages
    foxglove = foxglove_message_types()
    for topic in summary.topics:
        if topic.schema_encoding == "protobuf":
            assert topic.schema_name in foxglove, topic
        else:
            assert (topic.schema_encoding, topic.message_encoding) == ("jsonschema", "json"), topic
            assert topic.schema_name.startswith("slamfront."), topic
    assert {"/camera/depth", "/camera/points", "/scene/map", "/tf", "/ground_truth/loops"} <= {
        t.topic for t in summary.topics
    }


def test_json_messages_satisfy_their_embedded_json_schema(full_log: RunResult) -> None:
    validators: dict[str, jsonschema.Draft202012Validator] = {}
    checked = 0
    for message in read_messages(full_log.log_path):
        if message.message_encoding != "json":
            continue
        if message.topic not in validators:
            schema = json.loads(message.schema_data)
            jsonschema.Draft202012Validator.check_schema(schema)
            validators[message.topic] = jsonschema.Draft202012Validator(schema)
        validators[message.topic].validate(json.loads(message.data))
        checked += 1
    assert checked > 200 and "/loop_detector/loop_result" in validators


def test_frames_and_times_line_up_for_the_3d_panel(full_log: RunResult) -> None:
    frames = [m.decoded for m in read_messages(full_log.log_path, ["/frames"])]
    transforms = list(read_messages(full_log.log_path, ["/tf"]))
    assert len(transforms) == len(frames)  # one map -> camera transform per frame with a pose
    for message, info in zip(transforms, frames):
        (transform,) = message.decoded.transforms
        assert (transform.parent_frame_id, transform.child_frame_id) == ("map", "camera")
        assert message.log_time_ns == round(info.timestamp * 1e9)
    scene = [m.decoded for m in read_messages(full_log.log_path, ["/scene/map"])]
    assert len(scene) == 8  # every 10 frames (the last write adds nothing new)
    entities = {e.id: e for e in scene[-1].entities}
    assert {"path/reference", "path/query", "loop_closures"} <= entities.keys()
    assert all(e.frame_id == "map" for e in entities.values())
    assert len(entities["path/reference"].lines[0].points) == 40
    accepted = sum(m.decoded.accepted and m.decoded.match >= 0 for m in read_messages(full_log.log_path, ["/loop_detector/loop_result"]))
    assert len(entities["loop_closures"].lines[0].points) == 2 * accepted > 0


def test_the_foxglove_layout_shows_topics_the_logs_have(full_log: RunResult) -> None:
    layout = json.loads(LAYOUT.read_text())
    # a loop-closure run fills the first tab; the back-end tab is checked on the demo's log (test_demo.py)
    assert layout_problems(layout, full_log.log_path, tab="Loop closure") == []
    plotted = [p["value"] for k, c in layout["configById"].items() if k.startswith("Plot!") for p in c["paths"]]
    assert "/loop_detector/loop_result.confidence" in plotted
    assert {"Loop closure", "Back end"} <= {t["title"] for t in layout["configById"]["Tab!slamfront-tabs"]["tabs"]}
    readme = (REPO / "README.md").read_text()
    assert "foxglove/slamfront-layout.json" in readme


@pytest.mark.parametrize("recipe, overrides, layout", [
    ("synthetic_localize", {"main.params.frames_per_traversal": 30, "main.params.route_length_m": 45},
     "slamfront-localization.json"),
    ("synthetic_register", {"frames_per_traversal": 8, "route_length_m": 30}, "slamfront-registration.json"),
])
def test_localization_and_registration_layouts_show_topics_their_logs_have(
    recipe: str, overrides: dict[str, int], layout: str, tmp_path: Path
) -> None:
    loaded, path = load_recipe(recipe, [f"source.params.{k}={v}" for k, v in overrides.items()] + ["eval.plots=false"])
    result = run_pipeline(build_pipeline(loaded, str(path)), str(path), tmp_path, progress=False)
    assert layout_problems(json.loads((LAYOUT.parent / layout).read_text()), result.log_path) == []
    assert f"`slamfront layout {layout}`" in result.report_path.read_text()  # the report names the layout to use


def test_every_shipped_layout_is_found_by_name(cli) -> None:
    for layout in sorted(LAYOUT.parent.glob("*.json")):
        code, out, _ = cli("layout", layout.stem)
        assert code == 0 and json.loads(Path(out.strip()).read_text()) == json.loads(layout.read_text())
    code, _, err = cli("layout", "nope")
    assert code == 2 and "no shipped Foxglove layout named 'nope'" in err and "slamfront-registration.json" in err


def test_the_layout_check_notices_a_panel_without_its_topic(full_log: RunResult) -> None:
    layout = json.loads(LAYOUT.read_text())
    layout["configById"]["Plot!slamfront-confidence"]["paths"][0]["value"] = "/loop_detector/loop_result.nothing"
    layout["configById"]["RosOut!slamfront-log"]["topicToRender"] = "/no/such/topic"
    problems = layout_problems(layout, full_log.log_path, tab="Loop closure")
    assert any("has no field nothing" in p for p in problems) and any("/no/such/topic" in p for p in problems)


def test_the_report_states_log_size_and_write_throughput(full_log: RunResult) -> None:
    metrics = full_log.metrics
    assert metrics["log_bytes"] == full_log.log_path.stat().st_size
    assert metrics["log_bytes_per_frame"] == metrics["log_bytes"] / 80
    assert 0 < metrics["log_write_fraction"] < 1 and metrics["log_write_mb_per_s"] > 0
    report = full_log.report_path.read_text()
    assert "## Log" in report and "write throughput" in report and "KiB per frame" in report


def test_inspect_validate_flags_a_message_that_does_not_round_trip(full_log: RunResult, tmp_path: Path, cli) -> None:
    code, stdout, _ = cli("inspect", full_log.log_path, "--validate")
    assert code == 0 and "valid:" in stdout
    broken = tmp_path / "broken.mcap"
    rewrite_log(
        full_log.log_path, broken,
        lambda topic, index, data: data.replace(b'"accepted":', b'"accepted" :') if topic.startswith("/loop") else data,
    )
    code, stdout, err = cli("inspect", broken, "--validate")
    assert code == 2 and "--validate" in err
    assert "INVALID: /loop_detector/loop_result message" in stdout and "round-trip" in stdout
