"""The registration plugins' own log messages, declared through ``slamfront_message_types``."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from slamfront.messages import Message


@dataclass(frozen=True, eq=False)
class CloudRegistration(Message):
    """How one frame's cloud was registered: to which frame, with which transform and quality.

    ``outcome`` is ``first`` (the cloud that anchors the model), ``aligned`` (the first
    attempt passed the quality check), ``fallback`` (a fallback attempt passed it),
    ``rejected`` (no attempt passed: the pose is a guess and the cloud stays out of the
    model) or ``failed`` (the frame gave no usable cloud: ``reason`` says why).
    """

    schema_name: ClassVar[str] = "slamfront.CloudRegistration"
    plain_fields: ClassVar[tuple[str, ...]] = ("pose", "transform")
    volatile_fields: ClassVar[tuple[str, ...]] = ("seconds",)
    frame: int
    outcome: str
    pose: np.ndarray
    """(4, 4) estimated camera-to-world pose of this frame."""
    target: int = -1
    """The frame whose cloud this one was aligned to; -1 when none."""
    transform: np.ndarray | None = None
    """(4, 4) transform from this frame's camera to the target frame's camera."""
    fitness: float = math.nan
    """Fraction of this cloud's points with a target point within the ICP distance."""
    inlier_rmse: float = math.nan
    """RMS distance of those correspondences, metres."""
    n_points: int = 0
    """Points left after filtering and downsampling."""
    n_correspondences: int = 0
    method: str = ""
    """Which attempt produced the transform, e.g. ``fpfh+ransac+icp`` or ``previous motion+icp``."""
    reason: str = ""
    """Why a fallback was needed, or why the frame was rejected or failed."""
    seconds: dict[str, float] = field(default_factory=dict)
    """Wall time of each processing step for this frame."""

    def foxglove(self, stamp_ns: int) -> list[tuple[str, Any]]:
        from slamfront.mcaplog import foxglove

        return [("pose", foxglove.pose_in_frame(self.pose, stamp_ns))]


@dataclass(frozen=True, eq=False)
class RegisteredTrajectory(Message):
    """The final camera poses of a registration, after any pose-graph refinement."""

    schema_name: ClassVar[str] = "slamfront.RegisteredTrajectory"
    volatile_fields: ClassVar[tuple[str, ...]] = ("seconds",)
    frames: np.ndarray
    """(N,) int64 frame indices."""
    poses: np.ndarray
    """(N, 4, 4) camera-to-world poses."""
    refined: bool = False
    """True when a pose graph with loop edges changed the chained poses."""
    loop_edges: np.ndarray | None = None
    """(M, 2) int64 frame pairs whose loop constraint was kept."""
    seconds: dict[str, float] = field(default_factory=dict)
    """Wall time of the end-of-run steps (loop registration, pose graph, model)."""

    def foxglove(self, stamp_ns: int) -> list[tuple[str, Any]]:
        from slamfront.mcaplog import foxglove

        return [("trajectory", foxglove.poses_in_frame(self.poses, stamp_ns))]
