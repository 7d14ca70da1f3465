"""Recipes: one YAML file per experiment, validated by pydantic before the first frame.

A recipe names a source, one plugin per stage it uses (``plugin:`` + ``params:``, the
params validated by that plugin's own ``Config``), and options for the log and the
evaluation. ``--set a.b=c`` overrides any field before validation (the value is parsed
as YAML, so ``--set loop_detector.params.threshold=0.3`` gives a float).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from slamfront.errors import PluginError, RecipeError
from slamfront.limits import check_limit
from slamfront.plugin import STAGE_KINDS, Kind, Plugin, PluginConfig, Source, Stage
from slamfront.registry import PluginRegistry, config_context
from slamfront.resources import shipped_dir
from slamfront.suggest import did_you_mean, model_keys_at
from slamfront.text import shorten
from slamfront.yamlfile import _bounded_yaml, load_yaml, read_yaml_mapping  # noqa: F401 (re-exported)

logger = logging.getLogger(__name__)

LogLevel = Literal["debug", "info", "warning", "error"]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class StageSpec(_Strict):
    """One stage of a recipe: which plugin, with which parameters."""

    plugin: str = Field(description="plugin name (see `slamfront plugins`)")
    params: dict[str, Any] = Field(default_factory=dict, description="the plugin's Config fields")


class LogOptions(_Strict):
    """What goes into ``run.mcap`` besides the stage outputs."""

    images: bool = Field(True, description="log input images as foxglove.CompressedImage")
    image_max_width: int = Field(320, ge=16, description="downscale logged images to this width")
    image_format: Literal["jpeg", "png"] = Field("jpeg", description="png is lossless")
    jpeg_quality: int = Field(80, ge=1, le=100)
    depth: bool = Field(False, description="log depth images (foxglove.RawImage)")
    depth_encoding: Literal["16UC1", "32FC1"] = Field(
        "16UC1", description="16UC1: millimetres (compact); 32FC1: float32 metres, exact (replayable)"
    )
    points: bool = Field(False, description="log each depth frame as a foxglove.PointCloud in the camera frame")
    points_stride: int = Field(4, ge=1, description="point clouds use every n-th pixel in each direction")
    scene: bool = Field(True, description="log the path and loop closures for Foxglove's 3-D panel (/scene/map)")
    scene_every: int = Field(20, ge=1, description="update /scene/map every this many frames")
    compression: Literal["zstd", "lz4", "none"] = Field("zstd", description="MCAP chunk compression")
    chunk_size: int = Field(1 << 20, ge=1024, description="MCAP chunk size in bytes")

    @field_validator("chunk_size")
    @classmethod
    def _readable_chunks(cls, value: int) -> int:
        check_limit("chunk_bytes", value, "the chunk size (readers refuse larger chunks)")
        return value
    sync_seconds: float | None = Field(
        5.0, gt=0, description="close the chunk and fsync this often, bounding what a power cut loses (null: never)"
    )
    level: LogLevel = Field(
        "info", description="lowest level of the plugins' logging records kept in /log (warnings also go to the terminal)"
    )


class EvalOptions(_Strict):
    """How the run is evaluated and reported."""

    plots: bool = Field(True, description="write PNG plots next to report.md")
    recall_at_k: list[Annotated[int, Field(ge=1)]] = Field(default_factory=lambda: [1, 5, 10])
    tolerances: list[Annotated[int, Field(ge=0)]] = Field(
        default_factory=list,
        description="also score loops at these tolerances (zeta), for sources that support it; "
        "metrics get the suffix _zeta<t>",
    )
    loop_scoring: Literal["frame", "place"] = Field(
        "frame", description="frame: a loop report is correct when its match frame is a true match; place: when any "
        "frame of the matched place is (detectors that merge frames into places list them)",
    )
    unsearched_frames: Literal["score", "exclude"] = Field(
        "score", description="score: a frame the detector answered without searching (repeating an earlier answer) "
        "counts like any other; exclude: it is left out of the precision-recall curve and the recall's denominator",
    )
    retrieval_max_k: int = Field(
        20, ge=0, description="descriptor retrieval: recall when a correct reference is among the psi "
        "nearest, psi = 1..this (Rodrigues 2019 figs 4.1/4.2); 0 turns it off",
    )


class Recipe(_Strict):
    """A whole experiment."""

    name: str = Field(description="run name; the default output folder is logs/<name>/")
    description: str = ""
    plugin_modules: list[str] = Field(
        default_factory=list, description="extra importable plugin modules to register"
    )
    source: StageSpec
    descriptor: StageSpec | None = None
    place_map: StageSpec | None = None
    loop_detector: StageSpec | None = None
    localizer: StageSpec | None = None
    registration: StageSpec | None = None
    backend: StageSpec | None = None
    log: LogOptions = Field(default_factory=LogOptions)
    eval: EvalOptions = Field(default_factory=EvalOptions)

    def stage_specs(self) -> dict[Kind, StageSpec]:
        """The source and the stages present, in run order."""
        specs = {"source": self.source}
        for kind in STAGE_KINDS:
            spec = getattr(self, kind)
            if spec is not None:
                specs[kind] = spec
        return specs  # type: ignore[return-value]

    def to_yaml(self) -> str:
        return yaml.safe_dump(self.model_dump(mode="json"), sort_keys=False)


def recipes_dir() -> Path:
    """The shipped recipes (installed package data; ``recipes/`` in the repository)."""
    return shipped_dir("recipes")


def find_named_file(name_or_path: str | Path, folder: Path, what: str, hint: str) -> Path:
    """A path as given; for a bare name, ``<name>.yaml`` in the current directory, else the
    shipped ``folder/<name>.yaml``. The user's own file always wins over a shipped one; a
    folder of that name (``slamfront run demo -o demo`` makes one) does not hide a recipe."""
    path = Path(name_or_path)
    bare = path.suffix == "" and path.name == str(name_or_path)
    if path.exists() and not (bare and path.is_dir()):
        return path
    if bare:
        for candidate in (path.with_name(f"{path.name}.yaml"), folder / f"{path.name}.yaml"):
            if candidate.is_file():
                return candidate
    if path.exists():
        return path  # a folder named as given, and no recipe of that name: the reader says so
    raise RecipeError(f"{name_or_path}: no such {what} file ({hint})")


def find_recipe(name_or_path: str | Path) -> Path:
    """A recipe file: a path as given, or the name of a shipped recipe (``demo``)."""
    return find_named_file(name_or_path, recipes_dir(), "recipe", "shipped recipes: `slamfront recipes`")


def read_recipe_dict(path: Path) -> dict[str, Any]:
    """Parse a recipe file to a dict, with the file named in any error."""
    return read_yaml_mapping(path, "recipe")


def parse_override(item: str, origin: str) -> tuple[str, Any]:
    """``KEY=VALUE`` as (key, value parsed as YAML; an empty value is ""); ``origin`` names
    where the item came from in the error."""
    key, sep, value_text = item.partition("=")
    if not sep or not key:
        raise RecipeError(f"{origin} {_shown(item)}: expected KEY=VALUE, e.g. loop_detector.params.threshold=0.3")
    try:
        return key, _bounded_yaml(value_text) if value_text.strip() else ""
    except ValueError as exc:
        reason = str(exc).split("YAML: ", 1)[-1].lstrip(": ")
        raise RecipeError(f"{origin} {_shown(item)}: value is not valid YAML: {reason}") from None


def apply_overrides(raw: dict[str, Any], overrides: Iterable[str], origin: str = "--set") -> dict[str, Any]:
    """Apply ``a.b.c=value`` overrides to a recipe dict (returns a new dict).

    The value is parsed as YAML. Missing intermediate mappings are created, so
    ``--set loop_detector.params.k=5`` works whether or not ``params`` was written.
    ``--set STAGE.plugin=X`` naming another plugin starts X from its own defaults: the
    old plugin's params are dropped (they rarely fit), and ``--set STAGE.params...``
    given with it apply to X whatever their order on the command line.
    """
    result = yaml.safe_load(yaml.safe_dump(raw))  # deep copy of plain data
    parsed = [(item, *parse_override(item, origin)) for item in overrides]
    # plugin switches first, so that the params set beside them are not dropped with the old ones
    parsed.sort(key=lambda entry: not _is_plugin_switch(entry[1]))
    for item, key, value in parsed:
        if _is_plugin_switch(key):
            stage = result.get(key.split(".")[0])
            if isinstance(stage, dict) and stage.get("plugin") != value:
                stage.pop("params", None)
        node: Any = result
        parts = key.split(".")
        for depth, part in enumerate(parts[:-1]):
            if isinstance(node, dict):
                if node.get(part) is None:
                    if depth == 0 and part in STAGE_KINDS and parts[1] != "plugin":
                        raise RecipeError(
                            f"{origin} {_shown(item)}: the recipe has no {part!r} stage; set {part}.plugin first"
                        )
                    node[part] = {}
                node = node[part]
            elif isinstance(node, list) and part.isdigit() and int(part) < len(node):
                node = node[int(part)]
            else:
                raise RecipeError(f"{origin} {_shown(item)}: {'.'.join(parts[: depth + 1])} is not a mapping")
        if not isinstance(node, dict):
            raise RecipeError(f"{origin} {_shown(item)}: {'.'.join(parts[:-1])} is not a mapping")
        node[parts[-1]] = value
    return result


def _shown(item: str) -> str:
    """An override as quoted in a message: one line, cut (a pasted document can be megabytes)."""
    return repr(shorten(item, 120))


def _is_plugin_switch(key: str) -> bool:
    kind, _, field = key.partition(".")
    return field == "plugin" and kind in ("source", *STAGE_KINDS)


def _format_validation(exc: ValidationError, prefix: str, model: type[BaseModel] | None = None, owner: str = "") -> str:
    """pydantic's first error as ``prefix.field.path: message (got value)``.

    An unknown key (pydantic's bare "Extra inputs are not permitted") names the closest
    keys ``model`` accepts at that place instead.

    :param model: the model that was validated, to suggest keys from.
    :param owner: what the keys belong to, for the message (``the nearest_neighbour loop_detector``).
    """
    err = exc.errors()[0]
    loc = ".".join(str(p) for p in (prefix, *err["loc"]) if p != "")
    more = f" [+{len(exc.errors()) - 1} more]" if len(exc.errors()) > 1 else ""
    # a dataclass inside a model (the back end's solver options) reports an unknown key as an unexpected argument
    if err["type"] in ("extra_forbidden", "unexpected_keyword_argument") and model is not None and err["loc"]:
        *path, key = err["loc"]
        known = model_keys_at(model, path)
        if known is not None:
            what = f"parameter of {owner}" if owner else "key"
            return f"{loc}: unknown {what}; {did_you_mean(str(key), known, 'keys')}{more}"
    got = err.get("input")
    shown = "" if err["type"] == "missing" or isinstance(got, dict) else f" (got {shorten(repr(got), 80)})"
    message = err["msg"]
    if err["type"] == "value_error" and "error" in err.get("ctx", {}):
        message = str(err["ctx"]["error"])  # a validator's own words, without pydantic's "Value error, "
    return f"{loc}: {message}{shown}{more}"


def parse_recipe(raw: Mapping[str, Any], origin: str) -> Recipe:
    """Validate a recipe dict's own structure (not yet the plugins' params)."""
    try:
        return Recipe.model_validate(raw)
    except ValidationError as exc:
        raise RecipeError(f"{origin}: {_format_validation(exc, '', Recipe)}") from exc


def load_recipe(path_or_name: str | Path, overrides: Iterable[str] = ()) -> tuple[Recipe, Path]:
    """Read, override and validate a recipe file. Returns the recipe and its path."""
    path = find_recipe(path_or_name)
    raw = apply_overrides(read_recipe_dict(path), overrides)
    return parse_recipe(raw, str(path)), path


def override_keys(recipe: Recipe, registry: PluginRegistry) -> list[str]:
    """Every key ``--set`` takes for ``recipe``: its own fields, each stage's ``plugin``, the
    params of the plugins it names, and the log and eval options (for shell completion)."""
    keys = [name for name, field in Recipe.model_fields.items() if field.annotation in (str, list[str])]
    keys += [f"{kind}.plugin" for kind in ("source", *STAGE_KINDS)]
    for module in recipe.plugin_modules:
        registry.register_module(module)
    for kind, spec in recipe.stage_specs().items():
        if spec.plugin in registry.names(kind):
            keys += [f"{kind}.params.{name}" for name in registry.get(kind, spec.plugin).cls.Config.model_fields]
    keys += [f"log.{name}" for name in LogOptions.model_fields]
    keys += [f"eval.{name}" for name in EvalOptions.model_fields]
    return keys


@dataclass
class Pipeline:
    """A recipe's plugins, constructed and checked against each other."""

    recipe: Recipe
    plugins: dict[Kind, Plugin]
    registry: PluginRegistry

    @property
    def source(self) -> Source:
        return self.plugins["source"]  # type: ignore[return-value]

    @property
    def stages(self) -> list[Stage]:
        """The processing stages, in run order."""
        return [self.plugins[k] for k in STAGE_KINDS if k in self.plugins]  # type: ignore[misc]


def validate_stage_params(
    recipe: Recipe, origin: str, registry: PluginRegistry, data: Path | None = None
) -> dict[Kind, tuple[type[Plugin], PluginConfig]]:
    """Find every stage's plugin class and validate its params, constructing nothing.

    Cheap enough to check many recipes up front (a campaign does, before its first run).

    :raises RecipeError: a param is invalid (names ``<stage>.params.<field>``).
    :raises PluginError: a plugin is unknown or a plugin module cannot be imported.
    """
    for module in recipe.plugin_modules:
        registry.register_module(module)
    context = config_context(registry, data)
    configs: dict[Kind, tuple[type[Plugin], PluginConfig]] = {}
    for kind, spec in recipe.stage_specs().items():
        try:
            info = registry.get(kind, spec.plugin)
        except PluginError as exc:
            raise PluginError(f"{origin}: {kind}.plugin: {exc}") from exc
        try:
            config = info.cls.Config.model_validate(spec.params, context=context)
        except ValidationError as exc:
            owner = f"the {spec.plugin} {kind}"
            message = _format_validation(exc, f"{kind}.params", info.cls.Config, owner)
            raise RecipeError(f"{origin}: {message}") from exc
        configs[kind] = (info.cls, config)
    return configs


def build_pipeline(
    recipe: Recipe,
    origin: str,
    registry: PluginRegistry | None = None,
    data: Path | None = None,
    substitutes: Mapping[Kind, Callable[[type[Plugin], PluginConfig], Plugin]] | None = None,
) -> Pipeline:
    """Construct every plugin of ``recipe`` from its validated params and check them.

    :param origin: the recipe's file name, for messages.
    :param data: data root for relative paths (default :func:`slamfront.data.data_root`).
    :param substitutes: for some kinds, what to construct instead of the recipe's plugin,
        called with its class and validated config (a replay substitutes a source that
        reads the log and stages that give back what the log recorded).
    :raises RecipeError: a param is invalid (names ``<stage>.params.<field>``).
    :raises PluginError: a plugin is unknown or incompatible with another.
    """
    registry = registry or PluginRegistry()
    configs = validate_stage_params(recipe, origin, registry, data)
    for problem in registry.broken:  # every plugin this recipe names was found: the broken ones are not its
        logger.warning("%s (%s does not use it)", problem, origin)
    substitutes = substitutes or {}
    plugins: dict[Kind, Plugin] = {
        kind: substitutes[kind](cls, config) if kind in substitutes else cls(config)
        for kind, (cls, config) in configs.items()
    }
    for kind, plugin in plugins.items():
        missing = [need for need in getattr(plugin, "requires", ()) if need not in plugins]
        if missing:
            raise PluginError(
                f"{origin}: {kind} plugin {plugin.name!r} needs a {' and a '.join(missing)} stage"
            )
        try:
            plugin.check(plugins)
        except PluginError as exc:
            raise PluginError(f"{origin}: {kind}: {exc}") from exc
    return Pipeline(recipe=recipe, plugins=plugins, registry=registry)


