"""bow_bayes: greedy vs NNDR over several world seeds, and RTAB-Map memory management on a long stream.

``seeds``: the synthetic_bow recipe's stream (2 laps of 300 frames, 320x240, SIFT 300)
for world seeds 1 and 3-7 (seed 2 chose the recipe's descriptor and feature
count; seeds 11-13 the thresholds' sweep), both vocabulary rules, under each scoring
rule; mean ± sd over seeds and the paired greedy - NNDR difference. Writes
``results/bow_bayes.md``.

``memory``: a 10,000-frame stream (10 laps of 1,000 frames, 160x120, ORB 150, world
seed 21). An unbounded run over its first 2,000 frames measures the detector's time per
frame, to which the linear time model is fitted; then budgets in modelled seconds at
which about 10 %, 30 % and 60 % of those frames trigger transfers (deterministic runs)
give recall and AUC against the budget. Writes ``results/bow_memory.md``.

``wall``: two runs over all 10,000 frames on the wall clock with a 30 ms budget (then
with ``forget_places``: one place more than entered WM leaves); the detector fits its
time model to its own first frames and scales it by the measured load. Writes
``results/bow_memory_wall.md`` and its plot.

``flat``: the same 10,000 frames under a 5 ms budget on the detector's default linear
time model, both forgetting rules: deterministic transfers and modelled times, whatever
the machine's load. Writes ``results/bow_memory_flat.md``.

Feature streams are rendered once and cached (``bow_streams.py``); every time here is
the detector's own, rendering and feature extraction excluded.

Run: .venv/bin/python benchmarks/bench_bow_bayes.py seeds    (about 3 minutes idle; streams cached)
     .venv/bin/python benchmarks/bench_bow_bayes.py memory   (about 20 minutes; stream cached)
     .venv/bin/python benchmarks/bench_bow_bayes.py wall     (about 12 minutes; stream cached)
     .venv/bin/python benchmarks/bench_bow_bayes.py flat     (about 10 minutes; stream cached)
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bow_streams import Run, Stream, StreamSpec, mean_sd, run_detector, score, synthetic_stream  # noqa: E402
from common import RESULTS, best_of, publish, table  # noqa: E402

from slamfront.core.distances import nearest_two, pairwise  # noqa: E402
from slamfront.core.memory import LinearTimeModel  # noqa: E402
from slamfront.report import plots  # noqa: E402
from slamfront_plugins.loop_detectors.bow_bayes import BowBayes  # noqa: E402

SEEDS = (1, 3, 4, 5, 6, 7)
RECIPE = {"descriptor_type": "sift", "stm_size": 10, "time_budget_s": 0.7}
"""The synthetic_bow recipe's detector settings (its 0.7 s budget is never reached here)."""
SCORINGS = (
    ("search", "place", "score", "merged frames searched (RTAB-Map), place scoring: the default"),
    ("search", "frame", "score", "merged frames searched, frame scoring"),
    ("repeat", "place", "exclude", "merged frames repeat the last answer and are left out, place scoring"),
    ("repeat", "frame", "score", "merged frames repeat the last answer and are scored by frame (the old rule)"),
)
LONG = StreamSpec(21, laps=10, frames_per_lap=1000, route_m=1000, width=160, height=120, descriptor="orb",
                  max_features=150)
TARGET_SHARES = (0.10, 0.30, 0.60)
SHORT = 2000
"""Frames of the budget sweep (the stream's first two laps)."""
WALL_BUDGET_S = 0.03
"""The wall-clock budget of the 10,000-frame runs."""
FLAT_BUDGET_S = 0.005
"""The modelled budget of ``flat`` (the detector's default time model)."""
LAST = 1000
MEMORY_HEADERS = ("budget", "frames triggering transfers", "R@100%P", "AUC-PR", "places transferred", "max WM",
                  "words searched at the end", "median ms (measured)", "p99 ms (measured)", "median ms (modelled)",
                  "p99 ms (modelled)")


# --- seeds ------------------------------------------------------------------------------


def seeds() -> None:
    streams = [synthetic_stream(StreamSpec(seed)) for seed in SEEDS]
    scores: dict[tuple[str, str, str, str], list[dict]] = {}
    vocabulary: dict[str, list[float]] = {"greedy_error": [], "nndr_error": [], "greedy_words": [], "nndr_words": [],
                                          "transferred": [], "merged": []}
    per_seed = []
    for stream in streams:
        for merged in ("search", "repeat"):
            for rule in ("greedy", "nndr"):
                config = BowBayes.Config(vocabulary_update=rule, merged_frames=merged,
                                         compare_rules=rule == "greedy" and merged == "search", **RECIPE)
                run = run_detector(config, stream, f"seed {stream.spec.seed} {rule} {merged}")
                for mode, scoring, unsearched, _ in SCORINGS:
                    if mode == merged:
                        scores.setdefault((mode, scoring, unsearched, rule), []).append(
                            score(run, stream.truth, scoring, unsearched))
                if config.compare_rules:
                    _vocabulary_columns(run, vocabulary)
        default = [scores[("search", "place", "score", rule)][-1] for rule in ("greedy", "nndr")]
        per_seed.append([stream.spec.seed, len(stream.descriptors), default[0]["n_queries_with_true_match"],
                         default[0]["recall_at_100p"], default[1]["recall_at_100p"], default[0]["auc_pr"],
                         default[1]["auc_pr"]])
        print(table(["seed", "frames", "revisiting", "greedy", "nndr", "greedy AUC", "nndr AUC"], per_seed[-1:]))
    summary = []
    for mode, scoring, unsearched, label in SCORINGS:
        greedy, nndr = scores[(mode, scoring, unsearched, "greedy")], scores[(mode, scoring, unsearched, "nndr")]
        summary.append([label, *_paired(greedy, nndr, "recall_at_100p"), *_paired(greedy, nndr, "auc_pr")])
    body = "\n\n".join([
        f"Synthetic street (the synthetic_bow recipe): world seeds {', '.join(map(str, SEEDS))}, 2 laps of 300 frames "
        "in one stream (day, then dusk), 320x240, SIFT (300 features); T_sim 0.2, T_loop 0.11, T_NNDR 0.8 and the "
        "derived T_ND1 / T_ND2 on squared distances, STM 10, time budget 0.7 s (never reached: "
        f"{int(sum(vocabulary['transferred']))} places transferred). Mean ± sd over the {len(SEEDS)} seeds; "
        "'greedy - NNDR' is the paired difference on the same stream.",
        "## Recall at 100 % precision and AUC-PR by scoring rule",
        table(["frames merged by T_sim / scoring", "greedy R@100%P", "NNDR R@100%P", "greedy - NNDR R@100%P",
               "greedy AUC", "NNDR AUC", "greedy - NNDR AUC"], summary),
        "## Per seed (default rule: merged frames searched, place scoring)",
        table(["world seed", "frames", "revisiting frames", "greedy R@100%P", "NNDR R@100%P", "greedy AUC",
               "NNDR AUC"], per_seed),
        "## Vocabulary (greedy run, the NNDR vocabulary built from the same frames beside it)",
        table(["", "greedy", "NNDR"], [
            ["mean quantisation error (squared L2)", mean_sd(vocabulary["greedy_error"]),
             mean_sd(vocabulary["nndr_error"])],
            ["words kept", mean_sd(vocabulary["greedy_words"]), mean_sd(vocabulary["nndr_words"])],
            ["frames merged by T_sim", mean_sd(vocabulary["merged"]), ""],
        ]),
    ])
    publish("bow_bayes", "bow_bayes: greedy vs NNDR vocabulary over world seeds", body)


def _paired(greedy: list[dict], nndr: list[dict], key: str) -> list[str]:
    a = [g[key] for g in greedy]
    b = [n[key] for n in nndr]
    return [mean_sd(a), mean_sd(b), mean_sd([x - y for x, y in zip(a, b)])]


def _vocabulary_columns(run: Run, into: dict[str, list[float]]) -> None:
    stats = run.statistics
    last = stats[-1]
    into["greedy_error"].append(float(np.nanmean([s.quantisation_error for s in stats])))
    into["nndr_error"].append(float(np.nanmean([s.other_quantisation_error for s in stats])))
    into["greedy_words"].append(float(last.vocabulary_size))
    into["nndr_words"].append(float(last.other_vocabulary_size))
    into["transferred"].append(float(sum(s.transferred for s in stats)))
    into["merged"].append(float(sum(s.merged for s in stats)))


# --- memory -----------------------------------------------------------------------------


def memory() -> None:
    stream = synthetic_stream(LONG)
    short = _prefix(stream, SHORT)
    unbounded = run_detector(BowBayes.Config(descriptor_type="orb", time_budget_s=0.0), short, "unbounded")
    model, fit = _fit_time_model(unbounded)
    print(f"time model: {model}  R^2 {fit:.3f}", flush=True)
    modelled = np.array([_modelled(model, s) for s in unbounded.statistics])
    rows = [_memory_row("unbounded", unbounded, short, float("nan"))]
    for target in TARGET_SHARES:
        budget = _first_budget(modelled, target)
        for attempt in range(2):  # one prediction from the unbounded run, then one correction if far off
            run = run_detector(BowBayes.Config(descriptor_type="orb", time_budget_s=budget, time_model="linear",
                                               **model), short, f"budget {budget * 1000:.2f} ms")
            got = _share_transferring(run)
            print(f"target {target:.0%}: budget {budget * 1000:.3f} ms -> {got:.1%} of frames transfer", flush=True)
            if abs(got - target) <= 0.05 or attempt == 1:
                break
            budget = _corrected(modelled, budget, got, target)
        rows.append(_memory_row(f"{budget * 1000:.2f} ms (modelled)", run, short, budget))
    body = "\n\n".join([
        _setting(stream),
        "## Time model",
        f"Fitted by non-negative least squares to the unbounded run's measured time per frame: base {model['model_base_s']:.3g} s "
        f"+ {model['model_comparison_s']:.3g} s per feature-word comparison + {model['model_place_s']:.3g} s per WM "
        f"place (R^2 = {fit:.3f}). The modelled runs compare the budget with these seconds, so they are "
        "deterministic; the budgets were set so that about 10 %, 30 % and 60 % of the frames trigger transfers.",
        f"## Recall and AUC against the budget: the first {SHORT:,} frames (2 laps), deterministic",
        f"The unbounded search grows with the vocabulary (about 54 words a frame), so an unbounded run over all "
        f"10,000 frames would take hours on this machine; budgets that leave 70-90 % of a stream unbounded cost "
        f"almost as much. The budget sweep therefore runs on the first {SHORT:,} frames (the second lap revisits "
        "the first). Time columns: the last 1,000 frames. Load average at the end "
        f"{_load(os.getloadavg())}.",
        table(MEMORY_HEADERS, rows),
        "## Nearest-word search, 150 queries (exact): ours vs numpy brute force (pairwise + sort)",
        table(["metric", "words", "ours ms", "baseline ms", "speed-up"], _search_scaling()),
    ])
    publish("bow_memory", "bow_bayes: RTAB-Map memory management, recall against the budget", body)


def _setting(stream: Stream) -> str:
    return (
        f"Synthetic street, world seed {LONG.seed}, {len(stream.descriptors)} frames (10 laps of "
        "1,000, day/dusk alternating, 160x120), ORB (150 features), greedy vocabulary with the derived thresholds, "
        "T_sim 0.2, STM 10, RTAB-Map forgetting (until as many words left the search as arrived, and whenever the "
        "time model predicts the next frame over the budget until it does not), recent places protected (0.2 of "
        "WM), weight handoff, retrieval of 2 neighbours. Merged frames searched, place scoring. Times are the detector's own; "
        "rendering and ORB are excluded (features cached)."
    )


def wall() -> None:
    """All 10,000 frames on the wall clock: the detector's own measured time decides."""
    stream = synthetic_stream(LONG)
    load_before = os.getloadavg()
    wall_rows, verdicts, walls = [], [], {}
    for forget_places in (False, True):
        label = "wall clock" + (", forget_places" if forget_places else "")
        load_wall = os.getloadavg()
        wall = run_detector(BowBayes.Config(descriptor_type="orb", time_budget_s=WALL_BUDGET_S, time_model="wall",
                                            forget_places=forget_places), stream, f"{label} {WALL_BUDGET_S * 1000:.0f} ms")
        walls[forget_places] = wall
        wall_rows.append(_memory_row(f"{WALL_BUDGET_S * 1000:.0f} ms ({label})", wall, stream, WALL_BUDGET_S))
        verdicts.append(
            _time_line(label, wall, WALL_BUDGET_S, "processing_seconds", "the detector's time")
            + f" Load average (1/5/15 min) before this run {_load(load_wall)}, after it {_load(os.getloadavg())}.")
    figure = _memory_plot(walls[False], walls[True], WALL_BUDGET_S)
    verdict = "\n".join([*verdicts, f"- Load average before the benchmark {_load(load_before)} (2 cores shared "
                                     "with other work)."])
    body = "\n\n".join([
        _setting(stream),
        f"## Per-image time under a wall-clock budget over all {len(stream.descriptors):,} frames",
        "The detector fits its time model to its own measured times of the frames before the first one over "
        f"budget (at least {BowBayes.Config().calibration_frames}) and scales its predictions by the median "
        "measured/predicted ratio of recent frames (the machine's load).",
        table(MEMORY_HEADERS, wall_rows),
        verdict,
        f"![time and memory]({figure})",
    ])
    publish("bow_memory_wall", "bow_bayes: per-image time under a wall-clock budget over 10,000 frames", body)


def flat() -> None:
    """The per-image time under a modelled budget over all 10,000 frames: deterministic, whatever the load."""
    stream = synthetic_stream(LONG)
    rows, verdicts = [], []
    for forget_places in (False, True):
        config = BowBayes.Config(descriptor_type="orb", time_budget_s=FLAT_BUDGET_S, time_model="linear",
                                 forget_places=forget_places)
        label = "modelled" + (", forget_places" if forget_places else "")
        run = run_detector(config, stream, f"{label} {FLAT_BUDGET_S * 1000:.0f} ms")
        rows.append(_memory_row(f"{FLAT_BUDGET_S * 1000:.0f} ms ({label})", run, stream, FLAT_BUDGET_S))
        verdicts.append(_time_line(label, run, FLAT_BUDGET_S, "modelled_seconds", "the modelled time"))
    c = BowBayes.Config()
    body = "\n\n".join([
        "The stream of "
        f"``memory`` (world seed {LONG.seed}, {len(stream.descriptors)} frames, ORB), the detector's default linear "
        f"time model ({c.model_base_s:g} s + {c.model_comparison_s:g} s per feature-word comparison + "
        f"{c.model_place_s:g} s per WM place) against a {FLAT_BUDGET_S * 1000:.0f} ms budget: the transfers, and so "
        "every number but the measured times, are the same on any machine under any load. Load average at the end "
        f"{_load(os.getloadavg())}.",
        table(MEMORY_HEADERS, rows),
        "\n".join(verdicts),
    ])
    publish("bow_memory_flat", "bow_bayes: per-image time under a modelled budget over 10,000 frames", body)


def _time_line(label: str, run: Run, budget: float, field: str, what: str) -> str:
    """One line: the share of frames transferring, and the median / p99 of ``field`` over the last frames."""
    ms = np.array([getattr(s, field) for s in run.statistics[-LAST:]]) * 1000
    median, p99, limit = float(np.median(ms)), float(np.percentile(ms, 99)), budget * 1000
    return (f"- {label}, budget {limit:.0f} ms: {_share_transferring(run):.1%} of the {len(run.statistics)} frames "
            f"trigger transfers; over the last {LAST} frames {what} per image has median {median:.2f} ms "
            f"({median / limit:.2f} x the budget) and p99 {p99:.2f} ms ({p99 / limit:.2f} x).")


def _prefix(stream: Stream, frames: int) -> Stream:
    """The stream's first ``frames`` frames, with the ground truth of the queries among them."""
    truth = stream.truth.subset(stream.truth.queries < frames)
    return Stream(stream.spec, stream.descriptors[:frames], stream.metric, truth, 0.0)


def _modelled(model: dict[str, float], s: object) -> float:
    return (model["model_base_s"] + model["model_comparison_s"] * s.n_features * s.searched_words  # type: ignore[attr-defined]
            + model["model_place_s"] * s.searched_places)  # type: ignore[attr-defined]


def _fit_time_model(run: Run) -> tuple[dict[str, float], float]:
    """The detector's own fit (non-negative least squares) of the measured seconds, as config fields."""
    stats = [s for s in run.statistics if s.n_features > 0]
    model, fit = LinearTimeModel.fit(*(np.array([getattr(s, f) for s in stats]) for f in (
        "n_features", "searched_words", "searched_places", "processing_seconds")))
    return {"model_base_s": model.base_s, "model_comparison_s": model.comparison_s, "model_place_s": model.place_s}, fit


def _share_transferring(run: Run) -> float:
    return float(np.mean([s.transferred > 0 for s in run.statistics]))


def _first_budget(modelled: np.ndarray, target: float) -> float:
    """A first guess: the budget the unbounded run first exceeds at the frame leaving ``target`` of the stream after it.

    Past that frame nearly every frame that brings new words triggers a transfer.
    """
    index = int(len(modelled) * (1.0 - target))
    return float(np.max(modelled[: max(index, 1)]))


def _corrected(modelled: np.ndarray, budget: float, got: float, target: float) -> float:
    """Move the crossing frame by the share missed (the unbounded time grows about linearly)."""
    running = np.maximum.accumulate(modelled)
    crossing = int(np.searchsorted(running, budget))
    shift = int((got - target) * len(modelled))
    return float(running[int(np.clip(crossing + shift, 1, len(modelled) - 1))])


def _memory_row(label: str, run: Run, stream: Stream, budget: float) -> list[object]:
    metrics = score(run, stream.truth)
    stats = run.statistics
    last = stats[-LAST:]
    ms = np.array([s.processing_seconds for s in last]) * 1000
    modelled = np.array([s.modelled_seconds for s in last]) * 1000
    return [label, f"{_share_transferring(run):.1%}", metrics["recall_at_100p"], metrics["auc_pr"],
            sum(s.transferred for s in stats), max(s.wm_size for s in stats), stats[-1].active_words,
            float(np.median(ms)), float(np.percentile(ms, 99)),
            float(np.median(modelled)) if np.isfinite(modelled).all() else "",
            float(np.percentile(modelled, 99)) if np.isfinite(modelled).all() else ""]


def _memory_plot(wall: Run, settled: Run, budget: float) -> str:
    def series(run: Run, field: str, scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
        return np.arange(len(run.statistics)), np.array([getattr(s, field) for s in run.statistics]) * scale

    path = RESULTS / "bow_memory_wall.png"
    plots.series_panels(
        [
            ("ms per image", {"wall-clock budget": series(wall, "processing_seconds", 1000.0),
                              "wall-clock budget, forget_places": series(settled, "processing_seconds", 1000.0)},
             {"budget": budget * 1000.0}),
            ("places in WM", {"wall-clock budget": series(wall, "wm_size"),
                              "wall-clock budget, forget_places": series(settled, "wm_size")}, {}),
        ],
        path, "bow_bayes on 10,000 frames: time per image and working memory (Wang et al. 2017, fig. 9)",
    )
    return path.name


def _load(load: tuple[float, float, float]) -> str:
    return "/".join(f"{v:.1f}" for v in load)


def _search_scaling() -> list[list[object]]:
    rng = np.random.default_rng(0)
    rows = []
    for metric, width, dtype in (("hamming", 32, np.uint8), ("l2", 128, np.float32)):
        for n_words in (1_000, 10_000, 100_000):
            if dtype == np.uint8:
                words = rng.integers(0, 256, (n_words, width), dtype=np.uint8)
                queries = rng.integers(0, 256, (150, width), dtype=np.uint8)
            else:
                words = rng.random((n_words, width), dtype=np.float32) * 100
                queries = rng.random((150, width), dtype=np.float32) * 100
            ours = best_of(3, lambda q=queries, w=words, m=metric: nearest_two(q, w, m))
            baseline = best_of(1, lambda q=queries, w=words, m=metric: np.sort(pairwise(q, w, m), axis=1)[:, :2])
            rows.append([metric, n_words, ours * 1000, baseline * 1000, baseline / ours])
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("what", nargs="?", choices=("seeds", "memory", "wall", "flat", "all"), default="all")
    args = parser.parse_args()
    if args.what in ("seeds", "all"):
        seeds()
    if args.what in ("memory", "all"):
        memory()
    if args.what in ("wall", "all"):
        wall()
    if args.what in ("flat", "all"):
        flat()


if __name__ == "__main__":
    main()
