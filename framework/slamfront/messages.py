"""The shared message contract: typed records every stage and tool understands.

Every stage output is a frozen dataclass deriving from :class:`Message`. The log stores
it as JSON (``message_encoding = "json"``) with a JSON Schema (``schema_encoding =
"jsonschema"``) generated from the dataclass, so Foxglove shows every field and any
reader can decode it without slamfront; arrays and floats round-trip bit-exactly
(:mod:`slamfront.message_codec`).

Base64 is exact but no plot can read it. The array fields a person plots (poses,
transforms, per-candidate costs) are therefore also written as ``<field>_values``: the
same numbers as a flat row-major list of JSON numbers (``null`` where not finite), e.g.
``/frames.pose_values[3]`` is the ground-truth x in a Foxglove Plot (x, y, z of a 4x4
pose are items 3, 7 and 11). A class names these fields in ``plain_fields``; decoding
reads only the exact field, and encoding writes the list again from it, so the round
trip stays bit-exact.

This module holds what stages share: frames, features, places, loop results, poses and
the run's own records (:data:`SHARED_MESSAGES`). A plugin that needs a message type of its
own derives from :class:`Message` in its package and declares it with the
``slamfront_message_types`` hook, so tools that read logs know it without importing
anything a log names (:mod:`slamfront.message_types`).
"""

from __future__ import annotations

import dataclasses
import json
import typing
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from slamfront.message_codec import (
    PLAIN_SCHEMA,
    PLAIN_SUFFIX,
    decode_any,
    decode_value,
    encode_object,
    plain_values,
    schema_for,
    strip_optional,
    type_hints,
)

__all__ = [
    "PLAIN_SUFFIX", "SHARED_MESSAGES", "AcceptThreshold", "Features", "FrameInfo", "LoopResult", "LoopTruth", "LoopVerdict", "Message",
    "PlaceAssignment", "PointCloud", "PoseGraphRecord", "RelativePose", "RunEvent", "RunMetrics", "StageStatistics",
    "Trajectory", "decode_any", "strip_optional",
]


@dataclass(frozen=True, eq=False)
class Message:
    """Base of every slamfront message. Subclasses are frozen dataclasses.

    :cvar schema_name: the MCAP schema name, ``slamfront.<Type>``.
    """

    schema_name: ClassVar[str] = "slamfront.Message"
    volatile_fields: ClassVar[tuple[str, ...]] = ()
    """Fields that measure the machine (wall times), not the method: ``slamfront diff``
    leaves them out unless ``--strict``, so a replay or a rerun still compares equal."""
    plain_fields: ClassVar[tuple[str, ...]] = ()
    """Array fields also written as ``<field>_values``, plain JSON numbers a plot can read."""

    def to_json(self) -> bytes:
        """Encode as compact UTF-8 JSON (see the module docstring for arrays and floats)."""
        return encode_object(
            {f.name: getattr(self, f.name) for f in dataclasses.fields(self)},
            {f"{name}{PLAIN_SUFFIX}": plain_values(getattr(self, name)) for name in self.plain_fields},
        )

    @classmethod
    def from_json(cls, data: bytes | str) -> typing.Self:
        """Decode what :meth:`to_json` wrote; arrays come back with their dtype and bits."""
        raw = json.loads(data)
        hints = type_hints(cls)
        kwargs = {}
        for f in dataclasses.fields(cls):
            if f.name in raw:
                kwargs[f.name] = decode_value(raw[f.name], hints[f.name])
        return cls(**kwargs)

    @classmethod
    def json_schema(cls) -> dict[str, Any]:
        """A JSON Schema (draft 2020-12) describing the encoded message."""
        hints = type_hints(cls)
        properties = {f.name: schema_for(hints[f.name]) for f in dataclasses.fields(cls)}
        for name in cls.plain_fields:
            properties[f"{name}{PLAIN_SUFFIX}"] = PLAIN_SCHEMA
        return {
            "$schema": "https://json-schema.org/draft/2020-12/schema",
            "title": cls.schema_name,
            "description": (cls.__doc__ or "").strip().splitlines()[0],
            "type": "object",
            "properties": properties,
        }

    def foxglove(self, stamp_ns: int) -> list[tuple[str, Any]]:
        """Extra Foxglove messages that show this one in a panel: ``[(topic suffix, protobuf)]``.

        The runtime writes each on ``/<stage kind>/<suffix>``. Default: none.
        """
        return []

    def same_as(self, other: Message) -> bool:
        """True when both messages encode to the same bytes (arrays compared bit for bit)."""
        return type(self) is type(other) and self.to_json() == other.to_json()


# --- the messages every run can produce -----------------------------------------------


@dataclass(frozen=True, eq=False)
class FrameInfo(Message):
    """What the source said about a frame (its pixels go to the image topic)."""

    schema_name: ClassVar[str] = "slamfront.FrameInfo"
    plain_fields: ClassVar[tuple[str, ...]] = ("pose",)
    frame: int
    timestamp: float
    traversal: str
    sequence_index: int
    name: str
    width: int
    height: int
    has_depth: bool = False
    pose: np.ndarray | None = None
    """(4, 4) ground-truth camera-to-world transform, when the source knows it."""
    scene: str = ""
    """The scene the frame shows ("" for the source's own; see ``Frame.scene``)."""


@dataclass(frozen=True, eq=False)
class Features(Message):
    """A descriptor stage's output for one frame: a global vector and/or local features."""

    schema_name: ClassVar[str] = "slamfront.Features"
    frame: int
    vector: np.ndarray | None = None
    """(D,) global descriptor."""
    keypoints: np.ndarray | None = None
    """(N, 2) float32 pixel coordinates x, y of local features."""
    descriptors: np.ndarray | None = None
    """(N, D) local descriptors: float32, or uint8 packed bits for binary descriptors."""
    metric: str = "l2"
    """How vectors/descriptors are compared: ``l1``, ``l2``, ``cosine`` or ``hamming``."""
    keypoint_info: np.ndarray | None = None
    """(N, 4) float32 size, angle, response, octave of each keypoint (optional)."""


@dataclass(frozen=True, eq=False)
class PlaceAssignment(Message):
    """A place map's decision for one frame: which place it joined."""

    schema_name: ClassVar[str] = "slamfront.PlaceAssignment"
    frame: int
    place: int
    new_place: bool
    n_places: int


@dataclass(frozen=True, eq=False)
class LoopResult(Message):
    """A loop detector's answer for one query frame.

    ``match`` is the frame index of the matched place, or -1 for an explicit "no answer".
    ``confidence`` is in [0, 1], higher is surer; evaluation sweeps it to draw the
    precision-recall curve. ``accepted`` is the detector's own decision at its
    configured operating point.
    """

    schema_name: ClassVar[str] = "slamfront.LoopResult"
    frame: int
    match: int
    confidence: float
    accepted: bool
    candidates: np.ndarray | None = None
    """(K,) int64 candidate frame indices, best first (for recall@K), if the detector ranks."""
    reason: str = ""
    """Why there is no answer, when ``match`` is -1."""
    match_frames: np.ndarray | None = None
    """(K,) int64 every frame the matched place stands for (it and the frames merged into it),
    for place scoring (``eval.loop_scoring: place``); None: the match is one frame."""
    searched: bool = True
    """False when the detector did not search for this frame but repeated an earlier answer
    (``eval.unsearched_frames: exclude`` leaves such frames out of the scores)."""


@dataclass(frozen=True, eq=False)
class RunMetrics(Message):
    """The run's final metrics, as written to ``metrics.json``."""

    schema_name: ClassVar[str] = "slamfront.RunMetrics"
    values: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True, eq=False)
class PointCloud(Message):
    """Points with colours in the world frame: one frame's aligned cloud, or a global model.

    Shown in Foxglove as ``foxglove.PointCloud`` on ``/<stage>/<role>_cloud``.
    """

    schema_name: ClassVar[str] = "slamfront.PointCloud"
    frame: int
    """The frame the cloud belongs to (for a model: the last frame it includes)."""
    role: str
    """``aligned`` (one frame's cloud placed in the world) or ``model`` (everything, merged)."""
    points: np.ndarray
    """(N, 3) float32 metres in ``frame_id``."""
    colors: np.ndarray | None = None
    """(N, 3) uint8 RGB."""
    frame_id: str = "map"

    def foxglove(self, stamp_ns: int) -> list[tuple[str, Any]]:
        from slamfront.mcaplog import foxglove

        return [(f"{self.role}_cloud", foxglove.point_cloud(self.points, stamp_ns, self.colors, self.frame_id))]


@dataclass(frozen=True, eq=False)
class StageStatistics(Message):
    """A stage's :meth:`~slamfront.plugin.Stage.statistics` at the end of the run.

    Logged on ``/<kind>/stage_statistics`` so a replay that reads this stage from the
    log reports the same counters without running it.
    """

    schema_name: ClassVar[str] = "slamfront.StageStatistics"
    values: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True, eq=False)
class RunEvent(Message):
    """A step of the run itself, so a reader can tell the phases apart.

    ``event`` is ``"finish"`` just before the stages' ``finish()`` is called: stage
    messages after it were produced at the end of the run, not for the last frame.
    """

    schema_name: ClassVar[str] = "slamfront.RunEvent"
    event: str
    n_frames: int


@dataclass(frozen=True, eq=False)
class LoopTruth(Message):
    """The source's loop ground truth (``LoopGroundTruth`` in compressed-row form).

    Logged once at the end of a run, so evaluating a replay needs only the log.
    """

    schema_name: ClassVar[str] = "slamfront.LoopTruth"
    queries: np.ndarray
    """(Q,) int64 query frame indices, sorted."""
    indptr: np.ndarray
    """(Q + 1,) int64 row offsets into ``matches``."""
    matches: np.ndarray
    """(M,) int64 correct matches of each query, by row."""


# --- geometry and the back end --------------------------------------------------------


@dataclass(frozen=True, eq=False)
class RelativePose(Message):
    """A measured rigid motion between two frames (odometry, or a verified loop closure).

    Any stage may produce it (registration, a localizer, the back end's own
    verification); the back end adds it as an edge of its pose graph.
    """

    schema_name: ClassVar[str] = "slamfront.RelativePose"
    plain_fields: ClassVar[tuple[str, ...]] = ("transform",)
    frame_from: int
    frame_to: int
    transform: np.ndarray
    """(4, 4) float64 pose of ``frame_to``'s camera in ``frame_from``'s camera (T_from^-1 T_to)."""
    information: np.ndarray | None = None
    """(6, 6) float64 information in the order (x, y, z, rx, ry, rz); None: the consumer's default."""
    method: str = ""
    """How it was measured, e.g. ``pnp``, ``icp``, ``ground_truth``."""
    inliers: int = 0
    """Correspondences supporting it (0 when not applicable)."""


@dataclass(frozen=True, eq=False)
class Trajectory(Message):
    """Poses of a run's frames as one estimate: ``odometry``, ``optimised``, ..."""

    schema_name: ClassVar[str] = "slamfront.Trajectory"
    label: str
    frames: np.ndarray
    """(N,) int64 frame indices."""
    poses: np.ndarray
    """(N, 4, 4) float64 camera-to-world transforms."""

    def foxglove(self, stamp_ns: int) -> list[tuple[str, Any]]:
        from slamfront.mcaplog import foxglove

        return [(f"trajectory/{self.label}", foxglove.poses_in_frame(self.poses, stamp_ns))]



# --- what a back end's own messages say, for the tools that read them --------------------


class LoopVerdict:
    """Mixed into a back end's message type that records its decision on one loop closure a
    detector reported. The loop-closure evaluation then scores the closures the back end
    verified and added (``n_verified``, ``precision_verified``, ``recall_verified``) without
    knowing the back end. The message has the fields ``frame`` (the query frame), ``match``
    and ``added``.
    """

    frame: int
    match: int
    added: bool


class PoseGraphRecord:
    """Mixed into a message type that holds a whole pose graph, so ``slamfront optimize
    run.mcap`` finds the last one in a log and optimises it again."""

    def to_graph(self, name: str = "log") -> Any:
        """The :class:`slamfront.core.posegraph.PoseGraph` (validated; raises CoreError)."""
        raise NotImplementedError


@dataclass(frozen=True, eq=False)
class AcceptThreshold(Message):
    """A loop detector's acceptance threshold: calibrated (``accept: auto``) or as given."""

    schema_name: ClassVar[str] = "slamfront.AcceptThreshold"
    detector: str
    threshold: float
    auto: bool
    source: str
    """``reference`` (against itself), ``stream`` (its first frames), ``queries`` (the queries'
    leave-the-answer-out confidences, logged whenever they move the threshold) or ``given``."""
    n_wrong: int
    """Wrong answers the threshold was calibrated on (0 when given)."""
    false_accept_rate: float
    largest_wrong: float
    """The most confident of them (NaN when given)."""


SHARED_MESSAGES: tuple[type[Message], ...] = (
    FrameInfo, Features, PlaceAssignment, LoopResult, RunMetrics, PointCloud, StageStatistics, RunEvent, LoopTruth,
    RelativePose, Trajectory, AcceptThreshold,
)
"""The framework's own message types; plugins declare theirs with ``slamfront_message_types``."""
