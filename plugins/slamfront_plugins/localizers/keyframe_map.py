"""The topological keyframe map of Barbosa 2017 §4.1.3: nodes described by local features.

Each node stores a keyframe's keypoints, descriptors, pose and (with depth) the 3-D
points of its keypoints; links join keyframes visited one after the other (the map's
topology). A frame is compared with the nodes by two-image matching
(:mod:`slamfront.matching`); with pre-selection only with the ``candidates`` nodes whose
global vectors are closest, so the cost stays flat as the map grows. The whole map
converts to and from a :class:`~slamfront_plugins.localizers.messages.KeyframeMap` message, which is how a
run logs it and saves it (``keyframe_map.npz``) for a later run.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from slamfront.core.buffers import GrowingRows
from slamfront.core.geometry import invert
from slamfront.core.pnp import pnp_ransac
from slamfront.matching import NO_MATCH, Matcher, TwoViewMatch
from slamfront_plugins.localizers.messages import KeyframeMap


@dataclass(frozen=True)
class View:
    """What matching needs of one image.

    :ivar frame: the frame index.
    :ivar keypoints: (N, 2) float32 pixels.
    :ivar descriptors: (N, D) descriptors.
    :ivar vector: (V,) float32 unit global vector for pre-selection, or None.
    :ivar camera_matrix: (3, 3) intrinsics, or None.
    :ivar size: (width, height) of the image in pixels, or None.
    :ivar scene: the frame's scene (``Frame.scene``).
    """

    frame: int
    keypoints: np.ndarray
    descriptors: np.ndarray
    vector: np.ndarray | None = None
    camera_matrix: np.ndarray | None = None
    size: tuple[int, int] | None = None
    scene: str = ""

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
    """Keyframes compared with a view, most similar first (``matches[k]`` is with ``nodes[k]``).

    The first ``n_verified`` are exact (RANSAC ran); the rest carry only their putative
    match count (``n_putative``), an upper bound on their inliers, in decreasing order.
    """

    nodes: np.ndarray
    matches: list[TwoViewMatch]
    n_verified: int = 0

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
        self.links: list[set[int]] = []
        """Per node, the nodes visited just before or after it (the map's edges)."""
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
        self.links.append(set())
        return keyframe

    def link(self, a: int, b: int) -> None:
        """Join two nodes: the route went from one to the other."""
        if a != b:
            self.links[a].add(b)
            self.links[b].add(a)

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
        return Ranked(np.asarray(nodes, dtype=np.int64)[ranked].reshape(-1), [*(matches[k] for k in verified), *bound],
                      len(verified))

    def region(self, node: int, radius: int = 2) -> set[int]:
        """The nodes at most ``radius`` links from ``node`` (itself included): one place of the map."""
        region, frontier = {node}, {node}
        for _ in range(radius):
            frontier = {b for a in frontier for b in self.links[a]} - region
            region |= frontier
        return region

    def competing_inliers(self, view: View, ranked: Ranked, radius: int = 2) -> int:
        """Inliers of the most similar keyframe outside the best one's region (:meth:`region`).

        Keyframes a link or two from the best one see the same place (a camera looking
        down a street sees the next keyframes' scene), so the second best overall says
        little; the best keyframe of *another place* is the real competitor. The radius
        matches what evaluation counts as the right region (the nearest keyframe or one
        of its two neighbours either way). Exact: a compared node whose putative count
        could beat the competitor found so far is verified. 0 when the map has no other place.
        """
        best = ranked.best[0]
        if best < 0:
            return 0
        near = self.region(best, radius)
        found = 0
        for k in range(ranked.n_verified):
            if int(ranked.nodes[k]) not in near:
                found = ranked.matches[k].inliers  # verified ones come most inliers first
                break
        for k in range(ranked.n_verified, len(ranked.nodes)):
            node = int(ranked.nodes[k])
            if node in near:
                continue
            if ranked.matches[k].n_putative <= found:
                break  # bounds decrease from here
            found = max(found, self.compare(view, node).inliers)
        return found

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
        # closest matches first: PnP keeps the first of several pixels matched to one keyframe point
        pairs = match.pairs[np.argsort(match.distances, kind="stable")]
        solution = pnp_ransac(
            keyframe.points[pairs[:, 1]], view.keypoints[pairs[:, 0]], view.camera_matrix,
            threshold_px=threshold_px, min_inliers=min_inliers,
        )
        if solution is None:
            return None, 0
        # solution.transform maps keyframe-camera points into this camera: T_view_keyframe
        return keyframe.pose @ invert(solution.transform), len(solution.inliers)

    # --- the map as a message (logged, saved, loaded) ------------------------------------

    def to_message(self, descriptor: str, metric: str, vector_kind: str) -> KeyframeMap:
        """Everything the map holds, as one message (features concatenated, ``offsets`` delimiting them)."""
        keyframes = self.keyframes
        views = [k.view for k in keyframes]
        known = bool(keyframes) and all(k.pose is not None for k in keyframes)
        with_points = bool(keyframes) and all(k.points is not None for k in keyframes)
        with_camera = bool(keyframes) and all(v.camera_matrix is not None for v in views)
        edges = sorted((a, b) for a, linked in enumerate(self.links) for b in linked if a < b)
        descriptors = [v.descriptors for v in views]
        return KeyframeMap(
            frames=np.array([v.frame for v in views], dtype=np.int64),
            poses=np.stack([k.pose for k in keyframes]).astype(np.float64) if known else None,
            scenes=[v.scene for v in views],
            edges=np.array(edges, dtype=np.int64).reshape(-1, 2),
            descriptor=descriptor,
            metric=metric,
            offsets=np.cumsum([0, *(len(v) for v in views)]).astype(np.int64),
            keypoints=np.concatenate([v.keypoints for v in views]) if views else np.zeros((0, 2), np.float32),
            descriptors=np.concatenate(descriptors) if views else None,
            points=np.concatenate([k.points for k in keyframes]) if with_points else None,
            vector_kind=vector_kind if views and all(v.vector is not None for v in views) else "",
            vectors=np.stack([v.vector for v in views]) if views and all(v.vector is not None for v in views) else None,
            camera_matrices=np.stack([v.camera_matrix for v in views]) if with_camera else None,
        )

    @classmethod
    def from_message(cls, message: KeyframeMap, matcher: Matcher, candidates: int | None = None) -> TopologicalMap:
        """The map a :meth:`to_message` message describes, node for node, bit for bit.

        :raises ValueError: the message has no features (a run that did not keep its map).
        """
        if message.offsets is None or message.keypoints is None or message.descriptors is None:
            raise ValueError("the map holds no features (only keyframe frames and poses)")
        built = cls(matcher, candidates)
        for node, frame in enumerate(message.frames.tolist()):
            rows = slice(int(message.offsets[node]), int(message.offsets[node + 1]))
            view = View(
                frame=int(frame),
                keypoints=message.keypoints[rows],
                descriptors=message.descriptors[rows],
                vector=None if message.vectors is None else message.vectors[node],
                camera_matrix=None if message.camera_matrices is None else message.camera_matrices[node],
                scene=message.scenes[node] if message.scenes else "",
            )
            points = None if message.points is None else message.points[rows]
            built.add(view, None if message.poses is None else message.poses[node], points)
        for a, b in (message.edges if message.edges is not None else np.zeros((0, 2), np.int64)).tolist():
            built.link(int(a), int(b))
        return built
