"""A row store that grows by doubling, for maps built one frame at a time."""

from __future__ import annotations

import numpy as np


class GrowingRows:
    """Append-only (N, D) array with amortised O(1) appends; :attr:`view` is the filled part."""

    def __init__(self, width: int, dtype: np.dtype | type = np.float32, capacity: int = 256) -> None:
        self._data = np.empty((capacity, width), dtype=dtype)
        self._size = 0

    def append(self, row: np.ndarray) -> int:
        """Store one row; returns its position."""
        if self._size == len(self._data):
            grown = np.empty((2 * len(self._data), self._data.shape[1]), dtype=self._data.dtype)
            grown[: self._size] = self._data[: self._size]
            self._data = grown
        self._data[self._size] = row
        self._size += 1
        return self._size - 1

    def __len__(self) -> int:
        return self._size

    @property
    def view(self) -> np.ndarray:
        """The stored rows (a view: do not keep it across appends)."""
        return self._data[: self._size]
