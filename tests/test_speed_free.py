"""Speed-free sequence matching: queries re-timed or driven backwards are still matched
(hierarchical_sequence's cone of speeds, SeqSLAM's paths), and the re-timing itself."""

from __future__ import annotations

import numpy as np
import pytest

from slamfront.core.retiming import retimed_frames, retimed_positions
from slamfront.core.seqslam import path_scores_block, path_scores_reference
from slamfront.core.sequences import coarse_to_fine_lengths, cone_speeds, refined_speeds
from slamfront.messages import LoopResult
from slamfront_plugins.loop_detectors.hierarchical_sequence import HierarchicalSequence, SequenceDecision
from slamfront_plugins.place_maps.hierarchical import HierarchicalPlaceMap
from tests.hierarchical_helpers import noisy, route_descriptors, run_stages

# --- re-timing ------------------------------------------------------------------------------------


@pytest.mark.parametrize(("timing", "mean_speed"), [("half", 0.5), ("double", 2.0), ("varying", 1.2),
                                                    ("reversed", -1.0)])
def test_retimed_positions_run_at_the_profile_speed_inside_the_route(timing: str, mean_speed: float) -> None:
    positions = retimed_positions(1000, timing)  # type: ignore[arg-type]
    assert positions.min() >= 0 and positions.max() <= 999
    steps = np.diff(positions)
    assert np.mean(steps) == pytest.approx(mean_speed, rel=0.05)
    if timing == "varying":
        assert 0.55 < steps.min() < 0.65 and 1.75 < steps.max() < 1.85


def test_stop_and_go_repeats_frames_and_otherwise_runs_at_the_recorded_pace() -> None:
    frames = retimed_frames(1000, "stop_and_go", seed=3)
    steps = np.diff(frames)
    assert set(steps.tolist()) == {0, 1} and (steps == 0).sum() >= 50
    assert frames[0] == 0 and frames[-1] == 999


# --- the speeds a cone search tries ---------------------------------------------------------------------


def test_cone_speeds_step_by_one_frame_and_mirror_for_reverse() -> None:
    forward = cone_speeds(0.5, 2.0, 8, False)
    assert forward[0] == 0.5 and forward[-1] == 2.0 and np.allclose(np.diff(forward), 1 / 8)
    both = cone_speeds(0.5, 2.0, 8, True)
    assert np.allclose(np.sort(both[both < 0]), -forward[::-1])


def test_refined_speeds_stay_on_the_settled_side_within_one_coarse_step() -> None:
    fine = refined_speeds(-1.0, 8, 16, 0.5, 2.0)
    assert np.all(fine < 0) and np.abs(fine + 1.0).max() <= 1 / 8 + 1e-9 and len(fine) == 5
    assert coarse_to_fine_lengths(8, 40) == [8, 16, 32, 40]


# --- SeqSLAM's paths ---------------------------------------------------------------------------------


@pytest.mark.parametrize(("ds", "segment", "reverse"), [(10, 3, True), (10, 3, False), (40, 20, True)])
def test_compiled_path_search_equals_its_numpy_oracle_to_the_bit(ds: int, segment: int, reverse: bool) -> None:
    columns = np.random.default_rng(ds).random((70, ds + 20))
    scores = path_scores_block(columns, ds, segment, 0.5, 2.0, reverse)
    for n in (0, 7, 19):
        assert np.array_equal(scores[n], path_scores_reference(columns[:, n:n + ds + 1], segment, 0.5, 2.0, reverse))


def _difference_matrix(truth: np.ndarray, n_ref: int, seed: int = 0) -> np.ndarray:
    """(n_ref, Q) random differences, low along the true rows of each query."""
    d = np.random.default_rng(seed).uniform(1.0, 2.0, (n_ref, len(truth)))
    d[truth, np.arange(len(truth))] = 0.2
    return d


@pytest.mark.parametrize("timing", ["reversed", "half", "double", "varying"])
def test_paths_follow_a_retimed_or_reversed_query_that_lines_would_miss(timing: str) -> None:
    truth = 10 + retimed_frames(180, timing)  # type: ignore[arg-type]
    truth = truth[:60]
    d = _difference_matrix(truth, 200)
    scores = path_scores_block(d, 20, 10, 0.5, 2.0, True)
    found = np.argmin(scores, axis=1)
    assert np.abs(found - truth[10:10 + len(found)]).max() <= 2


# --- the hierarchical detector ---------------------------------------------------------------------


def _run(reference: np.ndarray, query: np.ndarray, **detector):  # type: ignore[no-untyped-def]
    vectors = np.concatenate([reference, query])
    traversals = ["reference"] * len(reference) + ["query"] * len(query)
    place_map = HierarchicalPlaceMap(HierarchicalPlaceMap.Config(similarity_threshold=0.9))
    outputs = run_stages(vectors, traversals, place_map, HierarchicalSequence(HierarchicalSequence.Config(**detector)))
    results = {m.frame - len(reference): m for m in outputs if isinstance(m, LoopResult)}
    return results, [m for m in outputs if isinstance(m, SequenceDecision)]


@pytest.mark.parametrize(("timing", "direction"), [("reversed", "reverse"), ("double", "forward"),
                                                   ("half", "forward")])
def test_hierarchical_matches_a_retimed_or_reversed_query_and_logs_its_direction(timing: str, direction: str) -> None:
    reference = route_descriptors(120, 2, seed=3)
    truth = retimed_frames(len(reference), timing)  # type: ignore[arg-type]
    query = noisy(reference[truth], 0.1, seed=5)
    results, decisions = _run(reference, query, sequence_frames=20)
    answered = [(k, r) for k, r in results.items() if r.match >= 0]
    right = [r.confidence for k, r in answered if abs(r.match - truth[k]) <= 2]
    wrong = [r.confidence for k, r in answered if abs(r.match - truth[k]) > 2]
    assert len(right) >= 0.7 * len(query)
    accepted_wrong = [c for c in wrong if c >= 0.04]
    assert len(accepted_wrong) <= 0.05 * len(right)
    settled = [d.direction for d in decisions if d.confidence > 0]
    assert settled.count(direction) >= 0.8 * len(settled)
    # at the map's pace only (the former straight lines) the same query is lost
    if timing != "half":
        results, _ = _run(reference, query, sequence_frames=20, speed_search="lines", rejoin=False, realign_next=False)
        assert sum(abs(r.match - truth[k]) <= 2 for k, r in results.items() if r.match >= 0) < 0.5 * len(right)


# --- sources: re-timed queries keep their ground truth ----------------------------------------------


def test_a_paired_source_retimes_its_query_and_the_truth_follows(tmp_path) -> None:  # type: ignore[no-untyped-def]
    from slamfront_plugins.sources.paired_datasets import PairedFolders
    from tests.test_paired_sources import _folders, _truth_rows

    reversed_ = PairedFolders(PairedFolders.Config(**_folders(tmp_path), query_timing="reversed"))
    _, queries, _ = reversed_.plan
    assert [q.name for q in queries][:3] == ["019.png", "018.png", "017.png"]
    assert _truth_rows(reversed_)[0] == [18, 19] and _truth_rows(reversed_)[19] == [0, 1]
    half = PairedFolders(PairedFolders.Config(**_folders(tmp_path), query_timing="half"))
    assert len(half.plan[1]) == 39 and _truth_rows(half)[5] == [1, 2, 3]


def test_the_synthetic_world_drives_its_query_backwards_or_resampled_by_odometry() -> None:
    from slamfront_plugins.sources.synthetic import SyntheticWorld

    world = SyntheticWorld(SyntheticWorld.Config(frames_per_traversal=60, route_length_m=60, query_timing="reversed"))
    truth = world.loop_ground_truth()
    first = truth.matches[truth.indptr[0]:truth.indptr[1]]
    assert len(world) == 120 and 59 in first.tolist() and 0 not in first.tolist()
    stops = SyntheticWorld.Config(frames_per_traversal=300, route_length_m=300, query_timing="stop_and_go")
    assert len(SyntheticWorld(stops).pass_positions(1)) > 300  # stops add frames
    smart = SyntheticWorld(stops.model_copy(update={"resample_m": 1.0}))
    assert np.array_equal(smart.pass_positions(1), np.arange(300.0))  # one frame per metre: the stops are gone


def test_equal_distance_keeps_one_frame_per_spacing_travelled_and_streams_the_same() -> None:
    from slamfront.core.retiming import DistanceSampler, equal_distance, travelled_m

    along = np.array([0.0, 0.4, 1.0, 1.0, 1.0, 1.6, 3.5, 3.4, 4.1])  # a stop, a jump, a step back
    assert travelled_m(along).tolist() == pytest.approx([0, 0.4, 1.0, 1.0, 1.0, 1.6, 3.5, 3.6, 4.3])
    assert equal_distance(along, 1.0).tolist() == [0, 2, 6, 8]
    walk = np.cumsum(np.random.default_rng(4).normal(size=(400, 3)) * [1, 1, 0.1], axis=0)
    walk[100:140] = walk[99]  # stopped
    for spacing in (0.3, 1.0, 2.5):
        sampler = DistanceSampler(spacing)
        streamed = [i for i, point in enumerate(walk) if sampler.keep(point)]
        kept = equal_distance(walk, spacing)
        assert streamed == kept.tolist() and kept[0] == 0
        assert np.sum((kept >= 99) & (kept < 140)) <= 1  # a stop keeps at most one frame
        marks = np.floor(travelled_m(walk) / spacing + 1e-9)
        assert np.all(marks[kept[1:]] > marks[kept[1:] - 1])  # each kept frame is the first past a new mark
        assert len(kept) == len(np.unique(marks))  # and every mark reached has one


# --- stops seen through noise, and candidates kept apart ---------------------------------------------


def test_a_stop_seen_through_sensor_noise_shares_its_place_and_is_still_matched() -> None:
    # every map frame is its own place (the map moves at every frame); the query stops now
    # and then, each stopped frame a new noisy view of the same place
    reference = route_descriptors(150, 1, seed=3)
    truth = retimed_frames(len(reference), "stop_and_go", seed=2)  # stops of 10-40 frames
    query = noisy(reference[truth], 0.05, seed=6)
    repeats = int((np.diff(truth) == 0).sum())
    assert repeats >= 15
    found = {}
    for still in (0.7, 0.0):
        detector = HierarchicalSequence(HierarchicalSequence.Config(sequence_frames=20, still=still))
        place_map = HierarchicalPlaceMap(HierarchicalPlaceMap.Config(similarity_threshold=0.9))
        outputs = run_stages(np.concatenate([reference, query]), ["reference"] * len(reference) +
                             ["query"] * len(query), place_map, detector)
        results = {m.frame - len(reference): m for m in outputs if isinstance(m, LoopResult)}
        right = sum(r.match >= 0 and abs(r.match - truth[k]) <= 2 and r.confidence >= 0.04
                    for k, r in results.items())
        found[still] = (detector._counts.get("stationary", 0), right)
    stopped, right = found[0.7]
    assert 0.8 * repeats <= stopped <= repeats  # the stops, and no moving frame
    assert found[0.0][0] == 0  # a noisy stop is not below the fixed 0.02 of the map's median step
    assert right >= 0.8 * len(query) and right > found[0.0][1]


def test_candidates_kept_for_the_full_comparison_end_apart() -> None:
    from slamfront_plugins.loop_detectors.hierarchical_frames import PairDistances, compare_candidates

    map_vectors = route_descriptors(100, 1, seed=8)
    query = noisy(map_vectors, 0.05, seed=9)
    pairs = PairDistances(lambda t, m: np.abs(query[t] - map_vectors[m]).sum(axis=1), 200)
    rows = np.arange(40, 60)
    # three anchors on the true line (map frame 40 and its neighbours), one elsewhere
    anchors = [(40, 40, 0), (40, 41, 1), (40, 39, 2), (40, 70, 3)]
    kwargs = dict(velocities=np.asarray([1.0]), slack=2, refine=2, screen_frames=6, screen_speeds=np.asarray([1.0]))
    together = compare_candidates(pairs, anchors, rows, 100, np.ones(100, dtype=bool), **kwargs)  # type: ignore[arg-type]
    apart = compare_candidates(pairs, anchors, rows, 100, np.ones(100, dtype=bool), distinct=10,  # type: ignore[arg-type]
                               **kwargs)
    assert {source for _, source in together} <= {0, 1, 2}  # the best two: both the true place
    assert 3 in {source for _, source in apart}  # the far candidate, for the uniqueness to compare with
    assert int(apart[0][0].at(59)) == 59


def test_an_answer_whose_line_run_back_meets_the_last_one_is_consistent_when_the_pace_changed() -> None:
    """``rejoin``: after a long iteration at a new pace the old line continued misses the new
    answer by more than alpha, but the new line run back meets the last answer where it ended;
    a line running the other way, or at a speed far from the last one's, is not taken for it."""
    from slamfront_plugins.loop_detectors.hierarchical_frames import Trajectory

    detector = HierarchicalSequence(HierarchicalSequence.Config())
    last = Trajectory(0.1, 100, 200, 1.0, 40)  # ended at query position 100, map frame 200
    detector._track = (last, 100)
    faster = Trajectory(0.1, 100, 200, 1.5, 40)  # at 150: map 275, where the old line continued says 250
    assert abs(int(faster.at(150)) - int(last.at(150))) > detector.config.alpha
    assert detector._consistent(faster, 150)
    assert not detector._consistent(Trajectory(0.1, 100, 200, 3.0, 40), 150)  # beyond cone_margin of 1.0
    assert not detector._consistent(Trajectory(0.1, 130, 180, -1.0, 40), 150)  # backwards through (100, 210)
    assert not detector._consistent(Trajectory(0.1, 100, 220, 1.5, 40), 150)  # misses the last answer
    strict = HierarchicalSequence(HierarchicalSequence.Config(rejoin=False))
    strict._track = (last, 100)
    assert not strict._consistent(faster, 150)
    assert strict._consistent(Trajectory(0.1, 100, 201, 1.0, 40), 150)


def test_faithful_candidate_paths_run_at_place_speeds_either_way() -> None:
    from slamfront_plugins.loop_detectors.hierarchical_levels import candidate_paths, place_speeds

    speeds = place_speeds(0.5, 2.0, 5, reverse=True)
    assert speeds[0] == 1.0 and set(np.abs(speeds)) == {0.5, 0.75, 1.0, 1.25, 1.5, 1.75, 2.0}
    paths = {speed: path.tolist() for path, speed in candidate_paths(np.array([20]), 5, speeds, 40)}
    assert paths[1.0] == [16, 17, 18, 19, 20]  # eq. 3.4's F_k
    assert paths[2.0] == [12, 14, 16, 18, 20] and paths[-1.0] == [24, 23, 22, 21, 20]
    assert all(path[-1] == 20 for path in paths.values())
    assert 2.0 not in {s for _, s in candidate_paths(np.array([5]), 5, speeds, 40)}  # would start before the map


@pytest.mark.parametrize(("timing", "sign"), [("reversed", -1), ("double", 1), ("half", 1)])
def test_faithful_cone_follows_a_retimed_or_reversed_query_the_letter_loses(timing: str, sign: int) -> None:
    from slamfront_plugins.loop_detectors.hierarchical_faithful import FaithfulSequenceDecision, HierarchicalFaithful

    reference = route_descriptors(120, 2, seed=3)
    truth = retimed_frames(len(reference), timing)  # type: ignore[arg-type]
    query = noisy(reference[truth], 0.1, seed=5)
    vectors = np.concatenate([reference, query])
    traversals = ["reference"] * len(reference) + ["query"] * len(query)

    def right(**detector: object) -> tuple[int, list[FaithfulSequenceDecision]]:
        place_map = HierarchicalPlaceMap(HierarchicalPlaceMap.Config(similarity_threshold=0.9))
        outputs = run_stages(vectors, traversals, place_map, HierarchicalFaithful(HierarchicalFaithful.Config(**detector)))
        results = [m for m in outputs if isinstance(m, LoopResult) and m.match >= 0]
        hits = sum(abs(r.match - truth[r.frame - len(reference)]) <= 2 for r in results)
        return hits, [m for m in outputs if isinstance(m, FaithfulSequenceDecision)]

    cone, decisions = right(speed_search="cone")
    assert cone >= 0.6 * len(query)
    answered = [d.speed for d in decisions if np.isfinite(d.speed)]
    assert sum(np.sign(answered) == sign) >= 0.8 * len(answered)
    if timing != "double":  # 2-frame places: at double pace the letter still steps one place per place
        letter, _ = right()  # the default: Rodrigues 2019's letter
        assert letter < 0.5 * cone


def test_the_cone_scores_each_stage_near_the_anchor_when_the_window_goes_past_the_map() -> None:
    """``cone_near_anchor``: a long query sequence that straddles a jump in the map. The track
    is anchored where the last answer ended, the window's first row, near the map's end; its
    first 30 frames run on to the map's end, its last 10 show the map's start (the route
    jumped back). Scored on the window's last rows, every line at the map's pace through the
    anchor has left the map there, and the cone never finds the right one; scored on the rows
    nearest the anchor, it does (and the full window keeps 30 of 40 rows inside)."""
    from slamfront_plugins.loop_detectors.hierarchical_frames import Cone, PairDistances, cone_trajectory, rows_near

    map_vectors = route_descriptors(120, 1, seed=11)
    truth = np.concatenate([np.arange(90, 120), np.arange(0, 10)])  # query position t shows map frame truth[t]
    query = noisy(map_vectors[truth], 0.05, seed=12)
    rows = np.arange(40)
    found = {}
    for near in (False, True):
        pairs = PairDistances(lambda t, m: np.abs(query[t] - map_vectors[m]).sum(axis=1), 200)
        cone = Cone(0.4, 2.5, (1.0, -1.0), 8, 4, near_anchor=near)
        found[near] = cone_trajectory(pairs, rows, 0, (91, 91), 2, cone, len(map_vectors))
    right = found[True]
    assert right is not None and abs(right.speed - 1.0) <= 1 / 40 and right.rows == 30
    assert np.array_equal(right.at(np.arange(30)), truth[:30])
    wrong = found[False]
    assert wrong is None or not np.array_equal(wrong.at(np.arange(30)), truth[:30])
    # the stages: the window's last rows unless the anchor lies before them
    assert rows_near(rows, 36, 8).tolist() == list(range(32, 40))
    assert rows_near(rows, 0, 8).tolist() == list(range(8))
    assert rows_near(rows, 20, 16).tolist() == list(range(20, 36))
    assert rows_near(rows, 5, 80) is rows
    # the detector's default, and the switch back to the window's last rows
    assert HierarchicalSequence(HierarchicalSequence.Config())._cone.near_anchor  # type: ignore[union-attr]
    assert not HierarchicalSequence(HierarchicalSequence.Config(cone_near_anchor=False))._cone.near_anchor  # type: ignore[union-attr]
