"""The topological keyframe map of Barbosa 2017 §4.1.3: nodes described by local features.

Each node stores a keyframe's keypoints, descriptors, pose and (with depth) the 3-D
points of its keypoints. A frame is compared with the nodes by two-image matching
(:mod:`slamfront.matching`); with pre-selection only with the ``candidates`` nodes whose
global vectors are closest, so the cost stays flat as the map grows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from slamfront.core.buffers import GrowingRows
from slamfront.core.geometry import invert
from slamfront.core.pnp import pnp_ransac
from slamfront.matching import NO_MATCH, Matcher, TwoViewMatch


@dataclass(frozen=True)
class View:
    """What matching needs of one image.

    :ivar frame: the frame index.
    :ivar keypoints: (N, 2) float32 pixels.
    :ivar descriptors: (N, D) descriptors.
    :ivar vector: (V,) float32 unit global vector for pre-selection, or None.
    :ivar camera_matrix: (3, 3) intrinsics, or None.
    """

    frame: int
    keypoints: np.ndarray
    descriptors: np.ndarray
    vector: np.ndarray | None = None
    camera_matrix: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.keypoints)


@dataclass(frozen=True)
class Keyframe:
    """A node of the map.

    :ivar points: (N, 3) float32 keypoints in the keyframe's camera frame (NaN: no
        depth), or None without depth.
    :ivar pose: (4, 4) camera-to-world, or None when the source gave none.
    """

    node: int
    view: View
    pose: np.ndarray | None
    points: np.ndarray | None


@dataclass(frozen=True)
class Ranked:
    """Keyframes compared with a view, most similar first (``matches[k]`` is with ``nodes[k]``)."""

    nodes: np.ndarray
    matches: list[TwoViewMatch]

    @property
    def best(self) -> tuple[int, TwoViewMatch]:
        """(node, match) of the most similar keyframe, or (-1, no match) if none was compared."""
        if len(self.nodes) == 0:
            return -1, NO_MATCH
        return int(self.nodes[0]), self.matches[0]

    @property
    def second_inliers(self) -> int:
        return self.matches[1].inliers if len(self.matches) > 1 else 0


class TopologicalMap:
    """Keyframes with brute-force or pre-selected comparison.

    :param matcher: the two-image matcher.
    :param candidates: with global vectors, compare in full only with this many nodes
        (0 or None: with all of them, the paper's brute force).
    """

    def __init__(self, matcher: Matcher, candidates: int | None = None) -> None:
        self.matcher = matcher
        self.candidates = candidates or None
        self.keyframes: list[Keyframe] = []
        self._vectors: GrowingRows | None = None
        self.n_comparisons = 0

    def __len__(self) -> int:
        return len(self.keyframes)

    def add(self, view: View, pose: np.ndarray | None, points: np.ndarray | None) -> Keyframe:
        """Make ``view`` a new node."""
        keyframe = Keyframe(len(self.keyframes), view, None if pose is None else np.asarray(pose), points)
        if self.candidates is not None:
            if view.vector is None:
                raise ValueError("pre-selection needs a global vector for every keyframe")
            if self._vectors is None:
                self._vectors = GrowingRows(len(view.vector))
            self._vectors.append(view.vector)
        self.keyframes.append(keyframe)
        return keyframe

    def preselect(self, view: View, exclude_node: int = -1) -> np.ndarray:
        """Node numbers to compare ``view`` with in full: all, or the closest by global vector."""
        nodes = np.arange(len(self.keyframes))
        if self.candidates is not None and self._vectors is not None and view.vector is not None:
            similarity = self._vectors.view @ view.vector
            if 0 <= exclude_node < len(similarity):
                similarity[exclude_node] = -np.inf
            if self.candidates < len(similarity):
                nodes = np.argpartition(-similarity, self.candidates - 1)[: self.candidates]
            else:
                nodes = np.argsort(-similarity)
        if exclude_node >= 0:
            nodes = nodes[nodes != exclude_node]
        return nodes

    def compare(self, view: View, node: int) -> TwoViewMatch:
        """Two-image match of ``view`` (A) against keyframe ``node`` (B)."""
        self.n_comparisons += 1
        other = self.keyframes[node].view
        return self.matcher.match(view.keypoints, view.descriptors, other.keypoints, other.descriptors)

    def _verify(self, view: View, node: int, pairs: np.ndarray, distances: np.ndarray) -> TwoViewMatch:
        self.n_comparisons += 1
        inlier, model = self.matcher.verify(view.keypoints, self.keyframes[node].view.keypoints, pairs)
        return TwoViewMatch(pairs[inlier], distances[inlier], len(pairs), model)

    def rank(self, view: View, exclude_node: int = -1) -> Ranked:
        """Compare ``view`` with the pre-selected nodes; most inliers first (ties: older node first).

        RANSAC keeps at most the putative matches, so it runs only on nodes whose
        putative count could still reach the second-best inlier count found so far:
        the best two are exact, the rest of the ranking is by their upper bound.
        """
        nodes = self.preselect(view, exclude_node)
        putative = [self.matcher.putative(view.descriptors, self.keyframes[int(n)].view.descriptors) for n in nodes]
        order = sorted(range(len(nodes)), key=lambda k: (-len(putative[k][0]), int(nodes[k])))
        matches: dict[int, TwoViewMatch] = {}
        top: list[int] = []  # inlier counts of the best two so far
        for k in order:
            pairs, distances = putative[k]
            if len(top) == 2 and len(pairs) < top[1]:
                break
            matches[k] = self._verify(view, int(nodes[k]), pairs, distances)
            top = sorted([*top, matches[k].inliers], reverse=True)[:2]
        unverified = [k for k in order if k not in matches]
        verified = sorted(matches, key=lambda k: (-matches[k].inliers, int(nodes[k])))
        bound = [TwoViewMatch(NO_MATCH.pairs, NO_MATCH.distances, len(putative[k][0])) for k in unverified]
        ranked = [*verified, *unverified]
        return Ranked(np.asarray(nodes, dtype=np.int64)[ranked].reshape(-1), [*(matches[k] for k in verified), *bound])

    def similar(self, view: View, fraction: float) -> int:
        """The most similar node that ``view`` matches with at least ``fraction`` of that node's keypoints, or -1.

        Exact: RANSAC runs on every pre-selected node whose putative matches could reach
        its own bar.
        """
        nodes = self.preselect(view)
        best, best_inliers = -1, -1
        for node in (int(n) for n in nodes):
            bar = fraction * len(self.keyframes[node].view)
            pairs, distances = self.matcher.putative(view.descriptors, self.keyframes[node].view.descriptors)
            if len(pairs) < bar:
                continue
            inliers = self._verify(view, node, pairs, distances).inliers
            if inliers >= bar and (inliers > best_inliers or (inliers == best_inliers and node < best)):
                best, best_inliers = node, inliers
        return best

    def refine(
        self, view: View, node: int, match: TwoViewMatch, threshold_px: float, min_inliers: int
    ) -> tuple[np.ndarray | None, int]:
        """The view's camera-to-world pose by PnP + RANSAC against keyframe ``node``'s 3-D points.

        :returns: (pose or None, PnP inliers); None when the keyframe has no depth or pose,
            or too few matches agree on one pose.
        """
        keyframe = self.keyframes[node]
        if keyframe.points is None or keyframe.pose is None or view.camera_matrix is None or match.inliers == 0:
            return None, 0
        solution = pnp_ransac(
            keyframe.points[match.pairs[:, 1]], view.keypoints[match.pairs[:, 0]], view.camera_matrix,
            threshold_px=threshold_px, min_inliers=min_inliers,
        )
        if solution is None:
            return None, 0
        # solution.transform maps keyframe-camera points into this camera: T_view_keyframe
        return keyframe.pose @ invert(solution.transform), len(solution.inliers)
