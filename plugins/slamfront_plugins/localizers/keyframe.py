"""The ``keyframe`` localizer: Barbosa 2017's topological keyframe map and global localization."""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import Field, model_validator
from tqdm import tqdm

from slamfront import DataError, Frame, Localizer, Plugin, PluginConfig, PluginError, StageInputs
from slamfront.core.confidence import coverage, evidence, logistic
from slamfront.core.pnp import backproject
from slamfront.core.thumbnail import thumbnail
from slamfront.formats.npz import read_message_npz
from slamfront.matching import Matcher, MatchingConfig, resolve_max_distance
from slamfront.messages import Features, Message
from slamfront_plugins.localizers.keyframe_map import Ranked, TopologicalMap, View
from slamfront_plugins.localizers.messages import KeyframeAdded, KeyframeMap, PoseEstimate

logger = logging.getLogger(__name__)

# Fitted by benchmarks/bench_localization_confidence.py on synthetic worlds 11-16 and 31-36 (ORB, the
# default matching, each world with its own surface patterns), which no reported number uses;
# columns as slamfront.core.confidence.EVIDENCE.
CONFIDENCE_WEIGHTS = (3.593, 0.5685, 0.2291, 1.703)
CONFIDENCE_BIAS = -13.41


def _localizer_matching() -> MatchingConfig:
    # Lowe's ratio test on top of the paper's matching: without it, unrelated images keep
    # 10-30 chance RANSAC inliers (docs/localization.md)
    return MatchingConfig(ratio=0.8)


class Acceptance(PluginConfig):
    """When an answer is given: a logistic model over its evidence, and a threshold."""

    weights: tuple[float, float, float, float] = Field(
        CONFIDENCE_WEIGHTS,
        description="weights of log(1 + inliers), inlier ratio, coverage, distinctiveness (core.confidence)",
    )
    bias: float = Field(CONFIDENCE_BIAS, description="the logistic model's bias")
    min_confidence: float = Field(
        0.5, ge=0, le=1, description="answers less sure than this are 'unknown place' (0: answer every frame)"
    )


class KeyframeLocalizer(Localizer):
    """Keyframe map from local features and global localization against it (Barbosa 2017 §4.1).

    **Training** (``reference`` frames): the first frame is a keyframe; a frame whose
    two-image matches with the current keyframe fall below ``keyframe_fraction`` of
    that keyframe's keypoints is a candidate, and becomes a keyframe if it is not
    similar (by the same measure) to any existing keyframe; if it is, that keyframe
    becomes the current one (a revisit). Keyframes keep their ground-truth pose.

    **Localization** (``query`` frames): each frame is matched with every keyframe
    (or, with ``preselection``, the ``candidates`` closest by a global vector) and takes
    the pose of the one with most RANSAC inliers: global localization, independent of
    the order frames come in (a kidnapped robot). With ``pnp_refinement`` the pose is
    corrected by PnP + RANSAC on the chosen keyframe's depth.

    **Unknown place** (beyond the paper): every answer carries a confidence from the
    evidence that separates right from wrong answers (:mod:`slamfront.core.confidence`:
    inliers, inlier ratio, coverage of the image, margin over the best keyframe of
    another place); below ``acceptance.min_confidence`` the frame is answered "unknown
    place" rather than given a confident wrong pose. The defaults were fitted on
    synthetic worlds no reported number uses (``benchmarks/bench_localization_confidence.py``).

    **A map you keep**: at the end of a run the whole map (features, 3-D points, poses,
    links) is logged and written as ``keyframe_map.npz``; ``map: PATH`` starts a later run
    from it, without the reference traversal (that map is then fixed: every frame is
    localized, none is added).

    ``stream`` frames (one sequence): ``two_pass`` trains on the whole stream, then
    localizes every frame against the final map at the end of the run (the paper's
    protocol); ``online`` localizes each frame against the keyframes so far, then
    trains on it.
    """

    name = "keyframe"
    requires = ("descriptor",)

    class Config(PluginConfig):
        matching: MatchingConfig = Field(
            default_factory=_localizer_matching,
            description="two-image matching (ratio test 0.8 by default; ratio: null is the paper's)",
        )
        keyframe_fraction: float = Field(
            0.25, gt=0, le=1,
            description="a frame matching fewer than this fraction of the current keyframe's keypoints is a candidate",
        )
        min_features: int = Field(20, ge=1, description="frames with fewer keypoints are neither keyframes nor localized")
        min_inliers: int = Field(12, ge=1, description="localized only with at least this many inliers")
        acceptance: Acceptance = Field(default_factory=Acceptance, description="confidence and its threshold")
        stream: Literal["two_pass", "online"] = Field("two_pass", description="how stream frames are used (see above)")
        exclude_self: bool = Field(
            False, description="two_pass: a keyframe is not localized against itself (leave-one-out)"
        )
        preselection: Literal["none", "thumbnail", "descriptor_vector"] = Field(
            "none",
            description="none: compare with every keyframe (the paper); thumbnail: a 32x24 patch-normalised image; "
            "descriptor_vector: the descriptor stage's global vector",
        )
        candidates: int = Field(10, ge=1, description="keyframes compared in full after pre-selection")
        pnp_refinement: bool = Field(False, description="correct the keyframe's pose by PnP + RANSAC on its depth")
        pnp_threshold_px: float = Field(3.0, gt=0, description="PnP RANSAC reprojection threshold")
        pnp_min_inliers: int = Field(15, ge=4, description="accept a PnP pose with at least this many inliers")
        map: Path | None = Field(
            None, description="localize against this saved map (a run's keyframe_map.npz) instead of building one; "
            "it stays fixed: every frame is localized, none is added",
        )
        keep_map: bool = Field(
            True, description="log the whole map at the end (features, 3-D points) so the run saves keyframe_map.npz",
        )

        @model_validator(mode="after")
        def _exclude_self_needs_two_pass(self) -> KeyframeLocalizer.Config:
            if self.exclude_self and self.stream != "two_pass":
                raise ValueError("exclude_self applies to stream: two_pass only")
            return self

    def __init__(self, config: Config | None = None) -> None:
        super().__init__(config)
        self._descriptor_type: str | None = None
        self._map: TopologicalMap | None = None
        self._metric = ""
        self._fixed = False  # a loaded map: nothing is added to it
        self._current = -1
        self._pending: list[View] = []
        self._keyframe_node: dict[int, int] = {}  # frame index -> node, for frames that became keyframes
        self._n_training = 0
        self._n_queries = 0
        self._latency_ms: list[float] = []

    def check(self, stages: Mapping[str, Plugin]) -> None:
        descriptor = stages["descriptor"]
        if not getattr(descriptor, "produces_local", False):
            raise PluginError(f"needs local features; descriptor {descriptor.name!r} produces none (use local_features)")
        if self.config.preselection == "descriptor_vector" and not getattr(descriptor, "produces_global", False):
            raise PluginError(
                f"preselection: descriptor_vector needs a descriptor with a global vector; {descriptor.name!r} has none"
            )
        self._descriptor_type = getattr(descriptor.config, "descriptor", None)
        resolve_max_distance(self.config.matching, self._descriptor_type)
        if self.config.map is not None:
            self._load(self.config.map)

    def _load(self, path: Path) -> None:
        """Read a saved map now, so a bad or mismatched file fails before the first frame."""
        saved = read_message_npz(path, KeyframeMap)
        if saved.descriptor != self._descriptor_type:
            raise PluginError(
                f"map: {path} holds {saved.descriptor or 'unnamed'} features; this recipe's descriptor gives "
                f"{self._descriptor_type}"
            )
        wanted = "" if self.config.preselection == "none" else self.config.preselection
        if wanted and saved.vector_kind != wanted:
            raise PluginError(
                f"map: {path} was saved without {wanted} vectors (it has {saved.vector_kind or 'none'}); "
                f"use the preselection it was built with"
            )
        try:
            self._map = TopologicalMap.from_message(saved, self._matcher(saved.metric), self._candidates())
        except ValueError as exc:
            raise DataError(f"{path}: {exc}") from None
        self._metric, self._fixed = saved.metric, True

    @property
    def map(self) -> TopologicalMap:
        """The keyframe map (built at the first frame, when the descriptor's metric is known)."""
        if self._map is None:
            raise PluginError("the keyframe map is created at the first frame")
        return self._map

    def _matcher(self, metric: str) -> Matcher:
        return Matcher(self.config.matching, metric, resolve_max_distance(self.config.matching, self._descriptor_type))

    def _candidates(self) -> int | None:
        return None if self.config.preselection == "none" else self.config.candidates

    # --- per frame ------------------------------------------------------------------

    def process(self, inputs: StageInputs) -> Sequence[Message]:
        frame = inputs.frame
        features: Features = inputs.one("descriptor", Features)
        if features.keypoints is None or features.descriptors is None:
            raise PluginError(f"descriptor gave no local features for frame {frame.index}")
        if self._map is None:
            self._map, self._metric = TopologicalMap(self._matcher(features.metric), self._candidates()), features.metric
        elif features.metric != self._metric:
            raise PluginError(f"the map's features are compared by {self._metric}, frame {frame.index}'s by "
                              f"{features.metric}")
        view = self._view(frame, features)
        if self._fixed:
            return [self._localize(view)]
        if frame.traversal == "reference":
            return self._train(frame, view)
        if frame.traversal == "query":
            return [self._localize(view)]
        if self.config.stream == "two_pass":
            self._pending.append(view)
            return self._train(frame, view)
        estimate = self._localize(view)
        return [estimate, *self._train(frame, view)]

    def finish(self) -> Sequence[Message]:
        out: list[Message] = []
        pending = tqdm(self._pending, desc="localizing against the keyframes", unit="frame", leave=False,
                       disable=None if len(self._pending) > 50 else True)  # None: only on a terminal
        for view in pending:
            exclude = self._keyframe_node.get(view.frame, -1) if self.config.exclude_self else -1
            out.append(self._localize(view, exclude))
        self._pending = []
        if self._map is not None:
            kind = "" if self.config.preselection == "none" else self.config.preselection
            whole = self.map.to_message(self._descriptor_type or "", self._metric, kind)
            if not self.config.keep_map:
                whole = dataclasses.replace(whole, offsets=None, keypoints=None, descriptors=None, points=None,
                                            vectors=None, camera_matrices=None)
            out.append(whole)
        return out

    def _view(self, frame: Frame, features: Features) -> View:
        vector = None
        if self.config.preselection == "thumbnail":
            vector = thumbnail(frame.gray(), 32, 24, 8)
        elif self.config.preselection == "descriptor_vector":
            if features.vector is None:
                raise PluginError(f"descriptor gave no global vector for frame {frame.index}")
            norm = float(np.linalg.norm(features.vector))
            vector = (features.vector / norm if norm > 0 else features.vector).astype(np.float32)
        return View(
            frame=frame.index,
            keypoints=np.asarray(features.keypoints, dtype=np.float32),
            descriptors=features.descriptors,
            vector=vector,
            camera_matrix=None if frame.camera is None else frame.camera.matrix,
            size=(int(frame.image.shape[1]), int(frame.image.shape[0])),
            scene=frame.scene,
        )

    # --- training -------------------------------------------------------------------

    def _train(self, frame: Frame, view: View) -> list[Message]:
        self._n_training += 1
        if len(view) < self.config.min_features:
            return []
        fraction = self.config.keyframe_fraction
        if self._current >= 0:
            current = self.map.keyframes[self._current]
            if self.map.compare(view, self._current).inliers >= fraction * len(current.view):
                return []
            similar = self.map.similar(view, fraction)
            if similar >= 0:
                self.map.link(self._current, similar)  # the route went on to a place seen before
                self._current = similar  # no new keyframe
                return []
        reason = "first keyframe" if self._current < 0 else f"fewer than {fraction:g} x keypoints matched any keyframe"
        keyframe = self.map.add(view, frame.pose, self._points(frame, view))
        if self._current >= 0:
            self.map.link(self._current, keyframe.node)
        self._current = keyframe.node
        self._keyframe_node[frame.index] = keyframe.node
        return [KeyframeAdded(frame=frame.index, node=keyframe.node, pose=keyframe.pose, n_features=len(view),
                              reason=reason)]

    def _points(self, frame: Frame, view: View) -> np.ndarray | None:
        if not self.config.pnp_refinement:
            return None
        if frame.depth is None or frame.camera is None:
            raise DataError(
                f"frame {frame.index} ({frame.name or 'unnamed'}): pnp_refinement needs depth and intrinsics, "
                "and the source gave none for this frame"
            )
        return backproject(view.keypoints, frame.depth, frame.camera.matrix)

    # --- localization ---------------------------------------------------------------

    def _localize(self, view: View, exclude_node: int = -1) -> PoseEstimate:
        start = time.perf_counter()
        estimate = self._estimate(view, exclude_node)
        # wall time goes to the statistics, not the message: messages stay bit-identical between runs
        self._latency_ms.append((time.perf_counter() - start) * 1000.0)
        return estimate

    def _estimate(self, view: View, exclude_node: int) -> PoseEstimate:
        self._n_queries += 1
        if len(view) < self.config.min_features:
            return self._unlocalized(view, f"too few features ({len(view)} < {self.config.min_features})")
        if len(self.map) == 0:
            return self._unlocalized(view, "the map has no keyframes yet")
        ranked = self.map.rank(view, exclude_node)
        node, match = ranked.best
        if node < 0:
            return self._unlocalized(view, "no keyframe to compare with")
        evidence = self._evidence(view, ranked)
        acceptance = self.config.acceptance
        if match.inliers < self.config.min_inliers:
            return self._unlocalized(
                view, f"best keyframe has {match.inliers} inliers (< {self.config.min_inliers})", ranked, evidence
            )
        if evidence["confidence"] < acceptance.min_confidence:
            return self._unlocalized(
                view, f"unknown place: confidence {evidence['confidence']:.2f} < {acceptance.min_confidence:g} "
                f"({match.inliers} inliers)", ranked, evidence,
            )
        keyframe = self.map.keyframes[node]
        pose, pnp_inliers, reason = keyframe.pose, 0, ""
        if self.config.pnp_refinement:
            refined, pnp_inliers = self.map.refine(
                view, node, match, self.config.pnp_threshold_px, self.config.pnp_min_inliers
            )
            if refined is not None:
                pose = refined
            else:
                reason = "PnP failed: kept the keyframe pose"
        return PoseEstimate(
            frame=view.frame,
            keyframe=keyframe.view.frame,
            node=node,
            pose=pose,
            keyframe_pose=keyframe.pose,
            refined=pose is not keyframe.pose,
            pnp_inliers=pnp_inliers,
            reason=reason,
            **self._answer_fields(ranked),
            **evidence,
        )

    def _evidence(self, view: View, ranked: Ranked) -> dict[str, float | int]:
        """The best answer's evidence and confidence (:mod:`slamfront.core.confidence`)."""
        _, match = ranked.best
        covered = coverage(view.keypoints[match.pairs[:, 0]], *view.size) if view.size is not None else 0.0
        competing = self.map.competing_inliers(view, ranked)
        acceptance = self.config.acceptance
        columns = evidence([match.inliers], [match.n_putative], [covered], [competing])
        confidence = float(logistic(columns, np.asarray(acceptance.weights), acceptance.bias)[0])
        return {"confidence": confidence, "n_putative": match.n_putative, "coverage": covered,
                "competing_inliers": competing}

    def _answer_fields(self, ranked: Ranked) -> dict[str, object]:
        return {"inliers": ranked.best[1].inliers, "second_inliers": ranked.second_inliers,
                "candidates": self._frames_of(ranked.nodes), "n_compared": len(ranked.nodes)}

    def _frames_of(self, nodes: np.ndarray) -> np.ndarray:
        return np.array([self.map.keyframes[int(n)].view.frame for n in nodes], dtype=np.int64)

    def _unlocalized(
        self, view: View, reason: str, ranked: Ranked | None = None, evidence: dict[str, float | int] | None = None
    ) -> PoseEstimate:
        """No pose: the reason, and whatever was compared (the best candidate and its evidence)."""
        logger.info("frame %d not localized: %s", view.frame, reason)
        answer = {} if ranked is None else self._answer_fields(ranked)
        return PoseEstimate(frame=view.frame, keyframe=-1, reason=reason, **answer, **(evidence or {}))

    def statistics(self) -> dict[str, int | float]:
        latency = np.asarray(self._latency_ms or [np.nan])
        return {
            "n_keyframes": 0 if self._map is None else len(self._map),
            "n_training_frames": self._n_training,
            "n_localization_queries": self._n_queries,
            "n_two_view_matches": 0 if self._map is None else self._map.n_comparisons,
            # per localized frame: matching, RANSAC and PnP (the descriptor stage is timed apart)
            "localization_latency_median_ms": float(np.median(latency)),
            "localization_latency_p99_ms": float(np.percentile(latency, 99)),
            "localization_latency_mean_ms": float(np.mean(latency)),
            "localization_latency_max_ms": float(np.max(latency)),
        }
