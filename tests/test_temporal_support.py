"""The temporally supported confidence (slamfront.core.temporal_support) and the operating point
on it of the nearest-neighbour detector (per frame) and of the faithful hierarchical detector
(per sequence decision, opt-in; rebuilt decisions lend support only when level 1 found them)."""

from __future__ import annotations

import numpy as np
import pytest

from slamfront.acceptance import Acceptance, AcceptThreshold
from slamfront.core.errors import CoreError
from slamfront.core.operating_point import threshold_at_false_accept_rate, travelled
from slamfront.core.temporal_support import (
    SupportTracker,
    contiguous_self_queries,
    support_of_last,
    supported_confidence,
)
from slamfront.messages import LoopResult
from slamfront_plugins.loop_detectors.hierarchical_faithful import FaithfulSequenceDecision, HierarchicalFaithful
from slamfront_plugins.loop_detectors.nearest_neighbour import NearestNeighbour
from slamfront_plugins.place_maps.hierarchical import HierarchicalPlaceMap
from tests.hierarchical_helpers import noisy, run_stages
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


def test_travelled_counts_a_slow_or_still_step_as_a_fraction_of_a_frame() -> None:
    steps = np.array([2.0, 2.0, 0.5, 0.0, 2.0, 8.0, np.nan])  # median 2: typical, a crawl, a stop, a jump, unknown
    assert travelled(steps) == pytest.approx([0, 1, 2, 2.25, 2.25, 3.25, 4.25, 5.25])
    assert travelled(np.zeros(3)) == pytest.approx([0, 1, 2, 3])  # no typical step: every step is a frame
    assert travelled(np.array([])) == pytest.approx([0])


def _crawling_reference(amount: float, **params: object) -> tuple[list, int]:
    """A route whose reference crawls through one place for 120 frames (a train at a station:
    each frame still differs from the last by noise, so it is not a stop), seen again under a
    change (``amount``)."""
    rng = np.random.default_rng(0)
    speed = np.full(400, 0.5)
    speed[150:270] = 0.01
    x = np.cumsum(speed)
    k = np.floor(x).astype(int)
    a = (x - k)[:, None]
    bases = rng.random((k.max() + 2, 32)) ** 4
    frames = (1 - a) * bases[k] + a * bases[k + 1] + rng.random((400, 32)) * 0.1
    reference = (frames / frames.sum(axis=1, keepdims=True)).astype(np.float32)
    vectors = np.concatenate([reference, noisy(reference, amount, seed=4)])
    detector = NearestNeighbour(NearestNeighbour.Config(**params))
    return _feed_global(detector, vectors, ["reference"] * 400 + ["query"] * 400, "l2"), 400


def test_a_reference_crawling_through_one_place_does_not_count_its_own_revisits_as_wrong() -> None:
    """The exclusion window measured along the reference's pace (``accept_exclusion_pace``): frames
    of the crawl more than 40 frames apart are one place, and counted as wrong answers they set
    the threshold above what right answers under a change reach."""
    out, n = _crawling_reference(0.6)
    frame_window, _ = _crawling_reference(0.6, accept_exclusion_pace=False)
    paced = next(m for m in out if isinstance(m, AcceptThreshold))
    framed = next(m for m in frame_window if isinstance(m, AcceptThreshold))
    assert framed.threshold > 0.1 and paced.threshold < 0.01
    accepted, accepted_framed = _accepted(out, n), _accepted(frame_window, n)
    assert all(abs(r.match - (r.frame - n)) <= 3 for r in accepted)
    assert len(accepted) > len(accepted_framed) + 30


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
    either = {**metrics, "accept_threshold": 0.62, "accept_threshold_supported": 0.6}
    assert "(confidence >= 0.62 or supported confidence >= 0.6, calibrated)" in headline(either)[0]


# --- the faithful detector: support counted in sequence decisions (opt-in) ------------------

SUPPORTED = {"accept_score": "supported_confidence", "accept_query_null": False}
OWN = {"accept_score": "confidence", "accept_query_null": False}


def test_an_answer_that_may_not_supply_support_is_supported_but_supports_nothing() -> None:
    """A chain: one decision found by the search, then decisions placed by continuing it (on its
    line by construction). Lending support only from found ones, the chain is supported while two
    found decisions are in the window, and no longer by itself."""
    frames = np.arange(0, 96, 12)
    matches = 300 + frames
    confidence = np.full(len(frames), 0.7)
    supplies = np.array([True, True, False, False, False, False, False, False])
    every = supported_confidence(frames, matches, confidence, answers=5, agree=3, tolerance=2, per_step=True)
    found = supported_confidence(frames, matches, confidence, answers=5, agree=3, tolerance=2, per_step=True,
                                 supplies=supplies)
    assert list(every[2:]) == pytest.approx([0.7] * 6)  # the chain supports itself
    assert list(found[2:]) == pytest.approx([0.7, 0.7, 0.7, 0, 0, 0])  # until both found ones are 5 steps back
    assert found[0] == found[1] == 0
    tracker = SupportTracker(5, 3, 2, per_step=True)
    assert [tracker.update(int(f), int(m), float(c), bool(s)) for f, m, c, s in
            zip(frames, matches, confidence, supplies)] == pytest.approx(list(found))


def test_decisions_count_as_steps_not_frames() -> None:
    """Sequence decisions ~12 query frames apart: per decision, 3 of the last 5 on one line
    support each other; per frame, a 5-frame window would never reach the decision before."""
    frames = np.arange(0, 96, 12)
    matches = 300 + frames
    confidence = np.full(len(frames), 0.7)
    matches[5], confidence[5] = 40, 1.0  # one confident decision elsewhere
    per_decision = supported_confidence(frames, matches, confidence, answers=5, agree=3, tolerance=2, per_step=True)
    assert list(per_decision[:2]) == [0, 0]  # a revisit's first two decisions wait
    assert per_decision[2] == per_decision[3] == per_decision[4] == pytest.approx(0.7)
    assert per_decision[5] == 0  # confident, but nothing continues it
    assert per_decision[6] == per_decision[7] == pytest.approx(0.7)  # 3 of the last 5 still on the line
    assert not supported_confidence(frames, matches, confidence, answers=5, agree=3, tolerance=2).any()
    tracker = SupportTracker(5, 3, 2, per_step=True)
    assert [tracker.update(int(f), int(m), float(c)) for f, m, c in zip(frames, matches, confidence)] == \
        pytest.approx(list(per_decision))


def test_faithful_supported_decisions_are_accepted_at_dusk_and_are_right() -> None:
    out, n = _dusk_like("hierarchical_faithful", 0.6, **SUPPORTED)
    accepted = _accepted(out, n)
    assert len(accepted) >= 200
    assert sum(abs(r.match - (r.frame - n)) <= 3 for r in accepted) >= 0.95 * len(accepted)
    assert [m.source for m in out if isinstance(m, AcceptThreshold)] == ["reference"]
    # one score per decision: a decision's answered frames are accepted together
    for d in (m for m in out if isinstance(m, FaithfulSequenceDecision) and m.query_frames[0] >= n):
        flags = {r.accepted for r in out if isinstance(r, LoopResult) and r.frame in set(d.query_frames.tolist())
                 and r.match >= 0}
        assert len(flags) <= 1
    # the answers' confidence (what R@100%P and AUC rank) is the one of the answers' own operating point
    plain, _ = _dusk_like("hierarchical_faithful", 0.6, **OWN)
    assert [m.confidence for m in out if isinstance(m, LoopResult)] == \
        [m.confidence for m in plain if isinstance(m, LoopResult)]


def _with_a_copied_stretch(**params: object) -> tuple[list, int]:
    """A dusk-like route whose query frames 100-119 are exact copies of reference frames 220-239:
    two confident (1 - v/2 = 1) decisions that nothing before them continues."""
    rng = np.random.default_rng(0)
    frames = np.repeat(rng.random((150, 32)), 2, axis=0) + rng.random((300, 32)) * 0.002
    reference = (frames / frames.sum(axis=1, keepdims=True)).astype(np.float32)
    query = noisy(reference, 0.6, seed=4)
    query[100:120] = reference[220:240]
    vectors = np.concatenate([reference, query])
    place_map = HierarchicalPlaceMap(HierarchicalPlaceMap.Config(similarity_threshold=0.9))
    detector = HierarchicalFaithful(HierarchicalFaithful.Config(**params))
    return run_stages(vectors, ["reference"] * 300 + ["query"] * 300, place_map, detector), 300


def test_faithful_isolated_confident_wrong_decisions_are_not_accepted() -> None:
    out, n = _with_a_copied_stretch(**SUPPORTED)
    copied = [m for m in out if isinstance(m, LoopResult) and 100 <= m.frame - n < 120]
    assert all(m.match >= 200 and m.confidence > 0.99 for m in copied)  # confident and wrong
    assert not any(m.accepted for m in copied)
    assert all(abs(r.match - (r.frame - n)) <= 3 for r in _accepted(out, n))
    # on its own confidence they are accepted
    plain, _ = _with_a_copied_stretch(**OWN)
    assert all(m.accepted for m in plain if isinstance(m, LoopResult) and 100 <= m.frame - n < 120)


def test_faithful_fixed_accept_compares_the_answers_own_confidence() -> None:
    out, n = _dusk_like("hierarchical_faithful", 0.6, accept=0.7, **SUPPORTED)
    results = [m for m in out if isinstance(m, LoopResult) and m.frame >= n and m.match >= 0]
    assert [(m.source, m.threshold) for m in out if isinstance(m, AcceptThreshold)] == [("given", 0.7)]
    assert results and all(r.accepted == (r.confidence >= 0.7) for r in results)
    assert HierarchicalFaithful(HierarchicalFaithful.Config(accept=0.7, **SUPPORTED)).statistics()[
        "accept_on_supported_confidence"] == 0
    # the default: the own confidence, or the supported one above its floor (both thresholds calibrated)
    assert HierarchicalFaithful.Config().accept_score == "confidence_or_supported"
    # ... calibrated over passes until ten wrong decisions, an outlying largest one discounted
    assert (HierarchicalFaithful.Config().accept_calibration_decisions, HierarchicalFaithful.Config().accept_discount_outlier) \
        == (10, True)
    default = HierarchicalFaithful().statistics()
    assert default["accept_on_supported_confidence"] == 1 and "accept_threshold_supported" in default
    assert HierarchicalFaithful(HierarchicalFaithful.Config(**OWN)).statistics()["accept_on_supported_confidence"] == 0
    assert HierarchicalFaithful(HierarchicalFaithful.Config(**SUPPORTED)).statistics()[
        "accept_on_supported_confidence"] == 1


def test_faithful_rebuilt_decisions_lend_support_only_when_level_1_found_them() -> None:
    """rebuilt_support: level1 (the default): a rebuilt decision lends support only when one of
    level 1's candidate sequences ends within alpha places of its end; other decisions always do.
    It changes which answers are accepted, never their confidence."""
    detectors = {}
    outs = {}
    for mode in ("level1", "always"):
        rng = np.random.default_rng(0)
        frames = np.repeat(rng.random((150, 32)), 2, axis=0) + rng.random((300, 32)) * 0.002
        reference = (frames / frames.sum(axis=1, keepdims=True)).astype(np.float32)
        vectors = np.concatenate([reference, noisy(reference, 0.6, seed=4)])
        place_map = HierarchicalPlaceMap(HierarchicalPlaceMap.Config(similarity_threshold=0.9))
        detectors[mode] = HierarchicalFaithful(HierarchicalFaithful.Config(rebuilt_support=mode, **SUPPORTED))
        outs[mode] = run_stages(vectors, ["reference"] * 300 + ["query"] * 300, place_map, detectors[mode])
    decisions = [m for m in outs["level1"] if isinstance(m, FaithfulSequenceDecision) and m.query_frames[0] >= 300]
    answered = [d for d in decisions if d.first >= 0 and not d.reason]
    lends = [point[3] for point in detectors["level1"]._points if point[1] >= 0]
    assert len(lends) == len(answered) and any(d.branch == "rebuilt" for d in answered)
    alpha = HierarchicalFaithful.Config().alpha
    expected = [d.branch != "rebuilt" or bool(np.any(np.abs(d.candidates[:, 1] - d.last) < alpha)) for d in answered]
    assert lends == expected
    assert not all(expected)  # some rebuilt decision was placed by continuation alone
    assert all(point[3] for point in detectors["always"]._points if point[1] >= 0)
    assert [m.confidence for m in outs["level1"] if isinstance(m, LoopResult)] == \
        [m.confidence for m in outs["always"] if isinstance(m, LoopResult)]


# --- the faithful detector: own confidence or floored support; calibration passes ------------

EITHER = {"accept_score": "confidence_or_supported", "accept_query_null": False}


def test_either_accepts_on_the_own_confidence_or_on_support_above_the_floor() -> None:
    """confidence_or_supported: the own confidence at the usual threshold, or the supported one at
    its calibrated threshold, never below support_floor_quantile of the wrong own confidences."""
    own = np.linspace(0.30, 0.60, 31)  # wrong answers' own confidences; 0.60 is the largest
    acceptance = Acceptance(HierarchicalFaithful.Config(**EITHER, support_floor_quantile=0.75), "faithful")
    threshold = acceptance.calibrate_reference(list(own), [0.0] * len(own))  # no wrong answer had support
    assert threshold == pytest.approx(0.60) and threshold > 0.60
    assert acceptance.support_threshold == pytest.approx(np.quantile(own, 0.75))  # the floor, not just above 0
    assert acceptance.accepts(0.61, 0.0)  # confident enough on its own
    assert acceptance.accepts(0.55, 0.54)  # supported above the floor (0.525)
    assert not acceptance.accepts(0.55, 0.50)  # supported, but by answers no more confident than wrong ones
    assert not acceptance.accepts(0.55)  # no supported confidence given: the own one alone
    # a wrong answer that was supported lifts the supported threshold above the floor
    scored = [0.0] * (len(own) - 1) + [0.58]
    acceptance = Acceptance(HierarchicalFaithful.Config(**EITHER, false_accept_rate=0.0), "faithful")
    acceptance.calibrate_reference(list(own), scored)
    assert acceptance.support_threshold > 0.58
    assert acceptance.statistics()["accept_threshold_supported"] == acceptance.support_threshold
    # one score alone: calibrated on what it thresholds (on the own confidence, score() is it)
    for score, values in (("supported_confidence", scored), ("confidence", list(own))):
        acceptance = Acceptance(HierarchicalFaithful.Config(accept_score=score), "faithful")
        assert acceptance.calibrate_reference(list(own), values) == pytest.approx(
            threshold_at_false_accept_rate(np.asarray(values), 0.01))
        assert acceptance.support_threshold is None and "accept_threshold_supported" not in acceptance.statistics()


def test_faithful_either_accepts_what_either_score_accepts_and_keeps_the_confidences() -> None:
    """A strong change (amount 0.8): the own confidence accepts some of the revisit, the
    supported confidence above the floor adds more, all right; nothing else moves."""
    out, n = _dusk_like("hierarchical_faithful", 0.8, **EITHER)
    own, _ = _dusk_like("hierarchical_faithful", 0.8, **OWN)
    supported, _ = _dusk_like("hierarchical_faithful", 0.8, **SUPPORTED)
    either, plain = _accepted(out, n), _accepted(own, n)
    assert {r.frame for r in plain} < {r.frame for r in either}  # more than on the own confidence alone
    assert sum(abs(r.match - (r.frame - n)) <= 3 for r in either) >= 0.95 * len(either)
    assert [m.confidence for m in out if isinstance(m, LoopResult)] == \
        [m.confidence for m in own if isinstance(m, LoopResult)] == \
        [m.confidence for m in supported if isinstance(m, LoopResult)]
    [logged] = [m for m in out if isinstance(m, AcceptThreshold)]
    [own_logged] = [m for m in own if isinstance(m, AcceptThreshold)]
    assert logged.threshold == own_logged.threshold  # the own confidence's threshold is unchanged


def test_a_calibration_pass_that_sees_no_wrong_answer_is_followed_by_one_a_place_later(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Every query sequence of a pass can come out unresolved (no answer at all): the next pass
    starts one place later, a different phase of the rho-place grid, up to
    accept_calibration_passes; a pass that sees wrong answers is the last."""
    starts: list[int] = []
    real = HierarchicalFaithful._reference_pass

    def first_sees_nothing(self: HierarchicalFaithful, frames: list[int], start: int, window: int) -> tuple:
        starts.append(start)
        copy, out = real(self, frames, start, window)
        return copy, (out if len(starts) > 1 else [])

    monkeypatch.setattr(HierarchicalFaithful, "_reference_pass", first_sees_nothing)
    out, _ = _dusk_like("hierarchical_faithful", 0.6, **OWN)
    [threshold] = [m for m in out if isinstance(m, AcceptThreshold)]
    assert len(starts) == 2 and threshold.n_wrong > 0 and threshold.threshold < 1
    starts.clear()
    out, _ = _dusk_like("hierarchical_faithful", 0.6, **OWN, accept_calibration_passes=1)
    [threshold] = [m for m in out if isinstance(m, AcceptThreshold)]
    assert len(starts) == 1 and threshold.n_wrong == 0 and threshold.threshold == 1
    monkeypatch.setattr(HierarchicalFaithful, "_reference_pass", real)
    detector = HierarchicalFaithful()
    place_map = HierarchicalPlaceMap(HierarchicalPlaceMap.Config(similarity_threshold=0.9))
    run_stages(np.concatenate([np.eye(40, 32, dtype=np.float32)[np.arange(40) % 32] + 0.01] * 2),
               ["reference"] * 40 + ["query"] * 40, place_map, detector)
    offsets = detector.place_map.place_offsets()
    passes = detector._calibration_starts(int(offsets[-1]), 5)
    assert passes[0] == 5 and len(passes) == 5 and all(p in offsets for p in passes[1:])
    assert passes == sorted(set(passes))


# --- the faithful detector: an outlying largest wrong decision is discounted -------------------


def test_the_own_threshold_discounts_an_outlying_wrong_decision_only_when_given_decisions() -> None:
    decisions = [0.60, 0.61, 0.62, 0.63, 0.80]
    own = [c for c in decisions for _ in range(8)]  # a decision is several frames
    for score in ("confidence", "confidence_or_supported"):
        acceptance = Acceptance(HierarchicalFaithful.Config(accept_score=score), "faithful")
        scored = own if score == "confidence" else [0.0] * len(own)  # on the own confidence, score() is it
        threshold = acceptance.calibrate_reference(own, scored, decisions)
        assert threshold == pytest.approx(0.6545, abs=2e-4) and acceptance.reference_threshold == threshold
        assert acceptance.statistics()["accept_threshold_undiscounted"] > 0.80
        [logged] = acceptance.messages()
        assert logged.threshold == threshold and logged.largest_wrong == 0.80
        assert acceptance.accepts(0.66) and not acceptance.accepts(0.65)
    plain = Acceptance(HierarchicalFaithful.Config(accept_score="confidence"), "faithful")
    assert plain.calibrate_reference(own, own) > 0.80 and "accept_threshold_undiscounted" not in plain.statistics()
    # on the supported confidence alone the decisions' own confidences are not what it thresholds
    supported = Acceptance(HierarchicalFaithful.Config(accept_score="supported_confidence"), "faithful")
    assert supported.calibrate_reference(own, own, decisions) > 0.80


def test_faithful_hands_over_one_confidence_per_wrong_decision(monkeypatch: pytest.MonkeyPatch) -> None:
    seen: list[tuple[list[float], list[float] | None]] = []
    real = Acceptance.calibrate_reference

    def spy(self: Acceptance, own: list[float], scored: list[float], decisions: list[float] | None = None) -> float:
        seen.append((list(own), decisions))
        return real(self, own, scored, decisions)

    monkeypatch.setattr(Acceptance, "calibrate_reference", spy)
    out, _ = _dusk_like("hierarchical_faithful", 0.6, **OWN, accept_discount_outlier=True)
    off, _ = _dusk_like("hierarchical_faithful", 0.6, **OWN, accept_discount_outlier=False)
    (own, decisions), (own_off, none) = seen
    assert none is None and own == own_off and decisions is not None
    # every wrong frame's confidence is its decision's, and fewer decisions than frames
    assert set(decisions) == set(own) and len(own) > len(decisions) >= 3
    [on_logged] = [m for m in out if isinstance(m, AcceptThreshold)]
    [off_logged] = [m for m in off if isinstance(m, AcceptThreshold)]
    assert on_logged.threshold <= off_logged.threshold
    assert [m.confidence for m in out if isinstance(m, LoopResult)] == \
        [m.confidence for m in off if isinstance(m, LoopResult)]


# --- the faithful detector: the calibration goes on until it has seen enough wrong decisions ---


def test_calibration_passes_go_on_until_they_have_seen_enough_wrong_decisions(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """accept_calibration_decisions K: passes (other phases of the query-sequence grid) run until
    the wrong decisions seen reach K, or accept_calibration_passes ran; every pass's wrong
    decisions are handed over, the first pass's first; the statistics say how many."""
    starts: list[int] = []
    detectors: list[HierarchicalFaithful] = []
    handed: list[list[float]] = []
    real_pass, real_calibrate = HierarchicalFaithful._reference_pass, Acceptance.calibrate_reference

    def counting(self: HierarchicalFaithful, frames: list[int], start: int, window: int) -> tuple:
        starts.append(start)
        detectors.append(self)
        return real_pass(self, frames, start, window)

    def spy(self: Acceptance, own: list[float], scored: list[float], decisions: list[float] | None = None) -> float:
        handed.append(list(decisions or []))
        return real_calibrate(self, own, scored, decisions)

    monkeypatch.setattr(HierarchicalFaithful, "_reference_pass", counting)
    monkeypatch.setattr(Acceptance, "calibrate_reference", spy)

    def run(k: int) -> tuple[int, list[float], dict]:
        starts.clear(), detectors.clear(), handed.clear()
        # the outlier discount on: the wrong decisions are handed over
        out, _ = _dusk_like("hierarchical_faithful", 0.6, **OWN, accept_calibration_decisions=k,
                            accept_discount_outlier=True)
        stats = detectors[0].statistics()
        assert [m for m in out if isinstance(m, AcceptThreshold)]
        return len(starts), handed[0], stats

    one, first, stats = run(1)  # until any wrong answer: the first pass sees some
    assert one == 1 and len(first) >= 3
    assert stats["accept_calibration_passes_run"] == 1 and stats["accept_n_wrong_decisions"] == len(first)
    every, seen, stats = run(10**6)  # never enough: every pass runs
    assert every == HierarchicalFaithful.Config().accept_calibration_passes
    assert seen[: len(first)] == first and len(seen) > len(first)
    assert stats["accept_calibration_passes_run"] == every and stats["accept_n_wrong_decisions"] == len(seen)
    # one more than the first pass saw: the pass that brings it there is the last
    passes, enough, _ = run(len(first) + 1)
    assert 2 <= passes < every and len(enough) >= len(first) + 1
    assert enough == seen[: len(enough)]
