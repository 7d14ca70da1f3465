"""bow_bayes: time per frame at 10,000 frames, the feature extraction beside it, and before/after a change.

Runs (each a fresh detector over a cached feature stream; ``bow_streams.py``):

- ``wall``: the 10,000-frame synthetic stream of ``bench_bow_bayes.py memory`` (world
  seed 21, 10 laps of 1,000 frames, day/dusk alternating, 160x120, ORB 150), RTAB-Map's
  rule on the wall clock with a 30 ms budget: the time the memory management keeps
  under the budget, and what it leaves in working memory (recall, WM, words searched).
- ``flat``: the same frames under the detector's deterministic time model (5 ms
  modelled budget): every transfer, and so every answer, is the same on any machine,
  so before and after a change do exactly the same work and only the time differs.
- ``cpu``: as ``wall``, but the detector's clock is its thread's CPU time
  (``time.thread_time``): on a shared machine, the stand-in for an idle one, where the
  wall clock would measure the same (other jobs neither take working memory away nor
  count in the time).
- ``recipe``: the ``synthetic_bow`` recipe's stream (world seed 1, 600 frames, SIFT 300
  at 320x240), memory never bounded (its 0.7 s budget is not reached): the search over
  a vocabulary growing to ~24,000 words.

Per frame: wall seconds and the calling thread's CPU seconds of the detector's
``process`` call (the machine is shared: the CPU time is what the detector costs, the
wall time adds what other jobs take from it), median and p99; feature extraction per
frame (thread CPU, descriptor only, rendering excluded) measured on the first 2,000
frames of the same world and on the recipe's 600 frames.

``--before DIR``: DIR holds an older slamfront source tree (``git archive <commit> |
tar -x -C DIR``); each run is measured on it too, in a child process, interleaved with
the current code (old, new, old, new ... for ``--pairs`` pairs), with a digest of the
answers so identical answers show as such.

Run: .venv/bin/python benchmarks/bench_bow_speed.py [--before DIR] [--pairs 1] [--runs wall flat recipe]
     (about 10 minutes per 10,000-frame run under load; streams cached after the first run)
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bow_streams import StreamSpec, run_detector, score, synthetic_stream  # noqa: E402
from common import publish, table  # noqa: E402

LONG = StreamSpec(21, laps=10, frames_per_lap=1000, route_m=1000, width=160, height=120, descriptor="orb",
                  max_features=150)
"""The 10,000-frame stream (as ``bench_bow_bayes.py``)."""
EXTRACTION_SAMPLE = StreamSpec(21, laps=2, frames_per_lap=1000, route_m=1000, width=160, height=120, descriptor="orb",
                               max_features=150)
"""The same world's first two laps, rendered again to time ORB on its frames."""
RECIPE = StreamSpec(1)
RUNS = {
    "wall": (LONG, {"descriptor_type": "orb", "time_budget_s": 0.03, "time_model": "wall"},
             "10,000 frames, ORB 150 at 160x120, budget 30 ms on the wall clock"),
    "flat": (LONG, {"descriptor_type": "orb", "time_budget_s": 0.005, "time_model": "linear"},
             "10,000 frames, ORB 150 at 160x120, modelled budget 5 ms (deterministic)"),
    "recipe": (RECIPE, {"descriptor_type": "sift", "time_budget_s": 0.7},
               "synthetic_bow: 600 frames, SIFT 300 at 320x240, unbounded in practice"),
    "cpu": (LONG, {"descriptor_type": "orb", "time_budget_s": 0.03, "time_model": "wall"},
            "10,000 frames, ORB 150 at 160x120, budget 30 ms on the detector thread's CPU clock"),
}
CPU_CLOCK = ("cpu",)
"""Runs whose detector charges a frame its thread's CPU time (a shared machine's stand-in
for an idle one: other jobs neither shrink working memory nor count in the time)."""


def measure(name: str) -> dict[str, object]:
    """One run of ``name`` with the slamfront this process imports."""
    from slamfront_plugins.loop_detectors.bow_bayes import BowBayes

    spec, config, _ = RUNS[name]
    stream = synthetic_stream(spec)
    load = os.getloadavg()[0]
    clock = time.thread_time if name in CPU_CLOCK else None
    run = run_detector(BowBayes.Config(**config), stream, name, progress=False, clock=clock)
    metrics = score(run, stream.truth)
    answers = hashlib.sha256()
    for frame in sorted(run.results):
        result = run.results[frame]
        answers.update(np.array([frame, result.match, result.accepted], dtype=np.int64).tobytes())
        answers.update(np.float64(result.confidence).tobytes())
    wall, cpu = run.frame_wall * 1000, run.frame_cpu * 1000
    return {
        "frames": len(wall),
        "wall_median": float(np.median(wall)), "wall_p99": float(np.percentile(wall, 99)),
        "cpu_median": float(np.median(cpu)), "cpu_p99": float(np.percentile(cpu, 99)),
        "cpu_last_median": float(np.median(cpu[-1000:])), "cpu_last_p99": float(np.percentile(cpu[-1000:], 99)),
        "recall": metrics["recall_at_100p"], "auc": metrics["auc_pr"],
        "wm_max": max(s.wm_size for s in run.statistics), "words_end": run.statistics[-1].active_words,
        "answers": answers.hexdigest()[:12], "load": load,
    }


def measure_in(source: Path, name: str) -> dict[str, object]:
    """:func:`measure` in a child process that imports slamfront from ``source``."""
    env = {**os.environ, "PYTHONPATH": f"{source / 'framework'}{os.pathsep}{source / 'plugins'}"}
    done = subprocess.run([sys.executable, __file__, "_measure", name], capture_output=True, text=True, env=env,
                          check=False)
    if done.returncode != 0:
        raise RuntimeError(f"{name} on {source} failed: {done.stderr.strip()[-800:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def extraction_rows() -> list[list[object]]:
    """Feature extraction per frame (thread CPU), beside the detector's own time."""
    rows = []
    for label, spec in (("ORB 150 at 160x120 (world seed 21, laps 1-2)", EXTRACTION_SAMPLE),
                        ("SIFT 300 at 320x240 (synthetic_bow, world seed 1)", RECIPE)):
        stream = synthetic_stream(spec)
        if stream.extraction_seconds is None:  # cached before extraction was timed: time it again
            (Path(__file__).resolve().parent / ".cache" / f"bow_{spec.key}.npz").unlink()
            stream = synthetic_stream(spec)
        ms = stream.extraction_seconds * 1000
        rows.append([label, len(ms), float(np.median(ms)), float(np.percentile(ms, 99))])
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("what", nargs="?", default="run", choices=("run", "_measure"))
    parser.add_argument("name", nargs="?", help=argparse.SUPPRESS)
    parser.add_argument("--before", type=Path, help="an older slamfront source tree to compare with")
    parser.add_argument("--pairs", type=int, default=1, help="interleaved before/after pairs per run")
    parser.add_argument("--runs", nargs="*", choices=tuple(RUNS), default=list(RUNS))
    parser.add_argument("--results", default="bow_speed", help="results file name (benchmarks/results/NAME.md)")
    args = parser.parse_args()
    if args.what == "_measure":
        print(json.dumps(measure(args.name)))
        return
    load_before = os.getloadavg()
    rows = []
    here = Path(__file__).resolve().parent.parent
    for name in args.runs:
        measured: dict[str, list[dict[str, object]]] = {"before": [], "after": []}
        for _ in range(args.pairs):
            if args.before is not None:
                measured["before"].append(measure_in(args.before, name))
            measured["after"].append(measure_in(here, name))
            print(name, {k: v[-1] for k, v in measured.items() if v}, flush=True)
        for label, results in measured.items():
            for result in results:
                rows.append([RUNS[name][2], label, result["frames"], result["wall_median"], result["wall_p99"],
                             result["cpu_median"], result["cpu_p99"], result["cpu_last_p99"], result["recall"],
                             result["auc"], result["wm_max"], result["words_end"], result["answers"],
                             f"{result['load']:.1f}"])
    extraction = extraction_rows()
    before = f" `before`: the source tree {args.before.name} (in a child process, interleaved with `after`)." \
        if args.before else ""
    body = "\n\n".join([
        "Detector time per frame: the `process` call of the `bow_bayes` stage, wall clock and the calling thread's "
        "CPU time (the machine is shared with other jobs: CPU time is what the detector costs, wall time adds what "
        f"other jobs take from it). Rendering and feature extraction excluded (below).{before} Load average "
        f"(1 min) {load_before[0]:.1f} at the start, {os.getloadavg()[0]:.1f} at the end, on {os.cpu_count()} cores.",
        "## Detector time per frame",
        table(["run", "code", "frames", "wall median ms", "wall p99 ms", "CPU median ms", "CPU p99 ms",
               "CPU p99 ms, last 1,000", "R@100%P", "AUC-PR", "max WM", "words searched at the end", "answers",
               "load"], rows),
        "*answers*: a digest of every frame's match, acceptance and confidence (the same digest: the same answers). "
        "With the wall-clock budget the transfers depend on the measured time, so faster code keeps more in working "
        "memory and answers differently; the modelled budget and the unbounded recipe stream do the same work "
        "before and after.",
        "## Feature extraction per frame (descriptor stage, thread CPU; rendering excluded)",
        table(["features", "frames", "median ms", "p99 ms"], extraction),
    ])
    publish(args.results, "bow_bayes: time per frame at 10,000 frames, extraction beside it", body,
            libraries=("numpy", "numba", "opencv-contrib-python-headless"))


if __name__ == "__main__":
    main()
