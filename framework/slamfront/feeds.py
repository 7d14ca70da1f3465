"""Where a run's frames come from: a live source, or a log being replayed.

The runtime drives stages one frame at a time from a :class:`FrameFeed`. A feed yields
:class:`FrameStep` objects (the frame, plus for a replay the messages that stages not
re-run produced for it in the original run), writes the frame's own topics to the new
log, and at the end hands over what the original run logged after its last frame.
:class:`SourceFeed` is the live case: a source plugin, nothing recorded.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from slamfront.core.loops import LoopGroundTruth
from slamfront.frame import Frame
from slamfront.mcaplog import foxglove
from slamfront.mcaplog.reader import LoggedMessage
from slamfront.mcaplog.topics import (
    CALIBRATION_TOPIC,
    DEPTH_TOPIC,
    FRAMES_TOPIC,
    GROUND_TRUTH_TOPIC,
    IMAGE_TOPIC,
    POINTS_TOPIC,
    TF_TOPIC,
)
from slamfront.mcaplog.writer import RunLogWriter
from slamfront.messages import FrameInfo
from slamfront.plugin import Source, Stage
from slamfront.recipe import LogOptions


@dataclass
class FrameStep:
    """One frame of a run.

    :ivar frame: the frame the stages receive.
    :ivar recorded: for stages read from a log, every message they logged while this
        frame was processed, by stage kind, in the order written.
    :ivar logged: the frame's own topics as read from a log (a replay copies them).
    """

    frame: Frame
    recorded: dict[str, list[LoggedMessage]] = field(default_factory=dict)
    logged: list[LoggedMessage] = field(default_factory=list)


class FrameFeed:
    """Base of the frame feeds the runtime can drive."""

    recorded_kinds: frozenset[str] = frozenset()
    """Stage kinds whose outputs come from a log instead of running the stage."""

    @property
    def source(self) -> Source:
        """The source, for evaluations (its ``loop_ground_truth``)."""
        raise NotImplementedError

    def total(self) -> int | None:
        """How many frames :meth:`steps` yields, when known (for the progress bar)."""
        return None

    def steps(self) -> Iterator[FrameStep]:
        raise NotImplementedError

    def log_frame(self, log: RunLogWriter, step: FrameStep) -> FrameInfo:
        """Write the frame's topics (info, image, depth, calibration, poses) to ``log``."""
        raise NotImplementedError

    def recorded_finish(self) -> dict[str, list[LoggedMessage]]:
        """Messages the recorded stages logged after the last frame (their ``finish()``)."""
        return {}

    def recorded_statistics(self, kind: str) -> dict[str, Any]:
        """A recorded stage's end-of-run statistics."""
        return {}

    def stage_for_inputs(self, kind: str, stage: Stage) -> Any:
        """What later stages find in ``inputs.stages[kind]``."""
        return stage

    def loop_ground_truth(self) -> LoopGroundTruth | None:
        return self.source.loop_ground_truth()

    def ending_note(self) -> str:
        """Said in the run's last ``/log`` line (e.g. where the replayed log came from)."""
        return ""


class FrameLogger:
    """Writes what the source gave for a frame: its info, image, depth, cloud and pose."""

    def __init__(self, log: RunLogWriter, options: LogOptions) -> None:
        self.log = log
        self.options = options

    def write(self, frame: Frame) -> FrameInfo:
        stamp = frame.timestamp_ns
        info = FrameInfo(
            frame=frame.index,
            timestamp=frame.timestamp,
            traversal=frame.traversal,
            sequence_index=frame.sequence_index,
            name=frame.name,
            width=int(frame.image.shape[1]),
            height=int(frame.image.shape[0]),
            has_depth=frame.depth is not None,
            pose=None if frame.pose is None else np.asarray(frame.pose, dtype=np.float64),
            scene=frame.scene,
        )
        options = self.options
        self.log.write(FRAMES_TOPIC, info, stamp)
        if options.images:
            image = foxglove.compressed_image(
                frame.image, stamp, options.image_max_width, options.image_format, options.jpeg_quality
            )
            self.log.write_foxglove(IMAGE_TOPIC, image, stamp)
        if options.depth and frame.depth is not None:
            self.log.write_foxglove(DEPTH_TOPIC, foxglove.depth_image(frame.depth, stamp, options.depth_encoding), stamp)
        if options.points and frame.depth is not None and frame.camera is not None:
            points, colours = _cloud(frame, options.points_stride)
            self.log.write_foxglove(POINTS_TOPIC, foxglove.point_cloud(points, stamp, colours), stamp)
        if frame.camera is not None:
            self.log.write_foxglove(CALIBRATION_TOPIC, foxglove.camera_calibration(frame.camera, stamp), stamp)
        if frame.pose is not None:
            self.log.write_foxglove(GROUND_TRUTH_TOPIC, foxglove.pose_in_frame(frame.pose, stamp), stamp)
            self.log.write_foxglove(TF_TOPIC, foxglove.frame_transforms(frame.pose, stamp), stamp)
        return info


def _cloud(frame: Frame, stride: int) -> tuple[np.ndarray, np.ndarray]:
    """Every ``stride``-th pixel with depth, back-projected into the camera frame."""
    assert frame.depth is not None and frame.camera is not None
    camera = frame.camera
    depth = frame.depth[::stride, ::stride]
    v, u = np.nonzero(depth > 0)
    z = depth[v, u].astype(np.float32)
    u, v = u * stride, v * stride
    x = (u - camera.cx) / camera.fx * z
    y = (v - camera.cy) / camera.fy * z
    image = frame.image if frame.image.ndim == 3 else np.repeat(frame.image[..., None], 3, axis=2)
    return np.stack([x, y, z], axis=1).astype(np.float32), image[v, u]


class SourceFeed(FrameFeed):
    """A live run: frames from a source plugin, logged as they arrive."""

    def __init__(self, source: Source, options: LogOptions) -> None:
        self._source = source
        self._options = options

    @property
    def source(self) -> Source:
        return self._source

    def total(self) -> int | None:
        try:
            return len(self._source)
        except (NotImplementedError, TypeError):
            return None

    def steps(self) -> Iterator[FrameStep]:
        for frame in self._source.frames():
            yield FrameStep(frame)

    def log_frame(self, log: RunLogWriter, step: FrameStep) -> FrameInfo:
        return FrameLogger(log, self._options).write(step.frame)
