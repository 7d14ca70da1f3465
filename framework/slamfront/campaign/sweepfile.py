"""Sweep files: one YAML file describing a campaign of runs, validated by pydantic.

A sweep names its base recipes (the methods), override sets applied to all of them
(``set``), named variants (datasets or conditions), a grid (every combination) and/or a
list of cases, repetitions, and the metrics to collect. Override paths are ``--set``
paths (``loop_detector.params.threshold``); values are YAML values.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from slamfront.errors import RecipeError
from slamfront.limits import over_limit
from slamfront.recipe import _format_validation, find_named_file, find_recipe, read_yaml_mapping
from slamfront.resources import shipped_dir

Overrides = dict[str, Any]
"""``{"a.b.c": value}``: what ``--set a.b.c=value`` would do."""


def _check_override_paths(overrides: Overrides) -> Overrides:
    for path in overrides:
        if not path or "=" in path or any(part == "" for part in path.split(".")):
            raise ValueError(f"{path!r} is not an override path like loop_detector.params.threshold")
    return overrides


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class MethodSpec(_Strict):
    """One base recipe of the campaign (a method, or a method on one experiment)."""

    recipe: str = Field(description="recipe file (relative to the sweep file) or shipped recipe name")
    set: Overrides = Field(default_factory=dict, description="overrides for this recipe only")
    labels: dict[str, str] = Field(
        default_factory=dict,
        description="extra result columns, e.g. {method: hsl, experiment: exp2}; 'method' renames the method",
    )

    _paths = field_validator("set")(_check_override_paths)


class Sweep(_Strict):
    """A whole campaign: the runs are methods x variants x cases x grid x repetitions."""

    name: str = Field(description="campaign name; the default output folder is logs/sweeps/<name>/")
    description: str = ""
    recipe: str | None = Field(None, description="the one base recipe (or use `recipes`)")
    recipes: dict[str, MethodSpec] = Field(
        default_factory=dict, description="several base recipes by method label (a cross-method study)"
    )
    set: Overrides = Field(default_factory=dict, description="overrides applied to every run")
    variants: dict[str, Overrides] = Field(
        default_factory=dict, description="named override sets, e.g. datasets or conditions (one axis)"
    )
    grid: dict[str, list[Any]] = Field(
        default_factory=dict, description="override path -> values; every combination is run"
    )
    cases: list[Overrides] = Field(
        default_factory=list, description="explicit override sets (each combined with the grid)"
    )
    repetitions: int = Field(1, ge=1, description="runs per combination")
    repetition_seed: str | None = Field(
        None, description="override path set to the repetition number (0, 1, ...), e.g. source.params.seed"
    )
    metrics: list[str] = Field(
        default_factory=lambda: ["recall_at_100p", "auc_pr"],
        min_length=1,
        description="metrics.json keys to collect (dotted for nested ones: timing.descriptor.median_ms)",
    )
    max_frames: int | None = Field(None, ge=1, description="stop every run after this many frames")

    _set_paths = field_validator("set")(_check_override_paths)

    @field_validator("variants")
    @classmethod
    def _variant_paths(cls, variants: dict[str, Overrides]) -> dict[str, Overrides]:
        for overrides in variants.values():
            _check_override_paths(overrides)
        return variants

    @field_validator("cases")
    @classmethod
    def _case_paths(cls, cases: list[Overrides]) -> list[Overrides]:
        for overrides in cases:
            _check_override_paths(overrides)
        return cases

    @field_validator("grid")
    @classmethod
    def _grid_values(cls, grid: dict[str, list[Any]]) -> dict[str, list[Any]]:
        _check_override_paths(grid)
        for path, values in grid.items():
            if not values:
                raise ValueError(f"{path}: a grid axis needs at least one value")
            if len({yaml.safe_dump(v) for v in values}) != len(values):
                raise ValueError(f"{path}: repeated values {values}")
        return grid

    @model_validator(mode="after")
    def _one_way_to_name_recipes(self) -> Sweep:
        if (self.recipe is None) == (not self.recipes):
            raise ValueError("give either `recipe` (one base recipe) or `recipes` (several), not both or neither")
        in_cases = {path for case in self.cases for path in case}
        both = sorted(in_cases & self.grid.keys())
        if both:
            raise ValueError(f"{both[0]} is both a grid axis and set by a case; keep it in one place")
        return self

    def methods(self) -> dict[str, tuple[str, MethodSpec]]:
        """``{method label: (field naming it, spec)}``; the one ``recipe`` is labelled by its file stem."""
        if self.recipe is not None:
            return {Path(self.recipe).stem: ("recipe", MethodSpec(recipe=self.recipe))}
        return {label: (f"recipes.{label}.recipe", spec) for label, spec in self.recipes.items()}

    def run_count(self) -> tuple[int, str]:
        """How many runs the sweep expands to, and the field that multiplies it most."""
        factors = {
            "recipes": len(self.recipes) or 1,
            "variants": len(self.variants) or 1,
            "cases": len(self.cases) or 1,
            "grid": math.prod(len(values) for values in self.grid.values()),
            "repetitions": self.repetitions,
        }
        return math.prod(factors.values()), max(factors, key=lambda name: factors[name])

    def parameter_paths(self) -> list[str]:
        """The override paths that vary between runs (result columns), in a stable order."""
        paths: list[str] = []
        for case in self.cases:
            paths += [p for p in case if p not in paths]
        return paths + [p for p in self.grid if p not in paths]


def sweeps_dir() -> Path:
    """The shipped sweeps (installed package data; ``sweeps/`` in the repository)."""
    return shipped_dir("sweeps")


def find_sweep(name_or_path: str | Path) -> Path:
    """A sweep file: a path as given, or the name of a shipped sweep."""
    return find_named_file(name_or_path, sweeps_dir(), "sweep", "shipped sweeps: `slamfront sweeps`")


def read_sweep(path: Path) -> Sweep:
    """Parse and validate a sweep file (its structure; recipes are checked by :func:`resolve_recipe`)."""
    raw = read_yaml_mapping(path, "sweep")
    try:
        sweep = Sweep.model_validate(raw)
    except ValidationError as exc:
        raise RecipeError(f"{path}: {_format_validation(exc, '', Sweep)}") from exc
    count, field = sweep.run_count()
    problem = over_limit("sweep_runs", count, "the number of runs (recipes x variants x cases x grid x repetitions)")
    if problem:  # checked before a single run is expanded
        raise RecipeError(f"{path}: {field}: {problem}")
    return sweep


def resolve_recipe(sweep_path: Path, field: str, recipe: str) -> Path:
    """A method's recipe file: beside the sweep file (``.yaml`` may be left out), else as
    given, else a shipped recipe.

    :param field: where the sweep names it (``recipe`` or ``recipes.<label>.recipe``), for messages.
    :raises RecipeError: naming the sweep file, the field and the recipe that is missing.
    """
    beside = sweep_path.parent / recipe
    for candidate in (beside, beside.with_name(beside.name + ".yaml")) if beside.suffix == "" else (beside,):
        if candidate.is_file():
            return candidate
    try:
        return find_recipe(recipe)
    except RecipeError:
        raise RecipeError(
            f"{sweep_path}: {field}: no such recipe {recipe!r} "
            "(looked beside the sweep file, in the working directory and in the shipped recipes)"
        ) from None
