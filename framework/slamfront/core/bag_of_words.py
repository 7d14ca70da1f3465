"""Bags of visual words and the Wang et al. 2017 image similarity (eq. 5), with an inverted index.

A bag is the multiset of word ids of an image's features. Two bags share a *pair* for
every feature of one that can be paired with a feature of the other on the same word:
``N_pair = sum_w min(count_a(w), count_b(w))``. The similarity divides it by the larger
bag: ``sim = N_pair / max(|a|, |b|)``, in [0, 1].

RTAB-Map counts only words seen exactly once in both signatures; Wang et al. 2017 speaks of
"common word pairs" without that restriction, so repeated words pair up to the smaller
count here.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable

import numpy as np

from slamfront.core.errors import CoreError


def bag_of(words: Iterable[int]) -> Counter[int]:
    """The bag of an image: word id -> number of its features quantised to it."""
    return Counter(int(w) for w in words)


def similarity(a: Counter[int], b: Counter[int]) -> float:
    """Wang et al. 2017 eq. 5: shared word pairs over the larger bag size (0 when either is empty)."""
    size = max(sum(a.values()), sum(b.values()))
    if size == 0:
        return 0.0
    small, large = (a, b) if len(a) <= len(b) else (b, a)
    pairs = sum(min(count, large[word]) for word, count in small.items() if word in large)
    return pairs / size


def unique_word_pairs(words_a: np.ndarray, words_b: np.ndarray) -> np.ndarray:
    """Feature pairs of two images through the words each image has exactly once (RTAB-Map's
    pairs for epipolar verification, Labbe & Michaud 2013): (K, 2) int64 indices into
    ``words_a`` / ``words_b``. Negative word ids (words kept by no place) pair with nothing."""
    a, b = np.asarray(words_a, np.int64), np.asarray(words_b, np.int64)
    ids_a, first_a, counts_a = np.unique(a, return_index=True, return_counts=True)
    ids_b, first_b, counts_b = np.unique(b, return_index=True, return_counts=True)
    once_a, once_b = (counts_a == 1) & (ids_a >= 0), (counts_b == 1) & (ids_b >= 0)
    _, in_a, in_b = np.intersect1d(ids_a[once_a], ids_b[once_b], assume_unique=True, return_indices=True)
    return np.stack([first_a[once_a][in_a], first_b[once_b][in_b]], axis=1).astype(np.int64).reshape(-1, 2)


class InvertedIndex:
    """Word -> places that contain it, so one image is compared with every place at once.

    Cost per query: the total length of the posting lists of the image's words, not
    the number of places.
    """

    def __init__(self) -> None:
        self._postings: dict[int, dict[int, int]] = {}
        self._bags: dict[int, Counter[int]] = {}
        self._sizes: dict[int, int] = {}

    def __len__(self) -> int:
        return len(self._bags)

    def __contains__(self, place: int) -> bool:
        return place in self._bags

    def places(self) -> np.ndarray:
        """(M,) int64 the indexed place ids, sorted."""
        return np.array(sorted(self._bags), dtype=np.int64)

    def add(self, place: int, bag: Counter[int]) -> None:
        if place in self._bags:
            raise CoreError(f"place {place} is already indexed")
        self._bags[place] = bag
        self._sizes[place] = sum(bag.values())
        for word, count in bag.items():
            self._postings.setdefault(word, {})[place] = count

    def remove(self, place: int) -> Counter[int]:
        """Take a place out of the index; returns its bag."""
        bag = self._bags.pop(place)
        del self._sizes[place]
        for word in bag:
            posting = self._postings[word]
            del posting[place]
            if not posting:
                del self._postings[word]
        return bag

    def similarities(self, bag: Counter[int], places: np.ndarray) -> np.ndarray:
        """(M,) Wang et al. 2017 eq. 5 similarity of ``bag`` to each of ``places`` (sorted ids, all indexed)."""
        pairs: dict[int, int] = {}
        for word, count in bag.items():
            for place, stored in self._postings.get(word, {}).items():
                pairs[place] = pairs.get(place, 0) + min(count, stored)
        size = sum(bag.values())
        places = np.asarray(places, dtype=np.int64)
        out = np.zeros(len(places))
        if pairs and len(places):
            # only the places sharing a word, placed by a search in the sorted ids
            sharing = np.fromiter(pairs.keys(), dtype=np.int64, count=len(pairs))
            shared = np.fromiter(pairs.values(), dtype=np.float64, count=len(pairs))
            larger = np.fromiter((max(size, self._sizes[p]) for p in pairs), dtype=np.float64, count=len(pairs))
            at = np.searchsorted(places, sharing)
            found = at < len(places)
            found[found] = places[at[found]] == sharing[found]
            out[at[found]] = shared[found] / larger[found]
        return out
