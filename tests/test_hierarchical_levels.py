"""Each level of the hierarchical sequence detector on hand-made cases (Rodrigues 2019 §3.2)."""

from __future__ import annotations

import numpy as np
import pytest

from slamfront_plugins.loop_detectors.hierarchical_levels import (
    TemporalConsistency,
    candidate_sequences,
    consistent,
    expand_with_padding,
    match_frames,
    sequence_costs,
)

# --- level 1 ----------------------------------------------------------------------------------


def test_candidates_need_rho_minus_one_places_before_them() -> None:
    # rho = 5: places 0..3 cannot end a sequence (eq. 3.4 and the remark after it)
    assert candidate_sequences(np.array([3, 4, 10, 0]), rho=5) == [(0, 4), (6, 10)]
    assert candidate_sequences(np.array([], dtype=np.int64), rho=5) == []


# --- level 2 ----------------------------------------------------------------------------------


def test_sequence_cost_is_the_sum_of_place_by_place_l1_distances() -> None:
    query = np.array([[1.0, 0.0], [0.0, 1.0]], dtype=np.float32)
    candidates = np.array(
        [
            [[1.0, 0.0], [0.0, 1.0]],  # identical: cost 0
            [[0.0, 1.0], [1.0, 0.0]],  # swapped: 2 + 2
            [[0.5, 0.5], [0.0, 1.0]],  # 1 + 0
        ],
        dtype=np.float32,
    )
    assert sequence_costs(query, candidates, "l1").tolist() == pytest.approx([0.0, 4.0, 1.0])


def test_consistency_is_eq_3_6() -> None:
    assert consistent((10, 14), (15, 19), alpha=5)  # next places: |14 - 15| = 1
    assert consistent((10, 14), (10, 14), alpha=5)  # overlap of 4 < 5
    assert not consistent((10, 14), (19, 23), alpha=5)  # |14 - 19| = 5, not < 5
    assert not consistent((10, 14), (2, 6), alpha=5)


def test_first_iteration_waits_and_is_validated_by_the_next() -> None:
    level2 = TemporalConsistency(rho=5, alpha=5)
    assert level2.step(1, (10, 14), n_map_places=100) == []  # no previous: it waits
    dispatched = level2.step(2, (15, 19), n_map_places=100)
    assert [(d.iteration, d.sequence, d.branch, d.synthetic) for d in dispatched] == [
        (1, (10, 14), "validated_by_next", False),  # no synthetic sequence for it (§3.2.3)
        (2, (15, 19), "consistent", True),
    ]


def test_consistent_with_previous_goes_straight_to_level_3() -> None:
    level2 = TemporalConsistency(rho=5, alpha=5)
    level2.step(1, (10, 14), 100)
    level2.step(2, (15, 19), 100)
    dispatched = level2.step(3, (20, 24), 100)
    assert [(d.iteration, d.branch) for d in dispatched] == [(3, "consistent")]
    assert level2.waiting is None and level2.processed == (20, 24)


def test_inconsistent_with_both_neighbours_is_rebuilt_from_the_previous_sequence() -> None:
    level2 = TemporalConsistency(rho=5, alpha=5)
    level2.step(1, (10, 14), 100)
    level2.step(2, (15, 19), 100)  # processed: (15, 19)
    assert level2.step(3, (60, 64), 100) == []  # a jump: waits
    dispatched = level2.step(4, (80, 84), 100)  # inconsistent with (60, 64) as well
    assert len(dispatched) == 1
    rebuilt = dispatched[0]
    # iteration 3 becomes F*,i-1 followed by the rho places after it (Alg. 3 lines 11-13, eq. 3.8)
    assert (rebuilt.iteration, rebuilt.sequence, rebuilt.branch, rebuilt.synthetic) == (3, (15, 24), "rebuilt", True)
    assert level2.waiting == (4, (80, 84))
    # iteration 5 near iteration 4 validates it
    dispatched = level2.step(5, (85, 89), 100)
    assert [(d.iteration, d.branch) for d in dispatched] == [(4, "validated_by_next"), (5, "consistent")]


def test_rebuild_is_clipped_at_the_end_of_the_map_and_does_not_keep_growing() -> None:
    level2 = TemporalConsistency(rho=5, alpha=5)
    level2.processed = (20, 29)  # a rebuilt sequence of 2 rho places
    level2.previous = (50, 54)
    level2.waiting = (7, (50, 54))
    dispatched = level2.step(8, (5, 9), n_map_places=32)
    assert dispatched[0].sequence == (25, 31)  # last rho places of (20, 29), then up to the map end


def test_nothing_to_rebuild_from_is_an_explicit_no_answer() -> None:
    level2 = TemporalConsistency(rho=5, alpha=5)
    level2.step(1, (10, 14), 100)
    dispatched = level2.step(2, (70, 74), 100)
    assert [(d.iteration, d.sequence, d.branch) for d in dispatched] == [(1, None, "unresolved")]


def test_a_sequence_still_waiting_at_the_end_is_rebuilt() -> None:
    level2 = TemporalConsistency(rho=5, alpha=5)
    level2.step(1, (10, 14), 100)
    level2.step(2, (15, 19), 100)
    level2.step(3, (70, 74), 100)  # waits; the traversal then ends
    dispatched = level2.finish(n_map_places=100)
    assert [(d.iteration, d.sequence, d.branch) for d in dispatched] == [(3, (15, 24), "rebuilt")]
    assert level2.finish(100) == []


def test_an_iteration_without_candidates_cannot_validate_the_waiting_one() -> None:
    level2 = TemporalConsistency(rho=5, alpha=5)
    level2.step(1, (10, 14), 100)
    level2.step(2, (15, 19), 100)
    level2.step(3, (70, 74), 100)
    dispatched = level2.step(4, None, 100)
    assert [(d.iteration, d.branch) for d in dispatched] == [(3, "rebuilt")]
    assert level2.previous is None and level2.waiting is None


# --- level 3 ----------------------------------------------------------------------------------


def _map(place_sizes: list[int], dim: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """Map-frame offsets of places with these sizes and one distinct descriptor per map frame."""
    offsets = np.concatenate([[0], np.cumsum(place_sizes)]).astype(np.int64)
    rng = np.random.default_rng(7)
    vectors = rng.random((int(offsets[-1]), dim)).astype(np.float32)
    return offsets, vectors


def test_padding_adds_a_place_on_each_side_until_the_frames_suffice() -> None:
    offsets = np.array([0, 2, 4, 5, 6, 9, 11], dtype=np.int64)  # 6 places of 2, 2, 1, 1, 3, 2 frames
    assert expand_with_padding((2, 3), offsets, needed=2) == (4, 6, 0)
    assert expand_with_padding((2, 3), offsets, needed=6) == (2, 9, 2)  # places 1 and 4 added
    assert expand_with_padding((2, 3), offsets, needed=9) == (0, 11, 4)


def test_padding_at_the_ends_of_the_map_uses_the_existing_side_only() -> None:
    offsets = np.array([0, 2, 4, 5, 6, 9, 11], dtype=np.int64)
    assert expand_with_padding((0, 1), offsets, needed=6) == (0, 6, 2)  # only after: places 2, 3
    assert expand_with_padding((4, 5), offsets, needed=7) == (4, 11, 2)  # only before: places 3, 2


def test_no_answer_when_the_whole_map_is_shorter_than_the_query() -> None:
    offsets, vectors = _map([2, 2])
    query = np.ones((5, 4), dtype=np.float32)
    assert expand_with_padding((0, 1), offsets, needed=5) is None
    result = match_frames(query, np.ones(5, bool), (0, 1), offsets, lambda a, b: vectors[a:b], "l1", None, True)
    assert (result.aligned == -1).all() and "fewer than the 5 frames" in result.reason


def test_template_matching_finds_the_offset_of_eq_3_10() -> None:
    offsets, vectors = _map([3, 3, 3, 3])
    query = vectors[5:9] + 0.01  # frames 5..8 of the map, slightly changed
    result = match_frames(query, np.ones(4, bool), (1, 2), offsets, lambda a, b: vectors[a:b], "l1", None, False)
    # F-bar = map frames 3..8; Q-bar fits at offset 2
    assert result.template_offset == 2 and result.aligned.tolist() == [5, 6, 7, 8]
    assert not result.used_synthetic and result.padded_places == 0
    assert result.mean_distance == pytest.approx(0.04, abs=1e-4)


def test_synthetic_descriptor_sequence_replaces_the_match_when_at_least_as_close() -> None:
    offsets, vectors = _map([3, 3, 3, 3])
    query = vectors[6:9].copy()  # the true continuation of a previous match ending at frame 5
    args = (np.ones(3, bool), (0, 1), offsets, lambda a, b: vectors[a:b], "l1")
    # the place sequence (0, 1) is wrong: template matching alone must pick something in frames 0..5
    alone = match_frames(query, *args, previous_last=5, synthetic=False)
    assert alone.aligned.max() <= 5 and np.isnan(alone.synthetic_cost)
    chosen = match_frames(query, *args, previous_last=5, synthetic=True)
    assert chosen.used_synthetic and chosen.aligned.tolist() == [6, 7, 8]
    assert chosen.synthetic_cost == pytest.approx(0.0) and chosen.cost == pytest.approx(0.0)


def test_synthetic_sequence_is_skipped_when_the_map_ends_first() -> None:
    offsets, vectors = _map([3, 3, 3])
    query = vectors[6:9].copy()
    result = match_frames(query, np.ones(3, bool), (1, 2), offsets, lambda a, b: vectors[a:b], "l1", 7, True)
    assert np.isnan(result.synthetic_cost) and not result.used_synthetic


def test_confidence_distance_leaves_featureless_query_frames_out() -> None:
    offsets, vectors = _map([4, 4])
    query = vectors[0:4].copy()
    query[1] = 0.0  # featureless
    informative = np.array([True, False, True, True])
    result = match_frames(query, informative, (0, 1), offsets, lambda a, b: vectors[a:b], "l1", None, False)
    assert result.aligned.tolist() == [0, 1, 2, 3]
    assert result.mean_distance == pytest.approx(0.0)  # the zero row (distance > 0) is not in v
    assert result.cost > 0
