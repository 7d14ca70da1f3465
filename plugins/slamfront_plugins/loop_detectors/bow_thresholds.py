"""Default T_ND1 / T_ND2 per descriptor type for the ``bow_bayes`` greedy vocabulary rule.

Wang et al. 2017's values (T_ND1 = 0.001, T_ND2 = 0.08) are for 64-d SURF, which OpenCV's
wheels do not have; these are re-derived for each descriptor type from measured
distance distributions by ``benchmarks/bench_bow_thresholds.py`` (results in
``benchmarks/results/bow_thresholds.md``; docs/bow_bayes.md explains the procedure):

- real images that none of the reported runs use (the RGB-D samples in the data root)
  are warped by random homographies with photometric changes and sensor noise, so
  every feature's true correspondence is known;
- *match distance*: from a feature to the feature detected at its true position in
  the warped image; *non-match distance*: from a feature to its nearest feature of
  the warped image that is not its correspondence (what ND is for an unseen thing);
- **T_ND1 = 1st percentile of the non-match distances**: below it, the nearest word
  is the same thing in at least 99 % of cases, so it represents the feature whatever
  NND says (Wang et al. 2017's role for T_ND1: drop words that would only duplicate one);
- **T_ND2 = the equal-error distance**, where the share of matches above it equals the
  share of non-matches below it: above it the nearest word is more likely another
  thing than the same one, so the feature becomes a word whatever NND says (Wang et al. 2017's
  role: never quantise with a large error). A high percentile of the match distances
  would not do: their tail (a corner re-detected at another scale) reaches past the
  median non-match distance.

Units: L2 on the descriptor as OpenCV returns it (SIFT/KAZE), L2 on RootSIFT's unit
vectors, and differing bits for binary descriptors.
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType

ND_THRESHOLDS: Mapping[str, tuple[float, float]] = MappingProxyType(
    {
        # descriptor: (T_ND1, T_ND2), from benchmarks/results/bow_thresholds.md
        "sift": (69.12, 174.6),
        "rootsift": (0.241, 0.3562),
        "kaze": (0.2555, 0.4119),
        "orb": (34.0, 55.0),
        "brisk": (74.0, 106.0),
        "akaze": (68.19, 93.0),
        "brief": (15.0, 41.0),
        "freak": (41.0, 72.0),
    }
)
"""(T_ND1, T_ND2) by descriptor type."""

SEED_SURF_THRESHOLDS = {"T_sim": 0.2, "T_loop": 0.11, "T_NNDR": 0.8, "T_ND1": 0.001, "T_ND2": 0.08}
"""Wang et al. 2017's table 4 (SURF-64 units), for reference."""
