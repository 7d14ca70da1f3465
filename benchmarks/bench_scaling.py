"""How each loop detector's cost grows with the map: 1k, 4k, 16k and 64k reference frames.

Two studies (``--study``):

**route** (default): a route of n map frames made of Nordland tiles, each with its own
seeded photometric and geometric change (:mod:`tiled_route`), described frame by frame
by each method's own descriptor, as a run does; n = 4k, 16k, 64k. A seeded stretch of
``--queries`` consecutive winter frames of tile 0 (the same at every size) is then
matched against the whole map: per-query time, the whole measured time (description +
map + queries), the extrapolation to n + n frames, peak memory, descriptor distances,
answers and recall at 100 % precision on those queries (a match is correct only in the
query's own tile, within 3 frames). Queries are a sample because comparing every one of
64k queries with 64k references (SeqSLAM) would take hours on 2 cores. Methods:
SeqSLAM, Fast-SeqSLAM, the hierarchical detector, from their Nordland recipes.

**cached** (the earlier study, below):

The descriptor stream is cached, not rendered: each method's own descriptor (from its
recipe) is computed once on the real Nordland route (3,576 summer + 3,576 winter frames),
then tiled to the map size, every copy after the first with a little noise (+-2 grey
levels on thumbnails, 5 % on RST-SHelo bins) so no two frames are identical. Description
and any rendering are excluded from every time. What is measured is the detector's
stages (place map + detector, as the recipe runs them) fed those descriptors:

- **map build**: feeding the n reference frames;
- **per query**: feeding a sample of consecutive query frames against the full map
  (their answers included: SeqSLAM answers its batch at the end), divided by the
  number of query frames fed (the hierarchical detector answers once per completed
  sequence of places, SeqSLAM every frame but the first and last ds/2: the answers are
  counted in their own column). A sample, because full query traversals are infeasible at 64k on
  2 cores for the methods that compare every query with every reference (~n^2);
- **total (extrapolated)**: map build + per query x n queries, i.e. a whole paired run
  of n + n frames;
- **peak RSS**: of the child process that ran that method at that size alone.

Each child loads the compiled kernels before timing (a once-per-process cost).

The growth exponent is the slope of log(per-query time) against log(n) over the sizes
(1 = linear search, 0 = constant). Methods come from recipes (with ``@key=value,...``
overrides), so any detector configuration can be added on the command line.

Run: .venv/bin/python benchmarks/bench_scaling.py [--study route|cached] [--sizes 4000 16000 64000] [--seeds 0 1 2]
     [--queries 300] [--seed 0] [--method LABEL=RECIPE[@key=value,...] ...]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import RESULTS, publish, table  # noqa: E402

METHODS = {
    "hierarchical": "nordland_hsl",
    "seqslam": "nordland_seqslam",
    "seqslam_fast (exact kNN)": "nordland_seqslam_fast",
    "seqslam_fast (HNSW)": "nordland_seqslam_fast@loop_detector.params.knn=hnsw",
    "nearest_neighbour": "nordland_hsl@place_map=null,loop_detector={plugin: nearest_neighbour}",
}
"""Label -> recipe[@overrides]: the methods measured by default (cached study)."""

ROUTE_METHODS = {
    "hierarchical": "nordland_hsl",
    "seqslam": "nordland_seqslam",
    "seqslam_fast": "nordland_seqslam_fast",
}
"""Label -> recipe[@overrides]: the methods of the route study."""

TUNED_FROM = 2900
"""Nordland places from here on chose RST-SHelo's defaults (docs/loop_closure.md): no query comes from them."""

NORDLAND = Path(os.environ.get("SLAMFRONT_DATA", Path(__file__).resolve().parents[2] / "shared" / "data")) / "nordland"

def split_overrides(text: str) -> list[str]:
    """``a=1,b={x: 1, y: 2}`` -> ``["a=1", "b={x: 1, y: 2}"]`` (commas inside braces kept)."""
    parts, depth, current = [], 0, ""
    for char in text:
        depth += 1 if char in "{[" else -1 if char in "}]" else 0
        if char == "," and depth == 0:
            parts.append(current)
            current = ""
        else:
            current += char
    return [p for p in [*parts, current] if p]


def tiled(vectors: np.ndarray, n: int, seed: int) -> np.ndarray:
    """``vectors`` repeated to n rows; copies after the first get a little noise."""
    rng = np.random.default_rng(seed)
    copies = [vectors]
    while sum(len(c) for c in copies) < n:
        if vectors.dtype == np.uint8:
            noise = rng.integers(-2, 3, vectors.shape)
            copies.append(np.clip(vectors.astype(np.int16) + noise, 0, 255).astype(np.uint8))
        else:
            noisy = vectors * (1 + 0.05 * rng.standard_normal(vectors.shape)).astype(vectors.dtype)
            noisy = np.abs(noisy)
            total = noisy.sum(axis=1, keepdims=True)
            copies.append(np.where(total > 0, noisy / np.where(total > 0, total, 1), 0).astype(vectors.dtype))
    return np.concatenate(copies)[:n]


def warm_up(vectors: np.ndarray, metric: str) -> None:
    """Load the compiled kernels before timing: importing numba and its cached machine code
    is a once-per-process cost (~1 s), not a cost of the map or of a query."""
    from slamfront.core.distances import pairwise
    from slamfront.core.seqslam import sequence_scores_block, trajectory_offsets

    pairwise(vectors, vectors, metric)  # type: ignore[arg-type]
    offsets = trajectory_offsets(2, 1.0, 1.0)
    sequence_scores_block(np.zeros((4, 3)), offsets)
    sequence_scores_block(np.zeros((40, 3)), offsets, [np.array([1])])


def measure(spec: str, references: np.ndarray, queries: np.ndarray, metric: str) -> dict[str, float]:
    """Feed the recipe's stages after the descriptor; time the map build and the queries."""
    import resource
    import time

    from slamfront import Frame, StageInputs
    from slamfront.messages import Features
    from slamfront.recipe import build_pipeline, load_recipe

    name, _, overrides = spec.partition("@")
    recipe, path = load_recipe(name, split_overrides(overrides))
    pipeline = build_pipeline(recipe, str(path))
    stages = [s for s in pipeline.stages if s.kind != "descriptor"]
    warm_up(references[:2], metric)
    pixel = np.zeros((1, 1), dtype=np.uint8)
    answers = 0

    def feed(index: int, traversal: str, vector: np.ndarray) -> None:
        nonlocal answers
        frame = Frame(index=index, timestamp=float(index), image=pixel, traversal=traversal)  # type: ignore[arg-type]
        inputs = StageInputs(frame=frame, outputs={"descriptor": [Features(frame=index, vector=vector, metric=metric)]},
                             stages={})
        for stage in stages:
            produced = list(stage.process(inputs))
            inputs.outputs[stage.kind] = produced
            inputs.stages = {**inputs.stages, stage.kind: stage}
            if stage.kind == "loop_detector":
                answers += sum(getattr(r, "match", -1) >= 0 for r in produced)

    start = time.perf_counter()
    for index, vector in enumerate(references):
        feed(index, "reference", vector)
    built = time.perf_counter()
    answers = 0
    for offset, vector in enumerate(queries):
        feed(len(references) + offset, "query", vector)
    for stage in stages:
        produced = list(stage.finish())
        if stage.kind == "loop_detector":
            answers += sum(getattr(r, "match", -1) >= 0 for r in produced)
    done = time.perf_counter()
    return {
        "build_s": built - start,
        "query_s": done - built,
        "answers": answers,
        "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }


def child(spec: str, cache: str, n: int, n_queries: int) -> None:
    stream = np.load(cache)
    references = tiled(stream["reference"], n, seed=1)
    start = min(1000, len(stream["query"]) - n_queries)  # the same stretch of the route at every size
    queries = stream["query"][start : start + n_queries]
    print(json.dumps(measure(spec, references, queries, str(stream["metric"]))))


def describe(spec: str, folder: Path) -> Path:
    """The method's descriptors of the whole Nordland route, cached as .npz (once per descriptor config)."""
    from tqdm import tqdm

    from slamfront import StageInputs
    from slamfront.recipe import build_pipeline, load_recipe

    name, _, overrides = spec.partition("@")
    recipe, path = load_recipe(name, split_overrides(overrides))
    key = recipe.descriptor.model_dump_json() if recipe.descriptor is not None else "none"
    cache = folder / f"{abs(hash(key))}.npz"
    if cache.exists():
        return cache
    pipeline = build_pipeline(recipe, str(path))
    descriptor = pipeline.plugins["descriptor"]
    vectors: dict[str, list[np.ndarray]] = {"reference": [], "query": []}
    metric = "l1"
    for frame in tqdm(pipeline.source.frames(), total=len(pipeline.source), desc=f"describe ({name})", leave=False):
        features = descriptor.process(StageInputs(frame=frame))[0]
        vectors[frame.traversal].append(features.vector)
        metric = features.metric
    np.savez(cache, reference=np.array(vectors["reference"]), query=np.array(vectors["query"]), metric=metric)
    return cache


def growth(sizes: list[int], values: list[float]) -> float:
    """Slope of log(value) against log(size)."""
    return float(np.polyfit(np.log(sizes), np.log(values), 1)[0])


CACHED_PANELS = (("per_query_ms", "detector time per query", "ms per query", True),
                 ("total_s", "whole paired run of n + n frames (extrapolated)", "seconds", True))
ROUTE_PANELS = (("per_query_ms", "detector time per query, tiled route", "ms per query", True),
                ("recall_at_100p", "recall at 100 % precision on the route's queries", "R@100%P", False))


def plot(results: dict[str, dict[int, dict[str, float]]], path: Path,
         panels: tuple[tuple[str, str, str, bool], ...] = CACHED_PANELS) -> Path:
    """One panel per ``(key, title, y label, log scale)``, every method's value against the map size."""
    from slamfront.report.plots import _pyplot

    plt = _pyplot()
    fig, axes = plt.subplots(1, len(panels), figsize=(11, 4.2))
    for axis, (key, title, label, log) in zip(axes, panels):
        for method, by_size in results.items():
            sizes = sorted(by_size)
            axis.plot(sizes, [by_size[n][key] for n in sizes], "o-", label=method)
        axis.set_xscale("log")
        if log:
            axis.set_yscale("log")
        axis.set_title(title)
        axis.set_ylabel(label)
        axis.set_xlabel("map size n (reference frames)")
        axis.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def route_child(spec: str, n: int, n_queries: int, seed: int) -> None:
    """One method at one map size on the tiled route; prints its measurements as JSON."""
    import resource
    import time

    from tiled_route import TiledRoute

    from slamfront import Frame, StageInputs
    from slamfront.core.loops import LoopGroundTruth
    from slamfront.evaluation.loops import score_loops
    from slamfront.messages import LoopResult
    from slamfront.recipe import EvalOptions, build_pipeline, load_recipe

    route = TiledRoute(NORDLAND, seed)
    # the query stretch, in tile 0, before place 2,900: RST-SHelo's defaults were chosen on Nordland 2,900-3,575
    start = int(np.random.default_rng(seed).integers(0, TUNED_FROM - n_queries))
    name, _, overrides = spec.partition("@")
    recipe, path = load_recipe(name, split_overrides(overrides))
    pipeline = build_pipeline(recipe, str(path))
    stages = pipeline.stages
    descriptor = next(s for s in stages if s.kind == "descriptor")
    warm = descriptor.process(StageInputs(frame=Frame(index=0, timestamp=0.0, image=route.image("reference", 0))))[0]
    warm_up(np.stack([warm.vector, warm.vector]), warm.metric)
    reported: dict[int, LoopResult] = {}
    spent = {"describe": 0.0, "stages": 0.0}

    def keep(produced: list) -> None:  # type: ignore[type-arg]
        for message in produced:
            if isinstance(message, LoopResult):
                reported[message.frame] = message

    def feed(index: int, traversal: str, sequence_index: int) -> None:
        image = route.image(traversal, sequence_index)
        frame = Frame(index=index, timestamp=float(index), image=image, traversal=traversal,  # type: ignore[arg-type]
                      sequence_index=sequence_index)
        inputs = StageInputs(frame=frame, stages={})
        began = time.perf_counter()
        inputs.outputs["descriptor"] = list(descriptor.process(inputs))
        described = time.perf_counter()
        inputs.stages = {"descriptor": descriptor}
        for stage in stages:
            if stage is descriptor:
                continue
            produced = list(stage.process(inputs))
            inputs.outputs[stage.kind] = produced
            inputs.stages = {**inputs.stages, stage.kind: stage}
            keep(produced)
        spent["describe"] += described - began
        spent["stages"] += time.perf_counter() - described

    began = time.perf_counter()
    for index in range(n):
        feed(index, "reference", index)
    built = time.perf_counter()
    build = dict(spent)
    feed(n, "query", start)  # the place map places the held map frames now; Fast-SeqSLAM builds its index
    first = time.perf_counter()
    first_describe = spent["describe"]
    for k in range(1, n_queries):
        feed(n + k, "query", start + k)
    for stage in stages:
        keep(list(stage.finish()))
    done = time.perf_counter()
    statistics: dict[str, float] = {}
    for stage in stages:
        statistics.update(stage.statistics())
    queries = np.arange(n, n + n_queries)
    truth = LoopGroundTruth.band(queries, start + np.arange(n_queries), 3, valid=(0, n - 1))
    scores = score_loops(reported, truth, [1], EvalOptions())
    print(json.dumps({
        "build_s": built - began, "build_describe_s": build["describe"], "first_query_s": first - built,
        "query_s": done - first, "query_describe_s": spent["describe"] - first_describe,
        "answers": int(sum(1 for r in reported.values() if r.match >= 0 and r.frame >= n)),
        "accepted": int(sum(1 for r in reported.values() if r.accepted and r.match >= 0 and r.frame >= n)),
        "recall_at_100p": scores.metrics["recall_at_100p"], "auc_pr": scores.metrics["auc_pr"],
        "distances": statistics.get("n_distances"),
        "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "query_start": start,
    }))


def measure_route(methods: dict[str, str], sizes: list[int], n_queries: int, seed: int
                  ) -> dict[str, dict[int, dict[str, float]]]:
    """Every method at every size on the tiled route of ``seed``, each in its own child process."""
    results: dict[str, dict[int, dict[str, float]]] = {}
    for n in sizes:  # sizes outside, methods inside: the methods at one size run close in time
        for label, spec in methods.items():
            done = subprocess.run([sys.executable, __file__, "--route-child", spec, str(n), str(n_queries), str(seed)],
                                  capture_output=True, text=True, check=False)
            if done.returncode != 0:
                raise RuntimeError(f"{label} at {n}: {done.stderr.strip()[-800:]}")
            m = json.loads(done.stdout.strip().splitlines()[-1])
            per_query = (m["query_s"] - m["query_describe_s"]) / (n_queries - 1)
            whole = m["build_s"] + m["first_query_s"] + m["query_s"]
            m.update(per_query_ms=1000 * per_query, whole_s=whole,
                     extrapolated_s=m["build_s"] + m["first_query_s"] + m["query_s"] / (n_queries - 1) * (n - 1))
            results.setdefault(label, {})[n] = m
            print(f"route {label} n={n}: {m['per_query_ms']:.2f} ms/query, answers {m['answers']}, "
                  f"R@100%P {m['recall_at_100p']:.3f}, build {m['build_s']:.1f} s, peak {m['peak_mb']:.0f} MB",
                  flush=True)
    return results


def route_study(methods: dict[str, str], sizes: list[int], n_queries: int, seed: int) -> str:
    """The tiled route of one seed: the markdown section of results/scaling.md."""
    load = [os.getloadavg()[0]]
    results = measure_route(methods, sizes, n_queries, seed)
    load.append(os.getloadavg()[0])
    rows = []
    for label, by_size in results.items():
        for n in sorted(by_size):
            m = by_size[n]
            versus = results.get("seqslam", {}).get(n)
            speedup = f"{versus['per_query_ms'] / m['per_query_ms']:.1f}x" if versus else "-"
            rows.append([label, n, m["answers"], m["accepted"], f"{m['recall_at_100p']:.3f}", m["per_query_ms"],
                         speedup, m["build_s"], m["build_describe_s"], m["first_query_s"], m["whole_s"],
                         m["extrapolated_s"],
                         m["distances"] if m["distances"] is not None else "-", m["peak_mb"]])
    start = next(iter(next(iter(results.values())).values()))["query_start"]
    largest = max(sizes)
    verdict = ""
    if "hierarchical" in results and "seqslam" in results and largest in results["hierarchical"]:
        h, q = results["hierarchical"][largest], results["seqslam"][largest]
        verdict = (f"At n = {largest}: the hierarchical detector takes {h['per_query_ms']:.2f} ms per query against "
                   f"SeqSLAM's {q['per_query_ms']:.1f} ms ({q['per_query_ms'] / h['per_query_ms']:.0f}x faster), "
                   f"R@100%P {h['recall_at_100p']:.3f} against {q['recall_at_100p']:.3f}.")
    figure = plot(results, RESULTS / "scaling_route.png", ROUTE_PANELS)
    return "\n\n".join(part for part in [
        "## Tiled route: 4k to 64k map frames, described as a run describes them",
        f"The map is a route of n summer frames in tiles of the Nordland route (3,576 frames each), every tile a "
        "different stretch of railway that looks like the others: its own cyclic pan (a multiple of 4 of 64 "
        "pixels) and mirroring, which no other tile shares, a small shift, scale and roll, and its own gain, "
        f"gamma and offset, drawn from seed {seed} and the tile number (`benchmarks/tiled_route.py`); frames are "
        "made and described on the fly by each method's own descriptor. "
        f"Queries: {n_queries} consecutive winter frames of tile 0 (places {start}-{start + n_queries - 1}, the "
        "same at every size, with tile 0's change; drawn before place 2,900, as places 2,900-3,575 chose "
        "RST-SHelo's defaults), matched against the whole map; a match is correct only in "
        "tile 0 within 3 frames (the other tiles look alike and grow with the map). The queries are a sample: "
        f"all {largest:,} queries against {largest:,} references would take SeqSLAM hours on this machine.",
        f"Load (1-min average) {load[0]:.1f} at start, {load[1]:.1f} at the end, on {os.cpu_count()} cores shared "
        "with other jobs: compare methods at one size (run one after the other), not with other runs.",
        table(["method", "map frames n", "answers (of the queries)", "accepted", "R@100%P (queries)",
               "ms per query (detector)", "SeqSLAM ms / this ms", "map build s", "of it description s",
               "first query s",
               f"whole s (map + {n_queries} queries)", "whole s (n + n, extrapolated)",
               f"descriptor distances ({n_queries} queries)", "peak RSS MB"], rows),
        verdict,
        f"![scaling on the tiled route]({figure.name})",
        "*ms per query* is the place map and detector per query frame after the first (answers included; "
        "SeqSLAM answers its batch at the end), description excluded; *map build* is describing and feeding "
        "the n map frames; *first query* is the first query frame alone, when the hierarchical place map "
        "chooses nu over the map frames it held and places them (and, past 10,000 places, checks whether a "
        "VP-tree would pay) and Fast-SeqSLAM builds its index: a one-time cost of the map, kept out of the "
        "per-query time and in the whole times. *whole, extrapolated* is map build + first query + n - 1 "
        "times the measured per-query time with description. Distances: the detectors' own count "
        "(`n_distances`) for the queries' searches and sequences.",
    ] if part)


def seeds_study(methods: dict[str, str], sizes: list[int], n_queries: int, seeds: list[int]) -> str:
    """The tiled route drawn from several seeds (tile changes and query stretch): per method and
    size, mean +- sd (min) over the seeds of the per-query time, the ratio to SeqSLAM's measured
    in the same seed, R@100%P and the answers accepted; the section "over seeds" of scaling.md."""
    load = [os.getloadavg()[0]]
    runs = {seed: measure_route(methods, sizes, n_queries, seed) for seed in seeds}
    load.append(os.getloadavg()[0])

    def spread(values: list[float], digits: int) -> str:
        return f"{np.mean(values):.{digits}f} ± {np.std(values):.{digits}f} ({min(values):.{digits}f})"

    rows = []
    for label in methods:
        for n in sizes:
            cells = [runs[seed][label][n] for seed in seeds]
            ratios = [runs[seed]["seqslam"][n]["per_query_ms"] / runs[seed][label][n]["per_query_ms"]
                      for seed in seeds if "seqslam" in runs[seed]]
            rows.append([label, n, len(seeds), spread([c["per_query_ms"] for c in cells], 2),
                         spread(ratios, 1) if ratios else "-", spread([c["recall_at_100p"] for c in cells], 3),
                         spread([float(c["accepted"]) for c in cells], 0),
                         spread([c["distances"] / 1e6 for c in cells], 2) if all(c["distances"] for c in cells) else "-",
                         " / ".join(f"{c['per_query_ms']:.2f}" for c in cells)])
    return "\n\n".join([
        "## Tiled route over seeds",
        f"The tiled route above drawn from seeds {', '.join(map(str, seeds))} (each seed its own tile changes and "
        f"its own stretch of {n_queries} consecutive winter queries of tile 0, before place 2,900); every method at "
        "every size in its own child process, the methods of one seed one after the other. Mean ± sd (min) over the "
        "seeds; the ratio is SeqSLAM's per-query time over the method's, both of the same seed. Load (1-min average) "
        f"{load[0]:.1f} at start, {load[1]:.1f} at the end, on {os.cpu_count()} cores.",
        table(["method", "map frames n", "seeds", "ms per query (detector)", "SeqSLAM ms / this ms",
               "R@100%P (queries)", "accepted", f"descriptor distances, M ({n_queries} queries)",
               "ms per query, each seed"], rows),
    ])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--study", choices=("route", "cached"), default="route")
    parser.add_argument("--sizes", type=int, nargs="+", default=None,
                        help="map sizes (route: 4000 16000 64000; cached: 1000 4000 16000 64000)")
    parser.add_argument("--queries", type=int, default=None,
                        help="query frames timed per size (route: 300 consecutive; cached: 200)")
    parser.add_argument("--seed", type=int, default=0, help="route study: tile changes and query stretch")
    parser.add_argument("--seeds", type=int, nargs="+", default=None,
                        help="route study over several seeds (default size 64000): a section of means and spreads")
    parser.add_argument("--method", action="append", default=[], metavar="LABEL=RECIPE[@key=value,...]",
                        help="measure this method (repeatable; default: the five built-in ones)")
    parser.add_argument("--child", nargs=4, help=argparse.SUPPRESS)
    parser.add_argument("--route-child", nargs=4, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(args.child[0], args.child[1], int(args.child[2]), int(args.child[3]))
        return
    if args.route_child:
        route_child(args.route_child[0], int(args.route_child[1]), int(args.route_child[2]), int(args.route_child[3]))
        return
    if args.study == "route" and args.seeds:
        methods = dict(m.split("=", 1) for m in args.method) if args.method else ROUTE_METHODS
        section = seeds_study(methods, args.sizes or [64000], args.queries or 300, args.seeds)
        publish("scaling", "How the detectors' cost grows with the map", section, keep_sections=True)
        return
    if args.study == "route":
        methods = dict(m.split("=", 1) for m in args.method) if args.method else ROUTE_METHODS
        section = route_study(methods, args.sizes or [4000, 16000, 64000], args.queries or 300, args.seed)
        publish("scaling", "How the detectors' cost grows with the map", section, keep_sections=True)
        return
    args.sizes = args.sizes or [1000, 4000, 16000, 64000]
    args.queries = args.queries or 200
    methods = dict(m.split("=", 1) for m in args.method) if args.method else METHODS
    load = [os.getloadavg()[0]]
    results: dict[str, dict[int, dict[str, float]]] = {}
    with tempfile.TemporaryDirectory() as folder:
        for label, spec in methods.items():
            cache = describe(spec, Path(folder))
            for n in args.sizes:
                done = subprocess.run([sys.executable, __file__, "--child", spec, str(cache), str(n), str(args.queries)],
                                      capture_output=True, text=True, check=False)
                if done.returncode != 0:
                    raise RuntimeError(f"{label} at {n}: {done.stderr.strip()[-800:]}")
                m = json.loads(done.stdout.strip().splitlines()[-1])
                per_query = m["query_s"] / args.queries
                m.update(per_query_ms=1000 * per_query, total_s=m["build_s"] + per_query * n)
                results.setdefault(label, {})[n] = m
                print(f"{label} n={n}: {m['per_query_ms']:.3f} ms/query, build {m['build_s']:.2f} s, "
                      f"peak {m['peak_mb']:.0f} MB", flush=True)
    load.append(os.getloadavg()[0])
    rows = []
    for label, by_size in results.items():
        sizes = sorted(by_size)
        slope = growth(sizes, [by_size[n]["per_query_ms"] for n in sizes]) if len(sizes) > 1 else float("nan")
        slope_total = growth(sizes, [by_size[n]["total_s"] for n in sizes]) if len(sizes) > 1 else float("nan")
        for n in sizes:
            m = by_size[n]
            rows.append([label, n, m["answers"], m["per_query_ms"], m["build_s"], m["total_s"], m["peak_mb"],
                         f"{slope:.2f}" if n == sizes[0] else "", f"{slope_total:.2f}" if n == sizes[0] else ""])
    figure = plot(results, RESULTS / "scaling.png")
    largest = max(args.sizes)
    per_query_at = {label: by_size[largest]["per_query_ms"] for label, by_size in results.items() if largest in by_size}
    fastest = min(per_query_at, key=per_query_at.get) if per_query_at else "-"
    body = "\n\n".join(part for part in [
        "## Cached descriptor stream: 1k to 64k map frames",
        f"Cached descriptor stream (real Nordland descriptors of each method, tiled with noise to the map size; "
        f"no rendering, description excluded). {args.queries} consecutive query frames timed per size against the "
        f"full map. Load (1-min average) {load[0]:.1f} at start, {load[1]:.1f} at the end, on {os.cpu_count()} cores: "
        "compare methods and sizes within this table, not with other runs.",
        table(["method", "map frames n", "answers (of the query frames timed)", "ms per query frame", "map build s", "total s (n + n, extrapolated)",
               "peak RSS MB", "growth exponent (per query)", "growth exponent (total)"], rows),
        f"![scaling]({figure.name})",
        "A row with 0 answers timed query frames that triggered no search (the hierarchical detector answers "
        "once per completed sequence of places): its per-query time is not a search's; the tiled-route study "
        "counts answers at every size." if any(m["answers"] == 0 for by in results.values() for m in by.values())
        else "",
        f"At n = {largest}: fastest per query is {fastest}; per-query ms: "
        + ", ".join(f"{k} {v:.3g}" for k, v in per_query_at.items()) + ".",
        "The sequence-matching methods that compare each query with every reference (SeqSLAM, Fast-SeqSLAM with "
        "exact kNN, the single-image baseline) grow linearly per query (n^2 for a whole run); the hierarchical "
        "detector searches place representatives only once per completed query sequence, and HNSW replaces the "
        "exhaustive comparison by a graph search. Fast-SeqSLAM builds its HNSW index when the first query "
        "arrives, so that build is inside its per-query time here (divided over the timed queries).",
    ] if part)
    publish("scaling", "How the detectors' cost grows with the map", body, keep_sections=True)


if __name__ == "__main__":
    main()
