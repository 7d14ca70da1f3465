"""The hierarchical sequence detectors online, end to end: hand-made routes, the no-answer paths,
the place-map seam and the synthetic world (Rodrigues 2019 ch. 3). ``faithful`` is
``hierarchical_faithful``, ``frames`` the frame-level ``hierarchical_sequence``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from slamfront import PlaceMap, PluginError
from slamfront.messages import LoopResult
from slamfront.recipe import build_pipeline, load_recipe, recipes_dir
from slamfront.runtime import run_pipeline
from slamfront_plugins.loop_detectors.hierarchical_faithful import FaithfulSequenceDecision, HierarchicalFaithful
from slamfront_plugins.loop_detectors.hierarchical_sequence import HierarchicalSequence, SequenceDecision
from slamfront_plugins.place_maps.flat import FlatPlaceMap
from slamfront_plugins.place_maps.hierarchical import HierarchicalPlaceMap
from tests.hierarchical_helpers import noisy, route_descriptors, run_stages

FRAMES_PER_PLACE = 2


def _paired(n_places: int, query_places: int | None = None, seed: int = 0):  # type: ignore[no-untyped-def]
    reference = route_descriptors(n_places, FRAMES_PER_PLACE, seed=seed)
    query = noisy(reference, 0.1)[: (query_places or n_places) * FRAMES_PER_PLACE]
    vectors = np.concatenate([reference, query])
    traversals = ["reference"] * len(reference) + ["query"] * len(query)
    return vectors, traversals, len(reference)


DETECTORS = {"faithful": HierarchicalFaithful, "frames": HierarchicalSequence}


def _detect(vectors, traversals, mode="frames", place_map=None, **detector):  # type: ignore[no-untyped-def]
    place_map = place_map or HierarchicalPlaceMap(HierarchicalPlaceMap.Config(similarity_threshold=0.9))
    kind = DETECTORS[mode]
    found = kind(kind.Config(**detector))
    timeline: list = []
    outputs = run_stages(vectors, traversals, place_map, found, timeline)
    return outputs, timeline, found


def _results(outputs) -> dict[int, LoopResult]:  # type: ignore[no-untyped-def]
    results = [m for m in outputs if isinstance(m, LoopResult)]
    frames = [r.frame for r in results]
    assert len(frames) == len(set(frames)), "a query frame was answered twice"
    return {r.frame: r for r in results}


@pytest.mark.parametrize("mode", ["faithful", "frames"])
def test_every_query_frame_is_answered_once_online_and_correctly(mode: str) -> None:
    vectors, traversals, n_reference = _paired(n_places=40)
    outputs, timeline, detector = _detect(vectors, traversals, mode=mode, accept_query_null_wait=False)
    results = _results(outputs)
    assert sorted(results) == list(range(n_reference, len(vectors)))
    # online: most answers come out while frames arrive, not at the end (frames mode answers
    # each sequence when the next one is compared: the last one at the end)
    during = sum(len([m for m in produced if isinstance(m, LoopResult)]) for frame, produced in timeline if frame >= 0)
    assert during >= 0.75 * len(results)
    if mode == "frames":  # and when its answers wait for the queries' null, at most accept_query_null_frames late
        _, waited_timeline, waited = _detect(vectors, traversals, mode=mode, accept_query_null_wait=True)
        limit = waited.config.accept_query_null_frames + 2 * FRAMES_PER_PLACE * waited.config.rho
        late = [frame - message.frame for frame, produced in waited_timeline if frame >= 0
                for message in produced if isinstance(message, LoopResult)]
        assert late and max(late) <= limit and waited.statistics()["accept_answers_waited"] > 0
    # an answer never comes before its query frame arrived
    for frame, produced in timeline:
        for message in produced:
            if isinstance(message, LoopResult) and frame >= 0:
                assert message.frame <= frame
    correct = [abs(r.match - (r.frame - n_reference)) <= 1 for r in results.values() if r.match >= 0]
    assert np.mean(correct) == 1.0 and len(correct) == len(results)
    assert all(0.0 <= r.confidence <= 1.0 for r in results.values())
    stats = detector.statistics()
    # faithful: the first sequence waits for the second; frames: each is answered with the next
    validated = 1 if mode == "faithful" else 7
    assert stats["n_searches"] == 40 // 5 and stats["n_validated_by_next"] == validated
    assert stats["n_consistent"] == 8 - validated
    assert stats["n_distances"] == (stats["n_distances_search"] + stats["n_distances_sequences"]
                                    + stats["n_distances_calibration"] + stats["n_distances_query_null"]) > 0


def test_decisions_record_the_branch_and_the_candidates() -> None:
    vectors, traversals, _ = _paired(n_places=30)
    outputs, _, _ = _detect(vectors, traversals, mode="faithful")
    decisions = [m for m in outputs if isinstance(m, FaithfulSequenceDecision)]
    assert [d.branch for d in decisions][:2] == ["validated_by_next", "consistent"]
    first = decisions[0]
    assert first.candidates.shape[1] == 2 and len(first.candidate_costs) == len(first.candidates)
    assert np.all(np.diff(first.candidate_costs) >= 0)  # ranked by eq. 3.5
    assert (first.first, first.last) == (0, 4) and first.query_frames.tolist() == list(range(60, 70))
    assert decisions[1].template_offset >= 0 and decisions[1].confidence > 0.5


def test_a_wrong_jump_waits_and_is_rebuilt() -> None:
    # the query leaves the route for one query sequence (5 places never seen), then comes back
    reference = route_descriptors(40, FRAMES_PER_PLACE, seed=0)
    detour = route_descriptors(5, FRAMES_PER_PLACE, seed=99)
    query = noisy(np.concatenate([reference[:20], detour, reference[30:60]]), 0.1)
    vectors = np.concatenate([reference, query])
    traversals = ["reference"] * len(reference) + ["query"] * len(query)
    outputs, _, detector = _detect(vectors, traversals, mode="faithful")
    decisions = {d.iteration: d for d in outputs if isinstance(d, FaithfulSequenceDecision)}
    assert decisions[3].branch == "rebuilt"  # the detour: inconsistent with iterations 2 and 4
    assert (decisions[3].first, decisions[3].last) == (5, 14)  # F*,2 = (5, 9) and the 5 places after it
    assert decisions[4].branch == "validated_by_next"
    results = _results(outputs)
    detour_frames = range(len(reference) + 20, len(reference) + 30)
    back = [r for f, r in results.items() if f >= len(reference) + 30]
    assert all(abs(r.match - (r.frame - len(reference) - 30 + 30)) <= 1 for r in back)
    assert max(results[f].confidence for f in detour_frames) < min(r.confidence for r in back)


def test_map_too_small_is_a_no_answer_for_every_query_frame() -> None:
    vectors, traversals, n_reference = _paired(n_places=3, query_places=3)
    vectors = np.concatenate([vectors, noisy(route_descriptors(10, 2, seed=5), 0.1)])
    traversals = traversals + ["query"] * 20
    outputs, _, _ = _detect(vectors, traversals, mode="faithful")
    results = _results(outputs)
    assert sorted(results) == list(range(n_reference, len(vectors)))
    assert all(r.match == -1 and not r.accepted for r in results.values())
    reasons = {r.reason for r in results.values()}
    assert "the map has 3 places, not more than rho=5" in reasons


@pytest.mark.parametrize("mode", ["faithful", "frames"])
def test_a_query_traversal_shorter_than_rho_places_gets_no_answer(mode: str) -> None:
    vectors, traversals, n_reference = _paired(n_places=20, query_places=3)
    outputs, _, _ = _detect(vectors, traversals, mode=mode)
    results = _results(outputs)
    assert len(results) == 6
    assert {r.reason for r in results.values()} == {"traversal ended before its query sequence was complete"}


@pytest.mark.parametrize("mode", ["faithful", "frames"])
def test_featureless_query_frames_get_no_answer(mode: str) -> None:
    vectors, traversals, n_reference = _paired(n_places=20)
    vectors[n_reference + 12] = 0.0  # a black frame in the query
    outputs, _, _ = _detect(vectors, traversals, mode=mode)
    results = _results(outputs)
    dark = results[n_reference + 12]
    assert dark.match == -1 and dark.reason.startswith("featureless")
    # the black frame is a place of its own, so the last places no longer fill a whole Q
    others = [r for f, r in results.items() if f != n_reference + 12]
    assert {r.reason for r in others if r.match < 0} <= {"traversal ended before its query sequence was complete"}
    assert sum(r.match >= 0 for r in others) >= 0.9 * len(others)


@pytest.mark.parametrize("mode", ["faithful", "frames"])
def test_stream_revisits_are_found_against_earlier_laps(mode: str) -> None:
    lap = route_descriptors(60, FRAMES_PER_PLACE, seed=2)
    vectors = np.concatenate([lap, noisy(lap, 0.1)])
    traversals = ["stream"] * len(vectors)
    outputs, _, detector = _detect(vectors, traversals, exclude_recent_places=10, mode=mode)
    results = _results(outputs)
    n = len(lap)
    second = [results[f] for f in range(n, 2 * n) if f in results and results[f].match >= 0]
    assert len(second) >= 0.8 * n
    assert np.mean([abs(r.match - (r.frame - n)) <= 1 for r in second]) >= 0.9
    # frames mode: the first sequence of the second lap still compares frames of the first
    # lap's end (excluded from the map); that answer is isolated, with confidence 0
    assert all(abs(r.match - (r.frame - n)) <= 1 for r in second if r.confidence > 0)
    first_lap = [results[f].confidence for f in range(n) if f in results and results[f].match >= 0]
    assert max(first_lap) < np.median([r.confidence for r in second])  # no place to revisit yet: low confidence
    assert detector.statistics()["n_map_too_small"] >= 1


def test_the_detector_needs_a_place_map_stage(write_recipe) -> None:
    recipe = {
        "name": "x", "source": {"plugin": "synthetic", "params": {"frames_per_traversal": 10, "route_length_m": 30}},
        "descriptor": {"plugin": "rst_shelo"}, "loop_detector": {"plugin": "hierarchical_sequence"},
    }
    with pytest.raises(PluginError, match="needs a place_map stage"):
        build_pipeline(*load_recipe(write_recipe(recipe)))


@pytest.mark.parametrize("mode", ["faithful", "frames"])
def test_a_place_map_it_cannot_search_by_place_is_refused_by_name(mode: str) -> None:
    class Unsearchable(PlaceMap):
        name = "unsearchable"

    with pytest.raises(PluginError, match="'unsearchable', which does not implement SearchablePlaceMap"):
        DETECTORS[mode]().check({"place_map": Unsearchable()})
    for searchable in (HierarchicalPlaceMap(), FlatPlaceMap()):
        DETECTORS[mode]().check({"place_map": searchable})


@pytest.mark.parametrize("mode", ["faithful", "frames"])
def test_the_flat_place_map_runs_the_detector(mode: str) -> None:
    # one place per frame: Q is rho frames, level 1 searches every reference frame; every
    # query frame is still answered once, correctly
    vectors, traversals, n_reference = _paired(n_places=40)
    outputs, _, detector = _detect(vectors, traversals, mode=mode, place_map=FlatPlaceMap())
    results = _results(outputs)
    assert sorted(results) == list(range(n_reference, len(vectors)))
    assert all(abs(r.match - (r.frame - n_reference)) <= 1 for r in results.values())
    stats = detector.statistics()
    searched = 80 - (4 if mode == "faithful" else 0)  # faithful: hits need rho - 1 places before them
    assert stats["n_searches"] == 80 // 5 and stats["n_distances_search"] == 16 * searched  # rho frames, whole map
    # the same answers as on the hierarchical map, where its places are single frames too
    single = HierarchicalPlaceMap(HierarchicalPlaceMap.Config(similarity_threshold=1.0))
    again = _results(_detect(vectors, traversals, mode=mode, place_map=single)[0])
    assert [(r.match, r.confidence) for r in again.values()] == [(r.match, r.confidence) for r in results.values()]


def test_a_recipe_still_asking_for_the_faithful_mode_is_told_which_plugin(cli, write_recipe) -> None:
    recipe = {
        "name": "old", "source": {"plugin": "synthetic", "params": {"frames_per_traversal": 10, "route_length_m": 30}},
        "descriptor": {"plugin": "rst_shelo"}, "place_map": {"plugin": "hierarchical"},
        "loop_detector": {"plugin": "hierarchical_sequence", "params": {"mode": "faithful", "rho": 5}},
    }
    code, _, err = cli("run", write_recipe(recipe), "-q")
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "plugin: hierarchical_faithful" in err and "Traceback" not in err
    # the frame-level mode is what hierarchical_sequence is: the old key is accepted as such
    assert HierarchicalSequence.Config(mode="frames", rho=4) == HierarchicalSequence.Config(rho=4)


def test_synthetic_world_revisits_at_full_precision(tmp_path: Path) -> None:
    """The method clearly earns this floor: measured 0.985 recall at 100 % precision (200+200 frames)."""
    raw = yaml.safe_load((recipes_dir() / "synthetic_hsl.yaml").read_text())
    raw["source"]["params"].update(frames_per_traversal=200, route_length_m=200, image_width=128, image_height=96)
    raw["log"] = {"images": False}
    path = tmp_path / "synthetic.yaml"
    path.write_text(yaml.safe_dump(raw))
    recipe, _ = load_recipe(path)
    result = run_pipeline(build_pipeline(recipe, str(path)), str(path), tmp_path / "run", progress=False)
    metrics = result.metrics
    assert metrics["recall_at_100p"] >= 0.9
    assert metrics["auc_pr"] >= 0.9
    assert metrics["n_searches"] < metrics["n_places_query"] < metrics["n_queries"]
    assert (tmp_path / "run" / "retrieval.png").exists() and (tmp_path / "run" / "matches.png").exists()


def test_decisions_round_trip_through_the_log_format() -> None:
    vectors, traversals, _ = _paired(n_places=15)
    outputs, _, _ = _detect(vectors, traversals)
    decision = next(m for m in outputs if isinstance(m, SequenceDecision))
    again = SequenceDecision.from_json(decision.to_json())
    assert again.same_as(decision) and again.query_frames.dtype == np.int64
    assert SequenceDecision.json_schema()["properties"]["candidates"]["type"] == "object"
    outputs, _, _ = _detect(vectors, traversals, mode="faithful")
    faithful = next(m for m in outputs if isinstance(m, FaithfulSequenceDecision))
    assert FaithfulSequenceDecision.from_json(faithful.to_json()).same_as(faithful)
