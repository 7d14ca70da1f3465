"""The hierarchical sequence detector on the whole Nordland route (3,576 + 3,576 frames).

1. The full run (``recipes/nordland_hsl.yaml``, logging included): seconds, frames/s,
   searches, peak memory; the single-image brute-force baseline (``nearest_neighbour``
   on the same RST-SHelo descriptors) measured in the same process for the ratio.
2. Online latency of every query frame: the stages are driven frame by frame and a
   query's latency is the processing time from its arrival to the frame whose
   processing produced its answer (descriptor + place map + detector; reading the
   image is not counted). Also the delay in frames, and the cost of one search.

Run: .venv/bin/python benchmarks/bench_hierarchical.py
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import peak_rss_mb, publish, table  # noqa: E402

from slamfront.messages import LoopResult  # noqa: E402
from slamfront.plugin import StageInputs  # noqa: E402
from slamfront.recipe import build_pipeline, load_recipe  # noqa: E402
from slamfront.runtime import run_pipeline  # noqa: E402

RECIPE = "nordland_hsl"


def whole_runs() -> list[list[object]]:
    rows = []
    baseline_fps = None
    for label, overrides in (
        ("nearest_neighbour (brute force, every frame)", ["place_map=null", "loop_detector.plugin=nearest_neighbour",
                                                          "loop_detector.params={}"]),
        ("hierarchical_sequence", []),
    ):
        recipe, path = load_recipe(RECIPE, overrides)
        with tempfile.TemporaryDirectory() as out:
            metrics = run_pipeline(build_pipeline(recipe, str(path)), str(path), Path(out), progress=False).metrics
        fps = metrics["frames_per_second"]
        baseline_fps = baseline_fps or fps
        detector = metrics["timing"]["loop_detector"]
        rows.append([
            label, metrics["n_frames"], metrics["seconds"], fps, fps / baseline_fps, metrics["n_searches"],
            detector["total_s"], metrics["recall_at_100p"], metrics["auc_pr"],
        ])
    return rows


def online_latency() -> tuple[list[list[object]], dict[str, float]]:
    recipe, path = load_recipe(RECIPE, ["log.images=false"])
    pipeline = build_pipeline(recipe, str(path))
    stages = pipeline.stages
    work: list[float] = []  # processing seconds of each frame
    arrival: dict[int, int] = {}
    answered_at: dict[int, int] = {}
    search_seconds: list[float] = []
    for position, frame in enumerate(pipeline.source.frames()):
        inputs = StageInputs(frame=frame)
        start = time.perf_counter()
        detector_seconds = 0.0
        for stage in stages:
            tick = time.perf_counter()
            inputs.outputs[stage.kind] = list(stage.process(inputs))
            inputs.stages = {**inputs.stages, stage.kind: stage}
            if stage.kind == "loop_detector":
                detector_seconds = time.perf_counter() - tick
        work.append(time.perf_counter() - start)
        if frame.traversal == "query":
            arrival[frame.index] = position
        produced = inputs.outputs.get("loop_detector", [])
        if any(isinstance(m, LoopResult) for m in produced):
            search_seconds.append(detector_seconds)
        for message in produced:
            if isinstance(message, LoopResult):
                answered_at[message.frame] = position
    last = len(work) - 1
    for stage in stages:
        for message in stage.finish():
            if isinstance(message, LoopResult):
                answered_at[message.frame] = last
    cumulative = np.concatenate([[0.0], np.cumsum(work)])
    latency_ms = np.array([
        (cumulative[answered_at[f] + 1] - cumulative[arrival[f]]) * 1e3 for f in arrival if f in answered_at
    ])
    delay = np.array([answered_at[f] - arrival[f] for f in arrival if f in answered_at])
    query_work_ms = np.array(work[len(work) - len(arrival) :]) * 1e3
    rows = [
        ["processing per query frame (all stages)", np.median(query_work_ms), np.percentile(query_work_ms, 99),
         query_work_ms.max()],
        ["one search (levels 1-3, frames that triggered one)", np.median(search_seconds) * 1e3,
         np.percentile(search_seconds, 99) * 1e3, max(search_seconds) * 1e3],
        ["latency: query frame arrives -> its answer", np.median(latency_ms), np.percentile(latency_ms, 99),
         latency_ms.max()],
    ]
    extra = {
        "answered": float(len(latency_ms)), "queries": float(len(arrival)),
        "delay_median": float(np.median(delay)), "delay_p99": float(np.percentile(delay, 99)),
        "delay_max": float(delay.max()),
    }
    return rows, extra


def main() -> None:
    runs = whole_runs()
    latency, extra = online_latency()
    body = "\n\n".join([
        "## Whole route, summer reference + winter queries (7,152 frames), logging included\n\n" + table(
            ["detector", "frames", "seconds", "frames/s", "frames/s vs baseline", "searches",
             "detector total s", "recall@100%P", "AUC-PR"], runs),
        "## Online latency of the hierarchical detector (ms)\n\n" + table(
            ["measure", "median", "p99", "max"], latency),
        (f"Every one of the {extra['queries']:.0f} query frames got its answer (or its explicit no-answer) "
         f"{extra['delay_median']:.0f} frames after it arrived (median; p99 {extra['delay_p99']:.0f}, max "
         f"{extra['delay_max']:.0f}): answers come out when the query sequence of rho = 5 places is "
         "complete, one iteration later when the sequence had to wait for the next one."),
        f"Peak memory: {peak_rss_mb():.0f} MB.",
    ])
    publish("hierarchical", "Hierarchical sequence detector on the whole Nordland route", body)


if __name__ == "__main__":
    main()
