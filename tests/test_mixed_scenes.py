"""The mixed_scenes source: a run's own frames, then other scenes' frames as out-of-map queries."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from slamfront.errors import RecipeError
from slamfront.recipe import build_pipeline, parse_recipe


def _source(params: dict):
    recipe = parse_recipe({"name": "mixed", "source": {"plugin": "mixed_scenes", "params": params}}, "test")
    return build_pipeline(recipe, "test").source


def test_other_scenes_follow_as_queries_with_their_scene(shared_data: Path) -> None:
    main = {"plugin": "synthetic", "params": {"mode": "paired", "frames_per_traversal": 4, "route_length_m": 40,
                                              "image_width": 32, "image_height": 24}}
    source = _source({"main": main, "others": [
        {"plugin": "image_folder", "params": {"folder": "images/loop10"}, "scene": "loop10", "start": 2, "step": 3},
        {"plugin": "synthetic", "params": {**main["params"], "seed": 5}, "start": 4, "limit": 2},
    ]})
    frames = list(source.frames())
    assert len(frames) == len(source) == 8 + 3 + 2
    assert [f.index for f in frames] == list(range(13))
    assert [f.traversal for f in frames] == ["reference"] * 4 + ["query"] * 9
    assert [f.scene for f in frames] == [""] * 8 + ["loop10"] * 3 + ["other2:synthetic"] * 2
    assert [f.name for f in frames[8:11]] == ["3.png", "6.png", "9.png"]  # loop10 frames 2, 5, 8
    assert np.all(np.diff([f.timestamp for f in frames]) > 0)
    assert frames[8].timestamp >= frames[7].timestamp + 60
    # the main source's loop ground truth still applies (its frames keep their indices)
    assert source.loop_ground_truth().queries.tolist() == [4, 5, 6, 7]


def test_a_bad_inner_source_is_a_recipe_error() -> None:
    with pytest.raises(RecipeError, match=r"source.params: .*main.params.seed: Input should be a valid integer"):
        _source({"main": {"plugin": "synthetic", "params": {"seed": "x"}}, "others": [{"plugin": "synthetic"}]})
    with pytest.raises(RecipeError, match=r"others.0.plugin: .*nope"):
        _source({"main": {"plugin": "synthetic"}, "others": [{"plugin": "nope"}]})
    with pytest.raises(RecipeError, match="others"):
        _source({"main": {"plugin": "synthetic"}, "others": []})
