"""Shared by the bow_bayes benchmarks: synthetic feature streams (cached), detector runs, scoring.

Rendering the synthetic street and extracting features takes far longer than the
detector itself, and the benchmarks run the detector many times over the same frames;
so each stream's descriptors and loop ground truth are computed once and kept in
``benchmarks/.cache/`` (not committed; delete it to recompute). Every timing the
benchmarks report is the detector's own: rendering and feature extraction are excluded.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from slamfront.core.loops import LoopGroundTruth
from slamfront.evaluation.loops import score_loops
from slamfront.frame import Frame
from slamfront.local_features import DESCRIPTORS, LocalFeatureExtractor
from slamfront.messages import Features, LoopResult
from slamfront.plugin import Source, StageInputs
from slamfront.recipe import EvalOptions
from slamfront_plugins.loop_detectors.bow_bayes import BowBayes
from slamfront_plugins.loop_detectors.bow_evaluation import feature_share
from slamfront_plugins.loop_detectors.bow_messages import BowStatistics
from slamfront_plugins.sources.synthetic import SyntheticWorld

CACHE = Path(__file__).resolve().parent / ".cache"


@dataclass(frozen=True)
class StreamSpec:
    """One synthetic stream: world seed, laps, size, features (the synthetic_bow recipe's defaults)."""

    seed: int
    laps: int = 2
    frames_per_lap: int = 300
    route_m: float = 300.0
    width: int = 320
    height: int = 240
    descriptor: str = "sift"
    max_features: int = 300
    scale: float = 1.0
    """Images resized by this factor before detection (local_features' ``scale``)."""

    @property
    def key(self) -> str:
        upscaled = f"_x{self.scale:g}" if self.scale != 1.0 else ""
        return (f"s{self.seed}_l{self.laps}_f{self.frames_per_lap}_r{self.route_m:g}_{self.width}x{self.height}_"
                f"{self.descriptor}{self.max_features}{upscaled}")


@dataclass(frozen=True)
class Stream:
    spec: StreamSpec
    descriptors: list[np.ndarray]
    metric: str
    truth: LoopGroundTruth
    seconds_to_make: float
    """Rendering and feature extraction, the first time (0 when read from the cache)."""
    extraction_seconds: np.ndarray | None = None
    """(N,) feature extraction alone, per frame (thread CPU seconds), when it was measured."""


def synthetic_stream(spec: StreamSpec) -> Stream:
    """The stream's descriptors and ground truth, from the cache or rendered now."""
    source = SyntheticWorld(SyntheticWorld.Config(
        seed=spec.seed, mode="stream", laps=spec.laps, frames_per_traversal=spec.frames_per_lap,
        route_length_m=spec.route_m, image_width=spec.width, image_height=spec.height,
    ))
    return _cached_stream(f"bow_{spec.key}", spec, source, f"render + {spec.descriptor} (world seed {spec.seed})")


def source_stream(name: str, spec: StreamSpec, source: Source) -> Stream:
    """Any source's frames as a feature stream (cached under ``name``); ``spec`` gives the
    features (descriptor, count, scale), its other fields only label the stream."""
    return _cached_stream(f"bow_{name}_{spec.descriptor}{spec.max_features}_x{spec.scale:g}", spec, source, name)


def _cached_stream(key: str, spec: StreamSpec, source: Source, label: str) -> Stream:
    path = CACHE / f"{key}.npz"
    metric = DESCRIPTORS[spec.descriptor].metric  # type: ignore[index]
    if path.exists():
        data = np.load(path)
        offsets = data["offsets"]
        stacked = data["descriptors"]
        descriptors = [stacked[a:b] for a, b in zip(offsets[:-1], offsets[1:])]
        truth = LoopGroundTruth(data["queries"], data["indptr"], data["matches"])
        extraction = data["extraction_seconds"] if "extraction_seconds" in data else None
        return Stream(spec, descriptors, metric, truth, 0.0, extraction)
    extractor = LocalFeatureExtractor(spec.descriptor, max_features=spec.max_features,  # type: ignore[arg-type]
                                      scale=spec.scale)
    started = time.perf_counter()
    descriptors, extraction = [], []
    for frame in tqdm(source.frames(), total=len(source), desc=label, unit="frame"):
        grey = frame.gray()
        tick = time.thread_time()
        descriptors.append(extractor.extract(grey).descriptors)
        extraction.append(time.thread_time() - tick)
    seconds = time.perf_counter() - started
    truth = source.loop_ground_truth()
    CACHE.mkdir(exist_ok=True)
    offsets = np.concatenate([[0], np.cumsum([len(d) for d in descriptors])]).astype(np.int64)
    np.savez(path, descriptors=np.concatenate(descriptors), offsets=offsets, queries=truth.queries,
             indptr=truth.indptr, matches=truth.matches, extraction_seconds=np.array(extraction))
    return Stream(spec, descriptors, metric, truth, seconds, np.array(extraction))


@dataclass(frozen=True)
class Run:
    results: dict[int, LoopResult]
    statistics: list[BowStatistics]
    seconds: float
    """The detector's wall time over the whole stream."""
    frame_wall: np.ndarray | None = None
    """(N,) wall seconds of each frame's ``process`` call."""
    frame_cpu: np.ndarray | None = None
    """(N,) CPU seconds of the calling thread in each frame's ``process`` call (what the
    detector itself costs, whatever else the machine runs)."""


def run_detector(
    config: BowBayes.Config, stream: Stream, label: str = "", progress: bool = True,
    clock: Callable[[], float] | None = None,
) -> Run:
    """Feed the stream's features to a fresh ``bow_bayes`` detector, as the runtime would.

    :param clock: the detector's clock for its time budget (default: the wall clock);
        ``time.thread_time`` charges a frame only the CPU time the detector itself used.
    """
    detector = BowBayes(config)
    if clock is not None:
        detector.clock = clock
    blank = np.zeros((1, 1), np.uint8)
    results: dict[int, LoopResult] = {}
    statistics: list[BowStatistics] = []
    frame_wall, frame_cpu = [], []
    started = time.perf_counter()
    frames = enumerate(stream.descriptors)
    for index, descriptors in tqdm(frames, total=len(stream.descriptors), desc=label or "bow_bayes", unit="frame",
                                   disable=not progress, leave=False):
        frame = Frame(index=index, timestamp=float(index), image=blank)
        message = Features(frame=index, descriptors=descriptors, metric=stream.metric)  # type: ignore[arg-type]
        wall, cpu = time.perf_counter(), time.thread_time()
        outputs = detector.process(StageInputs(frame=frame, outputs={"descriptor": [message]}))
        frame_cpu.append(time.thread_time() - cpu)
        frame_wall.append(time.perf_counter() - wall)
        for out in outputs:
            if isinstance(out, BowStatistics):
                statistics.append(out)
            else:
                results[out.frame] = out  # type: ignore[union-attr]
    return Run(results, statistics, time.perf_counter() - started, np.array(frame_wall), np.array(frame_cpu))


def score(run: Run, truth: LoopGroundTruth, loop_scoring: str = "place", unsearched: str = "score") -> dict:
    """The run's loop metrics under one scoring rule (as ``metrics.json`` has them)."""
    options = EvalOptions(loop_scoring=loop_scoring, unsearched_frames=unsearched)  # type: ignore[arg-type]
    return score_loops(run.results, truth, [1], options).metrics


def share(statistics: list[BowStatistics], field: str) -> float:
    """Share of the quantised features counted by ``field`` (``by_ratio_test`` or ``by_nd_high``)."""
    counts = np.array([getattr(s, field) for s in statistics])
    return feature_share(counts, np.array([s.n_features for s in statistics])) or 0.0


def mean_sd(values: list[float]) -> str:
    """``mean ± sd`` (sample sd) with three decimals."""
    array = np.asarray(values, dtype=np.float64)
    sd = float(array.std(ddof=1)) if len(array) > 1 else 0.0
    return f"{array.mean():.3f} ± {sd:.3f}"
