"""The hierarchical place map: places by threshold nu, the map graph, exact search (Rodrigues 2019 §3.1);
and the interface the detectors read place maps through, with the flat place map."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from slamfront import Frame, SearchablePlaceMap, StageInputs
from slamfront.core.vptree import brute_force_knn
from slamfront.messages import Features, PlaceAssignment
from slamfront_plugins.descriptors.rst_shelo import RstShelo
from slamfront_plugins.place_maps.flat import FlatPlaceMap
from slamfront_plugins.place_maps.hierarchical import (
    HierarchicalPlaceMap,
    PlaceThreshold,
    choose_similarity_threshold,
    place_sizes,
    place_sizes_reference,
)
from tests.hierarchical_helpers import route_descriptors


def _feed_all(
    place_map: HierarchicalPlaceMap, vectors: np.ndarray, traversals: list[str], finish: bool = False
) -> list[tuple[int, list]]:
    """(frame at which they came out, outputs) for every frame, and -1 for finish()."""
    timeline = []
    for index, (vector, traversal) in enumerate(zip(vectors, traversals)):
        frame = Frame(index=index, timestamp=float(index), image=np.zeros((2, 2), np.uint8), traversal=traversal)  # type: ignore[arg-type]
        inputs = StageInputs(frame=frame, outputs={"descriptor": [Features(frame=index, vector=vector, metric="l1")]})
        timeline.append((index, list(place_map.process(inputs))))
    if finish:
        timeline.append((-1, list(place_map.finish())))
    return timeline


def _feed(place_map: HierarchicalPlaceMap, vectors: np.ndarray, traversals: list[str]) -> list[PlaceAssignment]:
    return [m for _, out in _feed_all(place_map, vectors, traversals, finish=True) for m in out
            if isinstance(m, PlaceAssignment)]


def test_a_frame_joins_the_place_while_similar_to_its_first_descriptor() -> None:
    # S = 1 - L1 / 2; with nu = 0.8 a frame joins while its L1 distance to R(P_l) is <= 0.4
    e = np.eye(3, dtype=np.float32)
    frames = np.stack([e[0], 0.9 * e[0] + 0.1 * e[1], 0.75 * e[0] + 0.25 * e[1], e[1], e[1]])
    place_map = HierarchicalPlaceMap(HierarchicalPlaceMap.Config(similarity_threshold=0.8))
    assignments = _feed(place_map, frames, ["reference"] * 5)
    # distances to e0: 0, 0.2, 0.5 (new place), then e1 vs R = frame 2: 0.5 (new place), 0
    assert [a.place for a in assignments] == [0, 0, 1, 2, 2]
    assert [a.new_place for a in assignments] == [True, False, True, True, False]
    assert [p.frames for p in place_map.places] == [[0, 1], [2], [3, 4]]


def test_places_never_span_two_traversals() -> None:
    vectors = np.tile(np.eye(4, dtype=np.float32)[0], (6, 1))
    place_map = HierarchicalPlaceMap()
    assignments = _feed(place_map, vectors, ["reference"] * 3 + ["query"] * 3)
    assert [a.place for a in assignments] == [0, 0, 0, 1, 1, 1]
    stats = place_map.statistics()
    assert stats["n_places_reference"] == 1 and stats["n_places_query"] == 1
    assert stats["n_vertices"] == 1  # query places wait for a commit


def test_reference_places_join_the_map_with_route_edges_and_frames_in_order() -> None:
    vectors = route_descriptors(n_places=6, frames_per_place=3)
    place_map = HierarchicalPlaceMap(HierarchicalPlaceMap.Config(similarity_threshold=0.9))
    _feed(place_map, vectors, ["reference"] * len(vectors))
    assert place_map.n_map_places == 6 and place_map.n_map_frames == 18
    assert place_map.place_offsets().tolist() == [0, 3, 6, 9, 12, 15, 18]
    assert place_map.map_frame_range(2, 3) == (6, 12)
    assert place_map.map_frames(6, 9).tolist() == [6, 7, 8]
    assert sorted(place_map.edges) == [(i, i + 1, "route") for i in range(5)]
    place_map.link(1, 4)
    assert place_map.statistics()["n_loop_edges"] == 1


def test_committing_query_places_extends_the_map() -> None:
    vectors = route_descriptors(n_places=4, frames_per_place=2)
    place_map = HierarchicalPlaceMap(HierarchicalPlaceMap.Config(similarity_threshold=0.9))
    _feed(place_map, vectors, ["reference"] * 4 + ["stream"] * 4)
    assert place_map.n_map_places == 2
    assert place_map.commit(2) == 2 and place_map.commit(2) == 2  # idempotent
    assert place_map.map_frames(0, place_map.n_map_frames).tolist() == [0, 1, 2, 3, 4, 5]
    assert (1, 2, "route") not in place_map.edges  # another traversal: no route edge


@pytest.mark.parametrize("search", ["vptree", "brute_force", "auto"])
def test_nearest_places_equal_brute_force_over_representatives(search: str) -> None:
    vectors = route_descriptors(n_places=300, frames_per_place=2, dim=16, seed=3)
    place_map = HierarchicalPlaceMap(HierarchicalPlaceMap.Config(similarity_threshold=0.9, leaf_size=4, search=search))
    _feed(place_map, vectors, ["reference"] * len(vectors))
    representatives = place_map.map_representatives(range(place_map.n_map_places))
    rng = np.random.default_rng(0)
    for query in rng.random((20, 16)).astype(np.float32):
        query /= query.sum()
        got = place_map.nearest(query, 10, lo=4, hi=250)
        want = brute_force_knn(query, representatives, 10, "l1", lo=4, hi=250)
        assert got[0].tolist() == want[0].tolist() and np.array_equal(got[1], want[1])


def test_choosing_nu_from_a_reference_traversal() -> None:
    vectors = route_descriptors(n_places=50, frames_per_place=3)
    sizes = place_sizes(vectors, threshold=0.95)
    assert sizes.tolist() == [3] * 50  # the route's own places are recovered
    nu = choose_similarity_threshold(vectors, frames_per_place=3.0)
    assert place_sizes(vectors, nu).mean() == 3.0
    assert place_sizes(vectors, 0.0).tolist() == [150]  # nu = 0: one place


def test_compiled_place_sizes_are_the_per_frame_loop(shared_data: Path) -> None:
    """The compiled grouping (float32 L1) makes the places one distance call per frame
    makes, at every nu, on real RST-SHelo descriptors (Nordland summer, 600 frames) and
    on vectors built to sit on the threshold."""
    folder = shared_data / "nordland" / "summer"
    describer = RstShelo()
    vectors = np.stack([describer.describe(cv2.imread(str(path), cv2.IMREAD_GRAYSCALE))
                        for path in sorted(folder.glob("*.png"))[:600]])
    for nu in (0.0, 0.5, 0.7, 0.75, 0.8, 0.85, 0.9, 0.95, 1.0):
        assert place_sizes(vectors, nu).tolist() == place_sizes_reference(vectors, nu).tolist()
    # a distance exactly at nu (0.25 apart: S = 0.875), on both sides of the comparison
    on_edge = np.zeros((6, 8), dtype=np.float32)
    on_edge[:, 0] = [1.0, 0.875, 0.75, 1.0, 1.0, 0.0]
    on_edge[:, 1] = 1.0 - on_edge[:, 0]
    for nu in (0.875, np.nextafter(0.875, 1.0), np.nextafter(0.875, 0.0)):
        assert place_sizes(on_edge, nu).tolist() == place_sizes_reference(on_edge, nu).tolist()


def _nested_route(n_groups: int, seed: int = 0) -> tuple[np.ndarray, list[int], list[int]]:
    """Descriptors with places at two scales: groups of 6 frames (unrelated to each other),
    each made of sub-places of 2 frames (close to each other, unlike within a group).
    Returns (vectors, fine place sizes, coarse place sizes)."""
    rng = np.random.default_rng(seed)
    frames = []
    for _ in range(n_groups):
        base = rng.random(48) ** 4
        for _ in range(3):  # three sub-places of two near-identical frames
            sub = base * (1 + 0.6 * rng.random(48))
            frames += [sub + rng.random(48) * 1e-4 for _ in range(2)]
    vectors = np.asarray(frames)
    vectors = (vectors / vectors.sum(axis=1, keepdims=True)).astype(np.float32)
    return vectors, [2] * (3 * n_groups), [6] * n_groups


@pytest.mark.parametrize("scale", ["fine", "coarse"])
def test_automatic_nu_recovers_known_place_sizes(scale: str) -> None:
    vectors, fine, coarse = _nested_route(40)
    sizes = fine if scale == "fine" else coarse
    nu = choose_similarity_threshold(vectors, frames_per_place=float(np.mean(sizes)))
    assert place_sizes(vectors, nu).tolist() == sizes


def test_automatic_nu_aims_at_the_mean_size_when_no_threshold_gives_it_exactly() -> None:
    vectors, _, _ = _nested_route(40)
    mean = {nu: place_sizes(vectors, nu).mean() for nu in np.round(np.arange(0, 1.0005, 0.001), 3)}
    nu = choose_similarity_threshold(vectors, frames_per_place=4.0)
    assert abs(mean[round(nu, 3)] - 4.0) == min(abs(m - 4.0) for m in mean.values())


def test_paired_runs_choose_nu_from_the_reference_alone_before_the_first_query() -> None:
    reference, fine, _ = _nested_route(20)
    queries = [route_descriptors(30, 2, dim=48, seed=s) for s in (1, 2)]
    chosen = []
    for query in queries:
        place_map = HierarchicalPlaceMap(HierarchicalPlaceMap.Config(frames_per_place=2.0))
        vectors = np.concatenate([reference, query])
        timeline = _feed_all(place_map, vectors, ["reference"] * len(reference) + ["query"] * len(query))
        # nothing is placed while the reference arrives; all of it when the first query does
        assert all(out == [] for frame, out in timeline[: len(reference)])
        first_query = timeline[len(reference)][1]
        threshold = first_query[0]
        assert isinstance(threshold, PlaceThreshold) and threshold.auto
        assert threshold.calibration_frames == len(reference) and threshold.frames_per_place == 2.0
        placed = [m.frame for m in first_query[1:]]
        assert placed == list(range(len(reference) + 1))
        assert [p.frames for p in place_map.places[: len(fine)]] == [[2 * k, 2 * k + 1] for k in range(len(fine))]
        stats = place_map.statistics()
        assert stats["similarity_threshold"] == threshold.threshold and stats["similarity_threshold_frames"] == 120
        chosen.append(threshold.threshold)
    assert chosen[0] == chosen[1]  # the queries never enter the choice


def test_a_stream_holds_its_first_frames_then_keeps_nu() -> None:
    vectors, fine, _ = _nested_route(30)
    place_map = HierarchicalPlaceMap(HierarchicalPlaceMap.Config(frames_per_place=2.0, calibration_frames=60))
    timeline = _feed_all(place_map, vectors, ["stream"] * len(vectors))
    assert all(out == [] for _, out in timeline[:59])
    released = timeline[59][1]
    assert isinstance(released[0], PlaceThreshold) and released[0].calibration_frames == 60
    assert [m.frame for m in released[1:]] == list(range(60))
    assert all(len(out) == 1 for _, out in timeline[60:])  # then one assignment per frame, same nu
    assert [len(p.frames) for p in place_map.places] == fine
    assert place_map.threshold == choose_similarity_threshold(vectors[:60], 2.0)


def test_a_run_shorter_than_the_calibration_is_placed_at_the_end() -> None:
    vectors, fine, _ = _nested_route(5)
    place_map = HierarchicalPlaceMap(HierarchicalPlaceMap.Config(frames_per_place=2.0, calibration_frames=500))
    timeline = _feed_all(place_map, vectors, ["stream"] * len(vectors), finish=True)
    assert all(out == [] for frame, out in timeline if frame >= 0)
    assert [m.frame for m in timeline[-1][1] if isinstance(m, PlaceAssignment)] == list(range(len(vectors)))
    assert [len(p.frames) for p in place_map.places] == fine


def test_a_given_nu_is_logged_as_given() -> None:
    place_map = HierarchicalPlaceMap(HierarchicalPlaceMap.Config(similarity_threshold=0.8))
    out = _feed_all(place_map, route_descriptors(3, 2), ["reference"] * 6)
    threshold = out[0][1][0]
    assert isinstance(threshold, PlaceThreshold) and not threshold.auto and threshold.threshold == 0.8
    assert all(len(o) == 1 for _, o in out[1:])
    with pytest.raises(ValueError, match="auto"):
        HierarchicalPlaceMap.Config(similarity_threshold=1.5)


def test_auto_search_moves_to_a_vp_tree_only_where_it_computes_few_distances(monkeypatch) -> None:  # type: ignore[no-untyped-def]
    import slamfront.core.vptree as vptree
    import slamfront_plugins.place_maps.hierarchical as hierarchical

    monkeypatch.setattr(vptree, "VPTREE_MIN_PLACES", 600)
    monkeypatch.setattr(hierarchical, "VPTREE_MIN_PLACES", 600)
    rng = np.random.default_rng(4)
    curve = np.linspace(0, 0.5, 1000)[:, None] * np.arange(1, 17)[None, :]  # a smooth 1-D route in 16-D
    low = np.abs(np.sin(curve)).astype(np.float32) + 0.01
    high = rng.random((1000, 16)).astype(np.float32)  # spread over all 16 dimensions
    for vectors, expect_tree in ((low, True), (high, False)):
        vectors = vectors / vectors.sum(1, keepdims=True)
        config = HierarchicalPlaceMap.Config(similarity_threshold=1.0, leaf_size=4)  # a place per frame
        place_map = HierarchicalPlaceMap(config)
        _feed(place_map, vectors, ["reference"] * len(vectors))
        assert (place_map._tree is not None) is expect_tree
        for query in vectors[::97]:
            got = place_map.nearest(query, 5, lo=3, hi=900)
            want = brute_force_knn(query, vectors, 5, "l1", lo=3, hi=900)
            assert got[0].tolist() == want[0].tolist() and np.array_equal(got[1], want[1])


# --- the interface the detectors use, and the flat place map ---------------------------------------


@pytest.mark.parametrize("make", [lambda: HierarchicalPlaceMap(HierarchicalPlaceMap.Config(similarity_threshold=0.9)),
                                  FlatPlaceMap])
def test_both_place_maps_implement_the_interface_the_detectors_use(make) -> None:  # type: ignore[no-untyped-def]
    place_map = make()
    assert isinstance(place_map, SearchablePlaceMap)
    vectors = route_descriptors(30, 2, seed=3)
    traversals = ["reference"] * 40 + ["query"] * 20
    assignments = _feed(place_map, vectors, traversals)
    offsets = place_map.place_offsets()
    # the reference joined the map at once, in order; the query waits for commit()
    assert offsets[0] == 0 and np.all(np.diff(offsets) > 0) and offsets[-1] == 40
    assert place_map.map_frames_at(np.arange(40)).tolist() == list(range(40))
    first = len(offsets) - 1
    query_place = place_map.place_of(40)
    assert assignments[40].place == query_place and place_map.commit(query_place) == first
    assert place_map.commit(query_place) == first and len(place_map.place_offsets()) == first + 2
    # exact search over the map places' representatives
    reps = place_map.map_representatives(np.arange(first + 1))
    positions, distances = place_map.nearest(vectors[45], 3, lo=2, hi=first)
    expected, _ = brute_force_knn(vectors[45], reps, 3, "l1", 2, first)
    assert positions.tolist() == expected.tolist() and place_map.search_distances == first - 1
    assert np.array_equal(place_map.representatives([query_place]), vectors[[40]])
    assert place_map.similarity(0.0) == 1.0 and place_map.similarity(2.0) == 0.0


def test_the_flat_place_map_makes_every_frame_a_place() -> None:
    place_map = FlatPlaceMap()
    vectors = route_descriptors(10, 3, seed=4)
    vectors[5] = 0.0
    assignments = _feed(place_map, vectors, ["reference"] * 30)
    assert [(a.frame, a.place, a.new_place) for a in assignments] == [(f, f, True) for f in range(30)]
    assert place_map.place_offsets().tolist() == list(range(31))
    assert place_map.informative([4, 5, 6]).tolist() == [True, False, True]
    assert place_map.statistics() == {"n_places": 30, "n_vertices": 30}
