"""The distinctiveness of an answer (``1 - cost / best alternative cost``) and the faithful
detector's acceptance branch on it (``accept_score: ..._or_distinct``)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from slamfront.acceptance import Acceptance
from slamfront.core.operating_point import distinctiveness, threshold_at_false_accept_rate
from slamfront.messages import LoopResult, Message
from slamfront_plugins.loop_detectors.hierarchical_faithful import FaithfulSequenceDecision, HierarchicalFaithful
from slamfront_plugins.loop_detectors.hierarchical_frames import uniqueness
from slamfront_plugins.place_maps.hierarchical import HierarchicalPlaceMap
from tests.hierarchical_helpers import dusk_like_route, run_stages


def test_distinctiveness_is_one_minus_the_cost_over_the_best_alternative() -> None:
    assert distinctiveness(1.0, [2.0, 4.0]) == pytest.approx(0.5)
    assert distinctiveness(3.0, np.array([4.0, np.nan, 6.0])) == pytest.approx(0.25)  # NaN: no alternative
    assert distinctiveness(0.0, [2.0]) == 1.0  # a perfect fit against a real alternative


def test_distinctiveness_edge_cases() -> None:
    assert distinctiveness(1.0, []) == 0.0  # nothing to tell the answer apart from
    assert distinctiveness(1.0, [np.nan]) == 0.0
    assert distinctiveness(1.0, [0.0]) == 0.0  # the alternative fits perfectly
    assert distinctiveness(2.0, [1.0]) == 0.0  # the alternative fits better: clipped, never negative
    assert distinctiveness(float("nan"), [1.0]) == 0.0
    assert distinctiveness(1.0, [np.inf]) == 1.0  # every alternative infinitely far


def test_the_frame_level_uniqueness_is_the_shared_distinctiveness() -> None:
    costs = np.array([1.0, 1.2, 3.0, 5.0])
    ends = np.array([100, 103, 200, 300])
    # the candidate ending 3 frames away is the same answer; the next one apart costs 3.0
    assert uniqueness(costs, ends, 0, window=5) == pytest.approx(1 - 1.0 / 3.0)
    assert uniqueness(costs, ends, 0, window=500) == 0.0  # every candidate within the window


DISTINCT = {"accept_score": "confidence_or_distinct", "accept_query_null": False}


def test_the_distinct_threshold_is_calibrated_on_the_wrong_decisions_above_a_floor() -> None:
    own = list(np.linspace(0.30, 0.60, 31))  # wrong answers' own confidences
    wrong = [0.0, 0.02, 0.05, 0.11]  # wrong decisions' distinctiveness
    acceptance = Acceptance(HierarchicalFaithful.Config(**DISTINCT, distinct_floor_quantile=0.75), "faithful")
    threshold = acceptance.calibrate_reference(own, own)
    assert threshold > 0.60  # the own threshold is the usual one
    acceptance.calibrate_distinct(wrong, own)
    assert acceptance.distinct_threshold == pytest.approx(threshold_at_false_accept_rate(np.asarray(wrong), 0.01))
    assert acceptance.distinct_threshold > 0.11
    assert acceptance.distinct_floor == pytest.approx(np.quantile(own, 0.75))
    assert acceptance.accepts(0.61)  # its own confidence is enough
    assert acceptance.accepts(0.55, None, 0.2)  # distinct, above the floor (0.525)
    assert not acceptance.accepts(0.50, None, 0.2)  # distinct, but no more confident than most wrong answers
    assert not acceptance.accepts(0.55, None, 0.10)  # as distinct as a wrong decision
    assert not acceptance.accepts(0.55)  # no distinctiveness given
    stats = acceptance.statistics()
    assert stats["accept_threshold_distinct"] == acceptance.distinct_threshold and stats["accept_n_wrong_distinct"] == 4
    # no wrong decision at all: nothing is accepted on it; no floor asked: none
    acceptance = Acceptance(HierarchicalFaithful.Config(**DISTINCT, distinct_floor_quantile=0.0), "faithful")
    acceptance.calibrate_reference(own, own)
    acceptance.calibrate_distinct([], own)
    assert acceptance.distinct_threshold == 1.0 and acceptance.distinct_floor == 0.0
    # the other scores (the default among them) do not take it; a stream turns it off; a fixed accept
    # never has it
    assert not Acceptance(HierarchicalFaithful.Config(), "faithful").distinct
    for score in ("confidence", "confidence_or_supported"):
        assert not Acceptance(HierarchicalFaithful.Config(accept_score=score), "faithful").distinct
    assert Acceptance(HierarchicalFaithful.Config(accept_score="confidence_or_supported_or_distinct"),
                      "faithful").either
    stream = Acceptance(HierarchicalFaithful.Config(**DISTINCT), "faithful")
    stream.stream_answer(0, 0.1)
    assert not stream.distinct
    assert not Acceptance(HierarchicalFaithful.Config(**DISTINCT, accept=0.5), "faithful").distinct


def _dusk_like(amount: float, **params: Any) -> tuple[list[Message], int, HierarchicalFaithful]:
    """The faithful detector on a route seen again under a strong change (``amount``)."""
    vectors, traversals = dusk_like_route(amount)
    place_map = HierarchicalPlaceMap(HierarchicalPlaceMap.Config(similarity_threshold=0.9))
    detector = HierarchicalFaithful(HierarchicalFaithful.Config(accept_query_null=False, **params))
    return run_stages(vectors, traversals, place_map, detector), 300, detector


def test_the_distinct_branch_accepts_more_of_a_changed_revisit_and_keeps_the_confidences() -> None:
    own, n, own_detector = _dusk_like(0.8, accept_score="confidence")
    out, _, detector = _dusk_like(0.8, accept_score="confidence_or_distinct")

    def answers(msgs: list[Message]) -> dict[int, LoopResult]:
        return {m.frame: m for m in msgs if isinstance(m, LoopResult) and m.frame >= n}

    plain, either = answers(own), answers(out)
    accepted = [r for r in either.values() if r.accepted]
    assert sum(r.accepted for r in plain.values()) < len(accepted)  # more of the revisit accepted
    assert np.mean([abs(r.match - (r.frame - n)) <= 3 for r in accepted]) >= 0.95
    assert all(either[f].accepted for f, r in plain.items() if r.accepted)  # never fewer
    assert all(either[f].confidence == r.confidence for f, r in plain.items())  # the answers keep 1 - v/2
    decisions = [m for m in out if isinstance(m, FaithfulSequenceDecision) and m.first >= 0]
    assert decisions and all(0.0 <= m.distinctiveness <= 1.0 for m in decisions)
    assert all(np.isnan(m.distinctiveness) for m in own if isinstance(m, FaithfulSequenceDecision))
    stats = detector.statistics()
    assert 0 < stats["accept_threshold_distinct"] < 1 and stats["accept_n_wrong_distinct"] > 0
    # the alternatives' level-3 matches are counted: in the queries' distances and the calibration's
    assert stats["n_distances_distinct"] > 0
    plain_stats = own_detector.statistics()
    assert stats["n_distances_sequences"] - plain_stats["n_distances_sequences"] == stats["n_distances_distinct"]
    assert stats["n_distances_calibration"] > plain_stats["n_distances_calibration"]
