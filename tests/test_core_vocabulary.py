"""The online vocabulary: Wang et al. 2017's fig. 1/2 situations, the rules' edge cases, word life cycle."""

from __future__ import annotations

import numpy as np
import pytest

from slamfront.core.distances import nearest_two, pairwise
from slamfront.core.errors import CoreError
from slamfront.core.vocabulary import OnlineVocabulary, VocabularyThresholds, becomes_word, ratio

# Seed fig. 2(a): two words w1, w2 of V_{t-1}; features P1..P3 in a tight cluster well
# away from w1, P4 far from both. Coordinates are the picture's; thresholds are on
# squared distances (the vocabulary's unit for L2): T_ND2 = 4.6^2 sits between the
# cluster's distances to w1 (4.2-4.8) and P4's (9.4).
W1, W2 = (0.0, 0.0), (10.0, 0.0)
P1, P2, P3, P4 = (3.0, 3.0), (3.3, 3.4), (3.6, 3.1), (5.0, 8.0)
FIG2 = VocabularyThresholds(nndr=0.8, nd_low=0.1**2, nd_high=4.6**2)


def _fig2_vocabulary() -> OnlineVocabulary:
    vocabulary = OnlineVocabulary("l2", 2)
    vocabulary.update(np.array([W1, W2], np.float32), "nndr", FIG2)
    vocabulary.retain([0, 1])
    return vocabulary


def test_fig2_nndr_quantises_the_cluster_to_w1_and_greedy_gives_it_a_word() -> None:
    features = np.array([P1, P2, P3, P4], np.float32)
    nndr = _fig2_vocabulary().update(features, "nndr", FIG2)
    greedy = _fig2_vocabulary().update(features, "greedy", FIG2)
    # fig. 2(b): P1, P2, P3 -> w1; P4 -> new word w_{n+1}
    assert nndr.words.tolist() == [0, 0, 0, 2]
    assert nndr.new_words.tolist() == [2]
    # fig. 2(c): P4 first (largest ND), then P3 -> new words; P1, P2 -> P3's word w_{n+2}
    assert greedy.order.tolist() == [3, 2, 1, 0]
    assert greedy.new_words.tolist() == [2, 3]
    assert greedy.words.tolist() == [3, 3, 3, 2]
    # seed eq. 15: the cluster's error under greedy is far below NNDR's (squared distances)
    def d(v: object) -> float:
        return float(np.sum(np.square(v)))

    assert greedy.distances[:2].mean() == pytest.approx((d(np.subtract(P1, P3)) + d(np.subtract(P2, P3))) / 2, rel=1e-5)
    assert nndr.distances[:3].mean() == pytest.approx(np.mean([d(P1), d(P2), d(P3)]), rel=1e-5)
    assert greedy.distances[:2].mean() < nndr.distances[:3].mean()
    assert greedy.mean_error < nndr.mean_error / 5


def test_nndr_depends_on_feature_order_greedy_does_not() -> None:
    """Seed fig. 1: the ratio rule's words change with the processing order."""
    rng = np.random.default_rng(3)
    words = rng.normal(size=(20, 8)).astype(np.float32)
    features = (words[rng.integers(0, 20, 60)] + rng.normal(scale=0.6, size=(60, 8))).astype(np.float32)
    thresholds = VocabularyThresholds(nndr=0.8, nd_low=0.2, nd_high=2.5)
    reverse = features[::-1].copy()

    def run(rule: str, order: np.ndarray) -> set[tuple[float, ...]]:
        vocabulary = OnlineVocabulary("l2", 8)
        vocabulary.update(words, "nndr", thresholds)
        made = vocabulary.update(order, rule, thresholds)  # type: ignore[arg-type]
        return {tuple(np.round(vocabulary.descriptor(int(w)), 5)) for w in made.new_words}

    assert run("nndr", features) != run("nndr", reverse)
    assert run("greedy", features) == run("greedy", reverse)


def test_greedy_without_nd_limits_is_nndr_in_decreasing_nd_order() -> None:
    rng = np.random.default_rng(0)
    words = rng.normal(size=(30, 4)).astype(np.float32)
    features = rng.normal(size=(40, 4)).astype(np.float32)
    open_limits = VocabularyThresholds(nndr=0.8, nd_low=0.0, nd_high=np.inf)
    greedy = OnlineVocabulary("l2", 4)
    greedy.update(words, "nndr", open_limits)
    by_nd = greedy.update(features, "greedy", open_limits)
    ratio_rule = OnlineVocabulary("l2", 4)
    ratio_rule.update(words, "nndr", open_limits)
    sorted_features = features[by_nd.order]
    reordered = ratio_rule.update(sorted_features, "nndr", open_limits)
    np.testing.assert_array_equal(reordered.words, by_nd.words[by_nd.order])


def test_decision_rule_table() -> None:
    """Seed table 2 (greedy) and algorithm 2 (nndr), with missing neighbours as in algorithm 1."""
    t = VocabularyThresholds(nndr=0.8, nd_low=1.0, nd_high=5.0)
    assert becomes_word("greedy", 6.0, 100.0, t)  # ND > T_ND2: new even though NND >> ND
    assert not becomes_word("greedy", 0.5, 0.55, t)  # ND < T_ND1: nearest even though ND ~ NND
    assert becomes_word("greedy", 3.0, 3.3, t) and not becomes_word("greedy", 3.0, 10.0, t)
    assert not becomes_word("nndr", 6.0, 100.0, t) and becomes_word("nndr", 0.5, 0.55, t)
    assert ratio(np.inf, np.inf) == 1.0 and ratio(2.0, np.inf) == 1.0 and ratio(0.0, 0.0) == 0.0
    for rule in ("greedy", "nndr"):
        assert becomes_word(rule, np.inf, np.inf, t)  # empty vocabulary: every feature is a word
        assert becomes_word(rule, 2.0, np.inf, t)  # one word: no ratio test possible -> a word
    assert not becomes_word("greedy", 0.5, np.inf, t)  # ... unless ND < T_ND1


def test_first_image_words_and_duplicates() -> None:
    t = VocabularyThresholds(nndr=0.8, nd_low=0.5, nd_high=10.0)
    vocabulary = OnlineVocabulary("l2", 2)
    # the second feature duplicates the first: ND = 0 < T_ND1 -> no second word
    made = vocabulary.update(np.array([[0, 0], [0, 0], [5, 5]], np.float32), "greedy", t)
    assert len(vocabulary) == 2 and made.words.tolist() == [0, 0, 1]
    assert made.distances.tolist() == [0.0, 0.0, 0.0]
    empty = vocabulary.update(np.zeros((0, 2), np.float32), "greedy", t)
    assert len(empty.words) == 0 and np.isnan(empty.mean_error)


def test_binary_descriptors_use_hamming_bits() -> None:
    t = VocabularyThresholds(nndr=0.8, nd_low=2, nd_high=40)
    vocabulary = OnlineVocabulary("hamming", 32)
    rng = np.random.default_rng(1)
    base = rng.integers(0, 256, (5, 32), dtype=np.uint8)
    vocabulary.update(base, "greedy", t)
    assert len(vocabulary) == 5
    flipped = base.copy()
    flipped[:, 0] ^= 0b1  # one bit off each word: ND = 1 < T_ND1
    again = vocabulary.update(flipped, "greedy", t)
    assert again.words.tolist() == [0, 1, 2, 3, 4] and again.distances.tolist() == [1.0] * 5
    with pytest.raises(CoreError, match="do not fit"):
        vocabulary.update(rng.random((3, 32)).astype(np.float32), "greedy", t)
    with pytest.raises(CoreError, match="do not fit"):
        vocabulary.update(rng.integers(0, 256, (3, 64), dtype=np.uint8), "greedy", t)


def test_words_leave_and_rejoin_the_search_with_their_places() -> None:
    t = VocabularyThresholds(nndr=0.8, nd_low=0.0, nd_high=np.inf)
    vocabulary = OnlineVocabulary("l2", 2)
    first = vocabulary.update(np.array([[0, 0], [10, 0]], np.float32), "nndr", t)
    vocabulary.retain(first.words)
    second = vocabulary.update(np.array([[5, 30]], np.float32), "nndr", t)  # ND = NND: a word
    vocabulary.retain(second.words)
    vocabulary.retain([0])  # a second place uses word 0
    assert vocabulary.n_active == 3
    vocabulary.release(first.words)  # the first place goes to long-term memory
    assert vocabulary.is_active(np.array([0, 1, 2])).tolist() == [True, False, True]
    nd, _, word = vocabulary.nearest(np.array([[9.5, 0.0]], np.float32))
    assert word[0] != 1  # word 1 is not searched any more
    vocabulary.retain(first.words)  # retrieved
    _, _, word = vocabulary.nearest(np.array([[9.5, 0.0]], np.float32))
    assert word[0] == 1 and vocabulary.n_active == 3
    with pytest.raises(CoreError, match="more often"):
        vocabulary.release([2, 2])


def test_truncate_forgets_an_unkept_images_words() -> None:
    t = VocabularyThresholds(nndr=0.8, nd_low=0.0, nd_high=np.inf)
    vocabulary = OnlineVocabulary("l2", 2)
    vocabulary.retain(vocabulary.update(np.array([[0, 0], [10, 0]], np.float32), "nndr", t).words)
    before = len(vocabulary)
    vocabulary.update(np.array([[50, 50], [-50, 50]], np.float32), "nndr", t)
    assert len(vocabulary) == 4 and vocabulary.n_active == 4
    vocabulary.truncate(before)
    assert len(vocabulary) == 2 and vocabulary.n_active == 2
    with pytest.raises(CoreError, match="still uses"):
        vocabulary.truncate(0)


@pytest.mark.parametrize("metric", ["l2", "hamming"])
def test_nearest_two_matches_brute_force(metric: str) -> None:
    rng = np.random.default_rng(7)
    if metric == "l2":
        rows = rng.normal(size=(500, 16)).astype(np.float32) * 100
        queries = rng.normal(size=(300, 16)).astype(np.float32) * 100
    else:
        rows = rng.integers(0, 256, (500, 32), dtype=np.uint8)
        queries = rng.integers(0, 256, (300, 32), dtype=np.uint8)
    d1, d2, i1 = nearest_two(queries, rows, metric, chunk=64)  # type: ignore[arg-type]
    full = np.sort(pairwise(queries, rows, metric), axis=1)  # type: ignore[arg-type]
    np.testing.assert_allclose(d1, full[:, 0], rtol=1e-4)
    np.testing.assert_allclose(d2, full[:, 1], rtol=1e-4)
    exact = pairwise(queries, rows, metric)[np.arange(300), i1]  # type: ignore[arg-type]
    np.testing.assert_allclose(exact, full[:, 0], rtol=1e-4)
    one_d1, one_d2, one_i = nearest_two(queries[:3], rows[:1], metric)  # type: ignore[arg-type]
    assert np.all(np.isinf(one_d2)) and one_i.tolist() == [0, 0, 0]
    none = nearest_two(queries[:3], rows[:0], metric)  # type: ignore[arg-type]
    assert np.all(np.isinf(none[0])) and none[2].tolist() == [-1, -1, -1]


def test_l2_distances_and_thresholds_are_squared() -> None:
    """T_NNDR compares squared distances, as RTAB-Map: a plain ratio of 0.85 is 0.72 squared, below 0.8."""
    t = VocabularyThresholds(nndr=0.8, nd_low=0.0, nd_high=np.inf)
    vocabulary = OnlineVocabulary("l2", 1)
    vocabulary.retain(vocabulary.update(np.array([[0.0], [20.0]], np.float32), "nndr", t).words)
    # ND = 8.5 to word 0, NND = 11.5 to word 1: returned squared
    feature = np.array([[8.5]], np.float32)
    nd, nnd, word = vocabulary.nearest(feature)
    assert nd[0] == pytest.approx(8.5**2) and nnd[0] == pytest.approx(11.5**2) and word[0] == 0
    # a plain ratio of 0.85 (ND 9.19, NND 10.81): a word under a plain 0.8 test, not under the squared one
    made = vocabulary.update(np.array([[9.19]], np.float32), "nndr", t)
    assert len(made.new_words) == 0 and made.distances[0] == pytest.approx(9.19**2, rel=1e-5)
    assert (9.19 / 10.81) > 0.8 > (9.19 / 10.81) ** 2
    greedy = vocabulary.update(np.array([[9.19]], np.float32), "greedy", VocabularyThresholds(0.8, 1.0, 80.0))
    assert len(greedy.new_words) == 1  # 9.19^2 = 84.5 > T_ND2 = 80: a word by distance alone
    assert greedy.decided_by.tolist() == [1]


def _reference_update(vocabulary: OnlineVocabulary, descriptors: np.ndarray, rule: str, t: VocabularyThresholds):
    """The update loop in plain Python (the form the compiled loop replaced), word ids only."""
    from slamfront.core.vocabulary import decide

    n = len(descriptors)
    nd0, nnd0, word0 = vocabulary.nearest(descriptors)
    order = np.argsort(-nd0, kind="stable") if rule == "greedy" else np.arange(n)
    among = vocabulary._in_unit(pairwise(descriptors, descriptors, vocabulary.metric).astype(np.float64))
    new_d1, new_d2, new_w1 = np.full(n, np.inf), np.full(n, np.inf), np.full(n, -1)
    words, distances, decided = np.empty(n, np.int64), np.empty(n), np.empty(n, np.int8)
    next_id = len(vocabulary)
    for k in order.tolist():
        if new_d1[k] < nd0[k]:
            nd, nearest, nnd = new_d1[k], int(new_w1[k]), min(nd0[k], new_d2[k])
        else:
            nd, nearest, nnd = nd0[k], int(word0[k]), min(nnd0[k], new_d1[k])
        new, decided[k] = decide(rule, float(nd), float(nnd), t)  # type: ignore[arg-type]
        if new:
            words[k], distances[k] = next_id, 0.0
            column = among[:, k]
            closer = column < new_d1
            new_d2 = np.where(closer, new_d1, np.minimum(new_d2, column))
            new_w1 = np.where(closer, next_id, new_w1)
            new_d1 = np.where(closer, column, new_d1)
            next_id += 1
        else:
            words[k], distances[k] = nearest, nd
    return words, distances, decided


@pytest.mark.parametrize("metric", ["l2", "hamming"])
@pytest.mark.parametrize("rule", ["greedy", "nndr"])
def test_the_compiled_update_loop_decides_as_the_python_one(metric: str, rule: str) -> None:
    rng = np.random.default_rng(11)
    if metric == "l2":
        frames = [np.round(rng.normal(size=(80, 8)) * 3).astype(np.float32) for _ in range(6)]
        t = VocabularyThresholds(0.8, 2.0, 60.0)
    else:
        frames = [(rng.integers(0, 256, (80, 8), dtype=np.uint8) & 0x0F) for _ in range(6)]
        t = VocabularyThresholds(0.8, 1.0, 14.0)
    frames[3][:20] = frames[1][:20]  # exact repeats: ties and zero distances
    vocabulary = OnlineVocabulary(metric, frames[0].shape[1])  # type: ignore[arg-type]
    for k, descriptors in enumerate(frames):
        expected = _reference_update(vocabulary, descriptors, rule, t)
        got = vocabulary.update(descriptors, rule, t)  # type: ignore[arg-type]
        np.testing.assert_array_equal(got.words, expected[0])
        np.testing.assert_array_equal(got.distances, expected[1])
        np.testing.assert_array_equal(got.decided_by, expected[2])
        if k % 2:
            vocabulary.retain(got.words)
        else:
            vocabulary.truncate(len(vocabulary) - len(got.new_words))


def test_the_search_is_tiled_without_changing_a_rank() -> None:
    rng = np.random.default_rng(5)
    rows = np.round(rng.normal(size=(3000, 16)) * 20).astype(np.float32)
    rows[rng.integers(0, 3000, 600)] = rows[0]  # many exact ties: the lower row wins, as argmin
    queries = np.concatenate([rows[:40], np.round(rng.normal(size=(60, 16)) * 20).astype(np.float32)])
    whole = nearest_two(queries, rows, "l2", tile=len(rows))
    for tile, chunk in ((1, 7), (333, 64), (2048, 256)):
        for a, b in zip(nearest_two(queries, rows, "l2", chunk=chunk, tile=tile), whole):
            np.testing.assert_array_equal(a, b)
    norms = np.einsum("ij,ij->i", rows, rows)
    for a, b in zip(nearest_two(queries, rows, "l2", row_norms=norms), whole):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("length", [32, 64, 61])
def test_the_compiled_hamming_search_agrees_with_opencv(length: int) -> None:
    import cv2

    rng = np.random.default_rng(length)
    rows = rng.integers(0, 256, (2000, length), dtype=np.uint8) & 0x31  # few bits: many ties
    queries = np.concatenate([rows[:30], rng.integers(0, 256, (50, length), dtype=np.uint8) & 0x31])
    d1, d2, i1 = nearest_two(queries, rows, "hamming")
    dist, index = cv2.batchDistance(queries, rows, cv2.CV_32S, normType=cv2.NORM_HAMMING, K=2)
    np.testing.assert_array_equal(d1, dist[:, 0])
    np.testing.assert_array_equal(d2, dist[:, 1])
    np.testing.assert_array_equal(i1, index[:, 0])
    np.testing.assert_array_equal(pairwise(queries, rows, "hamming")[np.arange(len(queries)), i1], d1)
