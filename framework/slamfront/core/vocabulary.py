"""An online visual vocabulary with the two update rules of Wang et al. 2017.

A *word* is one stored descriptor. Each new image's features are quantised to words,
and the vocabulary grows with the features no word represents well. Two rules decide
which features become new words:

``nndr`` (RTAB-Map, Wang et al. 2017's algorithm 2)
    features in the order given; each is compared with the vocabulary *including the
    words this image has already added*; it becomes a new word iff ``ND / NND > T_NNDR``
    (ND, NND: distance to the nearest and second-nearest word).

``greedy`` (Wang et al. 2017's algorithm 3, table 2)
    ND of every feature to the previous vocabulary V_{t-1} is computed first; features
    are processed in *decreasing* ND, each compared with V_{t-1} and the words added so
    far from this image, and: ``ND > T_ND2`` -> new word; ``ND < T_ND1`` -> nearest
    word; otherwise new word iff ``ND / NND > T_NNDR``.

**Units.** Every distance here (ND, NND, the thresholds, the quantisation error) is in
the vocabulary's one unit: *squared* L2 for float descriptors, as the nearest-neighbour
search of RTAB-Map (FLANN) returns it and as Wang et al. 2017's SURF thresholds are
given (T_ND1 = 0.001, T_ND2 = 0.08), and differing bits for uint8-packed binary ones
(the Hamming distance of two bit vectors *is* their squared L2 distance, so the same
ratios mean the same thing). T_NNDR therefore compares squared distances, as RTAB-Map
does: 0.8 on squared distances is 0.894 on plain ones.

Without a second neighbour (an empty or one-word vocabulary) the ratio test cannot
vouch that the nearest word is distinctive, so it counts as failed (``ND / NND = 1``)
and the feature becomes a word, as in RTAB-Map's ``VWDictionary``. Wang et al. 2017's
algorithm 1 starts ND and NND at 100, beyond any SURF distance, which would make the
second feature of a run always join the first word; the greedy rule's T_ND1 / T_ND2
still apply first.

Words can be *deactivated* (their places moved to long-term memory, RTAB-Map style) and
*reactivated*; only active words are searched. Every word carries a reference count of
the places that use it, so a word leaves the search exactly when its last place does.

Search is exact brute force over the active words (``core.distances.nearest_two``:
tiled BLAS products for L2, a compiled popcount scan for Hamming); memory management
keeps the active set bounded, which is what keeps it real-time. The update loop itself
is compiled (``core.compiled_kernels.quantise``); :func:`decide` is its rule, in Python.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Literal

import numpy as np

from slamfront.core.distances import nearest_two, pairwise, single_threaded_blas
from slamfront.core.errors import CoreError
from slamfront.core.kernels import compiled

UpdateRule = Literal["greedy", "nndr"]
UPDATE_RULES: tuple[UpdateRule, ...] = ("greedy", "nndr")


@dataclass(frozen=True)
class VocabularyThresholds:
    """The update rules' thresholds, in the vocabulary's unit (squared L2, or bits: see the module docstring).

    :ivar nndr: T_NNDR, the ratio ND / NND (of squared distances) above which a feature becomes a new word.
    :ivar nd_low: T_ND1 (greedy only): below this ND the nearest word always represents it.
    :ivar nd_high: T_ND2 (greedy only): above this ND the feature always becomes a word.
    """

    nndr: float
    nd_low: float
    nd_high: float

    def __post_init__(self) -> None:
        if not 0.0 < self.nndr <= 1.0:
            raise CoreError(f"T_NNDR must be in (0, 1], got {self.nndr}")
        if not 0.0 <= self.nd_low <= self.nd_high:
            raise CoreError(f"need 0 <= T_ND1 <= T_ND2, got T_ND1={self.nd_low}, T_ND2={self.nd_high}")


@dataclass(frozen=True)
class Quantisation:
    """How one image's features were quantised.

    :ivar words: (N,) int64 word id of each feature, in the input order.
    :ivar distances: (N,) float64 distance of each feature to its word (0 for a feature
        that became a word itself): the quantisation error, in the vocabulary's unit
        (squared L2, or bits).
    :ivar new_words: (K,) int64 ids of the words this image added, in creation order.
    :ivar order: (N,) int64 the order the features were processed in.
    :ivar decided_by: (N,) int8 which test decided each feature (:data:`BY_RATIO`,
        :data:`BY_ND_HIGH`, :data:`BY_ND_LOW`): how much of the greedy rule is the ratio
        test and how much a plain distance threshold.
    """

    words: np.ndarray
    distances: np.ndarray
    new_words: np.ndarray
    order: np.ndarray
    decided_by: np.ndarray

    @property
    def mean_error(self) -> float:
        """Mean quantisation error of the image (NaN for an image without features)."""
        return float(self.distances.mean()) if len(self.distances) else float("nan")


def ratio(nd: float, nnd: float) -> float:
    """ND / NND; 1 without a second neighbour, 0 for two exact duplicates (see the module docstring)."""
    if np.isinf(nnd):
        return 1.0
    return nd / nnd if nnd > 0 else 0.0


BY_RATIO, BY_ND_HIGH, BY_ND_LOW = 0, 1, -1
"""Which test decided a feature: the ratio ND / NND, ND > T_ND2 (a word), ND < T_ND1 (the nearest word)."""


def decide(rule: UpdateRule, nd: float, nnd: float, thresholds: VocabularyThresholds) -> tuple[bool, int]:
    """Wang et al. 2017's decision for one feature (algorithm 2 line 6; algorithm 3 lines 9-17),
    and which test made it (:data:`BY_RATIO`, :data:`BY_ND_HIGH`, :data:`BY_ND_LOW`)."""
    if rule == "greedy":
        if nd > thresholds.nd_high:
            return True, BY_ND_HIGH
        if nd < thresholds.nd_low:
            return False, BY_ND_LOW
    return ratio(nd, nnd) > thresholds.nndr, BY_RATIO


def becomes_word(rule: UpdateRule, nd: float, nnd: float, thresholds: VocabularyThresholds) -> bool:
    """Whether one feature becomes a new word (see :func:`decide`)."""
    return decide(rule, nd, nnd, thresholds)[0]


class OnlineVocabulary:
    """Words stored as rows; the active ones packed in a matrix that search scans.

    :param metric: ``l2`` for float descriptors, ``hamming`` for uint8-packed binary ones.
    :param length: descriptor length (floats, or bytes for binary descriptors).
    """

    def __init__(self, metric: Literal["l2", "hamming"], length: int, capacity: int = 1024) -> None:
        if metric not in ("l2", "hamming"):
            raise CoreError(f"an online vocabulary needs l2 or hamming descriptors, not {metric!r}")
        self.metric = metric
        self.squared = metric == "l2"
        """Distances are squared L2 (float descriptors); bits are already in that unit."""
        self.length = length
        self.dtype = np.dtype(np.uint8 if metric == "hamming" else np.float32)
        self._words = np.empty((capacity, length), self.dtype)  # every word, by id
        self._refs = np.zeros(capacity, np.int64)  # places using each word
        self._row = np.full(capacity, -1, np.int64)  # row of each active word in _active
        self._active = np.empty((capacity, length), self.dtype)
        self._active_ids = np.empty(capacity, np.int64)
        self._norms = np.empty(capacity, np.float32)  # |w|^2 of each active row (l2): the search's ranking term
        self._n_words = 0
        self._n_active = 0

    # --- sizes --------------------------------------------------------------------

    def __len__(self) -> int:
        """Words ever kept (active or not)."""
        return self._n_words

    @property
    def n_active(self) -> int:
        """Words the search scans."""
        return self._n_active

    def descriptor(self, word: int) -> np.ndarray:
        """The stored descriptor of one word."""
        return self._words[word].copy()

    def is_active(self, words: np.ndarray) -> np.ndarray:
        return self._row[np.asarray(words, dtype=np.int64)] >= 0

    def references(self, words: np.ndarray) -> np.ndarray:
        return self._refs[np.asarray(words, dtype=np.int64)].copy()

    # --- quantisation -------------------------------------------------------------

    def check(self, descriptors: np.ndarray) -> None:
        """Refuse descriptors this vocabulary was not built for (length or type)."""
        if descriptors.ndim != 2 or descriptors.shape[1] != self.length or descriptors.dtype != self.dtype:
            shape = "x".join(str(s) for s in descriptors.shape)
            raise CoreError(
                f"descriptors {shape} {descriptors.dtype} do not fit this vocabulary, built for "
                f"{self.length}-long {self.dtype} descriptors ({self.metric})"
            )

    def nearest(self, descriptors: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(ND, NND, nearest word id) of each descriptor among the active words, ND and NND in the vocabulary's unit."""
        self.check(descriptors)
        norms = self._norms[: self._n_active] if self.squared else None
        nd, nnd, row = nearest_two(descriptors, self._active[: self._n_active], self.metric, row_norms=norms)
        word = np.where(row >= 0, self._active_ids[np.maximum(row, 0)], -1)
        return self._in_unit(nd), self._in_unit(nnd), word

    def _in_unit(self, distances: np.ndarray) -> np.ndarray:
        return np.square(distances) if self.squared else distances

    def update(self, descriptors: np.ndarray, rule: UpdateRule, thresholds: VocabularyThresholds) -> Quantisation:
        """Quantise one image's features, adding new words by ``rule``.

        New words start active with no reference: the caller either keeps them with
        :meth:`retain` (the image became a place) or drops them with :meth:`truncate`.
        """
        self.check(descriptors)
        with single_threaded_blas():
            return self._update(descriptors, rule, thresholds)

    def _update(self, descriptors: np.ndarray, rule: UpdateRule, thresholds: VocabularyThresholds) -> Quantisation:
        n = len(descriptors)
        nd0, nnd0, word0 = self.nearest(descriptors)
        order = np.argsort(-nd0, kind="stable") if rule == "greedy" else np.arange(n)
        # distances among this image's features: a feature that becomes a word is a
        # column here, so the running two nearest new words cost O(N) per new word
        among = self._in_unit(pairwise(descriptors, descriptors, self.metric).astype(np.float64)) if n else np.zeros((0, 0))
        words = np.empty(n, np.int64)
        distances = np.empty(n, np.float64)
        decided_by = np.empty(n, np.int8)
        # the feature-by-feature loop (algorithms 2 and 3), compiled: its decisions are
        # sequential (each new word can be the nearest of the features after it)
        created = compiled().quantise(
            order.astype(np.int64), nd0, nnd0, word0, among, rule == "greedy", float(thresholds.nndr),
            float(thresholds.nd_low), float(thresholds.nd_high), self._n_words, words, distances, decided_by,
        )
        new_words = self._add(descriptors[created])
        return Quantisation(words, distances, new_words, order.astype(np.int64), decided_by)

    # --- life cycle of words ------------------------------------------------------

    def retain(self, words: Iterable[int]) -> None:
        """One more place uses each of ``words`` (repeat a word to count it twice)."""
        ids = np.asarray(list(words), dtype=np.int64)
        self._check_ids(ids)
        np.add.at(self._refs, ids, 1)
        distinct = np.unique(ids)
        self._activate(distinct[self._row[distinct] < 0])  # ascending ids, as one at a time

    def release(self, words: Iterable[int]) -> None:
        """One place fewer uses each of ``words``; a word nobody uses leaves the search."""
        ids = np.asarray(list(words), dtype=np.int64)
        self._check_ids(ids)
        np.subtract.at(self._refs, ids, 1)
        if np.any(self._refs[ids] < 0):
            raise CoreError("released a word more often than it was retained")
        distinct = np.unique(ids)
        for word in distinct[(self._refs[distinct] == 0) & (self._row[distinct] >= 0)].tolist():
            self._deactivate(word)

    def truncate(self, n_words: int) -> None:
        """Forget every word with id >= ``n_words`` (an image that was not kept)."""
        if not 0 <= n_words <= self._n_words:
            raise CoreError(f"cannot truncate {self._n_words} words to {n_words}")
        if np.any(self._refs[n_words : self._n_words] > 0):
            raise CoreError("cannot forget words a place still uses")
        dropped = np.arange(self._n_words - 1, n_words - 1, -1)
        rows = self._row[dropped]
        if np.array_equal(rows, np.arange(self._n_active - 1, self._n_active - 1 - len(dropped), -1)):
            # the usual case: the image's new words are the last rows, in order
            self._row[dropped] = -1
            self._n_active -= len(dropped)
        else:
            for word in dropped[rows >= 0].tolist():
                self._deactivate(word)
        self._n_words = n_words

    # --- storage ------------------------------------------------------------------

    def _check_ids(self, ids: np.ndarray) -> None:
        if len(ids) and (ids.min() < 0 or ids.max() >= self._n_words):
            raise CoreError(f"word ids out of range 0..{self._n_words - 1}")

    def _add(self, descriptors: np.ndarray) -> np.ndarray:
        """Store ``descriptors`` (K, D) as new active words (ids in order); returns the ids."""
        k = len(descriptors)
        while self._n_words + k > len(self._words):
            self._words = _grown(self._words)
            self._refs = np.concatenate([self._refs, np.zeros(len(self._refs), np.int64)])
            self._row = np.concatenate([self._row, np.full(len(self._row), -1, np.int64)])
        ids = np.arange(self._n_words, self._n_words + k, dtype=np.int64)
        self._words[ids] = descriptors
        self._refs[ids] = 0
        self._n_words += k
        self._activate(ids)
        return ids

    def _activate(self, words: np.ndarray) -> None:
        """Append inactive ``words`` to the searched rows, in the order given."""
        k = len(words)
        while self._n_active + k > len(self._active):
            self._active = _grown(self._active)
            self._active_ids = _grown(self._active_ids)
            self._norms = _grown(self._norms)
        rows = np.arange(self._n_active, self._n_active + k)
        self._active[rows] = self._words[words]
        if self.squared:  # the einsum the search would do over all rows, so the same bits
            self._norms[rows] = np.einsum("ij,ij->i", self._active[rows], self._active[rows])
        self._active_ids[rows] = words
        self._row[words] = rows
        self._n_active += k

    def _deactivate(self, word: int) -> None:
        """Swap the last active row into this word's row: O(D), no reallocation."""
        row, last = int(self._row[word]), self._n_active - 1
        if row != last:
            moved = int(self._active_ids[last])
            self._active[row] = self._active[last]
            self._norms[row] = self._norms[last]
            self._active_ids[row] = moved
            self._row[moved] = row
        self._row[word] = -1
        self._n_active -= 1


def warm_up() -> None:
    """Load (or compile, the first time on a machine) the compiled update loop and Hamming
    search now, so the first image a detector quantises is not charged for them (~0.3 s
    to import numba)."""
    kernels = compiled()
    kernels.quantise(
        np.zeros(1, np.int64), np.zeros(1), np.zeros(1), np.zeros(1, np.int64), np.zeros((1, 1)), True, 0.8, 0.0, 1.0,
        0, np.zeros(1, np.int64), np.zeros(1), np.zeros(1, np.int8),
    )
    words = np.zeros((2, 4), np.uint64)
    kernels.two_nearest_hamming(words, words, np.zeros(2), np.zeros(2), np.zeros(2, np.int64))


def _grown(array: np.ndarray) -> np.ndarray:
    grown = np.empty((2 * len(array), *array.shape[1:]), array.dtype)
    grown[: len(array)] = array
    return grown
