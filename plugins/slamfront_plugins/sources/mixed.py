"""The ``mixed_scenes`` source: a run's own frames, then frames of other scenes as queries.

A localizer that answers for every frame is only half tested: it must also say "unknown
place" for a frame its map cannot hold. This source gives the frames of a ``main``
source unchanged, then frames of ``others`` (another dataset, another world seed) as
``query`` frames marked with their scene (``Frame.scene``), so nothing is trained on
them and evaluation knows they are out of the map. Any registered source can be main
or other.
"""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Iterator
from functools import cached_property
from typing import Any

from pydantic import Field, PrivateAttr, ValidationError, ValidationInfo, model_validator

from slamfront import Frame, PluginConfig, Source
from slamfront.core.loops import LoopGroundTruth
from slamfront.registry import PluginRegistry, registry_in_context

_SCENE_GAP_S = 60.0
"""Seconds between the last frame of one scene and the first of the next (timestamps must increase)."""


class SourceSpec(PluginConfig):
    """A source inside another: which plugin, with which parameters."""

    plugin: str = Field(description="source plugin name (see `slamfront plugins`)")
    params: dict[str, Any] = Field(default_factory=dict, description="that plugin's Config fields")


class OtherScene(SourceSpec):
    """Frames of another scene, and which of them to use."""

    scene: str = Field("", description="the scene's name in reports and logs (default: other<k>:<plugin>)")
    start: int = Field(0, ge=0, description="skip this source's first frames (e.g. a reference traversal)")
    step: int = Field(1, ge=1, description="then use every step-th frame")
    limit: int | None = Field(None, ge=1, description="at most this many frames")


def _resolve(
    spec: SourceSpec, registry: PluginRegistry, context: dict[str, Any], where: str
) -> tuple[type[Source], PluginConfig]:
    """The source class ``spec`` names (in the run's registry) and its params, validated as
    a recipe's would be; nothing is constructed."""
    try:
        cls = registry.get("source", spec.plugin).cls
    except Exception as exc:  # PluginError: unknown name, with the known ones
        raise ValueError(f"{where}.plugin: {exc}") from None
    try:
        config = cls.Config.model_validate(spec.params, context=context)
    except ValidationError as exc:
        problems = "; ".join(
            f"{where}.params.{'.'.join(str(p) for p in error['loc'])}: {error['msg']}" for error in exc.errors()
        )
        raise ValueError(problems) from None
    return cls, config  # type: ignore[return-value]


class MixedScenes(Source):
    """Frames of ``main``, then frames of each of ``others`` as out-of-map queries.

    Main frames keep their index, traversal and timestamps (so the main source's loop
    ground truth still applies). Each other scene's selected frames follow, renumbered,
    a minute after the previous scene, as ``query`` frames with ``scene`` set: a
    localizer never adds them to its map, and the localization report counts each
    answer it gives for one as a wrong one (its precision-recall curve and recall at
    100 % precision are over in-map and out-of-map frames together).
    """

    name = "mixed_scenes"

    class Config(PluginConfig):
        main: SourceSpec = Field(description="the run's own source (its frames build and query the map)")
        others: list[OtherScene] = Field(min_length=1, description="scenes whose frames are out of the map")
        _resolved: list[tuple[type[Source], PluginConfig]] = PrivateAttr(default_factory=list)

        @model_validator(mode="after")
        def _resolve_sources(self, info: ValidationInfo) -> MixedScenes.Config:
            # validated here, with the run's registry and data root, so a bad inner param is a recipe error
            registry = registry_in_context(info.context)
            context = dict(info.context or {})
            self._resolved = [_resolve(self.main, registry, context, "main")] + [
                _resolve(other, registry, context, f"others.{k}") for k, other in enumerate(self.others)
            ]
            return self

    config: Config

    def __init__(self, config: Config) -> None:
        super().__init__(config)
        self._sources = [cls(inner) for cls, inner in config._resolved]

    @cached_property
    def main(self) -> Source:
        return self._sources[0]

    def _selected(self, k: int) -> range:
        """Positions, in the k-th other source's frames, of the frames used."""
        spec, other = self.config.others[k], self._sources[k + 1]
        chosen = range(spec.start, len(other), spec.step)
        return chosen[: spec.limit] if spec.limit is not None else chosen

    def scene_name(self, k: int) -> str:
        spec = self.config.others[k]
        return spec.scene or f"other{k + 1}:{spec.plugin}"

    def __len__(self) -> int:
        return len(self.main) + sum(len(self._selected(k)) for k in range(len(self.config.others)))

    def frames(self) -> Iterator[Frame]:
        index, last = 0, None
        for frame in self.main.frames():
            yield frame
            index, last = frame.index + 1, frame.timestamp
        for k, other in enumerate(self._sources[1:]):
            chosen = self._selected(k)
            frames = itertools.islice(other.frames(), chosen.start, chosen.stop, chosen.step)
            first = None
            base = 0.0 if last is None else last + _SCENE_GAP_S
            for frame in frames:
                first = frame.timestamp if first is None else first
                timestamp = base + (frame.timestamp - first)
                yield dataclasses.replace(frame, index=index, timestamp=timestamp, traversal="query",
                                          scene=self.scene_name(k))
                index, last = index + 1, timestamp

    def loop_ground_truth(self) -> LoopGroundTruth | None:
        return self.main.loop_ground_truth()
