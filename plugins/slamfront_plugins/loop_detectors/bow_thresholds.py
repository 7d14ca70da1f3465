"""Default T_ND1 / T_ND2 per descriptor type for the ``bow_bayes`` greedy vocabulary rule.

Units: the vocabulary's, *squared* L2 for float descriptors (SIFT, RootSIFT, KAZE, as
OpenCV returns them), and differing bits for binary ones (a Hamming distance is the
squared L2 distance of the bit vectors). Wang et al. 2017's values, T_ND1 = 0.001 and
T_ND2 = 0.08, are squared distances of 64-d SURF (the FLANN search RTAB-Map uses
returns squared L2; 0.08 is 0.28 in plain units, about where unrelated SURF features
begin), and OpenCV's wheels have no SURF. So they are re-derived for each descriptor
type by ``benchmarks/bench_bow_thresholds.py derive`` (results in
``benchmarks/results/bow_thresholds.md``; docs/bow_bayes.md explains the procedure):

- real images that none of the reported runs use (the RGB-D samples in the data root)
  are warped by random homographies with photometric changes and sensor noise, so
  every feature's true correspondence is known;
- *match distance*: from a feature to the feature detected at its true position in
  the warped image; *non-match distance*: from a feature to its nearest feature of
  the other scenes (what ND is for an unseen thing);
- **T_ND2 = the equal-error distance**, where the share of matches above it equals the
  share of non-matches below it: above it the nearest word is more likely another
  thing than the same one, so the feature becomes a word whatever NND says (Wang et al. 2017's
  role: never quantise with a large error);
- **T_ND1 = 0.0125 T_ND2**, the paper's proportion (0.001 / 0.08): below it the
  nearest word is a near-duplicate and represents the feature whatever NND says.
  Between the two, the ratio test decides, over a band as wide as the paper's: the
  greedy rule stays a ratio rule with a different processing order, not a distance
  threshold (a band of 0.16, what plain-distance percentiles gave before, left most
  features to the distance tests).

And, for ``min_inliers: auto``'s calibration on a reference, how far apart its own views still
share geometry (``overlap_probes``, ``overlap_extent``; docs/bow_bayes.md, verification).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from types import MappingProxyType

import numpy as np

BAND = 0.001 / 0.08
"""T_ND1 / T_ND2 of Wang et al. 2017 (squared SURF distances): the band where the ratio test decides."""

ND_THRESHOLDS: Mapping[str, tuple[float, float]] = MappingProxyType(
    {
        # descriptor: (T_ND1, T_ND2), from benchmarks/results/bow_thresholds.md
        "sift": (381.0, 30480.0),
        "rootsift": (0.001586, 0.1269),
        "kaze": (0.002121, 0.1697),
        "orb": (0.6875, 55.0),
        "brisk": (1.325, 106.0),
        "akaze": (1.163, 93.0),
        "brief": (0.5125, 41.0),
        "freak": (0.9, 72.0),
    }
)
"""(T_ND1, T_ND2) by descriptor type."""

SEED_SURF_THRESHOLDS = {"T_sim": 0.2, "T_loop": 0.11, "T_NNDR": 0.8, "T_ND1": 0.001, "T_ND2": 0.08}
"""Wang et al. 2017's table 4 (SURF-64, squared distances for T_ND1 / T_ND2), for reference."""


# --- min_inliers: auto, how far the reference's own views overlap -------------------------------

OVERLAP_QUANTILE = 90.0
"""The percentile of a distance's sampled pairs' inliers that must exceed the far pairs' most: a
tenth of the pairs at that distance sharing geometry is enough to count (overlap is a property
of stretches of a route, a straight street, not of every frame)."""


def overlap_probes(span: int) -> list[int]:
    """Distances in frames at which the reference's overlap is probed: 1, then x sqrt(2) each
    (1, 2, 3, 4, 6, 8, 11, 16, 23, 32, 45, 64, ...), below a quarter of the reference."""
    probes: list[int] = []
    step = 0
    while (distance := round(2 ** (step / 2))) < span / 4:
        if not probes or distance > probes[-1]:
            probes.append(distance)
        step += 1
    return probes


def overlap_extent(distances: Sequence[int], inliers: Sequence[int], far: Sequence[int]) -> int:
    """How far apart (in frames) two views of one traversal still share geometry: the largest probed
    distance before the first one whose inliers' 90th percentile is no more than the most any far
    pair reaches (pairs a quarter to half the reference apart: views of unrelated places). 0 when
    even neighbouring frames are at that level, or nothing was probed.

    ``distances`` and ``inliers``: one entry per sampled pair (RANSAC inliers of a fundamental
    matrix between the two frames' features, as the detector verifies an answer).

    The far level is their maximum, not a percentile: a fit needs 7 pairs, so inliers are 0 or at
    least 7 and most far pairs have 0 (a percentile of them says nothing). A far pair that happens
    to reach many inliers only shortens the extent, which keeps more wrong answers in the
    calibration: the safe side."""
    distance_of = np.asarray(distances, dtype=np.int64)
    inliers_of = np.asarray(inliers, dtype=np.float64)
    if not len(far) or not len(distance_of):
        return 0
    level = float(np.max(np.asarray(far, dtype=np.float64)))
    extent = 0
    for distance in np.unique(distance_of):
        if np.percentile(inliers_of[distance_of == distance], OVERLAP_QUANTILE) <= level:
            break
        extent = int(distance)
    return extent


# --- min_inliers: auto, a level everywhere and a higher one where a look-alike was seen ----------

MIN_INLIERS_FLOOR = 8
"""RTAB-Map's VhEp/MatchCountMin: a 7-point fundamental matrix fits any 7 pairs."""


def inlier_minimums(inliers: Sequence[int], places: Sequence[Sequence[int]], rate: float,
                    floor: int = MIN_INLIERS_FLOOR) -> tuple[int, dict[int, int]]:
    """``min_inliers: auto`` from the RANSAC inliers of answers known to be wrong: the minimum
    everywhere, and a higher one for the places a high-scoring wrong answer involved.

    The minimum everywhere is one more than the wrong answers' inliers with the largest ``rate`` share
    of them left out (``floor(rate * n)`` answers; at least ``floor``). A left-out answer is not
    forgotten: the places it involved (``places[k]``, e.g. the place answered and the place of the
    frame that answered it) need one more than its inliers. A wrong answer whose pairs fit one
    fundamental matrix far above what unrelated places reach is a look-alike of those two places
    (a repeated facade, a sight line), which a query there may repeat; it says little about the
    rest of the route. With ``rate`` 0 nothing is left out: the minimum is above every wrong answer
    and no place has its own."""
    values = np.asarray(inliers, dtype=np.int64)
    if len(values) != len(places):
        raise ValueError(f"{len(values)} inlier counts but {len(places)} place lists")
    if not len(values):
        return floor, {}
    allowed = int(np.floor(rate * len(values)))
    level = max(floor, int(np.sort(values)[len(values) - 1 - allowed]) + 1)
    local: dict[int, int] = {}
    for count, involved in zip(values.tolist(), places):
        if count >= level:
            for place in involved:
                local[int(place)] = max(local.get(int(place), level), count + 1)
    return level, local
