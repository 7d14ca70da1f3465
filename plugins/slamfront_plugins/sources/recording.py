"""What the recording sources (``ros_bag``, ``euroc``, ``kitti_odometry``, ``video``) share:
which frames of a recording are used, and loop ground truth from the frames' poses."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TypeVar

import numpy as np
from pydantic import Field, model_validator

from slamfront import Camera, PluginConfig
from slamfront.core.loops import LoopGroundTruth, revisits_from_positions
from slamfront.core.retiming import equal_distance
from slamfront_plugins.sources.rgbd import KNOWN_CAMERAS, Intrinsics, KnownCamera

T = TypeVar("T")


class RecordingConfig(PluginConfig):
    """Which frames of a recording a run uses, and what counts as a revisit."""

    start: int = Field(0, ge=0, description="first frame (message) used, 0-based")
    step: int = Field(1, ge=1, description="use every step-th frame")
    limit: int | None = Field(None, ge=1, description="at most this many frames")
    revisit_radius_m: float = Field(3.0, gt=0, description="stream loop truth: a revisit comes this close")
    leave_radius_m: float | None = Field(
        None, gt=0, description="stream loop truth: the camera must have gone this far away in between "
        "(default twice revisit_radius_m)"
    )


class TimedRecordingConfig(RecordingConfig):
    """A recording with its own clock: a time window too (``start`` and ``step`` then count from it)."""

    start_time_s: float | None = Field(None, ge=0, description="skip the recording's first seconds (start and "
                                       "step then count frames from there)")
    end_time_s: float | None = Field(None, gt=0, description="stop this many seconds after the recording's start")

    @model_validator(mode="after")
    def _time_window(self) -> TimedRecordingConfig:
        if self.start_time_s is not None and self.end_time_s is not None and self.end_time_s <= self.start_time_s:
            raise ValueError("end_time_s must be after start_time_s")
        return self


class OdometryResampling(PluginConfig):
    """A recording whose frames carry poses can be resampled by the distance travelled."""

    resample_m: float = Field(
        0.0, ge=0, description="SMART (Pepperell et al. 2014): keep one frame per this many metres travelled by the "
        "frames' poses, so passes driven at different paces are matched at equal distance (after start and step, "
        "before limit); 0: every frame. Needs the poses (ground truth or odometry)"
    )


def selected(items: Sequence[T], config: RecordingConfig, positions: np.ndarray | None = None) -> list[T]:
    """``items[start::step]``, resampled by distance when the config asks (``positions``:
    the camera centre of each item, (len(items), 3)), at most ``limit`` of them."""
    chosen = list(items[config.start :: config.step])
    spacing = config.resample_m if isinstance(config, OdometryResampling) else 0.0
    if spacing > 0:
        if positions is None:
            raise ValueError("resample_m needs the frames' poses")
        kept = equal_distance(np.asarray(positions)[config.start :: config.step], spacing)
        chosen = [chosen[int(i)] for i in kept]
    return chosen if config.limit is None else chosen[: config.limit]


def n_selected(count: int, config: RecordingConfig) -> int:
    """How many of ``count`` items :func:`selected` keeps."""
    n = max(0, math.ceil((count - config.start) / config.step))
    return n if config.limit is None else min(n, config.limit)


def revisit_truth(positions: Sequence[np.ndarray] | np.ndarray, config: RecordingConfig) -> LoopGroundTruth:
    """Stream loop truth of frames at ``positions`` (N, 3): returns within the revisit radius after leaving."""
    points = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    return revisits_from_positions(points, config.revisit_radius_m, config.leave_radius_m)


def given_camera(camera: Intrinsics | KnownCamera | None, width: int, height: int) -> Camera | None:
    """A recipe's ``camera`` (four numbers or a known camera's name) for images of this size."""
    if camera is None:
        return None
    fx, fy, cx, cy = KNOWN_CAMERAS[camera] if isinstance(camera, str) else (camera.fx, camera.fy, camera.cx, camera.cy)
    return Camera(fx=fx, fy=fy, cx=cx, cy=cy, width=width, height=height)
