"""Localization latency vs number of keyframes: brute force (Barbosa 2017) vs pre-selection.

A synthetic street is driven once with one keyframe per metre (every rendered frame
becomes a keyframe, ORB, 500 features, 320x240); query frames from a second drive
(0.3 m aside, turned 2°) at random places of the map are localized against the first
N keyframes, N = 10 ... 10,000, by comparing with every keyframe (the paper's brute
force) and with the 10 keyframes whose thumbnails are most similar (pre-selection).
Both use the same matcher (brute force, distance threshold, RANSAC).

Run: .venv/bin/python benchmarks/bench_localization_scaling.py [--max-keyframes 10000]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import peak_rss_mb, publish, table  # noqa: E402

from slamfront.core.thumbnail import thumbnail  # noqa: E402
from slamfront.local_features import LocalFeatureExtractor  # noqa: E402
from slamfront.matching import DEFAULT_MAX_DISTANCE, Matcher, MatchingConfig  # noqa: E402
from slamfront_plugins.localizers.keyframe_map import TopologicalMap, View  # noqa: E402
from slamfront_plugins.sources.synthetic import SyntheticWorld  # noqa: E402

SIZES = (10, 100, 1000, 10000)
CANDIDATES = 10


def view_of(frame, extractor: LocalFeatureExtractor) -> View:  # type: ignore[no-untyped-def]
    grey = frame.gray()
    features = extractor.extract(grey)
    return View(frame.index, features.keypoints, features.descriptors, thumbnail(grey, 32, 24, 8),
                frame.camera.matrix)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--max-keyframes", type=int, default=SIZES[-1])
    parser.add_argument("--queries", type=int, default=8, help="queries per map size")
    args = parser.parse_args()
    sizes = [n for n in SIZES if n <= args.max_keyframes]
    n_max = sizes[-1]
    source = SyntheticWorld(SyntheticWorld.Config(
        mode="paired", frames_per_traversal=n_max, route_length_m=float(max(n_max, 100)), image_width=320,
        image_height=240, query_illumination="day",
    ))
    extractor = LocalFeatureExtractor("orb", max_features=500)
    matcher = Matcher(MatchingConfig(), "hamming", DEFAULT_MAX_DISTANCE["orb"])
    start = time.perf_counter()
    nodes = []
    for k in tqdm(range(n_max), desc="keyframes", unit="frame"):
        frame = source.frame_at(0, k, index=k)
        nodes.append((view_of(frame, extractor), frame.pose))
    build_s = time.perf_counter() - start

    rng = np.random.default_rng(0)
    rows = []
    for n in sizes:
        brute, preselect = TopologicalMap(matcher), TopologicalMap(matcher, candidates=CANDIDATES)
        for view, pose in nodes[:n]:
            brute.add(view, pose, None)
            preselect.add(view, pose, None)
        places = rng.choice(n, size=min(args.queries, n), replace=False)
        times = {"brute": [], "pre": []}
        agree, errors = 0, {"brute": [], "pre": []}
        for k in places:
            query = source.frame_at(1, int(k), index=n_max + int(k))
            view = view_of(query, extractor)
            chosen = {}
            for label, keyframes in (("brute", brute), ("pre", preselect)):
                tick = time.perf_counter()
                node, _ = keyframes.rank(view).best
                times[label].append(1000.0 * (time.perf_counter() - tick))
                chosen[label] = node
                errors[label].append(float(np.linalg.norm(keyframes.keyframes[node].pose[:3, 3] - query.pose[:3, 3])))
            agree += chosen["brute"] == chosen["pre"]
        brute_ms, pre_ms = float(np.median(times["brute"])), float(np.median(times["pre"]))
        rows.append([
            n, len(places), brute_ms, pre_ms, brute_ms / pre_ms, f"{agree}/{len(places)}",
            float(np.median(errors["brute"])), float(np.median(errors["pre"])),
        ])
        print(rows[-1], flush=True)
    body = "\n\n".join([
        f"{cv2.getNumThreads()} OpenCV threads; shared with other jobs, so compare the columns of one row.",
        f"Map: {n_max} keyframes, one per metre of a synthetic street (320x240, ORB 500), built in "
        f"{build_s:.0f} s (rendering included); peak memory {peak_rss_mb():.0f} MB. Queries: a second drive "
        f"at random places of the first N metres. Pre-selection: thumbnail (32x24, patch-normalised) cosine, "
        f"then the {CANDIDATES} best compared in full. Times: median per query frame.",
        table(["keyframes", "queries", "brute force ms", "pre-selection ms", "speed-up",
               "same keyframe", "error brute [m]", "error pre [m]"], rows),
    ])
    publish("localization_scaling", "Keyframe localization: latency vs map size", body)


if __name__ == "__main__":
    main()
