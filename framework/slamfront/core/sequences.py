"""Sequence alignment on distance matrices: slide a query sequence along a longer one, and
the speeds a speed-free line search tries (coarse to fine over a wide cone).

Used by sequence-based loop detectors (template matching of Rodrigues 2019, eq. 3.10). Pure
functions over arrays.
"""

from __future__ import annotations

import numpy as np

from slamfront.core.errors import CoreError


def alignment_costs(distances: np.ndarray) -> np.ndarray:
    """Cost of every placement of a query sequence inside a longer candidate sequence.

    :param distances: (n, m) float, ``distances[k, i]`` between query element k and
        candidate element i, with ``m >= n``.
    :returns: (m - n + 1,) float64, ``cost[j] = sum_k distances[k, j + k]``: the query
        laid over candidate elements ``j .. j + n - 1``.
    :raises CoreError: the candidate is shorter than the query, or either is empty.
    """
    distances = np.asarray(distances, dtype=np.float64)
    if distances.ndim != 2 or distances.shape[0] == 0:
        raise CoreError(f"need an (n, m) matrix with n >= 1, got shape {distances.shape}")
    n, m = distances.shape
    if m < n:
        raise CoreError(f"the candidate sequence ({m}) is shorter than the query ({n})")
    offsets = np.arange(m - n + 1)[:, None] + np.arange(n)[None, :]
    return distances[np.arange(n)[None, :], offsets].sum(axis=1)


def best_alignment(distances: np.ndarray) -> tuple[int, float]:
    """The offset with the lowest :func:`alignment_costs` (the first one on ties) and its cost."""
    costs = alignment_costs(distances)
    best = int(np.argmin(costs))
    return best, float(costs[best])


# --- speed-free line search: a wide cone of speeds, searched coarse to fine -----------------------


def cone_speeds(low: float, high: float, length: int, reverse: bool) -> np.ndarray:
    """(V,) signed speeds (map frames per query frame) spanning the cone ``low..high``, in
    steps of ``1 / length``: each step moves the far end of a ``length``-frame line by one
    frame, so no coarser line can be missed by more than a frame there. With ``reverse``,
    the same speeds negated too (a traversal driven the other way).

    :raises CoreError: not ``0 < low <= high``, or ``length < 1``.
    """
    if not 0 < low <= high:
        raise CoreError(f"need 0 < low <= high, got {low}, {high}")
    if length < 1:
        raise CoreError(f"need a length >= 1, got {length}")
    step = 1.0 / length
    forward = np.round(np.arange(low, high + step / 2, step), 9)
    return np.concatenate([forward, -forward[::-1]]) if reverse else forward


def refined_speeds(speed: float, coarse_length: int, fine_length: int, low: float, high: float) -> np.ndarray:
    """(V,) speeds around ``speed`` found over ``coarse_length`` frames, tried again over
    ``fine_length`` (> coarse_length) frames: every speed within one coarse step
    (``1 / coarse_length``) in fine steps (``1 / fine_length``), kept inside the cone
    ``low..high`` on ``speed``'s side (its sign: the direction is settled)."""
    sign = 1.0 if speed >= 0 else -1.0
    coarse, fine = 1.0 / max(coarse_length, 1), 1.0 / max(fine_length, 1)
    magnitudes = np.round(abs(speed) + np.arange(-coarse, coarse + fine / 2, fine), 9)
    magnitudes = magnitudes[(magnitudes >= low - 1e-9) & (magnitudes <= high + 1e-9)]
    if not len(magnitudes):
        magnitudes = np.asarray([min(max(abs(speed), low), high)])
    return sign * np.unique(magnitudes)


def coarse_to_fine_lengths(first: int, total: int) -> list[int]:
    """Frames compared at each stage of a coarse-to-fine line search: ``first``, doubled
    until ``total`` (the last stage compares all ``total``)."""
    lengths = [min(max(first, 1), total)]
    while lengths[-1] < total:
        lengths.append(min(2 * lengths[-1], total))
    return lengths
