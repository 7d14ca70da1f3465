"""The localizer plugins' own log messages, declared through ``slamfront_message_types``."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from slamfront.messages import Message


def _pose_in_map(suffix: str, pose: np.ndarray | None, stamp_ns: int) -> list[tuple[str, Any]]:
    """``[(suffix, foxglove.PoseInFrame)]`` for a known pose, else nothing."""
    if pose is None:
        return []
    from slamfront.mcaplog import foxglove  # lazy: the log package imports this module

    return [(suffix, foxglove.pose_in_frame(pose, stamp_ns))]


@dataclass(frozen=True, eq=False)
class PoseEstimate(Message):
    """A localizer's answer for one frame: the keyframe it recognised and the pose it infers.

    ``keyframe`` is the frame index of the chosen keyframe, or -1 when the frame could
    not be localized (``reason`` says why). ``pose`` is the estimated camera-to-world
    transform: the keyframe's stored pose, or that pose corrected by PnP when
    ``refined`` is true; ``keyframe_pose`` is the keyframe's pose either way, so one
    run scores both.
    """

    schema_name: ClassVar[str] = "slamfront.PoseEstimate"
    plain_fields: ClassVar[tuple[str, ...]] = ("pose", "keyframe_pose")
    frame: int
    keyframe: int
    node: int = -1
    """Position of the keyframe in the map (0 = first keyframe)."""
    pose: np.ndarray | None = None
    """(4, 4) estimated camera-to-world transform."""
    keyframe_pose: np.ndarray | None = None
    """(4, 4) the chosen keyframe's stored camera-to-world transform."""
    inliers: int = 0
    """Two-image matches with the most similar keyframe that survived RANSAC (the similarity)."""
    second_inliers: int = 0
    """The same for the second most similar keyframe."""
    refined: bool = False
    pnp_inliers: int = 0
    candidates: np.ndarray | None = None
    """(K,) int64 frame indices of the keyframes compared in full, most similar first
    (``candidates[0]`` is the answer, or the answer refused as an unknown place)."""
    n_compared: int = 0
    """Keyframes matched in full (all of them without pre-selection)."""
    reason: str = ""
    confidence: float = float("nan")
    """How sure the localizer is that the most similar keyframe shows this place, 0..1
    (NaN: nothing to compare); below its threshold the answer is "unknown place"."""
    n_putative: int = 0
    """Matches with the most similar keyframe before RANSAC."""
    coverage: float = 0.0
    """Share of a 4x4 grid over this image whose cells hold one of those inliers."""
    competing_inliers: int = 0
    """Inliers of the most similar keyframe of another place (more than two links from the best one)."""

    def foxglove(self, stamp_ns: int) -> list[tuple[str, Any]]:
        """The estimated pose as a ``PoseInFrame`` in ``map`` (suffix ``pose``)."""
        return _pose_in_map("pose", self.pose, stamp_ns)


@dataclass(frozen=True, eq=False)
class KeyframeAdded(Message):
    """A frame became a keyframe (a node of the topological map) during training."""

    schema_name: ClassVar[str] = "slamfront.KeyframeAdded"
    plain_fields: ClassVar[tuple[str, ...]] = ("pose",)
    frame: int
    node: int
    pose: np.ndarray | None = None
    """(4, 4) the keyframe's camera-to-world pose (from the source's ground truth)."""
    n_features: int = 0
    reason: str = ""

    def foxglove(self, stamp_ns: int) -> list[tuple[str, Any]]:
        """The keyframe's pose as a ``PoseInFrame`` (suffix ``keyframe_pose``)."""
        return _pose_in_map("keyframe_pose", self.pose, stamp_ns)


@dataclass(frozen=True, eq=False)
class KeyframeMap(Message):
    """The whole keyframe map at the end of a run: its nodes, their poses and links and,
    when the localizer keeps its map, every feature and 3-D point, so a later run can
    localize against it (saved as ``keyframe_map.npz``). K keyframes, N features in all.
    """

    schema_name: ClassVar[str] = "slamfront.KeyframeMap"
    frames: np.ndarray
    """(K,) int64 frame index of each keyframe, in node order."""
    poses: np.ndarray | None = None
    """(K, 4, 4) their camera-to-world poses, when known."""
    scenes: list[str] = field(default_factory=list)
    """(K,) the scene of each keyframe (``Frame.scene``)."""
    edges: np.ndarray | None = None
    """(E, 2) int64 linked node pairs (a < b): keyframes visited one after the other."""
    descriptor: str = ""
    """Local descriptor type the features are (``orb``, ``sift``, ...)."""
    metric: str = ""
    """How they are compared: ``hamming`` or ``l2``."""
    offsets: np.ndarray | None = None
    """(K + 1,) int64: keyframe k's features are rows ``offsets[k]:offsets[k + 1]``."""
    keypoints: np.ndarray | None = None
    """(N, 2) float32 pixel positions."""
    descriptors: np.ndarray | None = None
    """(N, D) descriptors (float32, or uint8 packed bits)."""
    points: np.ndarray | None = None
    """(N, 3) float32 keypoints in their keyframe's camera frame (NaN: no depth)."""
    vector_kind: str = ""
    """What ``vectors`` are: ``thumbnail`` or ``descriptor_vector`` ("" for none)."""
    vectors: np.ndarray | None = None
    """(K, V) float32 unit global vectors for pre-selection."""
    camera_matrices: np.ndarray | None = None
    """(K, 3, 3) float64 intrinsics of each keyframe."""

    def foxglove(self, stamp_ns: int) -> list[tuple[str, Any]]:
        """All keyframe poses as one ``PosesInFrame`` (suffix ``keyframes``)."""
        if self.poses is None or len(self.poses) == 0:
            return []
        from slamfront.mcaplog import foxglove

        return [("keyframes", foxglove.poses_in_frame(self.poses, stamp_ns))]
