"""Compiled loops for the all-pairs and sequence-search work (numba, imported on first use).

Two jobs in the framework are billions of tiny arithmetic steps that NumPy can only do
as millions of small calls or through huge temporaries: the L1 distance between every
pair of descriptors (retrieval evaluation, SeqSLAM's difference matrix, brute-force
search) and SeqSLAM's straight-trajectory search. Here they are plain loops compiled
by numba (``nogil``, so :func:`run_chunks` can split them over threads).

Every kernel reproduces the arithmetic of the NumPy code it replaces operation for
operation, so answers do not change by a bit:

- uint8 L1 sums are exact integers (order does not matter);
- float32 L1 sums follow NumPy's pairwise summation of a contiguous row
  (:func:`pairwise_sum`: 8 running partial sums, combined as a fixed tree, halves of
  blocks above 128 values), which is what ``np.abs(a - b).sum(-1)`` computes;
- a trajectory swept over every start row adds its ``ds + 1`` entries one after the
  other from 0 (as ``cost += column`` did); one gathered for a few start rows sums them
  with NumPy's pairwise order (as ``picked.sum(axis=2)`` did).

numba is imported only when a kernel is first called, so commands that never compute
distances do not pay for it; kernels are cached on disk after their first compilation.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np

PAIRWISE_BLOCK = 128
"""NumPy's ``PW_BLOCKSIZE``: rows up to this length are summed with 8 partial sums."""


def threads_for(work: float, minimum_work: float = 2e7) -> int:
    """How many threads a job of ``work`` elementary operations deserves: one below
    ``minimum_work`` (a thread hand-off costs ~50 us), else the usable CPUs (at most 8)."""
    if work < minimum_work:
        return 1
    usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return max(1, min(8, usable))


def run_chunks(work: Callable[[int, int], None], n: int, threads: int) -> None:
    """Call ``work(start, stop)`` over ``[0, n)`` split into ``threads`` contiguous ranges,
    in parallel when ``threads > 1`` (the kernels release the GIL)."""
    if threads <= 1 or n < 2:
        work(0, n)
        return
    bounds = np.linspace(0, n, min(threads, n) + 1).astype(int)
    with ThreadPoolExecutor(len(bounds) - 1) as pool:
        for future in [pool.submit(work, int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:])]:
            future.result()


@functools.cache
def compiled() -> Any:
    """The compiled kernels (a namespace), built on the first call."""
    import numba  # heavy (~0.3 s): only here

    jit = numba.njit(nogil=True, cache=True, error_model="numpy")

    @jit
    def pairwise_sum(values, start, n):  # type: ignore[no-untyped-def]
        # NumPy's pairwise summation (numpy/_core/src/umath/loops_utils.h.src), same order
        if n < 8:
            res = values.dtype.type(-0.0)
            for i in range(start, start + n):
                res += values[i]
            return res
        if n <= PAIRWISE_BLOCK:
            r0, r1, r2, r3 = values[start], values[start + 1], values[start + 2], values[start + 3]
            r4, r5, r6, r7 = values[start + 4], values[start + 5], values[start + 6], values[start + 7]
            i = 8
            while i < n - (n % 8):
                j = start + i
                r0 += values[j]
                r1 += values[j + 1]
                r2 += values[j + 2]
                r3 += values[j + 3]
                r4 += values[j + 4]
                r5 += values[j + 5]
                r6 += values[j + 6]
                r7 += values[j + 7]
                i += 8
            res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
            while i < n:
                res += values[start + i]
                i += 1
            return res
        half = n // 2
        half -= half % 8
        return pairwise_sum(values, start, half) + pairwise_sum(values, start + half, n - half)

    @jit
    def l1_uint8(a, b, out, lo, hi):  # type: ignore[no-untyped-def]
        # out[i, j] = sum |a[i] - b[j]| for rows lo..hi of a; exact in int32
        p = a.shape[1]
        for i in range(lo, hi):
            ai = a[i]
            for j in range(b.shape[0]):
                bj = b[j]
                acc = np.int32(0)
                for k in range(p):
                    x = np.int32(ai[k])
                    y = np.int32(bj[k])
                    acc += x - y if x > y else y - x
                out[i, j] = acc

    @jit
    def l1_float32(a, b, out, lo, hi):  # type: ignore[no-untyped-def]
        # float32 |a - b| summed in NumPy's pairwise order, bit for bit
        p = a.shape[1]
        buffer = np.empty(p, dtype=np.float32)
        for i in range(lo, hi):
            ai = a[i]
            for j in range(b.shape[0]):
                bj = b[j]
                for k in range(p):
                    buffer[k] = abs(ai[k] - bj[k])
                out[i, j] = np.float32(0.0) + pairwise_sum(buffer, 0, p)

    @jit
    def sweep(columns, offsets, queries, out, lo, hi):  # type: ignore[no-untyped-def]
        # columns: (C, R + reach + 1) float64 (rows past R are inf); query n = queries[i]
        # uses columns n .. n + W - 1; out[n, r] = min over trajectories of the sum
        # of their W entries added one after the other
        n_ref = out.shape[1]
        n_traj, width = offsets.shape
        cost = np.empty(n_ref, dtype=np.float64)
        for i in range(lo, hi):
            n = queries[i]
            best = out[n]
            best[:] = np.inf
            for v in range(n_traj):
                cost[:] = 0.0
                for k in range(width):
                    column = columns[n + k]
                    shift = offsets[v, k]
                    for r in range(n_ref):
                        cost[r] += column[r + shift]
                for r in range(n_ref):
                    if cost[r] < best[r]:
                        best[r] = cost[r]

    @jit
    def gather(columns, offsets, queries, rows, starts, out, lo, hi):  # type: ignore[no-untyped-def]
        # as sweep for query queries[i]'s start rows rows[starts[i]:starts[i + 1]] only
        # (others inf), each trajectory pairwise-summed as NumPy's ``picked.sum(axis=2)``
        n_traj, width = offsets.shape
        picked = np.empty(width, dtype=np.float64)
        for i in range(lo, hi):
            n = queries[i]
            out[n, :] = np.inf
            for index in range(starts[i], starts[i + 1]):
                row = rows[index]
                best = np.inf
                for v in range(n_traj):
                    for k in range(width):
                        picked[k] = columns[n + k, row + offsets[v, k]]
                    best = min(best, 0.0 + pairwise_sum(picked, 0, width))
                out[n, row] = best

    class Kernels:
        pass

    namespace = Kernels()
    for kernel in (pairwise_sum, l1_uint8, l1_float32, sweep, gather):
        setattr(namespace, kernel.__name__, kernel)
    return namespace
