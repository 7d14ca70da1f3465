"""The descriptor tests of Barbosa 2017, chapter 5.1, on any image sequence.

For each descriptor and each target frame (drawn at random, as the paper's 16):

- **local test** (§5.1.1, figs 36-37): two-image matches (brute force, distance
  threshold, RANSAC; :mod:`slamfront.matching`) with its ``neighbours`` previous and
  next frames. A good descriptor gives a bell-shaped curve peaking next to the target.
- **global test** (§5.1.2, tables 1-2): matches with every other frame; the ``top``
  frames with most matches (Q/C pairs) should be the target's neighbours. Ties are
  shared out evenly (a tie straddling the cut counts the share of near frames in it,
  not whichever is closest), and a frame with no match is never a hit.
- **matching speed** (§5.1.3, table 3): mean time of one two-frame match in the global test.
- **dissimilarity** (§5.1.4, table 4): the Euclidean distance (eq. 4.1) between the
  target's keypoint count and the matches found in each neighbour,
  ``sqrt(sum_j (N_target - C_j)^2)``, averaged over targets: how many of the target's
  keypoints its near neighbours do *not* share. Larger means more distinctive. (The
  paper's wording leaves the exact vectors open; this is our reading, stated here.)

Distances of correct matches (frames within 3 of the target, matched without a distance
threshold but with Lowe's ratio test 0.8 and RANSAC) and nearest-neighbour distances to
the 5 least similar frames of the global test are kept: they show where each
descriptor's distance threshold should lie (how :data:`~slamfront.matching.DEFAULT_MAX_DISTANCE`
was chosen).
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np

from slamfront.local_features import DESCRIPTORS, LocalFeatureExtractor, LocalFeatures
from slamfront.matching import Matcher, MatchingConfig, resolve_max_distance


@dataclass(frozen=True)
class DescriptorChoice:
    """A descriptor to test and the keypoint detector it uses."""

    descriptor: str
    detector: str = "native"

    @property
    def label(self) -> str:
        return self.descriptor if self.detector == "native" else f"{self.descriptor}+{self.detector}"

    @classmethod
    def parse(cls, text: str) -> DescriptorChoice:
        """``orb`` or ``brief+sift`` (descriptor + detector); describe-only ones default to SIFT keypoints (the paper)."""
        name, _, detector = text.strip().lower().partition("+")
        if not detector:
            detector = "sift" if name in DESCRIPTORS and DESCRIPTORS[name].needs_detector else "native"
        return cls(name, detector)


@dataclass
class DescriptorResult:
    """Everything measured for one descriptor.

    :ivar local: {target: (2 * neighbours + 1,) matches per offset, NaN outside the sequence or at 0}.
    :ivar top: {target: [(frame, matches), ...]} the ``top`` most similar frames.
    """

    label: str
    max_distance: float
    keypoints: np.ndarray
    """(F,) keypoints per frame."""
    extract_ms: float
    local: dict[int, np.ndarray] = field(default_factory=dict)
    top: dict[int, list[tuple[int, int]]] = field(default_factory=dict)
    match_ms: float = float("nan")
    dissimilarity: float = float("nan")
    top_near_fraction: float = float("nan")
    """Share of the top-``top`` frames within ``neighbours`` of their target (ties shared
    evenly, frames without a match never count: :func:`near_share`)."""
    verified_distances: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))
    unrelated_distances: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))


@dataclass
class DescriptorEvaluation:
    """The whole study: targets, options, and one result per descriptor."""

    n_frames: int
    names: list[str]
    targets: list[int]
    neighbours: int
    top: int
    results: list[DescriptorResult]

    def summary(self) -> dict[str, dict[str, float | int]]:
        """Per descriptor: the numbers of tables 3 and 4 and the global-test hit rate."""
        return {
            r.label: {
                "keypoints_mean": float(np.mean(r.keypoints)) if len(r.keypoints) else 0.0,
                "extract_ms": r.extract_ms,
                "match_ms": r.match_ms,
                "dissimilarity": r.dissimilarity,
                "top_near_fraction": r.top_near_fraction,
                "max_distance": r.max_distance,
            }
            for r in self.results
        }


def near_share(counts: np.ndarray, target: int, top: int, neighbours: int) -> float:
    """Share of the ``top`` most similar frames that lie within ``neighbours`` of ``target``.

    Neutral about ties: when equal counts straddle the cut, each slot left counts the
    share of near frames in the tied group, so the order frames are listed in decides
    nothing. A frame with 0 matches is never near (no evidence of a neighbour).

    :param counts: (F,) matches of the target with every frame (its own entry is ignored).
    """
    others = np.array([i for i in range(len(counts)) if i != target], dtype=np.int64)
    if len(others) == 0:
        return float("nan")
    values = np.asarray(counts, dtype=np.int64)[others]
    near = (np.abs(others - target) <= neighbours) & (values > 0)
    slots = min(top, len(others))
    hits, left = 0.0, slots
    for value in sorted(set(values.tolist()), reverse=True):
        if left == 0:
            break
        group = values == value
        taken = min(left, int(group.sum()))
        hits += taken * float(near[group].mean())
        left -= taken
    return hits / slots


def pick_targets(n_frames: int, count: int, seed: int) -> list[int]:
    """``count`` distinct frames drawn uniformly at random (simple random sampling, as §4.1.2), sorted."""
    rng = np.random.default_rng(seed)
    return sorted(int(i) for i in rng.choice(n_frames, size=min(count, n_frames), replace=False))


def extract_all(images: Iterable[tuple[str, np.ndarray]], choices: Sequence[DescriptorChoice], max_features: int,
                progress: bool = False) -> tuple[list[str], dict[str, list[LocalFeatures]], dict[str, float]]:
    """Features of every grey image for every descriptor (images are read once), and ms per frame."""
    from tqdm import tqdm

    extractors = {c.label: LocalFeatureExtractor(c.descriptor, c.detector, max_features) for c in choices}  # type: ignore[arg-type]
    features: dict[str, list[LocalFeatures]] = {label: [] for label in extractors}
    seconds = dict.fromkeys(extractors, 0.0)
    names = []
    for name, grey in tqdm(images, desc="features", unit="frame", disable=not progress):
        names.append(name)
        for label, extractor in extractors.items():
            start = time.perf_counter()
            features[label].append(extractor.extract(grey))
            seconds[label] += time.perf_counter() - start
    per_frame = {label: 1000.0 * s / max(len(names), 1) for label, s in seconds.items()}
    return names, features, per_frame


def evaluate_descriptor(
    label: str,
    descriptor: str,
    frames: Sequence[LocalFeatures],
    targets: Sequence[int],
    neighbours: int,
    top: int,
    config: MatchingConfig,
    extract_ms: float,
) -> DescriptorResult:
    """The four tests for one descriptor's features of a whole sequence."""
    metric = frames[0].metric if frames else DESCRIPTORS[descriptor].metric
    max_distance = resolve_max_distance(config, descriptor)
    matcher = Matcher(config, metric, max_distance)
    unthresholded = Matcher(config.model_copy(update={"max_distance": None}), metric, np.inf)
    # correct matches without a distance threshold: ratio test + RANSAC, neighbours only
    reference = Matcher(config.model_copy(update={"max_distance": None, "ratio": 0.8}), metric, np.inf)
    result = DescriptorResult(label, max_distance, np.array([len(f) for f in frames]), extract_ms)
    offsets = np.arange(-neighbours, neighbours + 1)
    timings, distances_ok, distances_far, near, dissimilarities = [], [], [], [], []
    n = len(frames)
    for target in targets:
        a = frames[target]
        counts = np.full(n, -1, dtype=np.int64)
        for other in range(n):
            if other == target:
                continue
            b = frames[other]
            start = time.perf_counter()
            match = matcher.match(a.keypoints, a.descriptors, b.keypoints, b.descriptors)
            timings.append(time.perf_counter() - start)
            counts[other] = match.inliers
            if 0 < abs(other - target) <= 3:
                distances_ok.append(reference.match(a.keypoints, a.descriptors, b.keypoints, b.descriptors).distances)
        local = np.full(len(offsets), np.nan)
        for k, offset in enumerate(offsets):
            other = target + offset
            if offset != 0 and 0 <= other < n:
                local[k] = counts[other]
        result.local[target] = local
        # listed most matches first, ties in frame order (the hit rate does not depend on it)
        ranked = sorted((i for i in range(n) if i != target), key=lambda i: (-counts[i], i))
        result.top[target] = [(int(i), int(counts[i])) for i in ranked[:top]]
        near.append(near_share(counts, target, top, neighbours))
        for i in ranked[-min(5, len(ranked)):] if ranked else []:
            _, d = unthresholded.putative(a.descriptors, frames[i].descriptors)
            distances_far.append(d)
        shared = local[np.isfinite(local)]
        if len(shared):
            dissimilarities.append(float(np.sqrt(np.sum((len(a) - shared) ** 2))))
    result.match_ms = 1000.0 * float(np.mean(timings)) if timings else float("nan")
    result.dissimilarity = float(np.mean(dissimilarities)) if dissimilarities else float("nan")
    result.top_near_fraction = float(np.mean(near)) if near else float("nan")
    result.verified_distances = np.concatenate(distances_ok) if distances_ok else result.verified_distances
    result.unrelated_distances = np.concatenate(distances_far) if distances_far else result.unrelated_distances
    return result


def evaluate_descriptors(
    images: Iterable[tuple[str, np.ndarray]],
    choices: Sequence[DescriptorChoice],
    n_targets: int = 16,
    targets: Sequence[int] = (),
    neighbours: int = 10,
    top: int = 5,
    max_features: int = 1000,
    config: MatchingConfig | None = None,
    seed: int = 0,
    progress: bool = False,
) -> DescriptorEvaluation:
    """Run the chapter 5.1 tests on ``(name, grey image)`` pairs of one sequence.

    :param targets: frame numbers (0-based) to test; empty: ``n_targets`` drawn at random.
    :raises ValueError: a target outside the sequence, or fewer than 2 frames.
    """
    config = config or MatchingConfig()
    names, features, extract_ms = extract_all(images, choices, max_features, progress)
    n = len(names)
    if n < 2:
        raise ValueError(f"the sequence has {n} frame(s); the tests need at least 2")
    chosen = sorted(set(targets)) if targets else pick_targets(n, n_targets, seed)
    outside = [t for t in chosen if not 0 <= t < n]
    if outside:
        raise ValueError(f"target frame(s) {outside} outside the sequence of {n} frames (0-based)")
    results = [
        evaluate_descriptor(c.label, c.descriptor, features[c.label], chosen, neighbours, top, config, extract_ms[c.label])
        for c in choices
    ]
    return DescriptorEvaluation(n, names, chosen, neighbours, top, results)
