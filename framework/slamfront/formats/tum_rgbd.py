"""TUM RGB-D sequence files: ``rgb.txt`` / ``depth.txt`` lists and timestamp association.

Association follows the TUM benchmark's ``associate.py``: every pair of stamps closer
than ``max_difference`` is a candidate; candidates are taken greedily, closest first,
each stamp used at most once; the result is sorted by the first stamp.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from slamfront.errors import DataError
from slamfront.formats.poses import numbered_fields


def read_file_list(path: Path) -> tuple[np.ndarray, list[str], list[int]]:
    """Stamps, the rest of each line (e.g. a file name) and line numbers of a TUM list."""
    stamps, names, numbers = [], [], []
    for number, fields in numbered_fields(path):
        if len(fields) < 2:
            raise DataError(f"{path}:{number}: expected 'timestamp filename', got {' '.join(fields)!r}")
        try:
            stamps.append(float(fields[0]))
        except ValueError:
            raise DataError(f"{path}:{number}: timestamp {fields[0]!r} is not a number") from None
        names.append(" ".join(fields[1:]))
        numbers.append(number)
    if not stamps:
        raise DataError(f"{path}: the list is empty")
    return np.array(stamps), names, numbers


def associate(first: np.ndarray, second: np.ndarray, max_difference: float = 0.02, offset: float = 0.0) -> np.ndarray:
    """(K, 2) index pairs (i, j) with ``|first[i] - (second[j] + offset)| < max_difference``.

    Greedy and one-to-one, closest pairs first, sorted by ``i``.
    """
    first = np.asarray(first, dtype=np.float64)
    second = np.asarray(second, dtype=np.float64) + offset
    order = np.argsort(second)
    sorted_second = second[order]
    candidates = []
    for i, stamp in enumerate(first):
        lo = np.searchsorted(sorted_second, stamp - max_difference, side="left")
        hi = np.searchsorted(sorted_second, stamp + max_difference, side="right")
        for k in range(lo, hi):
            difference = abs(stamp - sorted_second[k])
            if difference < max_difference:
                candidates.append((difference, i, int(order[k])))
    candidates.sort()
    used_first, used_second, pairs = set(), set(), []
    for _, i, j in candidates:
        if i not in used_first and j not in used_second:
            used_first.add(i)
            used_second.add(j)
            pairs.append((i, j))
    pairs.sort()
    return np.array(pairs, dtype=np.int64).reshape(-1, 2)
