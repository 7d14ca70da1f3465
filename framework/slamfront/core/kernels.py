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
  (:func:`slamfront.core.compiled_kernels.pairwise_sum`: 8 running partial sums, combined as a fixed tree, halves of
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


CHUNKS_PER_THREAD = 4
"""Ranges per thread: a thread whose core is busy with other work takes fewer of them, so
one slow half no longer holds the whole call (on a shared 2-core machine it did)."""


def run_chunks(work: Callable[[int, int], None], n: int, threads: int) -> None:
    """Call ``work(start, stop)`` over ``[0, n)`` split into contiguous ranges (a multiple of
    4 rows long, as the kernels' row blocks), ``threads`` of them running at once when
    ``threads > 1`` (the kernels release the GIL). Each row's result must not depend on its
    range (every kernel here computes row by row)."""
    if threads <= 1 or n < 2:
        work(0, n)
        return
    pieces = min(threads * CHUNKS_PER_THREAD, max(1, n // 4))
    bounds = np.unique(np.append(np.linspace(0, n, pieces + 1).astype(int) // 4 * 4, n))  # ends at n
    with ThreadPoolExecutor(min(threads, len(bounds) - 1)) as pool:
        for future in [pool.submit(work, int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:])]:
            future.result()


@functools.cache
def compiled() -> Any:
    """The compiled kernels (the module :mod:`slamfront.core.compiled_kernels`), imported on
    the first call: importing numba costs ~0.3 s, which commands that compute no
    distances do not pay."""
    import slamfront.core.compiled_kernels as kernels

    return kernels
