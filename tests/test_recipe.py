"""Recipes: parsing, overrides, validation against each plugin's Config."""

from __future__ import annotations

from pathlib import Path

import pytest

from slamfront.data import data_root
from slamfront.errors import PluginError, RecipeError
from slamfront.recipe import apply_overrides, build_pipeline, load_recipe, parse_recipe, recipes_dir
from tests.helpers import small_synthetic_recipe


def test_overrides_parse_values_as_yaml() -> None:
    raw = small_synthetic_recipe()
    out = apply_overrides(raw, ["loop_detector.params.threshold=0.35", "source.params.mode=stream", "eval.plots=true"])
    assert out["loop_detector"]["params"]["threshold"] == 0.35
    assert out["source"]["params"]["mode"] == "stream"
    assert out["eval"]["plots"] is True
    assert raw["eval"]["plots"] is False  # the input is not mutated


def test_override_errors_name_the_item() -> None:
    with pytest.raises(RecipeError, match="expected KEY=VALUE"):
        apply_overrides({}, ["novalue"])
    with pytest.raises(RecipeError, match="no 'localizer' stage"):
        apply_overrides({"name": "x"}, ["localizer.params.k=3"])
    with pytest.raises(RecipeError, match="name is not a mapping"):
        apply_overrides({"name": "x"}, ["name.sub=3"])


def test_invalid_param_names_stage_and_field(write_recipe) -> None:
    recipe = parse_recipe(
        apply_overrides(small_synthetic_recipe(), ["loop_detector.params.accept=2"]), "r.yaml"
    )
    with pytest.raises(RecipeError, match=r"r.yaml: loop_detector.params.accept: .*confidence in \[0, 1\] \(got 2\)"):
        build_pipeline(recipe, "r.yaml")


def test_unknown_param_is_an_error_not_ignored() -> None:
    recipe = parse_recipe(apply_overrides(small_synthetic_recipe(), ["descriptor.params.widht=3"]), "r.yaml")
    with pytest.raises(RecipeError, match="descriptor.params.widht: unknown parameter of the downsampled descriptor; did you mean 'width'"):
        build_pipeline(recipe, "r.yaml")


def test_unknown_plugin_suggests_close_names() -> None:
    recipe = parse_recipe(apply_overrides(small_synthetic_recipe(), ["loop_detector.plugin=nearest_neighbor"]), "r.yaml")
    with pytest.raises(PluginError, match="did you mean 'nearest_neighbour'"):
        build_pipeline(recipe, "r.yaml")


def test_missing_required_stage_is_reported() -> None:
    raw = small_synthetic_recipe()
    del raw["descriptor"]
    with pytest.raises(PluginError, match="needs a descriptor stage"):
        build_pipeline(parse_recipe(raw, "r.yaml"), "r.yaml")


def test_unknown_top_level_key(write_recipe) -> None:
    raw = small_synthetic_recipe()
    raw["loop_detectr"] = {"plugin": "x"}
    with pytest.raises(RecipeError, match="loop_detectr: unknown key; did you mean 'loop_detector'"):
        load_recipe(write_recipe(raw))


def test_name_defaults_to_file_stem(write_recipe) -> None:
    raw = small_synthetic_recipe()
    del raw["name"]
    recipe, _ = load_recipe(write_recipe(raw, "my_experiment.yaml"))
    assert recipe.name == "my_experiment"


def test_bad_yaml_names_file_and_line(tmp_path: Path) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text("name: x\nsource: [unclosed\n")
    with pytest.raises(RecipeError, match=r"bad.yaml:\d+: not valid YAML"):
        load_recipe(path)


def test_relative_data_paths_resolve_under_the_data_root(monkeypatch, tmp_path: Path) -> None:
    monkeypatch.setenv("SLAMFRONT_DATA", str(tmp_path))
    assert data_root() == tmp_path.resolve()
    raw = small_synthetic_recipe()
    raw["source"] = {"plugin": "image_folder", "params": {"folder": "images/loop10"}}
    pipeline = build_pipeline(parse_recipe(raw, "r.yaml"), "r.yaml")
    assert pipeline.source.config.folder == tmp_path.resolve() / "images/loop10"


def test_shipped_recipes_by_name() -> None:
    recipe, path = load_recipe("demo")
    assert path == recipes_dir() / "demo.yaml" and recipe.name == "demo"


def test_a_folder_named_like_a_shipped_recipe_does_not_hide_it(tmp_path, monkeypatch) -> None:
    """`slamfront run demo -o demo` leaves a folder `demo`; the next `slamfront run demo` still finds the recipe."""
    from slamfront.recipe import find_recipe

    monkeypatch.chdir(tmp_path)
    (tmp_path / "demo").mkdir()
    assert find_recipe("demo").name == "demo.yaml" and find_recipe("demo").is_file()
