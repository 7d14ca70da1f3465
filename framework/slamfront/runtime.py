"""Running a recipe: stream frames through the stages, log everything, evaluate, report.

Frames are pulled from the source one at a time and dropped after the last stage has
seen them, so memory stays flat in the number of frames except for what a stage keeps on
purpose (a map) and the small per-query results evaluation needs. The run loop knows
nothing of replays: a replay is a source that reads its frames from a log and stages
that give back what the original run logged (:mod:`slamfront.replay`).

The log is finalised whatever happens: normal end, a user error in the data, an
exception in a plugin, Ctrl-C or SIGTERM (which are held back while a record is being
written, :mod:`slamfront.interrupts`). Its last ``/log`` line says how the run ended.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import platform
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np
from tqdm import tqdm

import slamfront
from slamfront.errors import SlamfrontError, note_run_failure
from slamfront.evaluation import EvaluationContext, EvaluationReport, evaluations_for
from slamfront.interrupts import Interrupts, RunInterrupted
from slamfront.logcapture import RunLogCapture
from slamfront.mcaplog import foxglove
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
from slamfront.mcaplog.writer import LogSink, RunLogWriter
from slamfront.messages import LoopTruth, Message, RunEvent, RunMetrics, StageStatistics
from slamfront.outputs import claim_run_folder
from slamfront.plugin import Source, Stage, StageInputs
from slamfront.recipe import Pipeline
from slamfront.report.html import write_html
from slamfront.report.markdown import write_report
from slamfront.report.metrics_file import write_json_atomically
from slamfront.report.trajectory_files import write_trajectory_files
from slamfront.resources import layout_for

__all__ = [
    "CALIBRATION_TOPIC", "DEPTH_TOPIC", "FRAMES_TOPIC", "GROUND_TRUTH_TOPIC", "IMAGE_TOPIC", "LOG_TOPIC",
    "METRICS_TOPIC", "TF_TOPIC", "RunInterrupted", "RunResult", "execute_run", "run_pipeline", "topic_for",
]

logger = logging.getLogger(__name__)

@dataclass
class RunResult:
    """Where a run wrote its outputs, and its metrics."""

    out_dir: Path
    log_path: Path
    metrics_path: Path
    report_path: Path
    metrics: dict[str, Any]
    html_path: Path | None = None
    """``report.html``: the report as one self-contained page (plots inlined)."""
    notes: list[str] = field(default_factory=list)
    """What the user should know about how the run went (e.g. a replay's lost data)."""
    phase_seconds: dict[str, float] = field(default_factory=dict)
    """Wall time of the run's phases after setup: ``frame_loop`` (frames and the stages'
    ``finish``, logging included), ``evaluation`` (metrics and their plots), ``log_close``
    and ``report`` (metrics.json, report.md, report.html)."""


@dataclass
class StageTimer:
    """Per-frame wall time of the source and of each stage."""

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
            described = f"{plugin.name}=={plugin.version} ({info.origin})"
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


def _log_loop_truth(log: RunLogWriter, source: Source, stamp: int) -> str:
    """Log the source's loop ground truth so a replay can be evaluated from the log alone."""
    try:
        truth = source.loop_ground_truth()
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
    sinks: Sequence[LogSink] = (),
) -> RunResult:
    """Run a built pipeline and write ``run.mcap``, ``metrics.json`` and ``report.md``.

    :param origin: the recipe file (recorded in the log and the report).
    :param out_dir: created if missing.
    :param progress: show a progress bar (None: only on a terminal).
    :param max_frames: stop after this many frames (smoke tests); evaluation then
        scores only the queries that were reached.
    :param sinks: watchers of the log's channels and messages as they are written
        (``--live``: :class:`slamfront.mcaplog.live.LiveView`).
    :raises SlamfrontError: bad data met mid-run (the log is finalised first).
    """
    return execute_run(pipeline, origin, out_dir, progress, max_frames, sinks=sinks)


def execute_run(
    pipeline: Pipeline,
    origin: str,
    out_dir: Path,
    progress: bool | None = None,
    max_frames: int | None = None,
    metadata: dict[str, dict[str, str]] | None = None,
    input_files: Sequence[Path] = (),
    sinks: Sequence[LogSink] = (),
) -> RunResult:
    """Drive ``pipeline``'s stages with the frames of its source, log and evaluate.

    The log's last ``/log`` line says how the run ended, whatever phase it ended in
    (streaming, the stages' finish, evaluation and its plots), and it is written last:
    a run it calls completed has produced everything but the log's own statistics.

    :param metadata: extra MCAP metadata records (name -> key/values).
    :param input_files: files the run reads (a replayed log): never overwritten or removed.
    :param sinks: watchers of everything the log gets (``--live``).
    """
    recipe = pipeline.recipe
    folder = claim_run_folder(out_dir, input_files)
    log_path = out_dir / "run.mcap"
    source = pipeline.source
    stages: list[Stage] = pipeline.stages
    evaluations = [*evaluations_for(pipeline.plugins), *pipeline.registry.evaluations(pipeline.plugins)]
    scene = SceneLogger(recipe.log.scene_every) if recipe.log.scene else None
    observers = _Observers([*evaluations, *([scene] if scene else [])])
    timer, clock = StageTimer(), LogClock()
    phases: dict[str, float] = {}
    statistics: dict[str, dict[str, Any]] = {}
    n_frames, last_stamp = 0, 0
    ending = ("error", "run failed before the first frame")
    where = "before the first frame"  # what the run was doing, for the message if it fails
    log_opened = False
    started = time.perf_counter()
    library = f"slamfront {slamfront.__version__}"
    options = recipe.log
    capture = RunLogCapture(_logger_packages(pipeline), options.level)
    try:
        try:
            with (
                capture,
                Interrupts() as interrupts,
                RunLogWriter(
                    log_path, options.compression, options.chunk_size, library, options.sync_seconds,
                    interrupts.critical, on_sync=folder.log_synced,
                ) as log,
            ):
                log_opened = True
                for sink in sinks:
                    log.add_sink(sink)
                with clock:
                    _record_provenance(log, pipeline, origin, metadata or {})
                    log.sync()  # recipe and versions are on disk before the first frame: even a SIGKILL keeps them
                bar: tqdm | None = None
                try:
                    _warn_if_no_query_is_reached(pipeline, max_frames)
                    total = _length(source)
                    frame_logger = source.frame_logger(options)
                    bar = tqdm(
                        total=total if max_frames is None or total is None else min(total, max_frames),
                        desc=recipe.name,
                        unit="frame",
                        disable=None if progress is None else not progress,  # None: only on a terminal
                    )
                    frames = iter(source.frames())
                    while max_frames is None or n_frames < max_frames:
                        where = f"in the {source.name} source reading frame {n_frames}"
                        tick = time.perf_counter()
                        frame = next(frames, None)
                        if frame is None:
                            break
                        timer.add("source", time.perf_counter() - tick)
                        last_stamp = frame.timestamp_ns
                        with clock:
                            capture.flush(log, last_stamp)
                            info = frame_logger.write(log, frame)
                        observers.observe("frames", info)
                        inputs = StageInputs(frame=frame, outputs={}, stages={})
                        for stage in stages:
                            where = f"in the {stage.kind} plugin {stage.name!r} at frame {frame.index}"
                            tick = time.perf_counter()
                            produced = list(stage.process(inputs))
                            timer.add(stage.kind, time.perf_counter() - tick)
                            with clock:
                                capture.flush(log, last_stamp)
                                _write_stage_outputs(log, stage.kind, produced, last_stamp, observers)
                            inputs.outputs[stage.kind] = produced
                            inputs.stages = {**inputs.stages, stage.kind: stage}
                        n_frames += 1
                        if scene is not None:
                            with clock:
                                scene.after_frame(log, last_stamp)
                        bar.update()
                    with clock:
                        log.write(EVENTS_TOPIC, RunEvent(event="finish", n_frames=n_frames), last_stamp)
                    for stage in stages:
                        where = f"in the {stage.kind} plugin {stage.name!r} finishing the run"
                        tick = time.perf_counter()
                        produced = list(stage.finish())
                        timer.finish_seconds[stage.kind] = time.perf_counter() - tick
                        with clock:
                            capture.flush(log, last_stamp)
                            _write_stage_outputs(log, stage.kind, produced, last_stamp, observers)
                    # the source's own counters (frames a recording dropped), first, as the stages' are
                    statistics["source"] = dict(source.statistics())
                    for stage in stages:
                        where = f"in the {stage.kind} plugin {stage.name!r} giving its statistics"
                        values = dict(stage.statistics())
                        statistics[stage.kind] = values
                        with clock:
                            log.write(statistics_topic(stage.kind), StageStatistics(values=values), last_stamp)
                    seconds = time.perf_counter() - started
                    phases["frame_loop"] = seconds
                    where = "in evaluation"
                    metrics, sections = _evaluate(pipeline, out_dir, evaluations, statistics, n_frames, seconds)
                    phases["evaluation"] = time.perf_counter() - started - seconds
                    metrics["timing"] = timer.summary()
                    metrics["evaluation_seconds"] = phases["evaluation"]
                    tick = time.perf_counter()
                    with clock:
                        capture.flush(log, last_stamp)
                        log.write(METRICS_TOPIC, RunMetrics(values=metrics), last_stamp)
                    ending = ("info", f"run completed: {n_frames} frames in {seconds:.2f} s")
                except KeyboardInterrupt as exc:
                    ending = ("warning", f"run interrupted ({str(exc) or 'SIGINT'}) after {n_frames} frames {where}")
                    raise
                except SlamfrontError as exc:
                    ending = ("error", f"run stopped by bad input after {n_frames} frames {where}: {exc}")
                    raise
                except BaseException as exc:
                    ending = ("error", f"run failed after {n_frames} frames {where}: {type(exc).__name__}: {exc}")
                    raise
                finally:
                    if bar is not None:
                        bar.close()
                    if not log.failed:  # after a failed write (a full disk) the file is left as it is
                        with clock:
                            capture.flush(log, last_stamp)  # what the failing call logged, too
                            if scene is not None:
                                scene.write(log, last_stamp)
                            note = _log_loop_truth(log, source, last_stamp) + source.ending_note()
                            line = foxglove.log_line(ending[1] + note, last_stamp, ending[0])
                            log.write_foxglove(LOG_TOPIC, line, last_stamp)
                with clock:
                    log.close()
                phases["log_close"] = time.perf_counter() - tick
        finally:
            folder.record(complete=True)

        where = "while writing metrics.json and the report"
        tick = time.perf_counter()
        with _writing_outputs(out_dir, "the run completed and its log is complete, but"):
            metrics.update(_log_statistics(log, log_path, clock.seconds, seconds, n_frames))
            sections.append(_log_section(metrics, layout_for(set(pipeline.plugins))))
            # announced before each rename: a run killed here leaves only files its manifest vouches for
            metrics_path = write_json_atomically(out_dir / "metrics.json", metrics, folder.announce)
            # the run's TUM trajectories (groundtruth, odometry, optimised, estimated): written here, in one place
            write_trajectory_files(out_dir, {name: t for s in sections for name, t in s.trajectories.items()})
            report_path = write_report(out_dir, recipe, origin, metrics, sections, folder.announce)
            html_path = write_html(report_path, announce=folder.announce)
        phases["report"] = time.perf_counter() - tick
    except BaseException as exc:
        folder.close()
        if log_opened:
            note_run_failure(exc, log_path, where)
        raise
    folder.close()
    return RunResult(out_dir, log_path, metrics_path, report_path, metrics, html_path, phase_seconds=phases)


def _logger_packages(pipeline: Pipeline) -> set[str]:
    """The top-level logger names whose records the run keeps: slamfront's and each plugin's package."""
    return {"slamfront", *(type(plugin).__module__.partition(".")[0] for plugin in pipeline.plugins.values())}


def _length(source: Source) -> int | None:
    """How many frames the source will give, when it knows (for the progress bar)."""
    try:
        return len(source) or None
    except (NotImplementedError, TypeError):
        return None


def _warn_if_no_query_is_reached(pipeline: Pipeline, max_frames: int | None) -> None:
    """Say so when ``max_frames`` ends the run before the first query that has a true match:
    a loop detector or localizer then scores 0 for want of queries, not for being wrong."""
    if max_frames is None or not {"loop_detector", "localizer"} & set(pipeline.plugins):
        return
    try:
        truth = pipeline.source.loop_ground_truth()
    except Exception:  # noqa: BLE001 - only a hint; the run reports a real failure where it matters
        return
    if truth is None:
        return
    with_match = truth.queries[np.diff(truth.indptr) > 0]
    if len(with_match) and with_match[0] >= max_frames:
        logger.warning(
            "--max-frames %d stops the run before frame %d, the first query frame with a true match: "
            "no query is scored (recall will be 0); raise --max-frames above %d",
            max_frames, with_match[0], with_match[0],
        )


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
    pipeline: Pipeline, out_dir: Path, evaluations: Sequence[Any],
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
    context = EvaluationContext(pipeline.source, out_dir, pipeline.recipe.eval, dict(metrics), names)
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


def _log_section(metrics: dict[str, Any], layout: str) -> EvaluationReport:
    rows = [
        ("size", f"{metrics['log_bytes'] / 1e6:.2f} MB ({metrics['log_bytes_per_frame'] / 1024:.1f} KiB per frame)"),
        ("messages", str(metrics["log_messages"])),
        ("time spent writing", f"{metrics['log_write_seconds']:.2f} s ({100 * metrics['log_write_fraction']:.1f} % of the run)"),
        ("write throughput", f"{metrics['log_write_mb_per_s']:.1f} MB/s (compressed bytes on disk per second of writing)"),
        ("fsyncs", str(metrics["log_syncs"])),
    ]
    table = "\n".join(["| | |", "| --- | --- |", *(f"| {k} | {v} |" for k, v in rows)])
    note = (
        "Writing includes serialising every message and the periodic fsync (`log.sync_seconds`); the "
        "images are encoded (on the run's thread with `--live`), and chunks built, compressed and written, "
        f"on a second thread, and only the time the run waits for it counts. Open `run.mcap` in Foxglove with the shipped layout "
        f"`{layout}` (`slamfront layout {layout}` prints where it is)."
    )
    return EvaluationReport("Log", metrics={}, markdown=f"{table}\n\n{note}\n")

