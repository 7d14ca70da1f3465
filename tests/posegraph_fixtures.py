"""Small synthetic pose graphs for tests: a planar figure-eight-free loop driven twice."""

from __future__ import annotations

import numpy as np

from slamfront.core import geometry
from slamfront.core.graph_files import format_g2o
from slamfront.core.posegraph import PoseGraph, make_graph


def ring_truth(n: int = 60, radius: float = 10.0) -> np.ndarray:
    """(2n, 3, 3) true poses: a circle driven twice (the second lap 0.2 m outside)."""
    angles = np.tile(np.linspace(0, 2 * np.pi, n, endpoint=False), 2)
    radii = np.r_[np.full(n, radius), np.full(n, radius + 0.2)]
    return geometry.se2(radii * np.cos(angles), radii * np.sin(angles), angles + np.pi / 2)


def ring_graph(n: int = 60, seed: int = 0, noise: tuple[float, float] = (0.05, 0.01), name: str = "ring") -> PoseGraph:
    """Noisy odometry along :func:`ring_truth` and a loop closure from every lap-2 pose to
    its lap-1 twin, with information matching the noise."""
    rng = np.random.default_rng(seed)
    truth = ring_truth(n)
    total = len(truth)
    sources = np.r_[np.arange(total - 1), np.arange(n)]
    targets = np.r_[np.arange(1, total), np.arange(n) + n]
    exact = geometry.relative(truth[sources], truth[targets])
    noisy = exact @ geometry.se2(*(rng.normal(size=(3, len(sources))) * np.array([[noise[0]], [noise[0]], [noise[1]]])))
    information = np.repeat(np.diag([noise[0] ** -2, noise[0] ** -2, noise[1] ** -2])[None], len(sources), axis=0)
    return make_graph(2, np.arange(total), None, sources, targets, noisy, information, name=name)


def ring_g2o(n: int = 60, seed: int = 0) -> str:
    """:func:`ring_graph` as g2o text (edges only)."""
    return format_g2o(ring_graph(n, seed))
