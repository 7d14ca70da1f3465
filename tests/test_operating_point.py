"""accept: auto: every loop detector calibrates its acceptance threshold from wrong answers it
has seen (the reference against itself, or a stream's first frames), logs it, and never
reads the queries to do so."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from slamfront.acceptance import Acceptance, AcceptanceConfig, AcceptThreshold
from slamfront.core.operating_point import (
    outlier_discounted_threshold,
    query_null_threshold,
    query_shift_threshold,
    threshold_at_false_accept_rate,
)
from slamfront.core.temporal_support import supported_confidence
from slamfront.frame import Frame
from slamfront.messages import Features, LoopResult, Message
from slamfront.plugin import StageInputs
from slamfront_plugins.loop_detectors.bow_bayes import BowBayes
from slamfront_plugins.loop_detectors.hierarchical_faithful import HierarchicalFaithful
from slamfront_plugins.loop_detectors.hierarchical_sequence import HierarchicalSequence
from slamfront_plugins.loop_detectors.nearest_neighbour import NearestNeighbour
from slamfront_plugins.loop_detectors.seqslam import SeqSlam, SeqSlamFast
from slamfront_plugins.place_maps.hierarchical import HierarchicalPlaceMap
from tests.hierarchical_helpers import dusk_like_route, noisy, route_descriptors, run_stages

# --- the rule -----------------------------------------------------------------------------


def test_the_threshold_lets_through_at_most_the_rate_of_wrong_answers() -> None:
    wrong = np.random.default_rng(0).random(1000)
    for rate in (0.0, 0.01, 0.1):
        t = threshold_at_false_accept_rate(wrong, rate)
        assert np.mean(wrong >= t) <= rate
        assert np.mean(wrong >= np.nextafter(t, -np.inf) - 1e-3) > rate or rate == 0.0
    assert threshold_at_false_accept_rate(wrong, 0.0) > wrong.max()
    assert threshold_at_false_accept_rate(np.array([]), 0.01) == 1.0  # nothing seen: accept nothing
    assert threshold_at_false_accept_rate(np.array([0.2, np.nan]), 0.01) == pytest.approx(0.2)


def _discounted_reference(threshold: float, decisions: np.ndarray, rate: float) -> float:
    """outlier_discounted_threshold written out again: a normal fitted by median and MAD."""
    from scipy.stats import norm

    d = np.sort(decisions)
    med = np.median(d)
    spread = 1.4826 * np.median(np.abs(d - med))
    fitted = med + norm.ppf(1 - rate) * spread
    if len(d) < 3 or spread == 0 or d[-1] <= fitted:
        return threshold
    return min(threshold, max(np.nextafter(d[-2], 1.0), fitted))


def test_an_outlying_largest_wrong_decision_is_discounted_down_to_the_fit_or_the_next_one() -> None:
    rate = 0.01
    # by hand: median 0.62, MAD 0.01, fit 0.62 + 2.3263 x 0.014826 = 0.6545 < 0.80
    decisions = [0.60, 0.61, 0.62, 0.63, 0.80]
    threshold = threshold_at_false_accept_rate(np.asarray(decisions), rate)
    assert threshold > 0.80
    assert outlier_discounted_threshold(threshold, decisions, rate) == pytest.approx(0.6545, abs=2e-4)
    # the largest is no outlier: unchanged
    assert outlier_discounted_threshold(0.6401, [0.60, 0.61, 0.62, 0.63, 0.64], rate) == 0.6401
    # the fit falls below the second-largest: only one decision is discounted
    two_high = [0.60, 0.60, 0.61, 0.70, 0.90]
    assert outlier_discounted_threshold(0.9001, two_high, rate) == np.nextafter(0.70, 1.0)
    # never above the threshold given; too few decisions or no spread: unchanged
    assert outlier_discounted_threshold(0.5, decisions, rate) == 0.5
    assert outlier_discounted_threshold(0.9001, [0.6, 0.9], rate) == 0.9001
    assert outlier_discounted_threshold(0.9001, [0.6, 0.6, 0.6, 0.9], rate) == 0.9001
    assert outlier_discounted_threshold(0.9001, [0.6, 0.62, np.nan, 0.9, 0.61], rate) == pytest.approx(
        _discounted_reference(0.9001, np.array([0.6, 0.62, 0.9, 0.61]), rate))
    rng = np.random.default_rng(3)
    for n in (3, 5, 27):
        for _ in range(50):
            d = rng.normal(0.6, 0.02, n)
            d[rng.integers(n)] += rng.choice([0.0, 0.1])
            t = threshold_at_false_accept_rate(d, rate)
            got = outlier_discounted_threshold(t, d, rate)
            assert got == pytest.approx(_discounted_reference(t, d, rate), abs=1e-12)
            assert np.sort(d)[-2] < got <= t


def test_the_queries_null_only_lowers_the_threshold_to_its_own_quantile() -> None:
    rng = np.random.default_rng(1)
    null = rng.random(500) * 0.2
    assert query_null_threshold(0.5, null, 0.01) == threshold_at_false_accept_rate(null, 0.01) < 0.2
    assert query_null_threshold(0.1, null, 0.01) == 0.1  # never above the reference's
    acceptance = Acceptance(AcceptanceConfig(accept_query_null_frames=50), "d")
    acceptance.calibrate([0.4, 0.5], "reference")
    threshold = acceptance.threshold
    acceptance.query_null(0.05, frames=49)
    assert acceptance.threshold == threshold  # not enough query frames yet
    acceptance.query_null(0.1, frames=1)
    assert acceptance.threshold == pytest.approx(0.1) and acceptance.accepts(0.11) and not acceptance.accepts(0.09)
    logged = acceptance.messages()
    assert [m.source for m in logged] == ["reference", "queries"] and logged[1].n_wrong == 50
    assert acceptance.statistics()["accept_threshold_reference"] == threshold
    for config in (AcceptanceConfig(accept=0.3), AcceptanceConfig(accept_query_null=False)):  # fixed, or off
        fixed = Acceptance(config, "d")
        fixed.calibrate([0.4], "reference") if config.accept == "auto" else None
        before = fixed.threshold
        fixed.query_null(0.0, frames=1000)
        assert fixed.threshold == before and not fixed.wants_query_null


def test_the_shift_rule_moves_the_reference_threshold_by_the_drop_of_the_median() -> None:
    assert query_shift_threshold(0.7, 0.5, [0.40, 0.42, 0.44]) == pytest.approx(0.62)
    assert query_shift_threshold(0.7, 0.5, [0.6, 0.7]) == 0.7  # never above the reference's
    acceptance = Acceptance(AcceptanceConfig(accept_query_null_rule="shift", accept_query_null_frames=10), "d")
    acceptance.calibrate([0.4, 0.5, 0.6], "reference")  # median 0.5
    reference = acceptance.threshold
    acceptance.query_null(0.1, frames=9)
    assert acceptance.threshold == reference
    acceptance.query_null(0.1, frames=1)  # median of the null 0.1: down by 0.4
    assert acceptance.threshold == pytest.approx(reference - 0.4)
    fixed = Acceptance(AcceptanceConfig(accept=0.3, accept_query_null_rule="shift"), "d")
    fixed.query_null(0.0, frames=100)
    assert fixed.threshold == 0.3


# --- every detector, paired traversals ------------------------------------------------------


def _frame(index: int, traversal: str) -> Frame:
    return Frame(index=index, timestamp=float(index), image=np.zeros((2, 2), np.uint8), traversal=traversal)  # type: ignore[arg-type]


def _feed_global(detector: Any, vectors: np.ndarray, traversals: list[str], metric: str = "l1") -> list[Message]:
    out: list[Message] = []
    for index, (vector, traversal) in enumerate(zip(vectors, traversals)):
        inputs = StageInputs(frame=_frame(index, traversal),
                             outputs={"descriptor": [Features(frame=index, vector=vector, metric=metric)]})
        out += detector.process(inputs)
    return out + list(detector.finish())


def _uint8_route(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    places = rng.random((n, 64)) * 255
    queries = places + rng.normal(0, 40.0, places.shape)
    return np.clip(places, 0, 255).astype(np.uint8), np.clip(queries, 0, 255).astype(np.uint8)


def _run(name: str, reference: np.ndarray, query: np.ndarray) -> list[Message]:
    """The detector ``name`` with its defaults (accept: auto) over reference then query."""
    traversals = ["reference"] * len(reference) + ["query"] * len(query)
    vectors = np.concatenate([reference, query])
    if name in ("hierarchical_sequence", "hierarchical_faithful"):
        place_map = HierarchicalPlaceMap(HierarchicalPlaceMap.Config(similarity_threshold=0.9))
        cls = HierarchicalSequence if name == "hierarchical_sequence" else HierarchicalFaithful
        return run_stages(vectors, traversals, place_map, cls(cls.Config(sequence_frames=20)
                                                               if cls is HierarchicalSequence else None))
    if name == "nearest_neighbour":
        return _feed_global(NearestNeighbour(), vectors, traversals, "l2")
    cls = SeqSlam if name == "seqslam" else SeqSlamFast
    return _feed_global(cls(), vectors, traversals)


def _route(name: str, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    if name.startswith("seqslam"):
        return _uint8_route(300, seed)
    reference = route_descriptors(150, 2, seed=seed)
    return reference, noisy(reference, 0.1)


PAIRED = ["nearest_neighbour", "seqslam", "seqslam_fast", "hierarchical_sequence", "hierarchical_faithful"]


@pytest.mark.parametrize("name", PAIRED)
def test_paired_detectors_calibrate_on_the_reference_and_log_it(name: str) -> None:
    reference, query = _route(name)
    out = _run(name, reference, query)
    thresholds = [m for m in out if isinstance(m, AcceptThreshold)]
    assert [m.source for m in thresholds if m.source != "queries"] == ["reference"]
    t = thresholds[-1]  # the queries' own null may have moved it down since (never up)
    assert t.threshold <= thresholds[0].threshold
    assert t.auto and t.n_wrong > 10 and 0 < t.threshold <= 1
    assert t.threshold > t.largest_wrong or t.false_accept_rate > 0
    results = [m for m in out if isinstance(m, LoopResult) and m.frame >= len(reference)]
    accepted = [r for r in results if r.accepted]
    scores = {r.frame: r.confidence for r in results}
    if name == "nearest_neighbour":  # accept: auto thresholds its supported confidence
        scores = dict(zip(scores, supported_confidence(*(np.array(v) for v in zip(
            *[(r.frame, r.match, r.confidence) for r in results], strict=True)), NearestNeighbour.Config().support_answers,
            NearestNeighbour.Config().support_agree, NearestNeighbour.Config().support_tolerance_frames), strict=True))
    assert all(scores[r.frame] >= t.threshold for r in accepted)
    assert all(not r.accepted for r in results if scores[r.frame] < t.threshold)
    # a clean re-traversal: what is accepted is right, and something is
    assert accepted and np.mean([abs(r.match - (r.frame - len(reference))) <= 3 for r in accepted]) >= 0.95


@pytest.mark.parametrize("name", PAIRED)
def test_the_threshold_never_reads_the_queries(name: str) -> None:
    """The same reference with other queries (shuffled, or another route): the same threshold."""
    reference, query = _route(name)
    other = np.random.default_rng(5).permutation(len(query))

    def threshold(q: np.ndarray) -> float:
        return next(m.threshold for m in _run(name, reference, q) if isinstance(m, AcceptThreshold))

    assert threshold(query) == threshold(query[other]) == threshold(_route(name, seed=9)[1])


@pytest.mark.parametrize("name", PAIRED)
def test_a_fixed_operating_point_stays_available(name: str) -> None:
    key = "accept_confidence" if name.startswith("hierarchical") else "threshold"  # the older names still work
    cls = {"nearest_neighbour": NearestNeighbour, "seqslam": SeqSlam, "seqslam_fast": SeqSlamFast,
           "hierarchical_sequence": HierarchicalSequence, "hierarchical_faithful": HierarchicalFaithful}[name]
    assert cls.Config(**{key: 0.3}).accept == 0.3 and cls.Config(accept=0.4).accept == 0.4
    assert cls.Config().accept == "auto"
    with pytest.raises(ValueError):
        cls.Config(accept=1.5)


def test_bow_bayes_calibrates_paired_traversals_on_the_reference() -> None:
    rng = np.random.default_rng(0)
    landmarks = rng.normal(size=(120, 40, 16)).astype(np.float32)

    def observe(place: int) -> np.ndarray:
        seen = landmarks[place][rng.choice(40, 30, replace=False)]
        return (seen + rng.normal(scale=0.05, size=seen.shape)).astype(np.float32)

    def run(order: np.ndarray) -> list[Message]:
        detector = BowBayes(BowBayes.Config(nd_low=0.5, nd_high=2.0, stm_size=5, time_budget_s=0.0))
        out: list[Message] = []
        frames = [(p, "reference") for p in range(120)] + [(int(p), "query") for p in order]
        for index, (place, traversal) in enumerate(frames):
            features = Features(frame=index, descriptors=observe(place), metric="l2")
            out += detector.process(StageInputs(frame=_frame(index, traversal), outputs={"descriptor": [features]}))
        return out + list(detector.finish())

    first = [m for m in run(np.arange(120)) if isinstance(m, AcceptThreshold)]
    assert len(first) == 1 and first[0].auto and first[0].source == "reference" and first[0].n_wrong > 20
    again = [m for m in run(np.random.default_rng(3).permutation(120)) if isinstance(m, AcceptThreshold)]
    # the observation noise differs between the runs (one generator): thresholds agree closely
    assert again[0].n_wrong == first[0].n_wrong


def _bow_paired(reference: np.ndarray, queries: np.ndarray, seed: int = 0) -> list[Message]:
    """bow_bayes with accept: auto over reference places then query places (ids into ``landmarks``):
    each place is seen as 30 of its 40 landmarks, 8 of them its neighbour's (a route: adjacent
    places look alike)."""
    rng = np.random.default_rng(seed)
    shared = rng.normal(size=(5000, 16)).astype(np.float32)

    def observe(place: int) -> np.ndarray:
        own = shared[place * 32 + np.arange(40)]  # a window sliding 32 landmarks a place: neighbours share 8
        seen = own[rng.choice(40, 30, replace=False)]
        return (seen + rng.normal(scale=0.05, size=seen.shape)).astype(np.float32)

    detector = BowBayes(BowBayes.Config(nd_low=0.5, nd_high=2.0, stm_size=5, time_budget_s=0.0))
    out: list[Message] = []
    frames = [(int(p), "reference") for p in reference] + [(int(p), "query") for p in queries]
    for index, (place, traversal) in enumerate(frames):
        features = Features(frame=index, descriptors=observe(place), metric="l2")
        out += detector.process(StageInputs(frame=_frame(index, traversal), outputs={"descriptor": [features]}))
    return out + list(detector.finish())


def test_bow_bayes_accepts_revisits_of_a_route_and_no_coincidence() -> None:
    """Its threshold is set on the supported confidence, calibrated over as many places as a query
    searches: a re-traversal is accepted (all right); queries of another route are not."""
    out = _bow_paired(np.arange(60), np.arange(60))
    answers = [m for m in out if isinstance(m, LoopResult)]
    accepted = [a for a in answers if a.accepted]
    # right: a frame merged into the matched place is within 3 of the query's place (place scoring)
    assert len(accepted) >= 20 and all(np.min(np.abs(a.match_frames - (a.frame - 60))) <= 3 for a in accepted)
    # another route: the same generator's landmarks far from the reference's (no place in common)
    elsewhere = [m for m in _bow_paired(np.arange(60), np.arange(60) + 65) if isinstance(m, LoopResult)]
    assert elsewhere and not any(a.accepted for a in elsewhere)


def test_a_lone_similar_place_is_not_supported_a_revisit_along_the_route_is() -> None:
    """The support of an answer (bow_bayes's acceptance): a place that alone shares words with
    frame after frame drives 1 - p(no loop) to its ceiling, but not the filter that never holds it."""
    from slamfront.core.bayes_filter import BayesFilter
    from slamfront_plugins.loop_detectors.bow_bayes import _Support

    hypotheses = np.arange(200)
    lone, lone_support = BayesFilter(), _Support(BayesFilter().parameters)
    route, route_support = BayesFilter(), _Support(BayesFilter().parameters)
    for k in range(20):
        spike = np.zeros(200)
        spike[50] = 0.3  # one coincidental word, every frame
        step = lone.update(hypotheses, spike)
        supported_lone = lone_support.update(step, spike)
        along = np.exp(-0.5 * ((hypotheses - (100 + k)) / 1.5) ** 2) * 0.3  # the revisit and its neighbours
        step_route = route.update(hypotheses, along)
        supported_route = route_support.update(step_route, along)
    assert 1 - step.no_loop > 0.99 and supported_lone < 0.5
    assert supported_route > 0.99


# --- a stream --------------------------------------------------------------------------------


def test_a_stream_calibrates_on_its_first_frames_and_accepts_none_of_them() -> None:
    route = route_descriptors(100, 2, seed=3)
    vectors = np.concatenate([route, noisy(route, 0.05)])
    detector = NearestNeighbour(NearestNeighbour.Config(accept_calibration_frames=200))
    out = _feed_global(detector, vectors, ["stream"] * len(vectors), "l2")
    t = [m for m in out if isinstance(m, AcceptThreshold)]
    assert len(t) == 1 and t[0].source == "stream" and t[0].auto
    results = [m for m in out if isinstance(m, LoopResult)]
    assert not any(r.accepted for r in results if r.frame < 200)
    accepted = [r for r in results if r.accepted]
    assert accepted and all(abs(r.match - (r.frame - 200)) <= 2 for r in accepted)
    assert detector.statistics()["accept_threshold"] == t[0].threshold


def _look_alike_reference(amount: float, **params: Any) -> tuple[list[Message], int]:
    """A reference with a look-alike stretch (frames 220-279 repeat 40-99): its own wrong
    answers are confident there. The queries revisit only frames 100-219 (no look-alike),
    seen under a change (``amount``). Returns the outputs and the reference's length."""
    reference = route_descriptors(150, 2, seed=0)
    reference[220:280] = noisy(reference[40:100], 0.05, seed=3)
    query = noisy(reference[100:220], amount)
    place_map = HierarchicalPlaceMap(HierarchicalPlaceMap.Config(similarity_threshold=0.9))
    detector = HierarchicalSequence(HierarchicalSequence.Config(sequence_frames=20, **params))
    traversals = ["reference"] * len(reference) + ["query"] * len(query)
    return run_stages(np.concatenate([reference, query]), traversals, place_map, detector), len(reference)


@pytest.mark.parametrize("amount", [0.2, 0.4])
def test_the_queries_own_wrong_answers_lower_a_threshold_the_reference_set_too_high(amount: float) -> None:
    out, n = _look_alike_reference(amount, accept_query_null_frames=50)
    thresholds = [m for m in out if isinstance(m, AcceptThreshold)]
    assert thresholds[0].source == "reference" and thresholds[0].threshold > 0.5  # set by the look-alike
    moved = [m for m in thresholds if m.source == "queries"]
    assert moved and all(m.threshold < thresholds[0].threshold for m in moved) and moved[0].n_wrong >= 50
    accepted = [m for m in out if isinstance(m, LoopResult) and m.frame >= n and m.accepted]
    assert len(accepted) >= 40
    assert np.mean([abs(r.match - (r.frame - n + 100)) <= 3 for r in accepted]) >= 0.95
    # off: the reference's threshold alone, which accepts nothing here
    out, n = _look_alike_reference(amount, accept_query_null=False)
    assert [m.source for m in out if isinstance(m, AcceptThreshold)] == ["reference"]
    assert not any(m.accepted for m in out if isinstance(m, LoopResult) and m.frame >= n)


def _dusk_like(name: str, amount: float, **params: Any) -> tuple[list[Message], int]:
    """A route whose places share much of their look (less contrast than ``route_descriptors``),
    seen again under a strong change (``amount``): every query answer, right or wrong, is less
    confident than the reference's answers to itself, as at dusk. Returns the outputs and the
    reference's length."""
    vectors, traversals = dusk_like_route(amount)
    if name == "hierarchical_faithful":
        place_map = HierarchicalPlaceMap(HierarchicalPlaceMap.Config(similarity_threshold=0.9))
        # the null is of the answers' own confidence, off by default for the faithful preset
        params = {"accept_score": "confidence", "accept_query_null": True, **params}
        return run_stages(vectors, traversals, place_map, HierarchicalFaithful(HierarchicalFaithful.Config(**params))), 300
    if name == "nearest_neighbour_confidence":  # the queries' null is of the answers' own confidence (opt-in)
        params = {"accept_score": "confidence", "accept_query_null": True, **params}
    return _feed_global(NearestNeighbour(NearestNeighbour.Config(**params)), vectors, traversals, "l2"), 300


@pytest.mark.parametrize(("name", "amount"), [("hierarchical_faithful", 0.7), ("hierarchical_faithful", 0.8),
                                              ("nearest_neighbour_confidence", 0.6)])
def test_the_queries_null_lowers_the_threshold_at_dusk_for_faithful_and_nearest_neighbour(
    name: str, amount: float
) -> None:
    out, n = _dusk_like(name, amount)
    thresholds = [m for m in out if isinstance(m, AcceptThreshold)]
    assert thresholds[0].source == "reference"
    moved = [m for m in thresholds if m.source == "queries"]
    assert moved and all(m.threshold < thresholds[0].threshold for m in moved)  # down, never above
    accepted = [m for m in out if isinstance(m, LoopResult) and m.frame >= n and m.accepted]
    assert np.mean([abs(r.match - (r.frame - n)) <= 3 for r in accepted]) >= 0.95
    # off: the reference's threshold alone accepts fewer
    off, _ = _dusk_like(name, amount, accept_query_null=False)
    assert [m.source for m in off if isinstance(m, AcceptThreshold)] == ["reference"]
    assert len(accepted) > sum(1 for m in off if isinstance(m, LoopResult) and m.frame >= n and m.accepted)
    if name == "hierarchical_faithful":  # its default: off
        default, _ = _dusk_like(name, amount, accept_query_null=HierarchicalFaithful.Config().accept_query_null)
        assert [m.source for m in default if isinstance(m, AcceptThreshold)] == ["reference"]
    # a fixed accept never moves
    fixed, _ = _dusk_like(name, amount, accept=0.5)
    assert [(m.source, m.threshold) for m in fixed if isinstance(m, AcceptThreshold)] == [("given", 0.5)]


def test_the_headline_names_the_score_the_threshold_is_on():
    from slamfront.report.headline import headline

    metrics = {"recall_at_100p": 0.5, "auc_pr": 0.6, "precision_at_operating_point": 1.0,
               "recall_at_operating_point": 0.4, "accept_threshold": 0.75, "accept_auto": 1, "n_accepted": 3}
    assert "(confidence >= 0.75, calibrated)" in headline(metrics)[0]
    # the bag of words calibrates its supported confidence, not the confidence its answers carry
    assert "(supported confidence >= 0.75, calibrated)" in headline({**metrics, "accept_on_supported_confidence": 1})[0]
