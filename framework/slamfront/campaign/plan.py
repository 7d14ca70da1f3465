"""Expanding a sweep into runs: each a fully resolved, validated recipe with a stable key.

Order and precedence: for every method, variant, case, grid point and repetition (in
that nesting), the overrides are applied as ``--set`` would, in the order sweep ``set``,
method ``set``, variant, case, grid, repetition seed (later wins). Every run's recipe
and plugin params are validated here, before anything runs; data paths stay as written
and are resolved where the run executes.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from slamfront.campaign.sweepfile import Overrides, Sweep, resolve_recipe
from slamfront.errors import RecipeError
from slamfront.recipe import apply_overrides, parse_recipe, read_recipe_dict, validate_stage_params
from slamfront.registry import PluginRegistry


@dataclass(frozen=True)
class PlannedRun:
    """One run of a campaign, ready to execute anywhere."""

    index: int
    key: str
    """sha256 of the resolved recipe, ``max_frames`` and repetition: the resume key."""
    name: str
    """Folder under ``runs/``: readable factors plus the key's first characters."""
    method: str
    labels: dict[str, str]
    """``variant`` and the method's extra labels (result columns)."""
    params: dict[str, Any]
    """The varying override values (cases and grid) by path."""
    repetition: int
    recipe: dict[str, Any]
    """The resolved recipe as plain data (``Recipe.model_dump(mode="json")``)."""
    origin: str
    """The base recipe file."""
    overrides: tuple[str, ...]
    max_frames: int | None

    def describe(self) -> str:
        """``hsl variant=dusk threshold=0.3 rep=1``: the run in words."""
        parts = [self.method, *(f"{k}={v}" for k, v in self.labels.items())]
        parts += [f"{short_name(p)}={format_value(v)}" for p, v in self.params.items()]
        return " ".join([*parts, f"rep={self.repetition}"] if self.repetition else parts)


def format_value(value: Any) -> str:
    """A value as flow YAML, so ``yaml.safe_load`` gives it back (``1e-9`` stays a float)."""
    text = yaml.safe_dump(value, default_flow_style=True, width=1 << 30)
    return text.removesuffix("\n...\n").strip()


def override_items(overrides: Overrides) -> list[str]:
    """``{"a.b": 0.3}`` as ``["a.b=0.3"]``."""
    return [f"{path}={format_value(value)}" for path, value in overrides.items()]


def short_name(path: str) -> str:
    """The last part of an override path: ``loop_detector.params.nu`` -> ``nu``."""
    return path.rsplit(".", 1)[-1]


def run_key(recipe: dict[str, Any], max_frames: int | None, repetition: int) -> str:
    canonical = json.dumps(
        {"recipe": recipe, "max_frames": max_frames, "repetition": repetition},
        sort_keys=True, separators=(",", ":"), ensure_ascii=True,
    )
    return hashlib.sha256(canonical.encode()).hexdigest()


def _folder_name(method: str, labels: dict[str, str], params: dict[str, Any], repetition: int, key: str) -> str:
    parts = [method, *labels.values(), *(f"{short_name(p)}={format_value(v)}" for p, v in params.items())]
    if repetition:
        parts.append(f"r{repetition}")
    slug = re.sub(r"[^A-Za-z0-9_.=+-]+", "-", "_".join(parts)).strip("-_")[:80]
    return f"{slug}_{key[:10]}"


def plan_runs(
    sweep: Sweep, sweep_path: Path, registry: PluginRegistry | None = None, max_frames: int | None = None
) -> list[PlannedRun]:
    """Every run of ``sweep``, each recipe validated with its plugins' params.

    :param max_frames: overrides the sweep's ``max_frames`` (a quick smoke campaign).
    :raises RecipeError: naming the sweep file, the run and the field at fault.
    :raises PluginError: an unknown plugin, naming the sweep file and the run.
    """
    registry = registry or PluginRegistry()
    frames = max_frames if max_frames is not None else sweep.max_frames
    variants: list[tuple[str | None, Overrides]] = list(sweep.variants.items()) or [(None, {})]
    grid_paths = list(sweep.grid)
    points = list(itertools.product(*sweep.grid.values()))
    cases = sweep.cases or [{}]
    runs: list[PlannedRun] = []
    seen: dict[str, PlannedRun] = {}
    for label, (field, spec) in sweep.methods().items():
        path = resolve_recipe(sweep_path, field, spec.recipe)
        base = read_recipe_dict(path)
        labels = dict(spec.labels)
        method = labels.pop("method", label)
        for (variant, variant_set), case, point in itertools.product(variants, cases, points):
            run_labels = ({"variant": variant} if variant is not None else {}) | labels
            params = {**case, **dict(zip(grid_paths, point))}
            for repetition in range(sweep.repetitions):
                overrides = [
                    *override_items(sweep.set), *override_items(spec.set), *override_items(variant_set),
                    *override_items(params),
                ]
                if sweep.repetition_seed is not None:
                    overrides.append(f"{sweep.repetition_seed}={repetition}")
                run = _resolve(sweep_path, len(runs), method, run_labels, params, repetition, path, base,
                               overrides, frames, registry)
                if run.key in seen:
                    raise RecipeError(
                        f"{sweep_path}: runs {seen[run.key].describe()!r} and {run.describe()!r} "
                        "resolve to the same recipe; remove one (or use repetitions)"
                    )
                seen[run.key] = run
                runs.append(run)
    return runs


def _resolve(
    sweep_path: Path, index: int, method: str, labels: dict[str, str], params: dict[str, Any], repetition: int,
    recipe_path: Path, base: dict[str, Any], overrides: list[str], max_frames: int | None, registry: PluginRegistry,
) -> PlannedRun:
    provisional = PlannedRun(index, "", "", method, labels, params, repetition, {}, str(recipe_path), (), max_frames)
    where = f"{sweep_path}: run {provisional.describe()!r}"
    raw = apply_overrides(base, overrides, origin=where)
    recipe = parse_recipe(raw, f"{where} ({recipe_path})")
    validate_stage_params(recipe, f"{where} ({recipe_path})", registry)
    resolved = recipe.model_dump(mode="json")
    key = run_key(resolved, max_frames, repetition)
    return PlannedRun(
        index=index, key=key, name=_folder_name(method, labels, params, repetition, key), method=method,
        labels=labels, params=params, repetition=repetition, recipe=resolved, origin=str(recipe_path),
        overrides=tuple(overrides), max_frames=max_frames,
    )
