"""Replaying a run from its log: ``slamfront replay LOG [--recipe R] [--from STAGE]``.

A log holds everything a run saw and produced: the frames' info (index, time, traversal,
pose), images, intrinsics, every stage's outputs, each stage's end-of-run statistics,
the source's loop ground truth and the resolved recipe. A replay reads the frames from
the log instead of the source, copies the messages of the stages before ``STAGE`` to
the new log and feeds them to the later stages, which run again with the recipe given
(the log's own by default). The stages read from the log are never called.

A stage that reads pixels (``Stage.reads_pixels``: descriptors, localizers,
registration) can only be re-run when the log stores them exactly: PNG images at full
width and depth as ``32FC1``. By default, logs keep 320-px JPEGs, so ``--from``
defaults to the first stage after the last one that needs pixels.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
from pydantic import ConfigDict, ValidationError

from slamfront.core.loops import LoopGroundTruth
from slamfront.data import data_root
from slamfront.errors import LogError, PluginError, RecipeError
from slamfront.feeds import FrameFeed, FrameStep
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
    STATISTICS_SUFFIX,
    stage_of,
)
from slamfront.mcaplog.validate import check_channels, check_messages
from slamfront.mcaplog.writer import RunLogWriter
from slamfront.messages import FrameInfo, LoopTruth, RunEvent, StageStatistics, message_class
from slamfront.outputs import same_file
from slamfront.plugin import STAGE_KINDS, PluginConfig, Source, Stage
from slamfront.recipe import Recipe, StageSpec, build_pipeline, load_yaml, parse_recipe
from slamfront.registry import PluginRegistry
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
        context = {"data_root": data_root()}
        return config.model_validate(a.params, context=context).model_dump(mode="json") == config.model_validate(
            b.params, context=context
        ).model_dump(mode="json")
    except Exception:  # noqa: BLE001 (unknown plugin or invalid params: compare as written)
        return a.params == b.params


def _earliest_replayable(log: Path, kinds: list[str], pixel_readers: list[str], problem: str | None) -> str:
    """The first stage after the last one that reads pixels the log does not keep exactly."""
    later = kinds[kinds.index(pixel_readers[-1]) + 1 :] if problem and pixel_readers else kinds
    if not later:
        raise LogError(
            f"{log}: every stage of the recipe needs the frames' pixels and {problem}; "
            "re-run the recipe instead (`slamfront inspect LOG --recipe` prints it)"
        )
    return later[0]


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
    :param from_kind: the first stage to run again (default: the earliest the log can feed).
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
            config = cls.Config.model_validate(spec.params, context={"data_root": data_root()})
        except ValidationError:  # reported with its field when the pipeline is built
            return bool(cls.reads_pixels)
        return bool(cls.reads_pixels_with(config))

    if from_kind is None:
        from_kind = _earliest_replayable(log, kinds, [k for k in kinds if reads_pixels(k)], problem)
    if from_kind not in STAGE_KINDS:
        raise RecipeError(f"--from {from_kind}: not a stage kind; stages are {', '.join(STAGE_KINDS)}")
    if getattr(wanted, from_kind) is None:
        raise RecipeError(f"--from {from_kind}: the recipe has no {from_kind} stage (it has {', '.join(kinds)})")
    start = STAGE_KINDS.index(from_kind)
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
        needs_pixels=bool(pixel_stages), summary=summary, registry=registry,
        damage=None if summary.complete else summary.problem,
    )


class RecordedConfig(PluginConfig):
    """The original source's parameters, as recorded (not validated: its plugin may be absent)."""

    model_config = ConfigDict(extra="allow", frozen=True)


class RecordedSource(Source):
    """The original run's source as seen through its log (frames come from :class:`ReplayFeed`)."""

    name = "recorded"

    def __init__(self, plan: ReplayPlan) -> None:
        super().__init__(RecordedConfig.model_validate(plan.original.source.params))
        self.plan = plan
        self.name = plan.original.source.plugin  # type: ignore[misc]
        recorded = plan.summary.metadata.get("plugins", {}).get("source", plan.original.source.plugin)
        self.provenance = f"{recorded}, replayed from {plan.log}"
        self.truth: LoopGroundTruth | None = None
        self.truth_seen = False
        self.truth_note = ""

    def __len__(self) -> int:
        try:
            return self.plan.summary.topic(FRAMES_TOPIC).count
        except KeyError:
            return 0

    def frames(self) -> Iterator[Frame]:
        return (step.frame for step in ReplayFeed(self.plan, self).steps())

    def loop_ground_truth(self) -> LoopGroundTruth | None:
        """The ground truth logged by the original run; failing that, the original source's."""
        if not self.truth_seen:
            for logged in read_messages(self.plan.log, [LOOP_TRUTH_TOPIC], strict=False):
                self.take_truth(logged)
        if self.truth is None and not self.truth_note:
            self.truth = self._from_original_source()
        return self.truth

    def take_truth(self, logged: LoggedMessage) -> None:
        message: LoopTruth = logged.decoded
        self.truth = LoopGroundTruth(queries=message.queries, indptr=message.indptr, matches=message.matches)
        self.truth_seen = True

    def loop_ground_truth_at(self, tolerance: int) -> LoopGroundTruth | None:
        """Other tolerances (``eval.tolerances``) are not in the log: they come from the
        original source when its plugin and data are here, else there are none."""
        try:
            return self._original_source().loop_ground_truth_at(tolerance)
        except Exception:  # noqa: BLE001 (the evaluation then notes the tolerance as not scored)
            return None

    def _original_source(self) -> Source:
        spec = self.plan.original.source
        cls = PluginRegistry(modules=self.plan.original.plugin_modules).get("source", spec.plugin).cls
        config = cls.Config.model_validate(spec.params, context={"data_root": data_root()})
        return cls(config)  # type: ignore[return-value]

    def _from_original_source(self) -> LoopGroundTruth | None:
        try:
            truth = self._original_source().loop_ground_truth()
        except Exception as exc:  # noqa: BLE001 (no ground truth is a valid outcome)
            self.truth_note = f"; no loop ground truth in the log, nor from its source ({exc})"
            return None
        self.truth_note = "; loop ground truth rebuilt from the recipe's source (the log has none)"
        return truth


class RecordedStage:
    """Stands for a stage read from the log in ``inputs.stages``: its name, kind, version,
    config and class flags are there, its state is not (the stage never ran)."""

    _PUBLIC = frozenset({"name", "kind", "version", "config", "requires"})

    def __init__(self, stage: Stage, from_kind: str) -> None:
        self._stage = stage
        self._from_kind = from_kind

    def __getattr__(self, attribute: str) -> Any:
        stage = self.__dict__["_stage"]
        on_class = getattr(type(stage), attribute, None)
        if attribute in self._PUBLIC or isinstance(on_class, (bool, int, float, str, tuple)):
            return getattr(stage, attribute)
        raise PluginError(
            f"the {stage.kind} stage ({stage.name}) is read from the log in this replay (--from "
            f"{self.__dict__['_from_kind']}), so a later stage cannot use its {attribute!r}; replay --from {stage.kind}"
        )


@dataclass
class _PendingFrame:
    info: LoggedMessage
    logged: list[LoggedMessage] = field(default_factory=list)
    recorded: dict[str, list[LoggedMessage]] = field(default_factory=dict)


class ReplayFeed(FrameFeed):
    """Frames and recorded stage outputs read from a log, in the order they were written.

    Messages written between one frame's ``/frames`` message and the next belong to that
    frame; a ``finish`` event on ``/run/events`` starts the end of the run. A log that
    ends without it (the run was interrupted) loses its last frame, whose stage outputs
    may be incomplete.
    """

    def __init__(self, plan: ReplayPlan, source: RecordedSource) -> None:
        self.plan = plan
        self._source = source
        self.recorded_kinds = frozenset(plan.recorded)
        self._finish: dict[str, list[LoggedMessage]] = {}
        self._statistics: dict[str, dict[str, Any]] = {}
        self._finished = False
        self._dropped_last = False
        self._lost_frames = 0
        self._check_recorded_types()

    def _check_recorded_types(self) -> None:
        for topic in self.plan.summary.topics:
            if stage_of(topic.topic) in self.recorded_kinds and topic.message_encoding == "json":
                message_class(topic.schema_name)  # raises LogError naming the missing type

    @property
    def source(self) -> Source:
        return self._source

    def total(self) -> int | None:
        return len(self._source) or None

    def steps(self) -> Iterator[FrameStep]:
        pending: _PendingFrame | None = None
        for logged in read_messages_and_gaps(self.plan.log, strict=False):
            if logged is None:  # damage: the frame being gathered may lack messages, leave it out
                self._lost_frames += pending is not None
                pending = None
                continue
            topic = logged.topic
            if topic == LOOP_TRUTH_TOPIC:
                self._source.take_truth(logged)
            elif self._finished:
                self._after_finish(logged)
            elif topic == FRAMES_TOPIC:
                if pending is not None:
                    yield self._step(pending)
                pending = _PendingFrame(logged)
            elif topic == EVENTS_TOPIC:
                event: RunEvent = logged.decoded
                if event.event == "finish":
                    if pending is not None:
                        yield self._step(pending)
                    pending, self._finished = None, True
            elif pending is not None:
                kind = stage_of(topic)
                if kind is None and topic in FRAME_TOPICS:
                    pending.logged.append(logged)
                elif kind in self.recorded_kinds and not topic.endswith(f"/{STATISTICS_SUFFIX}"):
                    pending.recorded.setdefault(kind, []).append(logged)
        self._dropped_last = pending is not None

    def _after_finish(self, logged: LoggedMessage) -> None:
        kind = stage_of(logged.topic)
        if kind not in self.recorded_kinds:
            return
        if logged.topic.endswith(f"/{STATISTICS_SUFFIX}"):
            statistics: StageStatistics = logged.decoded
            self._statistics[kind] = dict(statistics.values)
        else:
            self._finish.setdefault(kind, []).append(logged)

    def _step(self, pending: _PendingFrame) -> FrameStep:
        info: FrameInfo = pending.info.decoded
        by_topic = {m.topic: m for m in pending.logged}
        camera = None
        if CALIBRATION_TOPIC in by_topic:
            k = CameraCalibration.FromString(by_topic[CALIBRATION_TOPIC].data)
            camera = Camera(fx=k.K[0], fy=k.K[4], cx=k.K[2], cy=k.K[5], width=k.width, height=k.height)
        image, depth = self._pixels(info, by_topic)
        frame = Frame(
            index=info.frame, timestamp=info.timestamp, image=image, traversal=info.traversal,  # type: ignore[arg-type]
            sequence_index=info.sequence_index, name=info.name, depth=depth, camera=camera, pose=info.pose,
            scene=info.scene,
        )
        return FrameStep(frame, recorded=pending.recorded, logged=[pending.info, *pending.logged])

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

    def log_frame(self, log: RunLogWriter, step: FrameStep) -> FrameInfo:
        for logged in step.logged:
            log.copy(logged)
        return step.logged[0].decoded

    def recorded_finish(self) -> dict[str, list[LoggedMessage]]:
        return self._finish

    def recorded_statistics(self, kind: str) -> dict[str, Any]:
        return self._statistics.get(kind, {})

    def stage_for_inputs(self, kind: str, stage: Stage) -> Any:
        return RecordedStage(stage, self.plan.from_kind) if kind in self.recorded_kinds else stage

    def loop_ground_truth(self) -> LoopGroundTruth | None:
        return self._source.loop_ground_truth()

    @property
    def lost_frames(self) -> int:
        """Frames left out because damage was met while gathering their messages."""
        return self._lost_frames

    def ending_note(self) -> str:
        read = ", ".join(self.plan.recorded) or "none"
        note = f"; replay of {self.plan.log} from {self.plan.from_kind} (read from the log: {read})"
        if self._dropped_last:
            note += "; the log ends without the run's finish, so its last frame was left out"
        if self.plan.damage:
            lost = f", {self._lost_frames} frames next to the damage were left out" if self._lost_frames else ""
            note += f"; the log is damaged and was replayed as far as it could be read{lost} (lost: {self.plan.damage})"
        return note + self._source.truth_note


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
    source = RecordedSource(plan)
    pipeline = build_pipeline(plan.recipe, origin, registry=plan.registry, source=source)
    feed = ReplayFeed(plan, source)
    metadata = {
        "replay": {
            "log": str(log),
            "from": plan.from_kind,
            "recorded_stages": ",".join(plan.recorded),
            "rerun_stages": ",".join(plan.rerun),
            **({"damage": plan.damage} if plan.damage else {}),
        }
    }
    result = execute_run(pipeline, feed, origin, out_dir, progress, metadata=metadata, input_files=[log])
    if plan.damage:
        lost = f" ({feed.lost_frames} frames next to the damage left out)" if feed.lost_frames else ""
        result.notes.append(f"{log} is damaged; replayed what could be read{lost}; lost: {plan.damage}")
    return result
