"""Every shipped recipe validates, runs on a small part of its data that reaches its queries,
and writes a log whose every topic has a Foxglove or registered slamfront schema and
whose every message decodes, in this process and, as a user runs it, in a fresh one
(`slamfront inspect LOGS... --validate`) that never ran the plugins."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from slamfront.mcaplog.reader import summarize
from slamfront.mcaplog.validate import validate_log
from slamfront.message_types import installed_message_types
from slamfront.recipe import Recipe, build_pipeline, load_recipe, recipes_dir
from slamfront.runtime import RunResult, run_pipeline
from slamfront_plugins.sources.synthetic import SyntheticWorld
from tests.helpers import write_tum_layout
from tests.recordings import BagSpec, write_bag

RECIPES = sorted(recipes_dir().glob("*.yaml"))


BAGS = {
    "realsense_bag": BagSpec(ros=1, image="rgb8", depth="16UC1", pose=None),
    "mono_odometry_bag": BagSpec(ros=1, image="jpeg", depth=None, pose="Odometry", topics={
        "image": "/camera/image_raw", "info": "/camera/camera_info", "pose": "/odom", "depth": "/unused"}),
}
"""The bag each shipped ros_bag recipe is smoke-run on: the topics and encodings it names."""


def data_root_for(recipe: Recipe, tmp_path: Path, shared_data: Path) -> Path:
    """The shared data root, or, for a recipe on a TUM sequence or a bag (not available here), a
    copy of it (by links) with synthetic frames where the recipe looks (a TUM-layout sequence,
    or a bag with the recipe's topics)."""
    spec = recipe.source.params.get("main", recipe.source.model_dump())
    if spec["plugin"] not in ("tum_rgbd", "ros_bag"):
        return shared_data
    root = tmp_path / "data"
    root.mkdir()
    for entry in shared_data.iterdir():
        (root / entry.name).symlink_to(entry)
    world = SyntheticWorld(SyntheticWorld.Config(mode="stream", laps=1, frames_per_traversal=12, image_width=160,
                                                 image_height=120))
    if spec["plugin"] == "ros_bag":
        assert recipe.name in BAGS, f"add the bag {recipe.name} is smoke-run on to BAGS"
        bag = root / spec["params"]["path"]
        bag.parent.mkdir(parents=True)
        write_bag(bag, world.frames(), BAGS[recipe.name])
        return root
    write_tum_layout(root / spec["params"]["root"], list(world.frames()))
    return root


def test_there_are_recipes() -> None:
    assert (recipes_dir() / "demo.yaml") in RECIPES


SMOKE: dict[str, tuple[list[str], int | None]] = {
    # (overrides, max frames) making each run short but long enough to reach its queries,
    # so it logs every message type it logs in full (default: its first 12 frames)
    **{name: (["source.params.frames_per_traversal=30"], None)
       for name in ("paired_demo", "synthetic_hsl", "synthetic_seqslam", "synthetic_bow", "synthetic_slam")},
    "synthetic_localize": (["source.params.main.params.frames_per_traversal=12"], 24),  # stops before other scenes
    **{path.stem: (["source.params.limit=40"], None) for path in RECIPES if path.stem.startswith("nordland_")},
    **{path.stem: (["source.params.limit=40", "source.params.block_start=10", "source.params.block_length=20"], None)
       for path in RECIPES if path.stem.startswith("nordland_") and path.stem[-5:] in ("_exp2", "_exp3")},
}
KIND_OUTPUTS = {
    # what each kind of stage of a shipped recipe must have logged in its smoke run
    "descriptor": "slamfront.Features", "place_map": "slamfront.PlaceAssignment",
    "loop_detector": "slamfront.LoopResult", "localizer": "slamfront.PoseEstimate",
    "registration": "slamfront.CloudRegistration", "backend": "slamfront.PoseGraphState",
}
_SMOKE_RUNS: dict[str, RunResult] = {}


def _smoke_run(path: Path, out: Path, shared_data: Path) -> tuple[RunResult, set[str]]:
    overrides, max_frames = SMOKE.get(path.stem, ([], 12))
    recipe, _ = load_recipe(path, overrides)
    pipeline = build_pipeline(recipe, str(path), data=data_root_for(recipe, out, shared_data))
    result = run_pipeline(pipeline, str(path), out, progress=False, max_frames=max_frames)
    _SMOKE_RUNS[path.stem] = result
    return result, set(pipeline.plugins)


@pytest.mark.parametrize("path", RECIPES, ids=[p.stem for p in RECIPES])
def test_recipe_validates_and_smoke_runs(path: Path, tmp_path: Path, shared_data: Path) -> None:
    recipe, _ = load_recipe(path)
    assert recipe.description, f"{path.name} needs a description (shown by `slamfront recipes`)"
    result, kinds = _smoke_run(path, tmp_path, shared_data)
    summary = summarize(result.log_path)
    assert summary.complete
    validation = validate_log(result.log_path)
    assert validation.valid and not validation.not_installed, (validation.problems, validation.not_installed)
    logged = {topic.schema_name for topic in summary.topics}
    for kind in kinds - {"source"}:
        assert kind in result.metrics["timing"]
        assert KIND_OUTPUTS[kind] in logged, f"{path.stem}: the smoke run's {kind} logged no {KIND_OUTPUTS[kind]}"


def test_every_recipes_log_validates_in_a_fresh_process(tmp_path_factory: pytest.TempPathFactory,
                                                        shared_data: Path) -> None:
    """As a user checks a log: `slamfront inspect LOG --validate` in a process that never ran
    a plugin, so message types come from the installed packages alone (one process for all
    the recipes' logs: each is validated on its own, the exit status is 0 only if all are)."""
    for path in RECIPES:  # those the parametrised test did not run already (e.g. with -k)
        if path.stem not in _SMOKE_RUNS:
            _smoke_run(path, tmp_path_factory.mktemp(path.stem), shared_data)
    logs = [_SMOKE_RUNS[path.stem].log_path for path in RECIPES]
    done = subprocess.run([sys.executable, "-m", "slamfront", "inspect", *map(str, logs), "--validate"],
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stdout[-4000:] + done.stderr
    assert done.stdout.count("valid: ") == len(logs) and "not installed" not in done.stdout
    # and between them the smoke runs log every message type the built-in packages declare
    logged = {topic.schema_name for log in logs for topic in summarize(log).topics}
    built_in = {t.cls.schema_name for t in installed_message_types() if t.origin.startswith("slamfront ")}
    assert built_in <= logged, f"no shipped recipe's smoke run logs {sorted(built_in - logged)}"
