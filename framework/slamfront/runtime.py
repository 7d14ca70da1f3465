"""Running a recipe: stream frames through the stages, log everything, evaluate, report.

Frames are pulled from the source one at a time and dropped after the last stage has
seen them, so memory stays flat in the number of frames except for what a stage keeps
on purpose (a map) and the small per-query results evaluation needs.

The log is finalised whatever happens: normal end, a user error in the data, an
exception in a plugin, Ctrl-C or SIGTERM. Its last ``/log`` line says how the run ended.
"""

from __future__ import annotations

import contextlib
import json
import os
import platform
import re
import signal
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

import slamfront
from slamfront.errors import SlamfrontError
from slamfront.evaluation import EvaluationContext, evaluations_for
from slamfront.frame import Frame
from slamfront.mcaplog import foxglove
from slamfront.mcaplog.writer import RunLogWriter
from slamfront.messages import FrameInfo, Message, RunMetrics
from slamfront.plugin import Stage, StageInputs
from slamfront.recipe import LogOptions, Pipeline
from slamfront.report.markdown import write_report

FRAMES_TOPIC = "/frames"
IMAGE_TOPIC = "/camera/image"
DEPTH_TOPIC = "/camera/depth"
CALIBRATION_TOPIC = "/camera/calibration"
GROUND_TRUTH_TOPIC = "/ground_truth/pose"
TF_TOPIC = "/tf"
LOG_TOPIC = "/log"
METRICS_TOPIC = "/metrics"


class RunInterrupted(KeyboardInterrupt):
    """The run was stopped by SIGINT or SIGTERM."""


def topic_for(kind: str, message: Message) -> str:
    """``/<stage kind>/<message type in snake_case>``, e.g. ``/loop_detector/loop_result``."""
    snake = re.sub(r"(?<!^)(?=[A-Z])", "_", type(message).__name__).lower()
    return f"/{kind}/{snake}"


@dataclass
class RunResult:
    """Where a run wrote its outputs, and its metrics."""

    out_dir: Path
    log_path: Path
    metrics_path: Path
    report_path: Path
    metrics: dict[str, Any]


@dataclass
class StageTimer:
    """Per-frame wall time of each stage (float32 seconds; 4 bytes per frame and stage)."""

    samples: dict[str, list[float]] = field(default_factory=dict)
    finish_seconds: dict[str, float] = field(default_factory=dict)

    def add(self, kind: str, seconds: float) -> None:
        self.samples.setdefault(kind, []).append(seconds)

    def summary(self) -> dict[str, dict[str, float]]:
        table = {}
        for kind, values in self.samples.items():
            array = np.asarray(values, dtype=np.float64) * 1000.0
            table[kind] = {
                "median_ms": float(np.median(array)),
                "p99_ms": float(np.percentile(array, 99)),
                "mean_ms": float(array.mean()),
                "total_s": float(array.sum() / 1000.0 + self.finish_seconds.get(kind, 0.0)),
                "finish_s": float(self.finish_seconds.get(kind, 0.0)),
            }
        return table


@contextlib.contextmanager
def _sigterm_as_interrupt() -> Iterator[None]:
    """Turn SIGTERM into :class:`RunInterrupted` so the log is finalised (main thread only)."""

    def handler(signum: int, _frame: Any) -> None:
        raise RunInterrupted(f"signal {signal.Signals(signum).name}")

    try:
        previous = signal.signal(signal.SIGTERM, handler)
    except ValueError:  # not the main thread: leave signals alone
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _source_length(pipeline: Pipeline) -> int | None:
    try:
        return len(pipeline.source)
    except (NotImplementedError, TypeError):
        return None


class FrameLogger:
    """Writes what the source gave for a frame: its info, image, depth and pose."""

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
        )
        self.log.write(FRAMES_TOPIC, info, stamp)
        if self.options.images:
            self.log.write_foxglove(
                IMAGE_TOPIC,
                foxglove.compressed_image(
                    frame.image, stamp, self.options.image_max_width, self.options.image_format,
                    self.options.jpeg_quality,
                ),
                stamp,
            )
        if self.options.depth and frame.depth is not None:
            self.log.write_foxglove(DEPTH_TOPIC, foxglove.depth_image(frame.depth, stamp), stamp)
        if frame.camera is not None:
            self.log.write_foxglove(CALIBRATION_TOPIC, foxglove.camera_calibration(frame.camera, stamp), stamp)
        if frame.pose is not None:
            self.log.write_foxglove(GROUND_TRUTH_TOPIC, foxglove.pose_in_frame(frame.pose, stamp), stamp)
            self.log.write_foxglove(TF_TOPIC, foxglove.frame_transforms(frame.pose, stamp), stamp)
        return info


def _write_stage_outputs(
    log: RunLogWriter, kind: str, messages: Sequence[Message], stamp: int, observers: Sequence[Any]
) -> None:
    for message in messages:
        log.write(topic_for(kind, message), message, stamp)
        for suffix, extra in message.foxglove(stamp):
            log.write_foxglove(f"/{kind}/{suffix}", extra, stamp)
        for observer in observers:
            observer.observe(kind, message)


def _record_provenance(log: RunLogWriter, pipeline: Pipeline, origin: str) -> None:
    recipe = pipeline.recipe
    log.add_metadata(
        "slamfront",
        {
            "version": slamfront.__version__,
            "python": platform.python_version(),
            "recipe_name": recipe.name,
            "recipe_file": origin,
        },
    )
    plugins = {}
    for kind, plugin in pipeline.plugins.items():
        info = pipeline.registry.get(kind, plugin.name)
        plugins[kind] = f"{plugin.name}=={plugin.version} ({info.distribution} {info.distribution_version})"
        log.add_metadata(f"params.{kind}", {"plugin": plugin.name, "params": plugin.config.model_dump_json()})
    log.add_metadata("plugins", plugins)
    log.add_attachment("recipe.yaml", "application/yaml", recipe.to_yaml().encode())


def run_pipeline(
    pipeline: Pipeline,
    origin: str,
    out_dir: Path,
    progress: bool | None = None,
    max_frames: int | None = None,
) -> RunResult:
    """Run a built pipeline and write ``run.mcap``, ``metrics.json`` and ``report.md``.

    :param origin: the recipe file (recorded in the log and the report).
    :param out_dir: created if missing.
    :param progress: show a progress bar (None: only on a terminal).
    :param max_frames: stop after this many frames (smoke tests); evaluation then
        scores only the queries that were reached.
    :raises SlamfrontError: bad data met mid-run (the log is finalised first).
    """
    recipe = pipeline.recipe
    out_dir.mkdir(parents=True, exist_ok=True)
    log_path = out_dir / "run.mcap"
    stages: list[Stage] = pipeline.stages
    evaluations = evaluations_for(set(pipeline.plugins))
    timer = StageTimer()
    n_frames, last_stamp = 0, 0
    ending = ("error", "run failed before the first frame")
    started = time.perf_counter()
    library = f"slamfront {slamfront.__version__}"
    with RunLogWriter(log_path, recipe.log.compression, recipe.log.chunk_size, library) as log:
        _record_provenance(log, pipeline, origin)
        frame_logger = FrameLogger(log, recipe.log)
        total = _source_length(pipeline)
        bar = tqdm(
            total=total if max_frames is None or total is None else min(total, max_frames),
            desc=recipe.name,
            unit="frame",
            disable=None if progress is None else not progress,  # None: only on a terminal
        )
        try:
            with _sigterm_as_interrupt():
                for frame in pipeline.source.frames():
                    if max_frames is not None and n_frames >= max_frames:
                        break
                    last_stamp = frame.timestamp_ns
                    info = frame_logger.write(frame)
                    for evaluation in evaluations:
                        evaluation.observe("frames", info)
                    inputs = StageInputs(frame=frame, outputs={}, stages={})
                    for stage in stages:
                        tick = time.perf_counter()
                        produced = list(stage.process(inputs))
                        timer.add(stage.kind, time.perf_counter() - tick)
                        _write_stage_outputs(log, stage.kind, produced, last_stamp, evaluations)
                        inputs.outputs[stage.kind] = produced
                        inputs.stages = {**inputs.stages, stage.kind: stage}
                    n_frames += 1
                    bar.update()
                for stage in stages:
                    tick = time.perf_counter()
                    produced = list(stage.finish())
                    timer.finish_seconds[stage.kind] = time.perf_counter() - tick
                    _write_stage_outputs(log, stage.kind, produced, last_stamp, evaluations)
            seconds = time.perf_counter() - started
            ending = ("info", f"run completed: {n_frames} frames in {seconds:.2f} s")
        except KeyboardInterrupt as exc:
            ending = ("warning", f"run interrupted ({exc or 'SIGINT'}) after {n_frames} frames")
            raise
        except SlamfrontError as exc:
            ending = ("error", f"run stopped by bad input after {n_frames} frames: {exc}")
            raise
        except BaseException as exc:
            ending = ("error", f"run failed after {n_frames} frames: {type(exc).__name__}: {exc}")
            raise
        finally:
            bar.close()
            log.write_foxglove(LOG_TOPIC, foxglove.log_line(ending[1], last_stamp, ending[0]), last_stamp)

        metrics: dict[str, Any] = {
            "recipe": recipe.name,
            "seconds": seconds,
            "frames_per_second": n_frames / seconds if seconds > 0 else 0.0,
            "n_frames": n_frames,
        }
        for stage in stages:
            for key, value in stage.statistics().items():
                metrics[key if key not in metrics else f"{stage.kind}.{key}"] = value
        names = {kind: plugin.name for kind, plugin in pipeline.plugins.items()}
        context = EvaluationContext(pipeline.source, out_dir, recipe.eval, dict(metrics), names)
        sections = [r for r in (e.finish(context) for e in evaluations) if r is not None]
        for section in sections:
            metrics.update(section.metrics)
        metrics["timing"] = timer.summary()
        log.write(METRICS_TOPIC, RunMetrics(values=metrics), last_stamp)

    metrics["log_bytes"] = log_path.stat().st_size
    metrics_path = write_json_atomically(out_dir / "metrics.json", metrics)
    report_path = write_report(out_dir, recipe, origin, metrics, sections)
    return RunResult(out_dir, log_path, metrics_path, report_path, metrics)


def write_json_atomically(path: Path, data: dict[str, Any]) -> Path:
    """Write to a temporary file and rename, so a crash never leaves half a metrics file."""
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(_finite(data), indent=2, default=_json_default, allow_nan=False) + "\n")
    os.replace(tmp, path)
    return path


def _finite(value: Any) -> Any:
    """NaN and infinities become null: metrics.json must be strict JSON for other tools."""
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    if isinstance(value, (float, np.floating)) and not np.isfinite(value):
        return None
    return value


def _json_default(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"cannot write {type(value).__name__} to metrics.json")
