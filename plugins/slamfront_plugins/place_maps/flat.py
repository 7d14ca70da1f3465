"""The ``flat`` place map: every frame is a place of its own, searched by exact brute-force kNN.

No grouping and no threshold to calibrate: the simplest map a sequence detector can run
on, beside ``hierarchical`` (Rodrigues 2019 §3.1), whose places of similar consecutive
frames shrink the search. With it a hierarchical detector searches level 1 over every
map frame instead of one representative per place, and runs an iteration every rho
frames instead of every rho places; what it compares after level 1 is unchanged.

Like ``hierarchical``, the places of the traversals in ``auto_commit`` (the reference, in
the paired protocol) join the map as they arrive; a detector commits the others.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import ClassVar

import numpy as np
from pydantic import Field

from slamfront import PlaceMap, Plugin, PluginConfig, PluginError, StageInputs
from slamfront.core.buffers import GrowingRows
from slamfront.core.vptree import brute_force_knn
from slamfront.frame import Traversal
from slamfront.messages import Message, PlaceAssignment
from slamfront.plugin import global_features, require_global_descriptor


class FlatPlaceMap(PlaceMap):
    """One place per frame, exact brute-force nearest-neighbour search over the map's frames.

    Outputs one ``PlaceAssignment`` per frame (always a new place, its id the frame index).
    A :class:`slamfront.plugin.SearchablePlaceMap`, so the hierarchical detectors run on it.
    """

    name: ClassVar[str] = "flat"
    requires = ("descriptor",)

    class Config(PluginConfig):
        max_distance: float = Field(
            2.0, gt=0, description="distance at which the similarity 1 - D / max_distance reaches 0 (2 = the largest "
            "L1 distance of unit-L1 vectors)"
        )
        auto_commit: list[Traversal] = Field(
            default_factory=lambda: ["reference"],
            description="traversals whose frames join the map when they arrive (the rest wait for commit())",
        )

    def __init__(self, config: Config | None = None) -> None:
        super().__init__(config)
        self._vectors: GrowingRows | None = None  # per frame
        self._map_vectors: GrowingRows | None = None  # per map position, contiguous for the search
        self._informative = GrowingRows(1, dtype=bool)
        self._map_frames = GrowingRows(1, dtype=np.int64)  # frame index at each map position
        self._position: dict[int, int] = {}  # frame index -> map position
        self._metric = "l1"
        self._distance_calls = 0

    def check(self, stages: Mapping[str, Plugin]) -> None:
        require_global_descriptor(stages)

    def process(self, inputs: StageInputs) -> Sequence[Message]:
        features = global_features(inputs)
        index = inputs.frame.index
        n = 0 if self._vectors is None else len(self._vectors)
        if index != n:
            raise PluginError(f"frames must arrive in order: expected {n}, got {index}")
        if self._vectors is None:
            self._vectors = GrowingRows(len(features.vector), dtype=features.vector.dtype)
            self._map_vectors = GrowingRows(len(features.vector), dtype=features.vector.dtype)
            self._metric = features.metric
        self._vectors.append(features.vector)
        self._informative.append(np.array([np.any(features.vector)]))
        if inputs.frame.traversal in self.config.auto_commit:
            self.commit(index)
        return [PlaceAssignment(frame=index, place=index, new_place=True, n_places=index + 1)]

    # --- SearchablePlaceMap ---------------------------------------------------------------

    def place_of(self, frame: int) -> int:
        return frame

    def vectors(self, frames: Sequence[int] | np.ndarray) -> np.ndarray:
        return self._vectors.view[np.asarray(frames, dtype=np.int64)]  # type: ignore[union-attr]

    def frame_vectors(self) -> np.ndarray:
        """As the hierarchical place map's: every frame's descriptor, row = frame index (a view)."""
        return np.empty((0, 0), dtype=np.float32) if self._vectors is None else self._vectors.view

    def informative(self, frames: Sequence[int] | np.ndarray) -> np.ndarray:
        return self._informative.view[np.asarray(frames, dtype=np.int64), 0]

    def representatives(self, places: Sequence[int] | np.ndarray) -> np.ndarray:
        return self.vectors(places)

    def commit(self, place: int) -> int:
        if place in self._position:
            return self._position[place]
        self._position[place] = len(self._map_frames)
        self._map_frames.append(np.array([place]))
        self._map_vectors.append(self._vectors.view[place])  # type: ignore[union-attr]
        return self._position[place]

    def place_offsets(self) -> np.ndarray:
        return np.arange(len(self._map_frames) + 1, dtype=np.int64)

    def map_frames_at(self, positions: np.ndarray) -> np.ndarray:
        return self._map_frames.view[np.asarray(positions, dtype=np.int64), 0]

    def map_representatives(self, positions: Sequence[int] | np.ndarray) -> np.ndarray:
        return self._map_vectors.view[np.asarray(positions, dtype=np.int64)]  # type: ignore[union-attr]

    def nearest(self, vector: np.ndarray, k: int, lo: int = 0, hi: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        n = 0 if self._map_vectors is None else len(self._map_vectors)
        if n == 0:
            return np.empty(0, dtype=np.int64), np.empty(0, dtype=np.float32)
        last = n - 1 if hi is None else min(hi, n - 1)
        self._distance_calls += max(0, last - lo + 1)
        return brute_force_knn(vector, self._map_vectors.view, k, self._metric, lo, hi)  # type: ignore[union-attr,arg-type]

    @property
    def search_distances(self) -> int:
        return self._distance_calls

    @property
    def metric(self) -> str:
        return self._metric

    def similarity(self, distance: float | np.ndarray) -> float | np.ndarray:
        """``1 - D / max_distance``, clipped to [0, 1]."""
        return np.clip(1.0 - np.asarray(distance) / self.config.max_distance, 0.0, 1.0)

    def statistics(self) -> dict[str, float | int]:
        n = 0 if self._vectors is None else len(self._vectors)
        return {"n_places": n, "n_vertices": len(self._map_frames)}
