"""TUM RGB-D sequence files: ``rgb.txt`` / ``depth.txt`` lists and timestamp association.

Association follows the TUM benchmark's ``associate.py``: every pair of stamps closer
than ``max_difference`` is a candidate; candidates are taken greedily, closest first,
each stamp used at most once; the result is sorted by the first stamp. It lives in
:mod:`slamfront.core.trajectory` (the trajectory metrics use it too) and is re-exported here.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from slamfront.core.trajectory import associate
from slamfront.errors import DataError
from slamfront.formats.poses import numbered_fields

__all__ = ["associate", "read_file_list"]


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
