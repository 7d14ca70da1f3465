"""Revisits at any speed and in either direction: sequence detectors on re-timed queries.

Nordland stretches of 600 frames (summer reference, winter query), the query re-timed by
the source's ``query_timing`` (:mod:`slamfront.core.retiming`: reversed, 0.5x, 2x, speed
varying smoothly 0.6x-1.8x, stop-and-go; the ground truth follows the frames, zeta 3 as
in the other benchmarks) and the unchanged control; each detector with its shipped
defaults: recall at 100 % precision, AUC-PR, precision / recall at the operating point,
wall time and descriptor distances per query, mean ± sd over the stretches. Rows from
the stretch the speed-free search was designed on (frames 2900-3499) are reported apart
from the held-out ones.

Run: nice .venv/bin/python benchmarks/bench_speed_direction.py [--workers 2]
     [--detectors nordland_hsl nordland_seqslam ...] [--starts 300 1100 1900]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import publish, table  # noqa: E402

from slamfront.recipe import build_pipeline, load_recipe  # noqa: E402
from slamfront.runtime import run_pipeline  # noqa: E402

QUICK = ["log.images=false", "eval.retrieval_max_k=0", "eval.tolerances=[]", "eval.plots=false"]
DETECTORS = ["nordland_hsl", "nordland_hsl_faithful", "nordland_seqslam", "nordland_seqslam_fast",
             "nordland_openseqslam"]
TIMINGS = ["original", "reversed", "half", "double", "varying", "stop_and_go"]
DESIGN = [2900]
HELD_OUT = [300, 1100, 1900]
LENGTH = 600
FIELDS = ["recall_at_100p", "auc_pr", "precision_at_operating_point", "recall_at_operating_point"]


def run(recipe: str, start: int, timing: str, scratch: str) -> dict:
    overrides = [*QUICK, f"source.params.start={start}", f"source.params.limit={LENGTH}",
                 f"source.params.query_timing={timing}"]
    loaded, path = load_recipe(recipe, overrides)
    began = time.perf_counter()
    metrics = run_pipeline(build_pipeline(loaded, str(path)), str(path),
                           Path(scratch) / f"{recipe}_{start}_{timing}", progress=False).metrics
    metrics = dict(metrics)
    metrics["seconds"] = time.perf_counter() - began
    return metrics


def cell(values: list[float], digits: int = 3) -> str:
    values = [v for v in values if v is not None and np.isfinite(v)]
    if not values:
        return "-"
    if len(values) == 1:
        return f"{values[0]:.{digits}f}"
    return f"{np.mean(values):.{digits}f} ± {np.std(values, ddof=1):.{digits}f}"


def rows(results: dict, detectors: list[str], starts: list[int]) -> list[list[object]]:
    out = []
    for recipe in detectors:
        for timing in TIMINGS:
            found = [results[(recipe, s, timing)] for s in starts if (recipe, s, timing) in results]
            if not found:
                continue
            queries = [m.get("n_query_frames") or m.get("n_places_query") or LENGTH for m in found]
            out.append([recipe, timing, len(found),
                        *(cell([m.get(k, np.nan) for m in found]) for k in FIELDS),
                        cell([1000 * m["seconds"] / q for m, q in zip(found, queries)], 1),
                        cell([m.get("n_distances", np.nan) / q for m, q in zip(found, queries)], 0)])
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--detectors", nargs="+", default=DETECTORS)
    parser.add_argument("--starts", nargs="+", type=int, default=HELD_OUT)
    args = parser.parse_args()
    load = os.getloadavg()[0]
    jobs = [(recipe, start, timing) for recipe in args.detectors for start in DESIGN + args.starts
            for timing in TIMINGS]
    results = {}
    with tempfile.TemporaryDirectory() as scratch, ProcessPoolExecutor(args.workers) as pool:
        futures = {pool.submit(run, *job, scratch): job for job in jobs}
        for done, future in enumerate(as_completed(futures), 1):  # progress: the runs take minutes
            job = futures[future]
            try:
                results[job] = future.result()
            except Exception as error:  # one failing run is reported, not fatal
                print(f"{job}: failed: {error}", file=sys.stderr)
            print(f"[{done}/{len(jobs)}] {job}", file=sys.stderr)
    headers = ["detector (shipped defaults)", "query timing", "stretches", "R@100%P", "AUC-PR",
               "precision at op. point", "recall at op. point", "ms / query (wall)", "distances / query"]
    csv = Path(__file__).resolve().parent / "results" / "speed_direction.csv"
    with open(csv, "w") as f:
        f.write("detector,start,timing," + ",".join(FIELDS) + ",seconds,n_distances\n")
        for (recipe, start, timing), m in sorted(results.items()):
            f.write(",".join([recipe, str(start), timing, *(f"{m.get(k, np.nan):.4f}" for k in FIELDS),
                              f"{m['seconds']:.2f}", str(m.get("n_distances", ""))]) + "\n")
    body = (
        f"Nordland stretches of {LENGTH} frames (summer reference, winter query, zeta 3), the query re-timed by "
        "`query_timing` (the ground truth follows the frames). Mean ± sd over stretches. The speed-free search "
        f"of `hierarchical_sequence` was designed on the stretch starting at {DESIGN[0]}; the held-out stretches "
        f"start at {', '.join(map(str, args.starts))} (frames {LENGTH} each). Wall time on a shared 2-core machine "
        f"(1-min load {load:.1f} at start, {args.workers} runs at a time): compare within a row group only.\n\n"
        f"## Held-out stretches\n\n{table(headers, rows(results, args.detectors, args.starts))}\n\n"
        f"## Design stretch (frames {DESIGN[0]}-{DESIGN[0] + LENGTH - 1})\n\n"
        f"{table(headers, rows(results, args.detectors, DESIGN))}\n\n"
        "Command: `nice .venv/bin/python benchmarks/bench_speed_direction.py "
        f"--detectors {' '.join(args.detectors)} --starts {' '.join(map(str, args.starts))}`; per-run numbers in "
        "speed_direction.csv.\n"
    )
    publish("speed_direction", "Sequence detectors on re-timed and reversed queries", body)


if __name__ == "__main__":
    main()
