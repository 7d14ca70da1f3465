"""How sure a localization answer is: evidence features and a logistic model over them.

A keyframe localizer always has a most similar keyframe; the question is whether it
shows the same place. Four numbers about the answer separate right from wrong (their
separation is measured in ``benchmarks/bench_localization_confidence.py``):

- ``log(1 + inliers)``: RANSAC inliers with the most similar keyframe;
- inlier ratio ``inliers / putative``: chance matches rarely agree on one geometry;
- coverage: share of a 4x4 grid over the query image holding an inlier (a shared
  object, a poster or a car, covers a corner; the same place covers the view);
- distinctiveness ``1 - competing / inliers``: the best keyframe of *another* place
  (more than two links from the best one) should match far worse.

The confidence is the logistic function of a weighted sum of them (Platt-style
calibration: fitted by :func:`fit_logistic` on labelled answers, it estimates the
probability that the answer is right on data like the calibration data).
"""

from __future__ import annotations

import numpy as np

from slamfront.core.errors import CoreError

EVIDENCE = ("log(1 + inliers)", "inlier ratio", "coverage", "distinctiveness")
"""Names of the evidence columns, in order."""

GRID = 4
"""Coverage is measured on a GRID x GRID grid over the image."""


def coverage(points: np.ndarray, width: int, height: int) -> float:
    """Share of a :data:`GRID` x :data:`GRID` grid over a ``width`` x ``height`` image holding one of (N, 2) ``points``."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    if len(points) == 0 or width <= 0 or height <= 0:
        return 0.0
    columns = np.clip((points[:, 0] * GRID / width).astype(np.int64), 0, GRID - 1)
    rows = np.clip((points[:, 1] * GRID / height).astype(np.int64), 0, GRID - 1)
    return len(np.unique(rows * GRID + columns)) / GRID**2


def evidence(inliers: np.ndarray, putative: np.ndarray, covered: np.ndarray, competing: np.ndarray) -> np.ndarray:
    """(N, 4) evidence columns (:data:`EVIDENCE`) of N answers.

    :param inliers: (N,) RANSAC inliers with the most similar keyframe.
    :param putative: (N,) matches before RANSAC.
    :param covered: (N,) coverage of the inliers (:func:`coverage`).
    :param competing: (N,) inliers of the most similar keyframe of another place.
    """
    inliers = np.asarray(inliers, dtype=np.float64)
    putative = np.asarray(putative, dtype=np.float64)
    competing = np.asarray(competing, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(putative > 0, inliers / np.maximum(putative, 1), 0.0)
        distinct = np.where(inliers > 0, 1.0 - np.minimum(competing, inliers) / np.maximum(inliers, 1), 0.0)
    return np.stack([np.log1p(inliers), ratio, np.asarray(covered, dtype=np.float64), distinct], axis=1)


def logistic(features: np.ndarray, weights: np.ndarray, bias: float) -> np.ndarray:
    """(N,) ``1 / (1 + exp(-(features @ weights + bias)))`` for (N, F) features and (F,) weights."""
    features = np.asarray(features, dtype=np.float64)
    weights = np.asarray(weights, dtype=np.float64)
    if features.ndim != 2 or features.shape[1] != len(weights):
        raise CoreError(f"need (N, {len(weights)}) features for {len(weights)} weights, got {features.shape}")
    z = features @ weights + bias
    return 0.5 * (1.0 + np.tanh(0.5 * z))  # the logistic function, without overflow for large |z|


def fit_logistic(features: np.ndarray, labels: np.ndarray, l2: float = 1e-3) -> tuple[np.ndarray, float]:
    """Weights and bias of a logistic regression (maximum likelihood, a small L2 penalty on the weights).

    :param features: (N, F) evidence.
    :param labels: (N,) bool, True where the answer was right.
    :raises CoreError: fewer than one example of each class.
    """
    x = np.asarray(features, dtype=np.float64)
    y = np.asarray(labels, dtype=bool).astype(np.float64)
    if x.ndim != 2 or len(x) != len(y):
        raise CoreError(f"need (N, F) features and (N,) labels, got {x.shape} and {y.shape}")
    if y.min(initial=1.0) == y.max(initial=0.0):
        raise CoreError("fitting a confidence needs right and wrong answers")

    def loss(theta: np.ndarray) -> tuple[float, np.ndarray]:
        z = x @ theta[:-1] + theta[-1]
        # log(1 + exp(z)) - y z, stably; its gradient is (sigmoid(z) - y) x
        value = np.sum(np.logaddexp(0.0, z) - y * z) / len(y) + l2 * np.sum(theta[:-1] ** 2)
        residual = 0.5 * (1.0 + np.tanh(0.5 * z)) - y
        gradient = np.r_[x.T @ residual / len(y) + 2.0 * l2 * theta[:-1], residual.mean()]
        return float(value), gradient

    from scipy.optimize import minimize  # ~0.5 s to import: only when a confidence is fitted

    result = minimize(loss, np.zeros(x.shape[1] + 1), jac=True, method="L-BFGS-B")
    return result.x[:-1], float(result.x[-1])
