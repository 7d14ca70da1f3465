"""The ``hierarchical`` place map: places of similar consecutive frames, a topological map
over them, and exact nearest-neighbour search of place representatives (Rodrigues 2019 §3.1).

Places (§3.1.2): a frame joins the last place ``P_l`` when ``S(R(P_l), g_t) >= nu``,
where ``R(P)`` is the place's first descriptor (its representative) and
``S = 1 - D / max_distance`` a similarity in [0, 1] from the L1 distance ``D``;
otherwise it starts place ``P_{l+1}``. A place never spans two traversals.

nu (Rodrigues 2019 leaves it open) is chosen from the data by default
(``similarity_threshold: auto``): the value whose places hold on average
``frames_per_place`` frames (2.26, the mean of Rodrigues 2019's own maps, Table 4.4) on
the frames it has seen, never on query ground truth. Paired runs choose it from the
whole reference traversal: reference frames are held without a place until the first
query frame arrives (or the run ends), then placed with the chosen nu. Runs without a
reference (one stream) hold their first ``calibration_frames`` frames and choose nu from
them; it is then kept for the rest of the run. The choice is a pure function of the
held descriptors, so a replay reproduces it bit for bit; it is logged as a
``PlaceThreshold`` message and in the run's metrics (``similarity_threshold``).

The map M = (V, E) (§3.1.3): every place that joins the map becomes a vertex, in the
order it joins; an edge links each vertex to the previous one of the same traversal
(the route), and :meth:`link` adds a loop-closure edge between two vertices. Places of
the traversals in ``auto_commit`` (the reference, in the paired protocol of §4.4) join
the map as they are created; other places join when a detector calls :meth:`commit`
(after it processed them, Alg. 1 line 14). The map's places are searched by their
representatives with an incremental VP-tree (exact kNN under L1), and the map keeps the
frames of its places in map order, so a detector can expand place sequences to frame
sequences (level 3).

Map positions (0, 1, 2, ... in joining order) are how detectors address map places;
place ids count every place ever created, map or not. Detectors read and grow the map
only through :class:`slamfront.plugin.SearchablePlaceMap`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import ClassVar, Literal

import numpy as np
from pydantic import Field, model_validator

from slamfront import PlaceMap, Plugin, PluginConfig, PluginError, StageInputs
from slamfront.core.buffers import GrowingRows
from slamfront.core.distances import to_one
from slamfront.core.kernels import compiled
from slamfront.core.vptree import VPTREE_MIN_PLACES, VPTree, brute_force_knn, vptree_pays
from slamfront.frame import Traversal
from slamfront.messages import Message, PlaceAssignment
from slamfront.plugin import global_features, require_global_descriptor


def place_sizes(vectors: np.ndarray, threshold: float, max_distance: float = 2.0, metric: str = "l1") -> np.ndarray:
    """Frames per place when ``vectors`` (one traversal, in order) are grouped with nu = ``threshold``.

    The same rule as :class:`HierarchicalPlaceMap` (a frame joins the last place while
    ``1 - D(R(P_l), g_t) / max_distance >= nu``), without building a map: used to choose
    nu from a reference traversal alone. float32 L1 (RST-SHelo) runs as one compiled loop
    whose distances have the bits of :func:`slamfront.core.distances.to_one`; other
    metrics and dtypes run :func:`place_sizes_reference`.
    """
    if metric == "l1" and vectors.dtype == np.float32 and len(vectors):
        new_place = np.empty(len(vectors), dtype=np.bool_)
        compiled().greedy_places_l1(np.ascontiguousarray(vectors), float(threshold), float(max_distance), new_place)
        return np.diff(np.append(np.flatnonzero(new_place), len(vectors))).astype(np.int64)
    return place_sizes_reference(vectors, threshold, max_distance, metric)


def place_sizes_reference(
    vectors: np.ndarray, threshold: float, max_distance: float = 2.0, metric: str = "l1"
) -> np.ndarray:
    """:func:`place_sizes` one distance call per frame (any metric; the compiled loop's oracle)."""
    sizes: list[int] = []
    representative: np.ndarray | None = None
    for vector in vectors:
        if representative is not None:
            distance = float(to_one(vector, representative[None, :], metric)[0])  # type: ignore[arg-type]
            if 1.0 - distance / max_distance >= threshold:
                sizes[-1] += 1
                continue
        representative = vector
        sizes.append(1)
    return np.asarray(sizes, dtype=np.int64)


THESIS_FRAMES_PER_PLACE = (200 / 112 + 646 / 236) / 2
"""Mean frames per place of Rodrigues 2019's maps (Table 4.4: GPW 200 frames in 112 places,
UofA 646 in 236): 2.26, the default target of the automatic nu."""


def choose_similarity_threshold(
    vectors: np.ndarray, frames_per_place: float, max_distance: float = 2.0, metric: str = "l1", step: float = 0.001
) -> float:
    """The nu on a grid of ``step`` whose places average closest to ``frames_per_place`` frames.

    Places shrink as nu grows, so a bisection over the grid finds the crossing; its two
    neighbours are compared directly (the lower nu on a tie). Deterministic: the same
    vectors always give the same nu.
    """
    grid = np.round(np.arange(0.0, 1.0 + step / 2, step), 6)

    def mean_size(index: int) -> float:
        return len(vectors) / len(place_sizes(vectors, float(grid[index]), max_distance, metric))

    lo, hi = 0, len(grid) - 1
    while hi - lo > 1:  # invariant: mean_size(lo) >= target > mean_size(hi), when it holds at the ends
        middle = (lo + hi) // 2
        if mean_size(middle) >= frames_per_place:
            lo = middle
        else:
            hi = middle
    best = min((lo, hi), key=lambda i: abs(mean_size(i) - frames_per_place))
    return float(grid[best])


@dataclass(frozen=True, eq=False)
class PlaceThreshold(Message):
    """The place map's nu: chosen from the data (``auto``) or as given, and the places it made."""

    schema_name: ClassVar[str] = "slamfront.PlaceThreshold"
    frame: int
    """The first frame placed with it."""
    threshold: float
    auto: bool
    calibration_frames: int
    """Frames nu was chosen from (0 when given)."""
    target_frames_per_place: float
    frames_per_place: float
    """Mean frames per place on the calibration frames (NaN when given)."""


@dataclass
class Place:
    """A run of consecutive similar frames of one traversal."""

    id: int
    traversal: str
    frames: list[int] = field(default_factory=list)
    """Frame indices, in order; ``frames[0]`` gives the representative."""
    map_position: int = -1
    """Position in the map, -1 while the place is not in it."""

    @property
    def representative_frame(self) -> int:
        return self.frames[0]


class HierarchicalPlaceMap(PlaceMap):
    """Places of similar consecutive frames in a topological map with exact VP-tree search (Rodrigues 2019 §3.1).

    A frame joins the current place while its similarity to the place's first
    descriptor stays >= ``similarity_threshold`` (nu; ``auto``: chosen from the reference
    traversal, or from the first frames of a stream, to a target of frames per place).
    Places of ``auto_commit`` traversals join the searchable map at once; a detector
    commits the others. Outputs one ``PlaceAssignment`` per frame (those of frames held
    for the calibration all at once, when nu is chosen) and one ``PlaceThreshold``.
    """

    name = "hierarchical"
    requires = ("descriptor",)

    class Config(PluginConfig):
        similarity_threshold: float | Literal["auto"] = Field(
            "auto", description="nu: a frame joins the current place when S(R(P_l), g_t) >= nu; auto: chosen "
            "from the reference traversal (or the first calibration_frames of a stream) to frames_per_place"
        )
        frames_per_place: float = Field(
            THESIS_FRAMES_PER_PLACE, gt=1,
            description="auto nu: target mean frames per place (2.26: Rodrigues 2019's maps, Table 4.4)",
        )
        calibration_frames: int = Field(
            200, ge=2, description="auto nu without a reference traversal: stream frames held to choose nu from"
        )
        max_distance: float = Field(
            2.0, gt=0, description="distance at which S reaches 0 (2 = the largest L1 distance of unit-L1 vectors)"
        )
        auto_commit: list[Traversal] = Field(
            default_factory=lambda: ["reference"],
            description="traversals whose places join the map when created (the rest wait for commit())",
        )
        search: Literal["auto", "vptree", "brute_force"] = Field(
            "auto", description="how representatives are searched; all are exact and give the same answer. "
            "The VP-tree of Rodrigues 2019 pays off only for large maps of low intrinsic dimension "
            "(benchmarks/results/vptree.md); auto searches by brute force and, when the map reaches 10,000 "
            "places (and each doubling after), moves to a VP-tree if one computes at most 10 % of the distances "
            "on them",
        )
        leaf_size: int = Field(32, ge=2, description="VP-tree leaf bucket size")

        @model_validator(mode="after")
        def _threshold_in_range(self) -> HierarchicalPlaceMap.Config:
            if self.similarity_threshold != "auto" and not 0 <= self.similarity_threshold <= 1:
                raise ValueError("similarity_threshold must be 'auto' or a number in [0, 1]")
            return self

    def __init__(self, config: Config | None = None) -> None:
        super().__init__(config)
        self.places: list[Place] = []
        self._vectors: GrowingRows | None = None
        self._place_of_frame: list[int] = []
        self._map_places: list[int] = []  # place id at each map position
        self._map_frames: list[int] = []  # frame indices of the map's places, in map order
        self._map_starts: list[int] = []  # first map-frame position of each map place
        self._map_frame_array = np.empty(0, dtype=np.int64)  # _map_frames as an array, refreshed when it grew
        self._offsets = np.zeros(1, dtype=np.int64)  # place_offsets(), refreshed when the map grew
        self._tree: VPTree | None = None
        self._representatives: GrowingRows | None = None  # of the map places, by map position
        self._metric = "l1"
        given = self.config.similarity_threshold
        self.threshold: float | None = None if given == "auto" else float(given)
        """nu in use; None while the automatic one is still being chosen."""
        self._held: list[tuple[int, str]] = []  # (frame, traversal) waiting for nu, in order
        self._informative = GrowingRows(1, dtype=bool)  # per frame: not featureless (its descriptor is not all zeros)
        self._n_frames = 0
        self._distance_calls = 0  # level-1 search distances (brute force, or the VP-tree's count)
        self._calibrated_on = 0  # frames the automatic nu was chosen from
        self._next_search_check = VPTREE_MIN_PLACES
        self.edges: set[tuple[int, int, str]] = set()
        """Map edges ``(position a, position b, kind)`` with a < b; kind ``route`` or ``loop``."""

    def check(self, stages: Mapping[str, Plugin]) -> None:
        require_global_descriptor(stages)

    # --- building -------------------------------------------------------------------------

    def process(self, inputs: StageInputs) -> Sequence[Message]:
        features = global_features(inputs)
        frame = inputs.frame
        if frame.index != self._n_frames:
            raise PluginError(f"frames must arrive in order: expected {self._n_frames}, got {frame.index}")
        self._n_frames += 1
        if self._vectors is None:
            self._vectors = GrowingRows(len(features.vector), dtype=features.vector.dtype)
            self._metric = features.metric
            if self._metric == "cosine" and self.config.search == "vptree":
                raise PluginError("the VP-tree needs a metric descriptor distance (l1, l2 or hamming), not cosine; "
                                  "use search: brute_force")
            self._representatives = GrowingRows(len(features.vector), dtype=features.vector.dtype)
            if self.config.search == "vptree":
                self._tree = VPTree(len(features.vector), self._metric, leaf_size=self.config.leaf_size)  # type: ignore[arg-type]
        self._vectors.append(features.vector)
        self._informative.append(np.array([np.any(features.vector)]))
        if self.threshold is not None:
            first = [self._given_threshold(frame.index)] if frame.index == 0 else []
            return [*first, self._assign(frame.index, frame.traversal)]
        # choosing nu: hold the reference traversal until a query arrives, or a stream's first frames
        holding_reference = bool(self._held) and self._held[0][1] in self.config.auto_commit
        if holding_reference and frame.traversal not in self.config.auto_commit:
            return [*self._calibrate(), self._assign(frame.index, frame.traversal)]
        self._held.append((frame.index, frame.traversal))
        if self._held[0][1] in self.config.auto_commit or len(self._held) < self.config.calibration_frames:
            return []
        return self._calibrate()

    def finish(self) -> Sequence[Message]:
        """Frames still held for the calibration (a run shorter than it) are placed now."""
        return self._calibrate() if self._held else []

    def _calibrate(self) -> list[Message]:
        """Choose nu from the held frames, then place them with it."""
        c = self.config
        frames = [index for index, _ in self._held]
        vectors = self.vectors(frames)
        self.threshold = choose_similarity_threshold(vectors, c.frames_per_place, c.max_distance, self._metric)
        sizes = place_sizes(vectors, self.threshold, c.max_distance, self._metric)
        out: list[Message] = [PlaceThreshold(
            frame=frames[0], threshold=self.threshold, auto=True, calibration_frames=len(frames),
            target_frames_per_place=c.frames_per_place, frames_per_place=len(frames) / len(sizes),
        )]
        held, self._held = self._held, []
        self._calibrated_on = len(frames)
        if len({traversal for _, traversal in held}) == 1 and not self.places and self.threshold > 0:
            # one traversal from the first frame: the grouping just made is what _assign would
            # decide frame by frame (same rule, same distance bits; S's clipping to [0, 1] changes
            # no comparison with nu > 0), so it is not computed again
            starts = np.zeros(len(held), dtype=bool)
            starts[np.cumsum(sizes)[:-1]] = True
            starts[0] = True
            return out + [self._assign(index, traversal, bool(new)) for (index, traversal), new in zip(held, starts)]
        return out + [self._assign(index, traversal) for index, traversal in held]

    def _given_threshold(self, frame: int) -> PlaceThreshold:
        return PlaceThreshold(
            frame=frame, threshold=float(self.threshold), auto=False, calibration_frames=0,  # type: ignore[arg-type]
            target_frames_per_place=float("nan"), frames_per_place=float("nan"),
        )

    def _assign(self, index: int, traversal: str, starts_place: bool | None = None) -> PlaceAssignment:
        """Frame ``index`` joins the current place or starts a new one (§3.1.2); ``starts_place``:
        that decision, already made by :func:`place_sizes` on the same frames."""
        assert self.threshold is not None
        current = self.places[-1] if self.places else None
        new_place = starts_place if starts_place is not None else (
            current is None
            or current.traversal != traversal
            or self.similarity(self.distance(self._vectors.view[index],  # type: ignore[union-attr]
                                             self.representative(current.id))) < self.threshold
        )
        if new_place:
            current = Place(id=len(self.places), traversal=traversal)
            self.places.append(current)
        current.frames.append(index)  # type: ignore[union-attr]
        self._place_of_frame.append(current.id)  # type: ignore[union-attr]
        if current.map_position >= 0:  # a growing map place: its new frame joins the map too
            self._map_frames.append(index)
        elif new_place and traversal in self.config.auto_commit:
            self.commit(current.id)  # type: ignore[union-attr]
        return PlaceAssignment(frame=index, place=current.id, new_place=new_place, n_places=len(self.places))  # type: ignore[union-attr]

    def commit(self, place_id: int) -> int:
        """Add a place to the map (a vertex, a route edge, the VP-tree); returns its map position.

        Places join in order; only the last place may still grow after joining.
        """
        place = self.places[place_id]
        if place.map_position >= 0:
            return place.map_position
        position = len(self._map_places)
        if position and self.places[self._map_places[-1]].traversal == place.traversal:
            self.edges.add((position - 1, position, "route"))
        place.map_position = position
        self._map_places.append(place_id)
        self._map_starts.append(len(self._map_frames))
        self._map_frames.extend(place.frames)
        self._representatives.append(self.representative(place_id))  # type: ignore[union-attr]
        if self._tree is not None:
            self._tree.add(self.representative(place_id))
        elif self.config.search == "auto":
            self._maybe_grow_tree()
        return position

    def link(self, position_a: int, position_b: int) -> None:
        """Record a loop-closure edge between two map vertices."""
        a, b = sorted((position_a, position_b))
        if a != b:
            self.edges.add((a, b, "loop"))

    # --- reading --------------------------------------------------------------------------

    @property
    def metric(self) -> str:
        return self._metric

    def distance(self, a: np.ndarray, b: np.ndarray) -> float:
        return float(to_one(a, b[None, :], self._metric)[0])  # type: ignore[arg-type]

    def similarity(self, distance: float | np.ndarray) -> float | np.ndarray:
        """S in [0, 1] from a distance: ``1 - D / max_distance``, clipped."""
        return np.clip(1.0 - np.asarray(distance) / self.config.max_distance, 0.0, 1.0)

    def vectors(self, frames: Sequence[int] | np.ndarray) -> np.ndarray:
        """(n, D) descriptors of frames (by frame index)."""
        return self._vectors.view[np.asarray(frames, dtype=np.int64)]  # type: ignore[union-attr]

    def frame_vectors(self) -> np.ndarray:
        """(N, D) descriptors of every frame so far, row = frame index (a view: read it, do not
        keep it across frames). Optional beyond :class:`slamfront.SearchablePlaceMap`: a detector
        that finds it reads descriptors in place instead of gathering copies."""
        if self._vectors is None:
            return np.empty((0, 0), dtype=np.float32)
        return self._vectors.view

    def representative(self, place_id: int) -> np.ndarray:
        """R(P): the place's first descriptor."""
        return self._vectors.view[self.places[place_id].representative_frame]  # type: ignore[union-attr]

    def representatives(self, places: Sequence[int] | np.ndarray) -> np.ndarray:
        """(n, D) R(P) of places (by place id)."""
        return self.vectors([self.places[int(p)].representative_frame for p in places])

    def place_of(self, frame: int) -> int:
        return self._place_of_frame[frame]

    @property
    def n_map_places(self) -> int:
        return len(self._map_places)

    @property
    def n_map_frames(self) -> int:
        return len(self._map_frames)

    def map_place(self, position: int) -> Place:
        return self.places[self._map_places[position]]

    def map_representatives(self, positions: Sequence[int] | np.ndarray) -> np.ndarray:
        """(n, D) representatives of map places (by map position)."""
        frames = [self.places[self._map_places[p]].representative_frame for p in positions]
        return self.vectors(frames)

    def map_frame_range(self, first: int, last: int) -> tuple[int, int]:
        """Map-frame positions ``[start, stop)`` covered by map places ``first..last``."""
        start = self._map_starts[first]
        stop = self._map_starts[last + 1] if last + 1 < len(self._map_starts) else len(self._map_frames)
        return start, stop

    def map_frames(self, start: int, stop: int) -> np.ndarray:
        """Frame indices at map-frame positions ``[start, stop)``."""
        return np.asarray(self._map_frames[start:stop], dtype=np.int64)

    def informative(self, frames: Sequence[int] | np.ndarray) -> np.ndarray:
        """(n,) bool: which frames have a descriptor that is not all zeros (not featureless)."""
        return self._informative.view[np.asarray(frames, dtype=np.int64), 0]

    def map_frames_at(self, positions: np.ndarray) -> np.ndarray:
        """Frame indices at any map-frame positions (an array of them)."""
        if len(self._map_frame_array) != len(self._map_frames):
            self._map_frame_array = np.asarray(self._map_frames, dtype=np.int64)
        return self._map_frame_array[positions]

    def place_offsets(self) -> np.ndarray:
        """(P + 1,) map-frame offsets of the map places (CSR): place p is ``[o[p], o[p+1])``."""
        if len(self._offsets) != len(self._map_starts) + 1 or self._offsets[-1] != len(self._map_frames):
            self._offsets = np.asarray([*self._map_starts, len(self._map_frames)], dtype=np.int64)
            self._offsets.flags.writeable = False
        return self._offsets

    def nearest(self, vector: np.ndarray, k: int, lo: int = 0, hi: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The ``k`` map places whose representatives are nearest to ``vector``, among map
        positions ``lo..hi``: ``(positions, distances)``, nearest first (exact)."""
        if self._representatives is None or len(self._representatives) == 0:
            return np.empty(0, dtype=np.int64), np.empty(0, dtype=np.float32)
        if self._tree is None:
            last = len(self._representatives) - 1 if hi is None else min(hi, len(self._representatives) - 1)
            self._distance_calls += max(0, last - lo + 1)
            return brute_force_knn(vector, self._representatives.view, k, self._metric, lo, hi)  # type: ignore[arg-type]
        before = self._tree.distance_calls
        found = self._tree.knn(vector, k, lo, hi)
        self._distance_calls += self._tree.distance_calls - before
        return found

    @property
    def search_distances(self) -> int:
        """Descriptor distances computed by :meth:`nearest` so far (what a detector's place search cost)."""
        return self._distance_calls

    def _maybe_grow_tree(self) -> None:
        """``search: auto``: at 10,000 map places and each doubling, keep a VP-tree over the
        representatives if it computes few enough distances on them (:func:`vptree_pays`)."""
        n = len(self._representatives)  # type: ignore[arg-type]
        if n < self._next_search_check or self._metric == "cosine":
            return
        self._next_search_check = 2 * n
        self._tree = vptree_pays(self._representatives.view, self._metric, self.config.leaf_size)  # type: ignore[union-attr,arg-type]

    def statistics(self) -> dict[str, float | int]:
        counts: dict[str, int] = {}
        frames: dict[str, int] = {}
        for place in self.places:
            counts[place.traversal] = counts.get(place.traversal, 0) + 1
            frames[place.traversal] = frames.get(place.traversal, 0) + len(place.frames)
        stats: dict[str, float | int] = {
            "similarity_threshold": float("nan") if self.threshold is None else self.threshold,
            "similarity_threshold_auto": int(self.config.similarity_threshold == "auto"),
            "similarity_threshold_frames": self._calibrated_on,
            "n_places": len(self.places),
            "n_vertices": len(self._map_places),
            "n_edges": len(self.edges),
            "n_loop_edges": sum(1 for edge in self.edges if edge[2] == "loop"),
        }
        for traversal in ("reference", "query", "stream"):
            if traversal in counts:
                stats[f"n_places_{traversal}"] = counts[traversal]
                stats[f"frames_per_place_{traversal}"] = frames[traversal] / counts[traversal]
        return stats
