"""bow_bayes over a long stream: per-image time, vocabulary and working memory, greedy vs NNDR.

One run: the synthetic world driven 10 laps (10,000 frames, 160x120), ORB features
extracted once, then fed to two ``bow_bayes`` detectors, one per vocabulary rule, with
a time budget so memory management works. Reported after 1k, 5k and 10k frames:
vocabulary size (kept / searched), working-memory size, per-image time (median, p99)
and the share of images over budget; then recall at 100 % precision on the whole
stream, and the nearest-word search time against the vocabulary size (the cost the
memory management keeps bounded) with a brute-force numpy baseline.

Run: .venv/bin/python benchmarks/bench_bow_bayes.py  [--frames N]  (about 20 minutes)
"""

from __future__ import annotations

import argparse
import platform
import sys
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import best_of, publish, table  # noqa: E402

from slamfront.core.distances import nearest_two, pairwise  # noqa: E402
from slamfront.core.loops import precision_recall  # noqa: E402
from slamfront.frame import Frame  # noqa: E402
from slamfront.local_features import LocalFeatureExtractor  # noqa: E402
from slamfront.messages import BowStatistics, Features, LoopResult  # noqa: E402
from slamfront.plugin import StageInputs  # noqa: E402
from slamfront_plugins.loop_detectors.bow_bayes import BowBayes  # noqa: E402
from slamfront_plugins.sources.synthetic import SyntheticWorld  # noqa: E402

BUDGET_S = 0.05
CHECKPOINTS = (1_000, 5_000, 10_000)


def render_features(n_frames: int) -> tuple[list[np.ndarray], SyntheticWorld, float]:
    laps = max(1, n_frames // 1000)
    source = SyntheticWorld(SyntheticWorld.Config(
        seed=3, mode="stream", laps=laps, frames_per_traversal=n_frames // laps, route_length_m=n_frames // laps,
        image_width=160, image_height=120,
    ))
    extractor = LocalFeatureExtractor("orb", max_features=150)
    started = time.perf_counter()
    features = [extractor.extract(f.gray()).descriptors for f in tqdm(source.frames(), total=len(source),
                                                                         desc="render + ORB", unit="frame")]
    return features, source, time.perf_counter() - started


def run_detector(rule: str, features: list[np.ndarray]) -> tuple[list[BowStatistics], list[LoopResult]]:
    detector = BowBayes(BowBayes.Config(vocabulary_update=rule, descriptor_type="orb", time_budget_s=BUDGET_S))
    blank = np.zeros((1, 1), np.uint8)
    stats, results = [], []
    for index, descriptors in enumerate(tqdm(features, desc=f"bow_bayes {rule}", unit="frame")):
        frame = Frame(index=index, timestamp=float(index), image=blank)
        message = Features(frame=index, descriptors=descriptors, metric="hamming")
        for out in detector.process(StageInputs(frame=frame, outputs={"descriptor": [message]})):
            (stats if isinstance(out, BowStatistics) else results).append(out)
    return stats, results


def checkpoint_rows(rule: str, stats: list[BowStatistics]) -> list[list[object]]:
    ms = np.array([s.processing_seconds for s in stats]) * 1000
    rows = []
    for at in CHECKPOINTS:
        if at > len(stats):
            break
        window = ms[max(0, at - 1000) : at]
        s = stats[at - 1]
        rows.append([rule, at, s.vocabulary_size, s.active_words, s.wm_size, s.ltm_size,
                     float(np.median(window)), float(np.percentile(window, 99)),
                     float(np.mean(window > BUDGET_S * 1000))])
    return rows


def recall(results: list[LoopResult], source: SyntheticWorld) -> tuple[float, float]:
    truth = source.loop_ground_truth()
    frames = truth.queries
    by_frame = {r.frame: r for r in results}
    match = np.array([by_frame[int(f)].match for f in frames])
    confidence = np.array([by_frame[int(f)].confidence for f in frames])
    curve = precision_recall(confidence, match >= 0, truth.is_correct(frames, match), int(truth.has_true_match().sum()))
    return curve.recall_at_100p, curve.auc


def search_scaling() -> list[list[object]]:
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
    parser.add_argument("--frames", type=int, default=10_000)
    args = parser.parse_args()
    features, source, render_s = render_features(args.frames)
    n_features = np.mean([len(f) for f in features])
    rows, recalls = [], []
    for rule in ("greedy", "nndr"):
        started = time.perf_counter()
        stats, results = run_detector(rule, features)
        seconds = time.perf_counter() - started
        rows += checkpoint_rows(rule, stats)
        r100, auc = recall(results, source)
        bound_hits = int(sum(s.transferred for s in stats))
        recalls.append([rule, r100, auc, sum(r.accepted for r in results), bound_hits,
                        max(s.wm_size for s in stats), len(features) / seconds])
    body = "\n\n".join([
        f"Machine: {platform.machine()}, Python {platform.python_version()}, numpy {np.__version__}. "
        f"Synthetic world seed 3, {len(features)} frames (10 laps, day/dusk alternating, 160x120), "
        f"ORB, {n_features:.0f} features per frame on average; rendering + ORB took {render_s:.0f} s. "
        f"Time budget T_time = {BUDGET_S * 1000:.0f} ms per image; STM 10 places. "
        "Time is the detector's own (vocabulary, similarity, Bayes filter, memory).",
        "## After 1k / 5k / 10k frames (time over the preceding 1,000 frames)",
        table(["rule", "frames", "vocabulary (kept)", "words searched", "WM places", "LTM places",
               "median ms", "p99 ms", "share over budget"], rows),
        "## Whole stream",
        table(["rule", "recall at 100 % precision", "AUC-PR", "loops accepted", "places transferred",
               "max WM", "frames/s (detector only)"], recalls),
        "## Nearest-word search, 150 queries (exact): ours vs numpy brute force (pairwise + sort)",
        table(["metric", "words", "ours ms", "baseline ms", "speed-up"], search_scaling()),
    ])
    publish("bow_bayes", "bow_bayes: long-stream time, vocabulary and memory", body)


if __name__ == "__main__":
    main()
