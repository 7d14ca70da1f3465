"""Re-timed traversals: the same route driven at another pace, or backwards.

A traversal of ``n`` frames, frame ``k`` at position ``k`` along the route (in frames),
is driven again with a speed profile: the re-timed pass's frame ``j`` is at position
``p_j``, ``p_{j+1} = p_j + s_j`` for speeds ``s_j`` in frames per frame (0: stopped), or
``p_j = n - 1 - j`` backwards. Sources use it to re-time a query traversal (the ground
truth follows the positions, so it stays exact) and benchmarks to test sequence
detectors that must not assume the reference's pace.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from slamfront.core.errors import CoreError

Timing = Literal["original", "reversed", "half", "double", "varying", "stop_and_go"]
"""original: as recorded; reversed: backwards at the same pace; half / double: 0.5x / 2x
the recorded speed; varying: speed swinging smoothly between 0.6x and 1.8x (period 250
frames); stop_and_go: the recorded speed, with stops of 10-40 frames every 40-120 frames
(seeded)."""

VARYING_PERIOD = 250
"""Frames per speed cycle of ``varying``: long enough that the speed barely changes over
one query sequence (40 frames), short enough that a 600-frame stretch sees two cycles."""


def retimed_positions(n: int, timing: Timing, seed: int = 0) -> np.ndarray:
    """(m,) float64 route positions (in recorded frames, ``0 <= p <= n - 1``) of a re-timed pass.

    :param n: frames of the recorded traversal.
    :param timing: the speed profile (:data:`Timing`).
    :param seed: draws the stops of ``stop_and_go``.
    :raises CoreError: fewer than 2 frames, or an unknown profile.
    """
    if n < 2:
        raise CoreError(f"a traversal of {n} frames cannot be re-timed")
    if timing == "original":
        return np.arange(n, dtype=np.float64)
    if timing == "reversed":
        return np.arange(n - 1, -1, -1, dtype=np.float64)
    if timing == "half":
        return np.arange(0.0, n - 1 + 1e-9, 0.5)
    if timing == "double":
        return np.arange(0.0, n - 1 + 1e-9, 2.0)
    if timing == "varying":
        speeds = 1.2 + 0.6 * np.sin(2 * np.pi * np.arange(4 * n) / VARYING_PERIOD)
    elif timing == "stop_and_go":
        rng = np.random.default_rng(seed)
        pieces = []
        while sum(len(p) for p in pieces) < 4 * n:
            pieces.append(np.ones(int(rng.integers(40, 121))))
            pieces.append(np.zeros(int(rng.integers(10, 41))))
        speeds = np.concatenate(pieces)
    else:
        raise CoreError(f"unknown timing {timing!r}")
    positions = np.concatenate([[0.0], np.cumsum(speeds)])
    return positions[positions <= n - 1]


def retimed_frames(n: int, timing: Timing, seed: int = 0) -> np.ndarray:
    """(m,) int64 recorded frames shown by a re-timed pass: each position's nearest recorded
    frame at or before it (a stop repeats a frame; a fast pass skips frames)."""
    return np.floor(retimed_positions(n, timing, seed) + 1e-9).astype(np.int64)


# -- SMART: matching at equal distance travelled --------------------------------------------


def travelled_m(positions: np.ndarray) -> np.ndarray:
    """(n,) distance travelled up to each frame along ``positions``: (n,) route positions in
    metres (either direction) or (n, d) points, e.g. the camera's centres from its poses."""
    points = np.asarray(positions, dtype=np.float64)
    steps = np.abs(np.diff(points)) if points.ndim == 1 else np.linalg.norm(np.diff(points, axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(steps)])


def equal_distance(positions: np.ndarray, spacing_m: float) -> np.ndarray:
    """(k,) indices of the frames kept when a pass is resampled to one frame per ``spacing_m``
    metres travelled (SMART, Pepperell et al. 2014): the first frame, then the first frame
    at or past each further multiple of ``spacing_m`` of :func:`travelled_m`. A stop keeps
    one frame; a stretch faster than one frame per ``spacing_m`` keeps every frame."""
    if spacing_m <= 0:
        raise CoreError(f"spacing_m must be positive, got {spacing_m}")
    if len(positions) == 0:
        return np.zeros(0, dtype=np.int64)
    marks = np.floor(travelled_m(positions) / spacing_m + 1e-9)
    return np.flatnonzero(np.concatenate([[True], marks[1:] > marks[:-1]]))


class DistanceSampler:
    """:func:`equal_distance` one frame at a time, for a source that streams (a bag): it
    never holds more than the last position."""

    def __init__(self, spacing_m: float) -> None:
        if spacing_m <= 0:
            raise CoreError(f"spacing_m must be positive, got {spacing_m}")
        self.spacing_m = spacing_m
        self._last: np.ndarray | None = None
        self._travelled = 0.0
        self._mark = 0.0

    def keep(self, position: np.ndarray) -> bool:
        """Whether the frame at ``position`` (route metres or a point) is kept."""
        point = np.atleast_1d(np.asarray(position, dtype=np.float64))
        if self._last is None:
            self._last = point
            return True
        self._travelled += float(np.linalg.norm(point - self._last))
        self._last = point
        mark = float(np.floor(self._travelled / self.spacing_m + 1e-9))
        if mark > self._mark:
            self._mark = mark
            return True
        return False
