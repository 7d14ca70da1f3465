"""Descriptor distance distributions, and the bow_bayes thresholds T_ND1 / T_ND2 derived from them.

Wang et al. 2017's T_ND1 = 0.001 and T_ND2 = 0.08 are SURF-64 values, and OpenCV's wheels have
no SURF; this script measures, for every descriptor type slamfront has, the two
distributions the thresholds separate and prints the derived values (copied into
``plugins/slamfront_plugins/loop_detectors/bow_thresholds.py``):

1. Calibration images: the RGB-D samples of the data root (Redwood, a room, ICL-NUIM,
   NYU, SUN); none is used by a reported bow_bayes run (loop10, Nordland, synthetic).
2. Each image is warped by ``WARPS`` random homographies (rotation +-20 deg, scale
   0.8-1.25, mild perspective) with a gain/offset change and sensor noise. A feature's
   *match distance* is its descriptor distance to the warped-image feature detected
   within 2.5 px of its true position (one-to-one, nearest in position).
3. Its *non-match distance* is the distance to its nearest descriptor among the
   features of all the *other* calibration scenes (a pool of several thousand): what
   ND is for a thing the vocabulary has never seen.
4. T_ND1 = 1st percentile of the non-match distances; T_ND2 = the equal-error distance,
   where the share of matches above it equals the share of non-matches below it
   (see the thresholds module for why).

Run: .venv/bin/python benchmarks/bench_bow_thresholds.py
"""

from __future__ import annotations

import platform
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import publish, table  # noqa: E402

from slamfront.core.distances import nearest_two, pairwise  # noqa: E402
from slamfront.data import data_root  # noqa: E402
from slamfront.imageio import list_images, read_image  # noqa: E402
from slamfront.local_features import DESCRIPTORS, LocalFeatureExtractor, LocalFeatures  # noqa: E402

WARPS = 3
MAX_FEATURES = 500
MATCH_RADIUS_PX = 2.5
CALIBRATION = ("rgbd/redwood_sample/color", "rgbd/room_sample/color", "rgbd/icl_livingroom_sample/color")
SINGLE = ("rgbd/single_frames/NYU_color.ppm", "rgbd/single_frames/SUN_color.jpg")


def calibration_images() -> list[tuple[str, np.ndarray]]:
    root = data_root()
    paths = [p for folder in CALIBRATION for p in list_images(root / folder)] + [root / p for p in SINGLE]
    return [(p.parent.parent.name if p.parent.name == "color" else p.stem, read_image(p, mode="gray")) for p in paths]


def random_warp(image: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A warped, re-lit, noisy copy of ``image`` and the homography taking it there."""
    h, w = image.shape
    angle = rng.uniform(-20, 20)
    scale = rng.uniform(0.8, 1.25)
    affine = np.vstack([cv2.getRotationMatrix2D((w / 2, h / 2), angle, scale), [0, 0, 1]])
    perspective = np.eye(3)
    perspective[2, :2] = rng.uniform(-1e-4, 1e-4, 2)
    centre = np.array([[1, 0, -w / 2], [0, 1, -h / 2], [0, 0, 1]])
    homography = np.linalg.inv(centre) @ perspective @ centre @ affine
    warped = cv2.warpPerspective(image, homography, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    gain, offset = rng.uniform(0.7, 1.3), rng.uniform(-20, 20)
    noisy = warped.astype(np.float32) * gain + offset + rng.normal(0, 3.0, warped.shape)
    return np.clip(noisy, 0, 255).astype(np.uint8), homography


def match_distances(original: LocalFeatures, warped: LocalFeatures, homography: np.ndarray, metric: str) -> np.ndarray:
    """Descriptor distance of each feature to the warped feature found at its true position."""
    if len(original) == 0 or len(warped) == 0:
        return np.zeros(0)
    projected = cv2.perspectiveTransform(original.keypoints[None].astype(np.float64), homography)[0]
    gap = np.linalg.norm(projected[:, None, :] - warped.keypoints[None, :, :], axis=2)
    nearest = np.argmin(gap, axis=1)
    close = gap[np.arange(len(original)), nearest] <= MATCH_RADIUS_PX
    # one-to-one: a warped feature claimed by two originals is ambiguous, skip both
    claimed = np.bincount(nearest[close], minlength=len(warped))
    keep = close & (claimed[nearest] == 1)
    rows = np.flatnonzero(keep)
    if len(rows) == 0:
        return np.zeros(0)
    d = pairwise(original.descriptors[rows], warped.descriptors[nearest[rows]], metric)  # type: ignore[arg-type]
    return np.diag(d).astype(np.float64)


def equal_error_distance(match: np.ndarray, non_match: np.ndarray) -> float:
    """The distance d where P(match distance > d) = P(non-match distance <= d)."""
    candidates = np.unique(np.concatenate([match, non_match]))
    above = 1.0 - np.searchsorted(np.sort(match), candidates, side="right") / len(match)
    below = np.searchsorted(np.sort(non_match), candidates, side="right") / len(non_match)
    return float(candidates[int(np.argmin(np.abs(above - below)))])


def measure(descriptor: str, images: list[tuple[str, np.ndarray]], seed: int = 0) -> dict[str, object]:
    spec = DESCRIPTORS[descriptor]
    extractor = LocalFeatureExtractor(descriptor, "fast" if spec.needs_detector else "native", MAX_FEATURES)  # type: ignore[arg-type]
    rng = np.random.default_rng(seed)
    features = [extractor.extract(image) for _, image in images]
    matches = []
    for (_, image), found in zip(images, features):
        for _ in range(WARPS):
            warped, homography = random_warp(image, rng)
            matches.append(match_distances(found, extractor.extract(warped), homography, spec.metric))
    match = np.concatenate(matches)
    non_match = []
    scenes = [scene for scene, _ in images]
    for k, found in enumerate(features):
        pool = [f.descriptors for j, f in enumerate(features) if scenes[j] != scenes[k] and len(f)]
        if len(found) and pool:
            d1, _, _ = nearest_two(found.descriptors, np.concatenate(pool), spec.metric)  # type: ignore[arg-type]
            non_match.append(d1)
    other = np.concatenate(non_match)
    low = float(np.percentile(other, 1))
    high = equal_error_distance(match, other)
    return {
        "descriptor": descriptor,
        "metric": spec.metric,
        "n_match": len(match),
        "n_non_match": len(other),
        "pool": int(np.mean([sum(len(f) for j, f in enumerate(features) if scenes[j] != scenes[k])
                             for k in range(len(features))])),
        "match_p50": float(np.median(match)),
        "match_p99": float(np.percentile(match, 99)),
        "equal_error": high,
        "equal_error_rate": float(np.mean(match > high)),
        "non_match_p1": low,
        "non_match_p50": float(np.median(other)),
        "overlap": float(np.mean(match > low)),
        "t_nd1": low,
        "t_nd2": high,
    }


def main() -> None:
    images = calibration_images()
    rows = [measure(name, images) for name in DESCRIPTORS]
    headers = ["descriptor", "metric", "match pairs", "non-match", "pool size", "match median", "match p99",
               "non-match p1 = T_ND1", "non-match median", "equal-error distance = T_ND2", "equal-error rate"]
    body = "\n\n".join([
        f"Machine: {platform.machine()}, Python {platform.python_version()}, OpenCV {cv2.__version__}. "
        f"{len(images)} calibration images (RGB-D samples: Redwood, room, ICL-NUIM, NYU, SUN), "
        f"{WARPS} random homographies each, at most {MAX_FEATURES} features per image; BRIEF and FREAK on FAST.",
        "Match: distance to the feature at the true warped position (within "
        f"{MATCH_RADIUS_PX} px, one-to-one). Non-match: distance to the nearest feature of the other scenes.",
        table(headers, [[r["descriptor"], r["metric"], r["n_match"], r["n_non_match"], r["pool"], r["match_p50"],
                         r["match_p99"], r["non_match_p1"], r["non_match_p50"], r["equal_error"],
                         r["equal_error_rate"]] for r in rows]),
        "As Python (plugins/slamfront_plugins/loop_detectors/bow_thresholds.py):",
        "```python\n" + "\n".join(f'"{r["descriptor"]}": ({r["t_nd1"]:.4g}, {r["t_nd2"]:.4g}),' for r in rows) + "\n```",
    ])
    publish("bow_thresholds", "Descriptor distances and bow_bayes thresholds", body)


if __name__ == "__main__":
    main()
