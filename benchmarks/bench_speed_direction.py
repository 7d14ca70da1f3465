"""Revisits at any speed and in either direction: sequence detectors on re-timed queries.

Nordland stretches of 600 frames (summer reference, winter query), the query re-timed by
the source's ``query_timing`` (:mod:`slamfront.core.retiming`: reversed, 0.5x, 2x, speed
varying smoothly 0.6x-1.8x, stop-and-go; the ground truth follows the frames, zeta 3 as
in the other benchmarks) and the unchanged control; each detector with its shipped
defaults: recall at 100 % precision, AUC-PR, precision / recall at the operating point,
wall time and descriptor distances per query, mean ± sd over the stretches. Rows from
the stretch the speed-free search was designed on (frames 2900-3499) are reported apart
from the held-out ones; the synthetic street (world seeds 1 and 2, 300 frames, the
detectors' synthetic recipes) was not designed on.

Run: nice .venv/bin/python benchmarks/bench_speed_direction.py [--workers 2]
     [--detectors nordland_hsl nordland_seqslam ...] [--starts 300 1900]; then --merge --detectors smart
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

from slamfront.core.retiming import retimed_frames  # noqa: E402
from slamfront.recipe import build_pipeline, load_recipe  # noqa: E402
from slamfront.runtime import run_pipeline  # noqa: E402

QUICK = ["log.images=false", "eval.retrieval_max_k=0", "eval.tolerances=[]", "eval.plots=false"]
DETECTORS = ["nordland_hsl", "nordland_hsl_faithful", "faithful_cone", "nordland_seqslam", "nordland_seqslam_fast",
             "nordland_openseqslam"]
TIMINGS = ["original", "reversed", "half", "double", "varying", "stop_and_go"]
DESIGN = [2900]
HELD_OUT = [300, 1900]
LENGTH = 600
IMAGE = Path(__file__).resolve().parent.parent / "docs" / "img" / "speed_direction.png"
FIELDS = ["recall_at_100p", "auc_pr", "precision_at_operating_point", "recall_at_operating_point"]


SYNTHETIC = {"nordland_hsl": "synthetic_hsl", "nordland_seqslam": "synthetic_seqslam", "smart": "synthetic_hsl"}
"""The synthetic street (world seeds 1, 2; 300 frames on a 300 m route) with the same detectors' synthetic recipes;
``smart``: synthetic_hsl with both traversals resampled to one frame per metre by odometry (SMART)."""
SMART = ["source.params.resample_m=1.0"]
VARIANTS = {"faithful_cone": ["loop_detector.params.speed_search=cone"]}
"""Rows that are a shipped recipe with an option set: ``faithful_cone`` is nordland_hsl_faithful with its speed-free
cone (``speed_search: cone``; the preset keeps Rodrigues 2019's letter)."""
SEEDS = [1, 2]
SYNTHETIC_FRAMES = 300


def run(recipe: str, start: int, timing: str, scratch: str) -> dict:
    """One run: a Nordland stretch from ``start``, or (negative start) synthetic world seed ``-start``."""
    folder = Path(scratch) / f"{recipe}_{start}_{timing}"  # by the row's own name: smart and synthetic_hsl differ
    overrides = VARIANTS.get(recipe, [])
    recipe = {"faithful_cone": "nordland_hsl_faithful"}.get(recipe, recipe)
    if start < 0:
        overrides = [*overrides, *QUICK, f"source.params.seed={-start}", f"source.params.frames_per_traversal={SYNTHETIC_FRAMES}",
                     f"source.params.route_length_m={SYNTHETIC_FRAMES}", f"source.params.query_timing={timing}"]
        overrides += SMART if recipe == "smart" else []
        recipe = SYNTHETIC[recipe]
    else:
        overrides = [*overrides, *QUICK, f"source.params.start={start}", f"source.params.limit={LENGTH}",
                     f"source.params.query_timing={timing}"]
    loaded, path = load_recipe(recipe, overrides)
    began = time.perf_counter()
    metrics = run_pipeline(build_pipeline(loaded, str(path)), str(path), folder, progress=False).metrics
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
            name = (SYNTHETIC[recipe] if starts and starts[0] < 0 else recipe) + (" + SMART" if recipe == "smart" else "")
            name = "nordland_hsl_faithful + cone" if recipe == "faithful_cone" else name
            out.append([name, timing, len(found),
                        *(cell([m.get(k, np.nan) for m in found]) for k in FIELDS),
                        cell([1000 * m["seconds"] / q for m, q in zip(found, queries)], 1),
                        cell([m.get("n_distances", np.nan) / q for m, q in zip(found, queries)], 0)])
    return out


def plot(results: dict, detectors: list[str], starts: list[int], path: Path) -> None:
    """Bars of R@100%P per query timing (mean over the held-out stretches), one group per detector."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 3.6), dpi=110)
    width = 0.8 / len(TIMINGS)
    for k, timing in enumerate(TIMINGS):
        means = [np.mean([results[(d, s, timing)]["recall_at_100p"] for s in starts if (d, s, timing) in results] or
                         [np.nan]) for d in detectors]
        ax.bar(np.arange(len(detectors)) + (k - len(TIMINGS) / 2 + 0.5) * width, means, width, label=timing)
    ax.set_xticks(np.arange(len(detectors)), detectors, fontsize=8)
    ax.set_ylabel("R@100%P (held-out stretches)")
    ax.set_ylim(0, 1)
    ax.legend(fontsize=7, ncol=len(TIMINGS), loc="upper center", bbox_to_anchor=(0.5, 1.15))
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def read_csv(path: Path) -> dict:
    """The per-run numbers of a previous run (``--from-csv``)."""
    results = {}
    lines = path.read_text().splitlines()
    header = lines[0].split(",")
    for line in lines[1:]:
        cells = dict(zip(header, line.split(",")))
        metrics = {k: float(cells[k]) for k in FIELDS}
        metrics["seconds"] = float(cells["seconds"])
        metrics["n_distances"] = float(cells["n_distances"]) if cells["n_distances"] else np.nan
        start = int(cells["start"])
        # the query frames of the re-timed pass (older files do not list them)
        metrics["n_query_frames"] = float(cells["n_queries"]) if cells.get("n_queries") else \
            float(len(retimed_frames(SYNTHETIC_FRAMES if start < 0 else LENGTH, cells["timing"])))  # type: ignore[arg-type]
        results[(cells["detector"], start, cells["timing"])] = metrics
    return results


def when(args: argparse.Namespace, load: float) -> str:
    """How the page's times were taken: which rows this run measured, and how many runs at a time."""
    if args.from_csv:
        return "re-rendered from speed_direction.csv"
    if args.merge:
        return (f"the rows of {', '.join(args.detectors)} rerun {args.workers} at a time, 1-min load {load:.1f} at "
                "start; the other rows from speed_direction.csv, measured earlier")
    return f"1-min load {load:.1f} at start, {args.workers} runs at a time"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--detectors", nargs="+", default=DETECTORS)
    parser.add_argument("--starts", nargs="+", type=int, default=HELD_OUT)
    parser.add_argument("--no-synthetic", dest="synthetic", action="store_false",
                        help="leave out the synthetic worlds")
    parser.add_argument("--merge", action="store_true",
                        help="keep the runs of results/speed_direction.csv and add these (e.g. --detectors smart)")
    parser.add_argument("--from-csv", action="store_true",
                        help="re-render the table and the plot from results/speed_direction.csv without running")
    args = parser.parse_args()
    load = os.getloadavg()[0]
    worlds = [-seed for seed in SEEDS] if args.synthetic else []
    jobs = [(recipe, start, timing) for recipe in args.detectors
            for start in ([] if recipe == "smart" else DESIGN + args.starts) + (worlds if recipe in SYNTHETIC else [])
            for timing in TIMINGS]
    csv = Path(__file__).resolve().parent / "results" / "speed_direction.csv"
    results = read_csv(csv) if args.from_csv or args.merge else {}
    jobs = [] if args.from_csv else jobs
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
    with open(csv, "w") as f:
        f.write("detector,start,timing," + ",".join(FIELDS) + ",seconds,n_distances,n_queries\n")
        for (recipe, start, timing), m in sorted(results.items()):
            queries = m.get("n_query_frames") or m.get("n_places_query") or LENGTH
            f.write(",".join([recipe, str(start), timing, *(f"{m.get(k, np.nan):.4f}" for k in FIELDS),
                              f"{m['seconds']:.2f}", f"{m.get('n_distances', np.nan):.0f}", f"{queries:.0f}"]) + "\n")
    shown = [d for d in DETECTORS if any(key[0] == d for key in results)]
    plot(results, shown, args.starts, IMAGE)
    body = (
        f"Nordland stretches of {LENGTH} frames (summer reference, winter query, zeta 3), the query re-timed by "
        "`query_timing` (the ground truth follows the frames). Mean ± sd over stretches. The speed-free search "
        f"of `hierarchical_sequence` was designed on the stretch starting at {DESIGN[0]}; the held-out stretches "
        f"start at {', '.join(map(str, args.starts))} (frames {LENGTH} each). Wall time on a shared 2-core machine "
        f"({when(args, load)}; other engineers' jobs ran beside them): compare within a row group only.\n\n"
        f"## Held-out stretches\n\n{table(headers, rows(results, shown, args.starts))}\n\n"
        f"## Design stretch (frames {DESIGN[0]}-{DESIGN[0] + LENGTH - 1})\n\n"
        f"{table(headers, rows(results, shown, DESIGN))}\n\n"
        f"## Synthetic street (world seeds {', '.join(map(str, SEEDS))}, {SYNTHETIC_FRAMES} frames; not designed on)\n\n"
        "The detectors' synthetic recipes (`synthetic_hsl`, `synthetic_seqslam`: day reference, dusk query); a "
        "reversed query keeps facing the route's forward direction.\n\n"
        f"{table(headers, rows(results, [d for d in [*DETECTORS, 'smart'] if d in SYNTHETIC], [-s for s in SEEDS]))}\n\n"
        "`synthetic_hsl + SMART`: both traversals resampled to one frame per metre travelled by the poses "
        "(`resample_m: 1`, Pepperell et al. 2014) before matching.\n\n"
        "![R@100%P per query timing](../../docs/img/speed_direction.png)\n\n"
        "Command: `nice .venv/bin/python benchmarks/bench_speed_direction.py` then "
        "`... bench_speed_direction.py --merge --detectors smart` (the SMART rows), then `... --merge --detectors "
        "nordland_hsl_faithful faithful_cone` (the faithful rows, after its operating point changed); per-run numbers in "
        "speed_direction.csv (`--from-csv` re-renders this page and the plot from it).\n"
    )
    publish("speed_direction", "Sequence detectors on re-timed and reversed queries", body)


if __name__ == "__main__":
    main()
