"""slamfront's own log messages: typed records that round-trip bit-exactly through MCAP.

Every stage output is a frozen dataclass deriving from :class:`Message`. The log stores
it as JSON (``message_encoding = "json"``) with a JSON Schema (``schema_encoding =
"jsonschema"``) generated from the dataclass, so Foxglove shows every field and any
reader can decode it without slamfront. NumPy arrays are stored as
``{"dtype": "<f4", "shape": [...], "data": <base64 of the raw bytes>}`` and floats as
JSON numbers (Python prints the shortest repr that round-trips) or, when not finite, as
the strings ``"nan"``, ``"inf"``, ``"-inf"``: decoding gives back identical bits.

Base64 is exact but no plot can read it. The array fields a person plots (poses,
transforms, per-candidate costs) are therefore also written as ``<field>_values``: the
same numbers as a flat row-major list of JSON numbers (``null`` where not finite), e.g.
``/frames.pose_values[3]`` is the ground-truth x in a Foxglove Plot (x, y, z of a 4x4
pose are items 3, 7 and 11). A class names these fields in ``plain_fields``; decoding
reads only the exact field, and encoding writes the list again from it, so the round
trip stays bit-exact.

A plugin that needs a message type of its own derives from :class:`Message` in its
module; :func:`message_class` finds it by schema name once the module is imported.
"""

from __future__ import annotations

import base64
import dataclasses
import functools
import json
import math
import types
import typing
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from slamfront.errors import LogError

_NONFINITE = {"nan": math.nan, "inf": math.inf, "-inf": -math.inf}


@functools.cache
def _type_hints(cls: type) -> dict[str, Any]:
    """``typing.get_type_hints`` of a message class, resolved once: evaluating the string
    annotations again for every decoded message took a tenth of a Nordland replay."""
    return typing.get_type_hints(cls)


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
        payload = {f.name: _encode(getattr(self, f.name)) for f in dataclasses.fields(self)}
        for name in self.plain_fields:
            payload[f"{name}{PLAIN_SUFFIX}"] = _plain(getattr(self, name))
        return json.dumps(payload, separators=(",", ":"), allow_nan=False).encode()

    @classmethod
    def from_json(cls, data: bytes | str) -> typing.Self:
        """Decode what :meth:`to_json` wrote; arrays come back with their dtype and bits."""
        raw = json.loads(data)
        hints = _type_hints(cls)
        kwargs = {}
        for f in dataclasses.fields(cls):
            if f.name in raw:
                kwargs[f.name] = _decode(raw[f.name], hints[f.name])
        return cls(**kwargs)

    @classmethod
    def json_schema(cls) -> dict[str, Any]:
        """A JSON Schema (draft 2020-12) describing the encoded message."""
        hints = _type_hints(cls)
        properties = {f.name: _schema_for(hints[f.name]) for f in dataclasses.fields(cls)}
        for name in cls.plain_fields:
            properties[f"{name}{PLAIN_SUFFIX}"] = _PLAIN_SCHEMA
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


PLAIN_SUFFIX = "_values"
"""Suffix of the plain-number copy of an array field (see ``Message.plain_fields``)."""


def decode_any(data: bytes | str) -> dict[str, Any]:
    """Decode any slamfront JSON message to a dict, arrays as NumPy arrays.

    Works without knowing the message class, so ``inspect`` and ``diff`` can read logs
    written by plugins that are not installed.
    """
    return {key: _decode(value, Any) for key, value in json.loads(data).items()}


def message_class(schema_name: str) -> type[Message]:
    """The imported :class:`Message` subclass with this schema name.

    :raises LogError: when no imported module defines it.
    """
    pending: list[type[Message]] = [Message]
    while pending:
        cls = pending.pop()
        if cls.schema_name == schema_name:
            return cls
        pending.extend(cls.__subclasses__())
    raise LogError(f"no message type named {schema_name!r} is known (is its plugin installed?)")


# --- encoding helpers -----------------------------------------------------------------


def _encode(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        array = np.ascontiguousarray(value)
        return {
            "dtype": array.dtype.str,
            "shape": list(array.shape),
            "data": base64.b64encode(array.tobytes()).decode("ascii"),
        }
    if isinstance(value, (float, np.floating)):
        value = float(value)
        if math.isfinite(value):
            return value
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf")
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, dict):
        return {str(k): _encode(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_encode(v) for v in value]
    return value


def _plain(value: Any) -> list[float | int | None] | None:
    """An array as a flat row-major list of JSON numbers (None where not finite)."""
    if value is None:
        return None
    flat = np.asarray(value).ravel()
    if flat.dtype.kind in "iub":
        return [int(v) for v in flat]
    return [float(v) if math.isfinite(v) else None for v in flat.astype(np.float64)]


def _is_array_payload(value: Any) -> bool:
    return isinstance(value, dict) and value.keys() == {"dtype", "shape", "data"}


def _decode(value: Any, hint: Any) -> Any:
    if value is None:
        return None
    if _is_array_payload(value):
        array = np.frombuffer(base64.b64decode(value["data"]), dtype=np.dtype(value["dtype"]))
        return array.reshape(value["shape"]).copy()
    if isinstance(value, str) and value in _NONFINITE and _accepts_float(hint):
        return _NONFINITE[value]
    if isinstance(value, dict):
        inner = _dict_value_hint(hint)
        return {k: _decode(v, inner) for k, v in value.items()}
    if isinstance(value, list):
        inner = _list_item_hint(hint)
        decoded = [_decode(v, inner) for v in value]
        return tuple(decoded) if typing.get_origin(strip_optional(hint)) is tuple else decoded
    if isinstance(value, int) and strip_optional(hint) is float:
        return float(value)
    return value


def strip_optional(hint: Any) -> Any:
    """``X | None`` -> ``X``; any other type hint unchanged."""
    if isinstance(hint, types.UnionType) or typing.get_origin(hint) is typing.Union:
        args = [a for a in typing.get_args(hint) if a is not type(None)]
        if len(args) == 1:
            return args[0]
    return hint


def _accepts_float(hint: Any) -> bool:
    if hint is Any or hint is float:
        return True
    if isinstance(hint, types.UnionType) or typing.get_origin(hint) is typing.Union:
        return any(_accepts_float(a) for a in typing.get_args(hint))
    return False


def _list_item_hint(hint: Any) -> Any:
    args = typing.get_args(strip_optional(hint))
    return args[0] if args else Any


def _dict_value_hint(hint: Any) -> Any:
    args = typing.get_args(strip_optional(hint))
    return args[1] if len(args) == 2 else Any


_ARRAY_SCHEMA = {
    "type": "object",
    "description": "NumPy array: dtype string, shape, raw little/big-endian bytes in base64",
    "properties": {
        "dtype": {"type": "string"},
        "shape": {"type": "array", "items": {"type": "integer"}},
        "data": {"type": "string", "contentEncoding": "base64"},
    },
}


_PLAIN_SCHEMA = {
    "anyOf": [{"type": "array", "items": {"type": ["number", "null"]}}, {"type": "null"}],
    "description": "the array field of the same name as a flat row-major list of plain numbers "
    "(null where not finite), for plots; a 4x4 pose's x, y, z are items 3, 7, 11",
}


def _schema_for(hint: Any) -> dict[str, Any]:
    origin = typing.get_origin(hint)
    if isinstance(hint, types.UnionType) or origin is typing.Union:
        options = [_schema_for(a) for a in typing.get_args(hint) if a is not type(None)]
        nullable = type(None) in typing.get_args(hint)
        schema = options[0] if len(options) == 1 else {"anyOf": options}
        return {"anyOf": [schema, {"type": "null"}]} if nullable else schema
    if hint is np.ndarray:
        return _ARRAY_SCHEMA
    if hint is bool:
        return {"type": "boolean"}
    if hint is int:
        return {"type": "integer"}
    if hint is float:
        return {"anyOf": [{"type": "number"}, {"enum": list(_NONFINITE)}]}
    if hint is str:
        return {"type": "string"}
    if origin in (list, tuple):
        return {"type": "array", "items": _schema_for(_list_item_hint(hint))}
    if origin is dict:
        return {"type": "object", "additionalProperties": _schema_for(_dict_value_hint(hint))}
    return {}


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


# --- localization ----------------------------------------------------------------------


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


@dataclass(frozen=True, eq=False)
class BowStatistics(Message):
    """A bag-of-words loop detector's state after one frame (vocabulary, memory, filter, time).

    Counts refer to the state after the frame was processed. Float fields are NaN
    where they do not apply (no features; no other rule tracked).
    """

    schema_name: ClassVar[str] = "slamfront.BowStatistics"
    volatile_fields: ClassVar[tuple[str, ...]] = ("processing_seconds",)
    frame: int
    n_features: int
    new_words: int
    vocabulary_size: int
    """Words kept so far, in working or long-term memory (Wang et al. 2017, fig. 4)."""
    active_words: int
    """Words the nearest-word search scans (those of STM and WM places)."""
    quantisation_error: float
    """Mean distance of the frame's features to their words (Wang et al. 2017, fig. 6), in the
    vocabulary's unit: squared L2 (float descriptors) or bits."""
    by_ratio_test: int = -1
    """Features the ratio test ND / NND decided (the rest: ND > T_ND2 or ND < T_ND1); -1: none quantised."""
    by_nd_high: int = -1
    """Features that became words because ND > T_ND2, without the ratio test (greedy rule)."""
    update_rule: str = "greedy"
    other_rule: str = ""
    """The other update rule, when the detector also tracks its vocabulary for comparison."""
    other_vocabulary_size: int = -1
    other_quantisation_error: float = float("nan")
    place: int = -1
    """The place this frame created or was merged into; -1 for none (no features, a query)."""
    merged: bool = False
    """The frame was more similar than T_sim to the previous one and merged into its place."""
    stm_size: int = 0
    wm_size: int = 0
    """Places in working memory after this frame (Wang et al. 2017, fig. 9a)."""
    ltm_size: int = 0
    transferred: int = 0
    retrieved: int = 0
    no_loop_posterior: float = float("nan")
    max_loop_posterior: float = float("nan")
    """The largest p(S_t = i) (Wang et al. 2017, fig. 7)."""
    loop_threshold: float = float("nan")
    """T_loop: a loop is accepted when ``no_loop_posterior`` is below it."""
    processing_seconds: float = 0.0
    """This frame's detector time (Wang et al. 2017, fig. 9b)."""
    searched_words: int = 0
    """Words the nearest-word search scanned for this frame (the time grows with them)."""
    searched_places: int = 0
    """Places in working memory when the frame was searched (or would have been)."""
    modelled_seconds: float = float("nan")
    """The deterministic time model's seconds for this frame, when the budget is compared with it."""
    time_budget_seconds: float = 0.0


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


@dataclass(frozen=True, eq=False)
class LoopConstraint(Message):
    """The back end's decision on one loop closure: added to the graph, or skipped and why."""

    schema_name: ClassVar[str] = "slamfront.LoopConstraint"
    plain_fields: ClassVar[tuple[str, ...]] = ("transform",)
    frame: int
    match: int
    added: bool
    reason: str
    transform: np.ndarray | None = None
    """(4, 4) float64 pose of ``frame`` in ``match``'s camera, when verified."""
    inliers: int = 0

    def foxglove(self, stamp_ns: int) -> list[tuple[str, Any]]:
        from slamfront.mcaplog import foxglove

        verdict = "added" if self.added else "skipped"
        text = f"loop closure {self.match} -> {self.frame} {verdict}: {self.reason}"
        return [("log", foxglove.log_line(text, stamp_ns, "info" if self.added else "warning", "backend"))]


@dataclass(frozen=True, eq=False)
class PoseGraphState(Message):
    """A pose graph as a back end built it, with its initial and optimised poses.

    ``slamfront optimize run.mcap`` re-optimises it; Foxglove shows its loop closures
    as line markers between the optimised positions.
    """

    schema_name: ClassVar[str] = "slamfront.PoseGraphState"
    dim: int
    vertices: np.ndarray
    """(N,) int64 vertex ids (frame indices), ascending."""
    initial: np.ndarray
    """(N, d+1, d+1) float64 poses before optimisation."""
    sources: np.ndarray
    """(M,) int64 edge start vertices."""
    targets: np.ndarray
    """(M,) int64 edge end vertices."""
    measurements: np.ndarray
    """(M, d+1, d+1) float64 measured T_source^-1 T_target."""
    information: np.ndarray
    """(M, k, k) float64 information, translation first (k = 3 or 6)."""
    optimised: np.ndarray | None = None
    """(N, d+1, d+1) float64 poses after optimisation, when done."""

    @classmethod
    def from_graph(cls, graph: Any, initial: np.ndarray, optimised: np.ndarray | None) -> PoseGraphState:
        """From a :class:`slamfront.core.posegraph.PoseGraph` and its poses."""
        return cls(
            dim=graph.dim, vertices=graph.ids, initial=initial, sources=graph.sources, targets=graph.targets,
            measurements=graph.measurements, information=graph.information, optimised=optimised,
        )

    def to_graph(self, name: str = "log") -> Any:
        """The :class:`slamfront.core.posegraph.PoseGraph` (validated; raises CoreError)."""
        from slamfront.core.posegraph import make_graph

        return make_graph(
            dim=self.dim, ids=self.vertices, poses=self.initial, sources=self.sources, targets=self.targets,
            measurements=self.measurements, information=self.information, name=name,
        )

    def loop_segments(self) -> np.ndarray:
        """(L, 2, d) endpoints of the loop closures (non-consecutive ids) at the latest poses."""
        poses = self.optimised if self.optimised is not None else self.initial
        loops = np.abs(self.targets - self.sources) != 1
        index = np.searchsorted(self.vertices, np.stack([self.sources[loops], self.targets[loops]], axis=1))
        return poses[index, : self.dim, self.dim]

    def foxglove(self, stamp_ns: int) -> list[tuple[str, Any]]:
        from slamfront.mcaplog import foxglove

        segments = self.loop_segments()
        if self.dim == 2:  # Foxglove draws in 3-D: planar graphs at z = 0
            segments = np.concatenate([segments, np.zeros((*segments.shape[:2], 1))], axis=-1)
        entity = foxglove.line_entity("loop_closures", segments, stamp_ns, (0.9, 0.1, 0.1, 1.0), strip=False)
        return [("loop_closures", foxglove.scene_update([entity]))]
