"""Straight lines through a table of query-to-map descriptor distances, each distance
computed once: the array work of sequence matching along lines (SeqSLAM's trajectories,
Milford & Wyeth 2012) when only the pairs the lines touch are computed, as the frame-level
hierarchical detector does.

:class:`PairDistances` keeps the distances of recent query positions against map-frame
positions; :meth:`PairDistances.line_costs` scores every line through one anchor (shifts x
speeds) in one step. Given where the descriptors are (:class:`DescriptorRows`) and an L1
metric on float32 or uint8 descriptors, that step is one compiled call
(:mod:`slamfront.core.line_kernels`) that computes the missing distances on the way; otherwise,
and as the reference the compiled call is tested against, it is
:func:`line_costs_reference`, NumPy. Both give the same bits and count the same distances.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class DescriptorRows:
    """Where the descriptors of the positions are: query position ``t`` is
    ``vectors[query_rows[t]]``, map-frame position ``m`` is ``vectors[map_rows[m]]``."""

    vectors: np.ndarray
    query_rows: np.ndarray
    map_rows: np.ndarray
    metric: str

    @property
    def compiled(self) -> bool:
        """Whether the compiled kernel computes these distances (``rowwise``'s L1 of float32
        or uint8 descriptors; other metrics go through the ``compute`` callable)."""
        return self.metric == "l1" and self.vectors.dtype in (np.float32, np.uint8) and self.vectors.ndim == 2


class PairDistances:
    """Distances between query positions and map-frame positions, each computed once.

    A table of ``keep`` rows, query position ``t`` in row ``t % keep``, one column per
    map-frame position (grown as the map grows), NaN where not computed yet: a lookup of
    any number of pairs is one fancy-indexing step, whatever the positions.

    :param compute: ``(t, m) -> (n,)`` distances between the query positions ``t[i]``
        and the map-frame positions ``m[i]`` (arrays of the same length); called once per
        :meth:`get` with every pair not computed before, so its overhead is paid once.
    :param keep: query positions older than the newest minus ``keep`` are forgotten.
    :param descriptors: where the descriptors are, now (called at each
        :meth:`line_costs`; None, or a callable returning None: always through ``compute``).
        The distances must be the ones ``compute`` gives (``rowwise`` of those rows).
    """

    def __init__(self, compute: Callable[[np.ndarray, np.ndarray], np.ndarray], keep: int,
                 descriptors: Callable[[], DescriptorRows | None] | None = None) -> None:
        self._compute = compute
        self._descriptors = descriptors
        self._keep = keep
        self._table = np.full((keep, 0), np.nan, dtype=np.float32)
        self._owner = np.full(keep, -1, dtype=np.int64)  # the query position each row holds
        self._state = np.array([-1, 0], dtype=np.int64)  # newest query position seen, distances computed

    @property
    def computed(self) -> int:
        """Distances computed so far (each pair once)."""
        return int(self._state[1])

    def get(self, t: np.ndarray, m: np.ndarray) -> np.ndarray:
        """(n,) float64 distances for the pairs ``(t[i], m[i])``; m must be >= 0."""
        t = np.asarray(t, dtype=np.int64)
        m = np.asarray(m, dtype=np.int64)
        if not len(t):
            return np.empty(0, dtype=np.float64)
        positions = np.unique(t)
        if positions[-1] - positions[0] >= self._keep:  # one lookup spans more than the table
            self._resize(int(positions[-1] - positions[0]) + 1)
        self._widen(int(m.max()) + 1)
        rows = positions % self._keep
        # a row is reused when it holds another position, or one older than the newest minus keep
        stale = (self._owner[rows] != positions) | (positions <= self._state[0] - self._keep)
        self._table[rows[stale]] = np.nan
        self._owner[rows[stale]] = positions[stale]
        self._state[0] = max(int(self._state[0]), int(positions[-1]))
        slot = t % self._keep
        values = self._table[slot, m]
        missing = np.isnan(values)
        if missing.any():
            columns = self._table.shape[1]
            keys = np.unique(t[missing] * columns + m[missing])  # each pair once
            pair_t, pair_m = keys // columns, keys % columns
            self._table[pair_t % self._keep, pair_m] = np.asarray(self._compute(pair_t, pair_m), dtype=np.float32)
            self._state[1] += len(keys)
            values = self._table[slot, m]
        return values.astype(np.float64)

    def line_costs(
        self, rows: np.ndarray, anchor_query: int, anchor_map: int, shifts: np.ndarray, velocities: np.ndarray,
        n_map: int, map_informative: np.ndarray | None, need: int,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Mean distance of every line through one anchor (:func:`line_costs_reference`):
        compiled when the descriptors allow it, the same bits and distance count either way."""
        found = self._descriptors() if self._descriptors is not None else None
        if found is None or not found.compiled:
            return line_costs_reference(self, rows, anchor_query, anchor_map, shifts, velocities, n_map,
                                        map_informative, need)
        informative = np.ones(n_map, dtype=bool) if map_informative is None else map_informative
        rows = np.ascontiguousarray(rows, dtype=np.int64)
        shifts = np.ascontiguousarray(shifts, dtype=np.int64)
        velocities = np.ascontiguousarray(velocities, dtype=np.float64)
        costs = np.empty((len(shifts), len(velocities)), dtype=np.float64)
        counts = np.empty((len(shifts), len(velocities)), dtype=np.int64)
        self._widen(n_map)
        while True:
            needed = _kernels().line_costs(
                self._table, self._owner, self._state, rows, int(anchor_query), int(anchor_map), shifts, velocities,
                int(n_map), informative, int(need), found.vectors, found.query_rows, found.map_rows, costs, counts,
            )
            if not needed:
                return costs, counts
            self._resize(int(needed))

    def best_lines(
        self, rows: np.ndarray, anchor_queries: np.ndarray, anchor_maps: np.ndarray, shifts: np.ndarray,
        velocities: np.ndarray, n_map: int, map_informative: np.ndarray | None, need: int,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Each anchor's lowest line (:meth:`line_costs`, reduced as ``costs.argmin()``), for
        many anchors in one call: level 2 screens a dozen anchors per iteration, and one
        Python round per anchor cost more than the lines themselves.

        :returns: ``(best, cost, count)``, (A,) each: the flat index ``s * V + v`` of the
            anchor's lowest line (the first NaN if any, as NumPy's argmin; -1 when no line
            has a finite cost), its cost and its pair count. The same bits, the same
            distances computed, in the same order, as :meth:`line_costs` anchor by anchor.
        """
        rows = np.ascontiguousarray(rows, dtype=np.int64)
        shifts = np.ascontiguousarray(shifts, dtype=np.int64)
        velocities = np.ascontiguousarray(velocities, dtype=np.float64)
        n = len(anchor_queries)
        best = np.full(n, -1, dtype=np.int64)
        cost = np.full(n, np.inf)
        count = np.zeros(n, dtype=np.int64)
        found = self._descriptors() if self._descriptors is not None else None
        if found is None or not found.compiled:
            for a in range(n):
                costs, counts = self.line_costs(rows, int(anchor_queries[a]), int(anchor_maps[a]), shifts, velocities,
                                                n_map, map_informative, need)
                lowest = int(costs.argmin())
                if math.isfinite(costs.flat[lowest]) or np.isfinite(costs).any():
                    best[a], cost[a], count[a] = lowest, costs.flat[lowest], counts.flat[lowest]
            return best, cost, count
        informative = np.ones(n_map, dtype=bool) if map_informative is None else map_informative
        queries = np.ascontiguousarray(anchor_queries, dtype=np.int64)
        maps = np.ascontiguousarray(anchor_maps, dtype=np.int64)
        self._widen(n_map)
        first = 0
        while True:
            stopped, needed = _kernels().best_lines(
                self._table, self._owner, self._state, rows, queries, maps, first, shifts, velocities, int(n_map),
                informative, int(need), found.vectors, found.query_rows, found.map_rows, best, cost, count,
            )
            if stopped < 0:
                return best, cost, count
            self._resize(int(needed))
            first = int(stopped)

    def _widen(self, width: int) -> None:
        """Columns for map-frame positions ``0..width-1`` (at least doubling)."""
        if width > self._table.shape[1]:
            grown = np.full((self._keep, max(width, 2 * self._table.shape[1])), np.nan, dtype=np.float32)
            grown[:, : self._table.shape[1]] = self._table
            self._table = grown

    def _resize(self, keep: int) -> None:
        """Room for ``keep`` positions, keeping the rows still valid."""
        table = np.full((keep, self._table.shape[1]), np.nan, dtype=np.float32)
        owner = np.full(keep, -1, dtype=np.int64)
        for row, position in enumerate(self._owner.tolist()):
            if position >= 0 and position > self._state[0] - self._keep:
                table[position % keep] = self._table[row]
                owner[position % keep] = position
        self._table, self._owner, self._keep = table, owner, keep


def line_costs_reference(
    distances: PairDistances,
    rows: np.ndarray,
    anchor_query: int,
    anchor_map: int,
    shifts: np.ndarray,
    velocities: np.ndarray,
    n_map: int,
    map_informative: np.ndarray | None,
    need: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Mean distance of every line through one anchor, in one lookup (NumPy).

    The line of shift ``s`` and speed ``v`` pairs query position ``rows[r]`` with map-frame
    position ``anchor_map + shifts[s] + round((rows[r] - anchor_query) * velocities[v])``
    (halves up); pairs outside ``0..n_map-1`` or on a map frame ``map_informative`` marks
    False are left out.

    :returns: (S, V) costs, the mean of the line's pair distances, inf where it has fewer
        than ``need`` pairs; (S, V) the number of pairs of each line.
    """
    steps = np.floor((rows[None, :] - anchor_query) * velocities[:, None] + 0.5).astype(np.int64)  # (V, R)
    positions = anchor_map + shifts[:, None, None] + steps[None, :, :]  # (S, V, R)
    inside = (positions >= 0) & (positions < n_map)
    if map_informative is not None:
        inside[inside] = map_informative[positions[inside]]
    counts = inside.sum(axis=2)
    enough = counts >= need
    costs = np.full(counts.shape, np.inf)
    if enough.any():
        values = np.zeros(positions.shape, dtype=np.float64)
        pairs = inside & enough[:, :, None]
        values[pairs] = distances.get(np.broadcast_to(rows, positions.shape)[pairs], positions[pairs])
        costs[enough] = values.sum(axis=2)[enough] / counts[enough]
    return costs, counts


@functools.cache
def _kernels() -> Any:
    """:mod:`slamfront.core.line_kernels`, imported on first use (numba costs ~0.3 s to import)."""
    import slamfront.core.line_kernels as kernels

    return kernels
