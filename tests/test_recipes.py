"""Every shipped recipe validates, runs on its first few frames, and writes a log whose
every topic has a Foxglove or registered slamfront schema and every message decodes."""

from __future__ import annotations

from pathlib import Path

import pytest

from slamfront.mcaplog.reader import summarize
from slamfront.mcaplog.validate import validate_log
from slamfront.recipe import Recipe, build_pipeline, load_recipe, recipes_dir
from slamfront.runtime import run_pipeline
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


@pytest.mark.parametrize("path", RECIPES, ids=[p.stem for p in RECIPES])
def test_recipe_validates_and_smoke_runs(path: Path, tmp_path: Path, shared_data: Path) -> None:
    recipe, _ = load_recipe(path)
    assert recipe.description, f"{path.name} needs a description (shown by `slamfront recipes`)"
    pipeline = build_pipeline(recipe, str(path), data=data_root_for(recipe, tmp_path, shared_data))
    result = run_pipeline(pipeline, str(path), tmp_path, progress=False, max_frames=12)
    assert summarize(result.log_path).complete
    validation = validate_log(result.log_path)
    assert validation.valid, validation.problems
    for kind in pipeline.plugins:
        if kind != "source":
            assert kind in result.metrics["timing"]
