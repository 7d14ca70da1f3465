"""The per-descriptor match distance thresholds (``DEFAULT_MAX_DISTANCE``), derived on real images.

Barbosa 2017 (§4.1.2) sets the distance threshold of two-image matching per descriptor,
empirically. This script is how ours are set, and regenerates them:

1. Real sequences: ``images/loop10`` (10 views of one desk) and the colour frames of the
   three RGB-D samples (Redwood, slambook room, ICL-NUIM living room), 1,000 features
   per frame (the localize recipes' setting; BRIEF and FREAK on SIFT keypoints).
2. *Correct matches*: every ordered pair of frames of one sequence at most 3 apart,
   matched with no distance threshold but with Lowe's ratio test (0.8) and a
   fundamental-matrix RANSAC (3 px): the distances of the surviving matches.
3. Threshold = the 95th percentile of the pooled correct-match distances (Hamming
   distances rounded up to a whole bit, L2 to two significant digits): the threshold
   keeps 95 % of verified matches on real images.
4. Beside it, for information only: the share of correct matches the previous (synthetic)
   thresholds kept; the same share for matches verified by RANSAC alone (no ratio test:
   the paper's matching without a threshold, which keeps 10-30 chance inliers per image
   pair, so its distances are not all correct ones); and the distances from each feature of a sequence to its nearest
   neighbour in the *other* sequences (unrelated scenes): their 5th and 10th percentiles
   show where chance matches begin.

Run: .venv/bin/python benchmarks/bench_descriptor_thresholds.py
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import publish, table  # noqa: E402

from slamfront.data import data_root  # noqa: E402
from slamfront.descriptor_eval import DescriptorChoice, evaluate_descriptor, extract_all  # noqa: E402
from slamfront.imageio import list_images, read_image  # noqa: E402
from slamfront.matching import DEFAULT_MAX_DISTANCE, Matcher, MatchingConfig  # noqa: E402

SEQUENCES = ("images/loop10", "rgbd/redwood_sample/color", "rgbd/room_sample/color", "rgbd/icl_livingroom_sample/color")
DESCRIPTORS = ("orb", "brief", "brisk", "freak", "akaze", "sift", "rootsift", "kaze")
PERCENTILE = 95.0
NEIGHBOURS = 3
MAX_FEATURES = 1000

# the thresholds set on the synthetic world before this procedure, for the comparison column
SYNTHETIC = {"orb": 50.0, "brief": 36.0, "brisk": 100.0, "freak": 75.0, "akaze": 90.0, "sift": 230.0,
             "rootsift": 0.37, "kaze": 0.38}


def rounded(value: float, metric: str) -> float:
    """Hamming: up to a whole bit; L2: two significant digits, up."""
    if metric == "hamming":
        return float(math.ceil(value))
    digits = 1 - int(math.floor(math.log10(abs(value))))
    return math.ceil(value * 10**digits) / 10**digits


def main() -> None:
    root = data_root()
    frames = {name: [(p.name, read_image(p, "gray")) for p in list_images(root / name)] for name in SEQUENCES}
    rows = []
    derived = {}
    for descriptor in DESCRIPTORS:
        choice = DescriptorChoice.parse(descriptor)
        features = {name: extract_all(images, [choice], MAX_FEATURES)[1][choice.label] for name, images in frames.items()}
        metric = next(iter(features.values()))[0].metric
        correct, ransac_only = [], []
        unthresholded = Matcher(MatchingConfig(), metric, np.inf)
        for sequence in features.values():
            result = evaluate_descriptor(choice.label, descriptor, sequence, list(range(len(sequence))), NEIGHBOURS,
                                         5, MatchingConfig(max_distance=1e9), 0.0)
            correct.append(result.verified_distances)
            for i, a in enumerate(sequence):
                for j, b in enumerate(sequence):
                    if 0 < abs(i - j) <= NEIGHBOURS:
                        ransac_only.append(unthresholded.match(a.keypoints, a.descriptors, b.keypoints,
                                                               b.descriptors).distances)
        verified, loose = np.concatenate(correct), np.concatenate(ransac_only)
        unrelated = []
        for name, sequence in features.items():
            others = [f for other, fs in features.items() if other != name for f in fs]
            pool = np.concatenate([f.descriptors for f in others])
            for f in sequence:
                unrelated.append(unthresholded.putative(f.descriptors, pool)[1])
        far = np.concatenate(unrelated)
        threshold = rounded(float(np.percentile(verified, PERCENTILE)), metric)
        derived[descriptor] = threshold
        rows.append([
            choice.label, metric, len(verified), SYNTHETIC[descriptor], f"{np.mean(verified <= SYNTHETIC[descriptor]):.0%}",
            threshold, f"{np.mean(verified <= threshold):.0%}", f"{np.mean(loose <= SYNTHETIC[descriptor]):.0%}",
            f"{np.mean(loose <= threshold):.0%}", float(np.percentile(far, 5)),
            float(np.percentile(far, 10)), f"{np.mean(far <= threshold):.0%}",
            "yes" if DEFAULT_MAX_DISTANCE.get(descriptor) == threshold else "no",
        ])
        print(rows[-1], flush=True)
    body = "\n\n".join([
        f"Sequences: {', '.join(f'`{s}`' for s in SEQUENCES)}; {MAX_FEATURES} features per frame; correct matches "
        f"= ratio test 0.8 + fundamental-matrix RANSAC between frames at most {NEIGHBOURS} apart; threshold = "
        f"{PERCENTILE:g}th percentile of their distances. *Unrelated NN*: distance from each feature to its nearest "
        "neighbour among the features of the other sequences.",
        table(["descriptor", "metric", "correct matches", "synthetic threshold", "kept by it", "derived threshold",
               "kept by it", "RANSAC-only kept by synthetic", "RANSAC-only kept by derived", "unrelated NN p5", "unrelated NN p10", "unrelated NN under it",
               "in DEFAULT_MAX_DISTANCE"], rows),
        "Derived (copy into `slamfront.matching.DEFAULT_MAX_DISTANCE`): "
        + ", ".join(f"`{k}`: {v:g}" for k, v in derived.items()),
    ])
    publish("descriptor_thresholds", "Match distance thresholds per descriptor, derived on real images", body)


if __name__ == "__main__":
    main()
