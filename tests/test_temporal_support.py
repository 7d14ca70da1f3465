"""The temporally supported confidence (slamfront.core.temporal_support) and the nearest-neighbour
detector's operating point on it."""

from __future__ import annotations

import numpy as np
import pytest

from slamfront.acceptance import AcceptThreshold
from slamfront.core.errors import CoreError
from slamfront.core.temporal_support import (
    SupportTracker,
    contiguous_self_queries,
    support_of_last,
    supported_confidence,
)
from slamfront.messages import LoopResult
from slamfront_plugins.loop_detectors.nearest_neighbour import NearestNeighbour
from tests.test_operating_point import _dusk_like, _feed_global


def test_answers_on_one_line_support_each_other_in_either_direction() -> None:
    frames = np.arange(10)
    confidence = np.linspace(0.9, 0.1, 10)
    forwards = supported_confidence(frames, 100 + frames, confidence, answers=6, agree=3, tolerance=1)
    backwards = supported_confidence(frames, 100 - frames, confidence, answers=6, agree=3, tolerance=1)
    assert np.array_equal(forwards, backwards)
    assert forwards[0] == forwards[1] == 0  # fewer than 3 answers yet: a revisit's first frames wait
    # from then on: the 3rd largest of the (up to 6) agreeing answers, this one included
    assert forwards[2] == pytest.approx(confidence[2])
    assert forwards[9] == pytest.approx(np.sort(confidence[4:10])[::-1][2])


def test_a_confident_answer_off_the_line_has_no_support() -> None:
    frames = np.arange(8)
    matches = 50 + frames
    matches[5] = 400  # confident and alone
    confidence = np.full(8, 0.2)
    confidence[5] = 0.99
    s = supported_confidence(frames, matches, confidence, answers=8, agree=4, tolerance=1)
    assert s[5] == 0 and s[4] == pytest.approx(0.2) and s[7] == pytest.approx(0.2)


def test_support_is_causal_and_the_tracker_agrees_with_the_array_function() -> None:
    rng = np.random.default_rng(1)
    frames = np.arange(60)
    matches = np.where(rng.random(60) < 0.7, 200 + frames + rng.integers(-1, 2, 60), rng.integers(0, 500, 60))
    matches[7] = -1  # no answer: supports nothing
    confidence = rng.random(60)
    full = supported_confidence(frames, matches, confidence, 20, 10, 1.0)
    head = supported_confidence(frames[:40], matches[:40], confidence[:40], 20, 10, 1.0)
    assert np.array_equal(full[:40], head)  # later answers never change an earlier one's support
    tracker = SupportTracker(20, 10, 1.0)
    online = [tracker.update(int(f), int(m), float(c)) for f, m, c in zip(frames, matches, confidence, strict=True)]
    assert np.allclose(online, full) and full[7] == 0


def test_bad_support_settings_fail_clearly() -> None:
    with pytest.raises(CoreError):
        support_of_last(np.arange(3), np.arange(3), np.ones(3), answers=2, agree=3, tolerance=1)
    with pytest.raises(ValueError):
        NearestNeighbour.Config(support_answers=4, support_agree=6)


def test_contiguous_self_queries_keep_stretches_of_consecutive_frames() -> None:
    assert np.array_equal(contiguous_self_queries(300, 30, 500), np.arange(300))
    picked = contiguous_self_queries(3000, 50, 500, run=50)
    assert len(picked) == 500 and picked[0] == 0 and picked[-1] == 2999
    assert np.count_nonzero(np.diff(picked) == 1) == 490  # ten stretches of 50
    assert len(contiguous_self_queries(20, 30, 500)) == 0


def _accepted(out: list, n: int) -> list[LoopResult]:
    return [m for m in out if isinstance(m, LoopResult) and m.frame >= n and m.accepted]


@pytest.mark.parametrize("amount", [0.5, 0.6])
def test_support_accepts_more_right_answers_at_dusk_and_keeps_them_right(amount: float) -> None:
    """A dusk-like route (every query answer less confident than the reference's wrong ones):
    the supported confidence, calibrated the same way on the reference, accepts more right
    answers than the answers' own confidence does, with or without the queries' null."""
    out, n = _dusk_like("nearest_neighbour", amount)
    accepted = _accepted(out, n)
    right = sum(abs(r.match - (r.frame - n)) <= 3 for r in accepted)
    assert right >= 0.95 * len(accepted)
    thresholds = [m for m in out if isinstance(m, AcceptThreshold)]
    assert [m.source for m in thresholds] == ["reference"]  # calibrated once, on the reference
    for own in ({"accept_score": "confidence"}, {"accept_score": "confidence", "accept_query_null": True}):
        plain, _ = _dusk_like("nearest_neighbour", amount, **own)
        assert right > sum(abs(r.match - (r.frame - n)) <= 3 for r in _accepted(plain, n)) + 20
    # the answers' confidence (what R@100%P and AUC rank) is the same either way
    assert [m.confidence for m in out if isinstance(m, LoopResult)] == \
        [m.confidence for m in plain if isinstance(m, LoopResult)]


def _with_an_impostor(**params: object) -> tuple[list, int, int]:
    """Queries from elsewhere (unrelated to the reference) but one: an exact copy of reference
    frame 40 (its answer is confident and wrong for the route the queries drive)."""
    rng = np.random.default_rng(3)
    reference = rng.random((150, 32)).astype(np.float32)
    query = rng.random((150, 32)).astype(np.float32)
    query[90] = reference[40]
    vectors = np.concatenate([reference, query])
    traversals = ["reference"] * 150 + ["query"] * 150
    return _feed_global(NearestNeighbour(NearestNeighbour.Config(**params)), vectors, traversals, "l2"), 150, 240


def test_a_confident_isolated_answer_is_not_accepted() -> None:
    out, n, impostor = _with_an_impostor()
    answer = next(m for m in out if isinstance(m, LoopResult) and m.frame == impostor)
    assert answer.match == 40 and answer.confidence > 0.9
    assert not answer.accepted and not _accepted(out, n)
    # on its own confidence it would have been accepted
    plain, _, _ = _with_an_impostor(accept_score="confidence")
    assert next(m for m in plain if isinstance(m, LoopResult) and m.frame == impostor).accepted


def test_a_fixed_accept_compares_the_answers_own_confidence() -> None:
    out, n = _dusk_like("nearest_neighbour", 0.6, accept=0.05)
    results = [m for m in out if isinstance(m, LoopResult) and m.frame >= n and m.match >= 0]
    assert [(m.source, m.threshold) for m in out if isinstance(m, AcceptThreshold)] == [("given", 0.05)]
    assert all(r.accepted == (r.confidence >= 0.05) for r in results)
    assert NearestNeighbour(NearestNeighbour.Config(accept=0.05)).statistics()["accept_on_supported_confidence"] == 0
    assert NearestNeighbour().statistics()["accept_on_supported_confidence"] == 1


def test_the_headline_says_a_threshold_just_above_zero_plainly() -> None:
    from slamfront.report.headline import headline

    metrics = {"recall_at_100p": 0.2, "auc_pr": 0.5, "precision_at_operating_point": 1.0,
               "recall_at_operating_point": 0.4, "accept_threshold": 5e-324, "accept_auto": 1, "n_accepted": 3,
               "accept_on_supported_confidence": 1}
    assert "(supported confidence > 0, calibrated)" in headline(metrics)[0]
