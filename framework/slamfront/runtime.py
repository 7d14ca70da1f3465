"""Running a recipe: stream frames through the stages, log everything, evaluate, report.

Frames are pulled from a feed (:mod:`slamfront.feeds`: a live source, or a log being
replayed) one at a time and dropped after the last stage has seen them, so memory stays
flat in the number of frames except for what a stage keeps on purpose (a map) and the
small per-query results evaluation needs. In a replay, the stages before ``--from`` are
not run: the messages they logged in the original run are copied to the new log and
handed to the later stages exactly as the stages themselves would have.

The log is finalised whatever happens: normal end, a user error in the data, an
exception in a plugin, Ctrl-C or SIGTERM (which are held back while a record is being
written, :mod:`slamfront.interrupts`). Its last ``/log`` line says how the run ended.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import platform
import time
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np
from tqdm import tqdm

import slamfront
from slamfront.errors import SlamfrontError
from slamfront.evaluation import EvaluationContext, EvaluationReport, evaluations_for
from slamfront.feeds import FrameFeed, SourceFeed
from slamfront.interrupts import Interrupts, RunInterrupted
from slamfront.mcaplog import foxglove
from slamfront.mcaplog.reader import LoggedMessage
from slamfront.mcaplog.scene import SceneLogger
from slamfront.mcaplog.topics import (
    CALIBRATION_TOPIC,
    DEPTH_TOPIC,
    EVENTS_TOPIC,
    FRAMES_TOPIC,
    GROUND_TRUTH_TOPIC,
    IMAGE_TOPIC,
    LOG_TOPIC,
    LOOP_TRUTH_TOPIC,
    METRICS_TOPIC,
    TF_TOPIC,
    statistics_topic,
    topic_for,
)
from slamfront.mcaplog.writer import RunLogWriter
from slamfront.messages import LoopTruth, Message, RunEvent, RunMetrics, StageStatistics
from slamfront.outputs import claim_run_folder
from slamfront.plugin import Stage, StageInputs
from slamfront.recipe import Pipeline
from slamfront.report.markdown import write_report

__all__ = [
    "CALIBRATION_TOPIC", "DEPTH_TOPIC", "FRAMES_TOPIC", "GROUND_TRUTH_TOPIC", "IMAGE_TOPIC", "LOG_TOPIC",
    "METRICS_TOPIC", "TF_TOPIC", "RunInterrupted", "RunResult", "execute_run", "run_pipeline", "topic_for",
]

@dataclass
class RunResult:
    """Where a run wrote its outputs, and its metrics."""

    out_dir: Path
    log_path: Path
    metrics_path: Path
    report_path: Path
    metrics: dict[str, Any]
    notes: list[str] = field(default_factory=list)
    """What the user should know about how the run went (e.g. a replay's lost data)."""


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


class LogClock:
    """Wall time spent writing the log (encoding images, serialising, compressing, syncing)."""

    def __init__(self) -> None:
        self.seconds = 0.0
        self._tick = 0.0

    def __enter__(self) -> LogClock:
        self._tick = time.perf_counter()
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.seconds += time.perf_counter() - self._tick


def _record_provenance(
    log: RunLogWriter, pipeline: Pipeline, origin: str, extra: dict[str, dict[str, str]]
) -> None:
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
        described = getattr(plugin, "provenance", None)  # a replay's source says where it read from
        if described is None:
            info = pipeline.registry.get(kind, plugin.name)
            described = f"{plugin.name}=={plugin.version} ({info.distribution} {info.distribution_version})"
        plugins[kind] = described
        log.add_metadata(f"params.{kind}", {"plugin": plugin.name, "params": plugin.config.model_dump_json()})
    log.add_metadata("plugins", plugins)
    for name, values in extra.items():
        log.add_metadata(name, values)
    log.add_attachment("recipe.yaml", "application/yaml", recipe.to_yaml().encode())


class _Observers:
    """Everything that watches the run's messages: evaluations and the 3-D scene."""

    def __init__(self, watchers: Sequence[Any]) -> None:
        self.watchers = list(watchers)

    def observe(self, kind: str, message: Message) -> None:
        for watcher in self.watchers:
            watcher.observe(kind, message)


def _write_stage_outputs(
    log: RunLogWriter, kind: str, messages: Sequence[Message], stamp: int, observers: _Observers
) -> None:
    for message in messages:
        log.write(topic_for(kind, message), message, stamp)
        for suffix, extra in message.foxglove(stamp):
            log.write_foxglove(f"/{kind}/{suffix}", extra, stamp)
        observers.observe(kind, message)


def _copy_recorded(
    log: RunLogWriter, kind: str, recorded: Iterable[LoggedMessage], observers: _Observers
) -> list[Message]:
    """Copy a recorded stage's messages unchanged; return its outputs (the JSON ones)."""
    outputs = []
    for logged in recorded:
        log.copy(logged)
        if logged.message_encoding == "json":
            message = logged.decoded
            outputs.append(message)
            observers.observe(kind, message)
    return outputs


def _log_loop_truth(log: RunLogWriter, feed: FrameFeed, stamp: int) -> str:
    """Log the source's loop ground truth so a replay can be evaluated from the log alone."""
    try:
        truth = feed.loop_ground_truth()
    except Exception as exc:  # noqa: BLE001 (best effort while the run is ending, maybe after a failure)
        return f"; loop ground truth not logged ({type(exc).__name__}: {exc})"
    if truth is not None:
        log.write(LOOP_TRUTH_TOPIC, LoopTruth(queries=truth.queries, indptr=truth.indptr, matches=truth.matches), stamp)
    return ""


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
    feed = SourceFeed(pipeline.source, pipeline.recipe.log)
    return execute_run(pipeline, feed, origin, out_dir, progress, max_frames)


def execute_run(
    pipeline: Pipeline,
    feed: FrameFeed,
    origin: str,
    out_dir: Path,
    progress: bool | None = None,
    max_frames: int | None = None,
    metadata: dict[str, dict[str, str]] | None = None,
    input_files: Sequence[Path] = (),
) -> RunResult:
    """Drive ``pipeline``'s stages with the frames of ``feed``; stages of the kinds in
    ``feed.recorded_kinds`` are not called, their logged messages are used instead.

    The log's last ``/log`` line says how the run ended, whatever phase it ended in
    (streaming, the stages' finish, evaluation and its plots), and it is written last:
    a run it calls completed has produced everything but the log's own statistics.

    :param metadata: extra MCAP metadata records (name -> key/values).
    :param input_files: files the run reads (a replayed log): never overwritten or removed.
    """
    recipe = pipeline.recipe
    folder = claim_run_folder(out_dir, input_files)
    log_path = out_dir / "run.mcap"
    stages: list[Stage] = pipeline.stages
    recorded = feed.recorded_kinds
    evaluations = evaluations_for(set(pipeline.plugins))
    scene = SceneLogger(recipe.log.scene_every) if recipe.log.scene else None
    observers = _Observers([*evaluations, *([scene] if scene else [])])
    timer, clock = StageTimer(), LogClock()
    statistics: dict[str, dict[str, Any]] = {}
    n_frames, last_stamp, phase = 0, 0, "start-up"
    ending = ("error", "run failed before the first frame")
    started = time.perf_counter()
    library = f"slamfront {slamfront.__version__}"
    options = recipe.log
    try:
        with (
            Interrupts() as interrupts,
            RunLogWriter(
                log_path, options.compression, options.chunk_size, library, options.sync_seconds, interrupts.critical
            ) as log,
        ):
            with clock:
                _record_provenance(log, pipeline, origin, metadata or {})
                log.sync()  # recipe and versions are on disk before the first frame: even a SIGKILL keeps them
            bar: tqdm | None = None
            try:
                total = feed.total()
                bar = tqdm(
                    total=total if max_frames is None or total is None else min(total, max_frames),
                    desc=recipe.name,
                    unit="frame",
                    disable=None if progress is None else not progress,  # None: only on a terminal
                )
                phase = "streaming"
                for step in feed.steps():
                    if max_frames is not None and n_frames >= max_frames:
                        break
                    frame = step.frame
                    last_stamp = frame.timestamp_ns
                    with clock:
                        info = feed.log_frame(log, step)
                    observers.observe("frames", info)
                    inputs = StageInputs(frame=frame, outputs={}, stages={})
                    for stage in stages:
                        if stage.kind in recorded:
                            with clock:
                                produced = _copy_recorded(log, stage.kind, step.recorded.get(stage.kind, ()), observers)
                        else:
                            tick = time.perf_counter()
                            produced = list(stage.process(inputs))
                            timer.add(stage.kind, time.perf_counter() - tick)
                            with clock:
                                _write_stage_outputs(log, stage.kind, produced, last_stamp, observers)
                        inputs.outputs[stage.kind] = produced
                        inputs.stages = {**inputs.stages, stage.kind: feed.stage_for_inputs(stage.kind, stage)}
                    n_frames += 1
                    if scene is not None:
                        with clock:
                            scene.after_frame(log, last_stamp)
                    bar.update()
                phase = "the stages' finish"
                with clock:
                    log.write(EVENTS_TOPIC, RunEvent(event="finish", n_frames=n_frames), last_stamp)
                recorded_finish = feed.recorded_finish()
                for stage in stages:
                    if stage.kind in recorded:
                        with clock:
                            _copy_recorded(log, stage.kind, recorded_finish.get(stage.kind, ()), observers)
                        continue
                    tick = time.perf_counter()
                    produced = list(stage.finish())
                    timer.finish_seconds[stage.kind] = time.perf_counter() - tick
                    with clock:
                        _write_stage_outputs(log, stage.kind, produced, last_stamp, observers)
                for stage in stages:
                    values = feed.recorded_statistics(stage.kind) if stage.kind in recorded else dict(stage.statistics())
                    statistics[stage.kind] = values
                    with clock:
                        log.write(statistics_topic(stage.kind), StageStatistics(values=values), last_stamp)
                seconds = time.perf_counter() - started
                phase = "evaluation"
                metrics, sections = _evaluate(pipeline, feed, out_dir, evaluations, statistics, n_frames, seconds)
                metrics["timing"] = timer.summary()
                with clock:
                    log.write(METRICS_TOPIC, RunMetrics(values=metrics), last_stamp)
                ending = ("info", f"run completed: {n_frames} frames in {seconds:.2f} s")
            except KeyboardInterrupt as exc:
                ending = ("warning", f"run interrupted ({str(exc) or 'SIGINT'}) after {n_frames} frames{_during(phase)}")
                exc.log_path = log_path  # type: ignore[attr-defined]  # the CLI says where the log is
                raise
            except SlamfrontError as exc:
                ending = ("error", f"run stopped by bad input after {n_frames} frames{_during(phase)}: {exc}")
                raise
            except BaseException as exc:
                ending = ("error", f"run failed after {n_frames} frames{_during(phase)}: {type(exc).__name__}: {exc}")
                raise
            finally:
                if bar is not None:
                    bar.close()
                if not log.failed:  # after a failed write (a full disk) the file is left as it is
                    with clock:
                        if scene is not None:
                            scene.write(log, last_stamp)
                        note = _log_loop_truth(log, feed, last_stamp) + feed.ending_note()
                        line = foxglove.log_line(ending[1] + note, last_stamp, ending[0])
                        log.write_foxglove(LOG_TOPIC, line, last_stamp)
            with clock:
                log.close()
    finally:
        folder.record(complete=True)

    with _writing_outputs(out_dir, "the run completed and its log is complete, but"):
        metrics.update(_log_statistics(log, log_path, clock.seconds, seconds, n_frames))
        sections.append(_log_section(metrics))
        metrics_path = write_json_atomically(out_dir / "metrics.json", metrics)
        report_path = write_report(out_dir, recipe, origin, metrics, sections)
    folder.record(complete=True)
    return RunResult(out_dir, log_path, metrics_path, report_path, metrics)


def _during(phase: str) -> str:
    """Where a run ended, for its last ``/log`` line (frames are counted while streaming)."""
    return "" if phase == "streaming" else f", in {phase}"


_OUTPUT_ERRNOS = frozenset({errno.ENOSPC, errno.EFBIG, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM})
"""Failures to write outputs that are the machine's state, not a bug: a full disk, a
file-size limit, a quota, a read-only or forbidden folder."""


@contextlib.contextmanager
def _writing_outputs(out_dir: Path, context: str = "") -> Iterator[None]:
    """Turn a full disk (or a folder that became unwritable) into a one-line error."""
    try:
        yield
    except OSError as exc:
        if exc.errno not in _OUTPUT_ERRNOS:
            raise
        prefix = f"{context} " if context else ""
        raise SlamfrontError(f"{out_dir}: {prefix}its outputs cannot be written: {exc.strerror or exc}") from None


def _evaluate(
    pipeline: Pipeline, feed: FrameFeed, out_dir: Path, evaluations: Sequence[Any],
    statistics: dict[str, dict[str, Any]], n_frames: int, seconds: float,
) -> tuple[dict[str, Any], list[EvaluationReport]]:
    """The run's metrics and report sections; evaluations write their plots meanwhile."""
    metrics: dict[str, Any] = {
        "recipe": pipeline.recipe.name,
        "seconds": seconds,
        "frames_per_second": n_frames / seconds if seconds > 0 else 0.0,
        "n_frames": n_frames,
    }
    for kind, values in statistics.items():
        for key, value in values.items():
            metrics[key if key not in metrics else f"{kind}.{key}"] = value
    names = {kind: plugin.name for kind, plugin in pipeline.plugins.items()}
    context = EvaluationContext(feed.source, out_dir, pipeline.recipe.eval, dict(metrics), names)
    with _writing_outputs(out_dir):
        sections = [r for r in (e.finish(context) for e in evaluations) if r is not None]
    for section in sections:
        metrics.update(section.metrics)
    return metrics, sections


def _log_statistics(
    log: RunLogWriter, path: Path, write_seconds: float, run_seconds: float, n_frames: int
) -> dict[str, float | int]:
    size = path.stat().st_size
    return {
        "log_bytes": size,
        "log_bytes_per_frame": size / n_frames if n_frames else 0.0,
        "log_messages": log.n_messages,
        "log_write_seconds": write_seconds,
        "log_write_fraction": write_seconds / run_seconds if run_seconds > 0 else 0.0,
        "log_write_mb_per_s": size / 1e6 / write_seconds if write_seconds > 0 else 0.0,
        "log_syncs": log.n_syncs,
    }


def _log_section(metrics: dict[str, Any]) -> EvaluationReport:
    rows = [
        ("size", f"{metrics['log_bytes'] / 1e6:.2f} MB ({metrics['log_bytes_per_frame'] / 1024:.1f} KiB per frame)"),
        ("messages", str(metrics["log_messages"])),
        ("time spent writing", f"{metrics['log_write_seconds']:.2f} s ({100 * metrics['log_write_fraction']:.1f} % of the run)"),
        ("write throughput", f"{metrics['log_write_mb_per_s']:.1f} MB/s (compressed bytes on disk per second of writing)"),
        ("fsyncs", str(metrics["log_syncs"])),
    ]
    table = "\n".join(["| | |", "| --- | --- |", *(f"| {k} | {v} |" for k, v in rows)])
    note = (
        "Writing includes encoding the images, serialising every message, chunk compression "
        "and the periodic fsync (`log.sync_seconds`). Open `run.mcap` in Foxglove with the "
        "shipped layout (`slamfront layout` prints where it is)."
    )
    return EvaluationReport("Log", metrics={}, markdown=f"{table}\n\n{note}\n")


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
