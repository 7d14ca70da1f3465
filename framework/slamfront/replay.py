"""Replaying a run from its log: ``slamfront replay LOG [--recipe R] [--from STAGE]``.

A log holds everything a run saw and produced: the frames' info (index, time, traversal,
pose), images, intrinsics, every stage's outputs, each stage's end-of-run statistics,
the source's loop ground truth and the resolved recipe. A replay is an ordinary run
through the same interfaces as any other: its source (:class:`RecordedSource`) reads the
frames from the log, and each stage before ``STAGE`` is substituted by a
:class:`RecordedStage` that gives back what the original stage logged; the later stages
run again with the recipe given (the log's own by default). Message types come from the
installed plugins (and, with ``--trust-log``, the recipe's plugin modules), never from a
module the log names.

A stage that reads pixels (``Stage.reads_pixels``: descriptors, localizers,
registration) can only be re-run when the log stores them exactly: PNG images at full
width and depth as ``32FC1`` (``log.image_format: auto``, the default, does so when a
stage after the first reads pixels). Otherwise ``--from`` defaults to the first stage
after the last one that needs pixels.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
from pydantic import ConfigDict, ValidationError

from slamfront.core.loops import LoopGroundTruth
from slamfront.errors import LogError, PluginError, RecipeError
from slamfront.feeds import FrameLogger
from slamfront.frame import Camera, Frame
from slamfront.mcaplog import foxglove
from slamfront.mcaplog.reader import (
    RECIPE_ATTACHMENT,
    LoggedMessage,
    LogSummary,
    embedded_recipe_text,
    read_messages,
    read_messages_and_gaps,
    summarize,
)
from slamfront.mcaplog.topics import (
    CALIBRATION_TOPIC,
    DEPTH_TOPIC,
    EVENTS_TOPIC,
    FRAME_TOPICS,
    FRAMES_TOPIC,
    IMAGE_TOPIC,
    LOOP_TRUTH_TOPIC,
    stage_of,
    statistics_topic,
)
from slamfront.mcaplog.validate import check_channels, check_messages
from slamfront.mcaplog.writer import RunLogWriter
from slamfront.message_types import MessageTypes
from slamfront.messages import FrameInfo, LoopTruth, Message, RunEvent, StageStatistics
from slamfront.outputs import same_file
from slamfront.plugin import STAGE_KINDS, Plugin, PluginConfig, Source, Stage, StageInputs
from slamfront.recipe import LogOptions, Recipe, StageSpec, build_pipeline, load_yaml, parse_recipe
from slamfront.registry import PluginRegistry, config_context
from slamfront.runtime import RunResult, execute_run
from slamfront.trust import refuse_untrusted


def log_recipe_data(log: Path) -> dict[str, Any]:
    """The recipe a log embeds (attachment ``recipe.yaml``) as plain data, parsed with
    YAML's costs bounded (:func:`slamfront.recipe.load_yaml`)."""
    origin = f"{log}:{RECIPE_ATTACHMENT}"
    raw = load_yaml(embedded_recipe_text(log), origin, LogError)
    if not isinstance(raw, dict):
        raise LogError(f"{origin}: a recipe must be a YAML mapping, got {type(raw).__name__}")
    return raw


def log_recipe(log: Path) -> Recipe:
    """The resolved recipe a log embeds (attachment ``recipe.yaml``)."""
    return parse_recipe(log_recipe_data(log), f"{log}:{RECIPE_ATTACHMENT}")


@dataclass
class ReplayPlan:
    """What a replay reads from the log and what it runs again."""

    log: Path
    original: Recipe
    """The recipe embedded in the log."""
    recipe: Recipe
    """The recipe the replay runs: the original's source and recorded stages, the given
    recipe's stages from ``from_kind`` on."""
    from_kind: str
    recorded: tuple[str, ...]
    """Stage kinds read from the log (never called)."""
    rerun: tuple[str, ...]
    needs_pixels: bool
    """Some re-run stage reads pixels: images (and depth) are decoded from the log."""
    summary: LogSummary
    registry: PluginRegistry
    types: MessageTypes
    """What decodes the log's messages: the registry's message types."""
    pixels_problem: str | None = None
    """Why the log's images/depth are not the frames' exact pixels (None when they are)."""
    damage: str | None = None
    """What the log lost, when a damaged log is replayed as far as it can be read."""


def _pixels_problem(original: Recipe, first: FrameInfo | None) -> str | None:
    """Why the log's images/depth are not the frames' exact pixels, or None when they are."""
    options = original.log
    if not options.images:
        return "the log stores no images (log.images: false)"
    if options.image_format != "png":
        return f"its images are {options.image_format.upper()} (lossy)"
    if first is not None and options.image_max_width < first.width:
        return f"its images are downscaled to {options.image_max_width} px (frames are {first.width} px wide)"
    if first is not None and first.has_depth and not (options.depth and options.depth_encoding == "32FC1"):
        return "it stores no exact depth (needs log.depth: true, log.depth_encoding: 32FC1)"
    return None


def _same_stage(kind: str, a: StageSpec | None, b: StageSpec | None, registry: PluginRegistry) -> bool:
    if a is None or b is None:
        return a is b
    if a.plugin != b.plugin:
        return False
    try:
        config = registry.get(kind, a.plugin).cls.Config  # type: ignore[arg-type]
        context = config_context(registry)
        return config.model_validate(a.params, context=context).model_dump(mode="json") == config.model_validate(
            b.params, context=context
        ).model_dump(mode="json")
    except Exception:  # noqa: BLE001 (unknown plugin or invalid params: compare as written)
        return a.params == b.params


EVALUATION = "evaluation"
"""``--from evaluation``: read every stage from the log, evaluate and report again."""


def _earliest_replayable(kinds: list[str], pixel_readers: list[str], problem: str | None) -> str:
    """The first stage after the last one that reads pixels the log does not keep exactly
    (:data:`EVALUATION` when there is none: only the evaluation runs again)."""
    later = kinds[kinds.index(pixel_readers[-1]) + 1 :] if problem and pixel_readers else kinds
    return later[0] if later else EVALUATION


def plan_replay(
    log: Path,
    recipe: Recipe | None = None,
    recipe_origin: str = "--recipe",
    from_kind: str | None = None,
    registry: PluginRegistry | None = None,
    trust_log: bool = False,
    salvage: bool = False,
) -> ReplayPlan:
    """Decide what a replay of ``log`` reads and what it re-runs.

    :param recipe: the recipe to replay with (default: the log's own).
    :param from_kind: the first stage to run again (default: the earliest the log can feed;
        :data:`EVALUATION` reads every stage from the log and only evaluates again).
    :param trust_log: let the log's recipe import its ``plugin_modules`` and name paths
        outside the data root (:mod:`slamfront.trust`); refused otherwise.
    :param salvage: replay a damaged log as far as it can be read (else refused).
    :raises RecipeError: the recipe changes a stage before ``from_kind`` or the source,
        or the log's recipe needs trust it was not given.
    :raises LogError: the log is damaged, or lacks what the re-run stages need.
    """
    summary = summarize(log)
    if not summary.complete and not salvage:
        raise LogError(
            f"{log}: the log is damaged, so a replay of it would silently lack what was lost ({summary.problem}); "
            "pass --salvage to replay what can be read, or `slamfront recover` it first"
        )
    check_channels(log, summary.topics)
    check_messages(log, salvage=not summary.complete)
    raw = log_recipe_data(log)
    if not trust_log:
        refuse_untrusted(raw, f"{log}:{RECIPE_ATTACHMENT}")
    original = parse_recipe(raw, f"{log}:{RECIPE_ATTACHMENT}")
    wanted = recipe or original
    registry = registry or PluginRegistry(modules=[*original.plugin_modules, *wanted.plugin_modules])
    if wanted.source.model_dump() != original.source.model_dump():
        raise RecipeError(
            f"{recipe_origin}: source differs from the log's ({original.source.plugin}); a replay reads its "
            "frames from the log, so the recipe must keep the log's source"
        )
    frames = read_messages(log, [FRAMES_TOPIC], strict=False)
    first = next((m.decoded for m in frames), None)
    frames.close()
    problem = _pixels_problem(original, first)
    kinds = [k for k in STAGE_KINDS if getattr(wanted, k) is not None or getattr(original, k) is not None]

    def reads_pixels(kind: str) -> bool:
        spec = getattr(wanted, kind)
        if spec is None:
            return False
        cls = registry.get(kind, spec.plugin).cls
        try:
            config = cls.Config.model_validate(spec.params, context=config_context(registry))
        except ValidationError:  # reported with its field when the pipeline is built
            return bool(cls.reads_pixels)
        return bool(cls.reads_pixels_with(config))

    if from_kind is None:
        from_kind = _earliest_replayable(kinds, [k for k in kinds if reads_pixels(k)], problem)
    if from_kind not in (*STAGE_KINDS, EVALUATION):
        raise RecipeError(f"--from {from_kind}: not a stage kind; stages are {', '.join(STAGE_KINDS)} (or {EVALUATION})")
    if from_kind != EVALUATION and getattr(wanted, from_kind) is None:
        raise RecipeError(f"--from {from_kind}: the recipe has no {from_kind} stage (it has {', '.join(kinds)})")
    start = STAGE_KINDS.index(from_kind) if from_kind != EVALUATION else len(STAGE_KINDS)
    recorded = tuple(k for k in kinds if STAGE_KINDS.index(k) < start and getattr(original, k) is not None)
    rerun = tuple(k for k in kinds if STAGE_KINDS.index(k) >= start and getattr(wanted, k) is not None)
    for kind in kinds:
        if STAGE_KINDS.index(kind) < start and getattr(wanted, kind) is not None:
            if not _same_stage(kind, getattr(wanted, kind), getattr(original, kind), registry):
                remedy = (
                    f"it reads the frames' pixels and {problem}, so only a new run can change it"
                    if problem and reads_pixels(kind) else f"replay --from {kind} (or earlier) to run it again"
                )
                raise RecipeError(
                    f"{recipe_origin}: {kind} differs from the log's, but stages before --from {from_kind} are read "
                    f"from the log; {remedy}"
                )
    pixel_stages = [k for k in rerun if reads_pixels(k)]
    if pixel_stages and problem:
        raise LogError(
            f"{log}: cannot re-run the {pixel_stages[0]} stage ({getattr(wanted, pixel_stages[0]).plugin}): it reads "
            f"the frames' pixels and {problem}; replay from a later stage, or log with log.image_format: png, "
            "log.image_max_width at least the image width (and log.depth_encoding: 32FC1 for depth)"
        )
    merged = wanted.model_dump()
    merged["source"] = original.source.model_dump()
    merged["plugin_modules"] = list(dict.fromkeys([*original.plugin_modules, *wanted.plugin_modules]))
    for kind in recorded:
        merged[kind] = getattr(original, kind).model_dump()
    effective = parse_recipe(merged, recipe_origin)
    return ReplayPlan(
        log=log, original=original, recipe=effective, from_kind=from_kind, recorded=recorded, rerun=rerun,
        needs_pixels=bool(pixel_stages), summary=summary, registry=registry, types=registry.message_types(),
        pixels_problem=problem,
        damage=None if summary.complete else summary.problem,
    )


class RecordedConfig(PluginConfig):
    """The original source's parameters, as recorded (not validated: its plugin may be absent)."""

    model_config = ConfigDict(extra="allow", frozen=True)


@dataclass
class RecordedFrame:
    """One frame of the original run as its log holds it."""

    info: LoggedMessage
    """Its ``/frames`` message."""
    logged: list[LoggedMessage] = field(default_factory=list)
    """Its other frame topics (image, depth, calibration, poses), as written."""
    outputs: dict[str, list[LoggedMessage]] = field(default_factory=dict)
    """What each stage read from the log logged while the frame was processed, in order."""


class LogRecording:
    """The original run, read once from its log in the order it was written: frame by frame,
    then what the stages logged at the end. The replay's source and its recorded stages
    share it, so the log is read once however many stages it feeds.

    Messages written between one frame's ``/frames`` message and the next belong to that
    frame; a ``finish`` event on ``/run/events`` starts the end of the run. A log that
    ends without it (the run was interrupted) loses its last frame, whose stage outputs
    may be incomplete.
    """

    def __init__(self, plan: ReplayPlan) -> None:
        self.plan = plan
        self.current: RecordedFrame | None = None
        """The frame the source gave last."""
        self.finish: dict[str, list[LoggedMessage]] = {}
        self.statistics: dict[str, dict[str, Any]] = {}
        self.truth: LoopTruth | None = None
        self.dropped_last = False
        self.lost_frames = 0
        """Frames left out because damage was met while gathering their messages."""

    def frames(self) -> Iterator[RecordedFrame]:
        """The original frames, each with what the recorded stages logged for it."""
        recorded = set(self.plan.recorded)
        pending: RecordedFrame | None = None
        finished = False
        for logged in read_messages_and_gaps(self.plan.log, strict=False, types=self.plan.types):
            if logged is None:  # damage: the frame being gathered may lack messages, leave it out
                self.lost_frames += pending is not None
                pending = None
                continue
            topic, kind = logged.topic, stage_of(logged.topic)
            if topic == LOOP_TRUTH_TOPIC:
                self.truth = logged.decoded
            elif finished:
                if kind in recorded and topic == statistics_topic(kind):
                    statistics: StageStatistics = logged.decoded
                    self.statistics[kind] = dict(statistics.values)
                elif kind in recorded:
                    self.finish.setdefault(kind, []).append(logged)
            elif topic == FRAMES_TOPIC:
                if pending is not None:
                    yield self._enter(pending)
                pending = RecordedFrame(logged)
            elif topic == EVENTS_TOPIC:
                event: RunEvent = logged.decoded
                if event.event == "finish":
                    if pending is not None:
                        yield self._enter(pending)
                    pending, finished = None, True
            elif pending is not None:
                if kind is None and topic in FRAME_TOPICS:
                    pending.logged.append(logged)
                elif kind in recorded and topic != statistics_topic(kind):
                    pending.outputs.setdefault(kind, []).append(logged)
        self.dropped_last = pending is not None

    def _enter(self, frame: RecordedFrame) -> RecordedFrame:
        self.current = frame
        return frame


class RecordedFrames(FrameLogger):
    """Logs a replayed frame by copying the original records unchanged (images stay as
    they were encoded, whatever the replay decodes from them)."""

    def __init__(self, recording: LogRecording) -> None:
        self.recording = recording

    def write(self, log: RunLogWriter, frame: Frame) -> FrameInfo:
        current = self.recording.current
        assert current is not None and frame.index == current.info.decoded.frame
        for logged in (current.info, *current.logged):
            log.copy(logged)
        return current.info.decoded


class RecordedSource(Source):
    """The original run's source as seen through its log: its frames (pixels decoded
    from the logged images when a re-run stage needs them), its loop ground truth."""

    name = "recorded"

    def __init__(self, plan: ReplayPlan, recording: LogRecording) -> None:
        super().__init__(RecordedConfig.model_validate(plan.original.source.params))
        self.plan = plan
        self.recording = recording
        self.name = plan.original.source.plugin  # type: ignore[misc]
        recorded = plan.summary.metadata.get("plugins", {}).get("source", plan.original.source.plugin)
        self.provenance = f"{recorded}, replayed from {plan.log}"
        self.truth_note = ""
        self._truth: LoopGroundTruth | None = None

    def __len__(self) -> int:
        try:
            return self.plan.summary.topic(FRAMES_TOPIC).count
        except KeyError:
            return 0

    def frames(self) -> Iterator[Frame]:
        for recorded in self.recording.frames():
            yield self._frame(recorded)

    def frame_logger(self, options: LogOptions) -> FrameLogger:
        return RecordedFrames(self.recording)

    def loop_ground_truth(self) -> LoopGroundTruth | None:
        """The ground truth logged by the original run; failing that, the original source's."""
        if self._truth is None and not self.truth_note:
            message = self.recording.truth or self._logged_truth()
            if message is not None:
                self._truth = LoopGroundTruth(queries=message.queries, indptr=message.indptr, matches=message.matches)
            else:
                self._truth = self._from_original_source()
        return self._truth

    def _logged_truth(self) -> LoopTruth | None:
        found = None
        for logged in read_messages(self.plan.log, [LOOP_TRUTH_TOPIC], strict=False, types=self.plan.types):
            found = logged.decoded
        return found

    def loop_ground_truth_at(self, tolerance: int) -> LoopGroundTruth | None:
        """Other tolerances (``eval.tolerances``) are not in the log: they come from the
        original source when its plugin and data are here, else there are none."""
        try:
            return self._original_source().loop_ground_truth_at(tolerance)
        except Exception:  # noqa: BLE001 (the evaluation then notes the tolerance as not scored)
            return None

    def _original_source(self) -> Source:
        spec = self.plan.original.source
        cls = self.plan.registry.get("source", spec.plugin).cls
        config = cls.Config.model_validate(spec.params, context=config_context(self.plan.registry))
        return cls(config)  # type: ignore[return-value]

    def _from_original_source(self) -> LoopGroundTruth | None:
        try:
            truth = self._original_source().loop_ground_truth()
        except Exception as exc:  # noqa: BLE001 (no ground truth is a valid outcome)
            self.truth_note = f"; no loop ground truth in the log, nor from its source ({exc})"
            return None
        self.truth_note = "; loop ground truth rebuilt from the recipe's source (the log has none)"
        return truth

    def ending_note(self) -> str:
        plan, recording = self.plan, self.recording
        read = ", ".join(plan.recorded) or "none"
        note = f"; replay of {plan.log} from {plan.from_kind} (read from the log: {read})"
        if recording.dropped_last:
            note += "; the log ends without the run's finish, so its last frame was left out"
        if plan.damage:
            lost = f", {recording.lost_frames} frames next to the damage were left out" if recording.lost_frames else ""
            note += f"; the log is damaged and was replayed as far as it could be read{lost} (lost: {plan.damage})"
        return note + self.truth_note

    def _frame(self, recorded: RecordedFrame) -> Frame:
        info: FrameInfo = recorded.info.decoded
        by_topic = {m.topic: m for m in recorded.logged}
        camera = None
        if CALIBRATION_TOPIC in by_topic:
            k = CameraCalibration.FromString(by_topic[CALIBRATION_TOPIC].data)
            camera = Camera(fx=k.K[0], fy=k.K[4], cx=k.K[2], cy=k.K[5], width=k.width, height=k.height)
        image, depth = self._pixels(info, by_topic)
        return Frame(
            index=info.frame, timestamp=info.timestamp, image=image, traversal=info.traversal,  # type: ignore[arg-type]
            sequence_index=info.sequence_index, name=info.name, depth=depth, camera=camera, pose=info.pose,
            scene=info.scene,
        )

    def _pixels(self, info: FrameInfo, by_topic: Mapping[str, LoggedMessage]) -> tuple[np.ndarray, np.ndarray | None]:
        shape = (info.height, info.width)
        if not self.plan.needs_pixels:
            # no re-run stage looks at pixels: a zero-cost stand-in of the right shape
            image = np.broadcast_to(np.zeros((1, 1, 3), np.uint8), (*shape, 3))
            depth = np.broadcast_to(np.zeros((1, 1), np.float32), shape) if info.has_depth else None
            return image, depth
        where = f"{self.plan.log}: frame {info.frame}"
        if IMAGE_TOPIC not in by_topic:
            raise LogError(f"{where} has no image on {IMAGE_TOPIC}")
        image = foxglove.decode_image(CompressedImage.FromString(by_topic[IMAGE_TOPIC].data), f"{where} ({IMAGE_TOPIC})")
        if image.shape[:2] != shape:
            raise LogError(f"{where}: the logged image is {image.shape[1]}x{image.shape[0]}, the frame was {info.width}x{info.height}")
        depth = None
        if info.has_depth:
            if DEPTH_TOPIC not in by_topic:
                raise LogError(f"{where} has no depth on {DEPTH_TOPIC}")
            depth = foxglove.decode_depth(RawImage.FromString(by_topic[DEPTH_TOPIC].data), f"{where} ({DEPTH_TOPIC})")
        return image, depth


class RecordedStage(Stage):
    """A stage read from the log instead of run: for each frame it gives back what the
    original stage logged for it, at the end what it logged when the run finished, and
    its logged statistics. It carries the original plugin's name, version, config and
    class flags (``produces_global``, ``reads_pixels``, ...), so later stages' checks see
    the stage they expect; its state is not there (the stage never ran).
    """

    def __init__(self, plugin: type[Stage], config: PluginConfig, recording: LogRecording) -> None:
        super().__init__(config)
        for attribute, value in _class_flags(plugin).items():
            setattr(self, attribute, value)
        self.recording = recording
        self.provenance = f"{plugin.name}=={plugin.version}, read from {recording.plan.log}"

    def process(self, inputs: StageInputs) -> list[Message]:
        current = self.recording.current
        assert current is not None and current.info.decoded.frame == inputs.frame.index
        return self._decoded(current.outputs.get(self.kind, ()))

    def finish(self) -> list[Message]:
        return self._decoded(self.recording.finish.get(self.kind, ()))

    def statistics(self) -> dict[str, float | int]:
        return self.recording.statistics.get(self.kind, {})

    @staticmethod
    def _decoded(logged: Iterable[LoggedMessage]) -> list[Message]:
        # the Foxglove messages that draw them are written again from the messages themselves
        return [m.decoded for m in logged if m.message_encoding == "json"]

    @classmethod
    def substitute(cls, recording: LogRecording) -> Callable[[type[Plugin], PluginConfig], Plugin]:
        """For :func:`~slamfront.recipe.build_pipeline`: a stage of the same plugin, read from the log."""

        def make(plugin: type[Plugin], config: PluginConfig) -> Plugin:
            assert issubclass(plugin, Stage)
            _check_types(recording.plan, plugin.kind)
            named = type(f"Recorded{plugin.__name__}", (cls,), {"__doc__": cls.__doc__})
            return named(plugin, config, recording)

        return make


def _class_flags(plugin: type) -> dict[str, Any]:
    """The plugin class's public constants (name, kind, version, flags like ``produces_local``)."""
    flags = {}
    for attribute in dir(plugin):
        value = getattr(plugin, attribute)
        if not attribute.startswith("_") and isinstance(value, (bool, int, float, str, tuple)):
            flags[attribute] = value
    return flags


def _check_types(plan: ReplayPlan, kind: str) -> None:
    """Refuse to read a stage from the log when one of its message types is not installed.

    :raises LogError: naming the topic and the type.
    """
    for topic in plan.summary.topics:
        if stage_of(topic.topic) == kind and topic.message_encoding == "json":
            plan.types.require(topic.schema_name, f"{plan.log}: {topic.topic}")


def replay_log(
    log: Path,
    out_dir: Path,
    recipe: Recipe | None = None,
    recipe_origin: str | None = None,
    from_kind: str | None = None,
    progress: bool | None = None,
    trust_log: bool = False,
    salvage: bool = False,
) -> RunResult:
    """Replay ``log`` into ``out_dir`` (``run.mcap``, ``metrics.json``, ``report.md``).

    The run is an ordinary run whose source reads the log (:class:`RecordedSource`) and
    whose stages before ``from_kind`` are :class:`RecordedStage` objects.

    :param recipe: replay with this recipe instead of the log's own.
    :param from_kind: the first stage to run again (see :func:`plan_replay`).
    :param trust_log: see :func:`plan_replay`.
    :param salvage: replay a damaged log as far as it can be read; the result's notes
        and the new log's last ``/log`` line say what was lost.
    """
    log = Path(log)
    if same_file(out_dir / "run.mcap", log):  # by identity: hard links and bind mounts too
        raise LogError(f"{log}: a replay cannot overwrite the log it reads; choose another -o folder")
    origin = recipe_origin or f"{log}:{RECIPE_ATTACHMENT}"
    plan = plan_replay(log, recipe, origin, from_kind, trust_log=trust_log, salvage=salvage)
    recording = LogRecording(plan)
    source = RecordedSource(plan, recording)
    substitutes: dict[str, Callable[[type[Plugin], PluginConfig], Plugin]] = {
        "source": lambda _cls, _config: source,
        **{kind: RecordedStage.substitute(recording) for kind in plan.recorded},
    }
    try:
        pipeline = build_pipeline(plan.recipe, origin, registry=plan.registry, substitutes=substitutes)
    except PluginError as exc:
        if not plan.recorded:
            raise
        raise PluginError(
            f"{exc} (in this replay the {', '.join(plan.recorded)} stage(s) before --from {plan.from_kind} are read "
            "from the log: they give their logged messages, not their state; replay from an earlier stage)"
        ) from exc
    metadata = {
        "replay": {
            "log": str(log),
            "from": plan.from_kind,
            "recorded_stages": ",".join(plan.recorded),
            "rerun_stages": ",".join(plan.rerun),
            **({"damage": plan.damage} if plan.damage else {}),
        }
    }
    result = execute_run(pipeline, origin, out_dir, progress, metadata=metadata, input_files=[log])
    if not plan.rerun:
        result.notes.append(
            f"no stage ran again: every stage was read from {log}"
            + (f" (each reads the frames' pixels and {plan.pixels_problem})" if from_kind is None and plan.pixels_problem else "")
            + "; the replay evaluated and reported the logged outputs again"
        )
    if plan.damage:
        lost = f" ({recording.lost_frames} frames next to the damage left out)" if recording.lost_frames else ""
        result.notes.append(f"{log} is damaged; replayed what could be read{lost}; lost: {plan.damage}")
    return result
