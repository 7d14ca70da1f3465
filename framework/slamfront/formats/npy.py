""".npy files without unpickling code.

Letting ``np.load`` unpickle runs whatever a crafted file's pickle asks for.
Some datasets (VPR-Bench's ``ground_truth_new.npy``) are NumPy *object* arrays, which
``np.save`` can only store as a pickle. :func:`load_npy` reads plain arrays with
``allow_pickle=False`` and object arrays with an unpickler that can build NumPy arrays,
dtypes and scalars and nothing else (the "restricting globals" recipe of the
:mod:`pickle` documentation): a file naming any other callable is refused.
"""

from __future__ import annotations

import io
import pickle
from pathlib import Path
from typing import Any

import numpy as np
from numpy.lib import format as npy_format

from slamfront.errors import DataError

try:  # NumPy 2 moved the pickling helpers; files written by NumPy 1 name the old module
    from numpy._core.multiarray import _reconstruct, scalar
except ImportError:  # pragma: no cover (NumPy 1)
    from numpy.core.multiarray import _reconstruct, scalar  # type: ignore[no-redef]

_ALLOWED: dict[tuple[str, str], Any] = {
    (module, name): value
    for module in ("numpy.core.multiarray", "numpy._core.multiarray")
    for name, value in (("_reconstruct", _reconstruct), ("scalar", scalar))
}
_ALLOWED[("numpy", "ndarray")] = np.ndarray
_ALLOWED[("numpy", "dtype")] = np.dtype


_HEADER_READERS = {(1, 0): npy_format.read_array_header_1_0, (2, 0): npy_format.read_array_header_2_0}


class _ArraysOnly(pickle.Unpickler):
    def find_class(self, module: str, name: str) -> Any:
        try:
            return _ALLOWED[(module, name)]
        except KeyError:
            raise pickle.UnpicklingError(f"it asks to run {module}.{name}, which a data file never needs") from None


def load_npy(path: Path) -> np.ndarray:
    """The array in ``path``; object arrays are rebuilt without running code.

    :raises DataError: the file is missing, not a .npy file, or its pickle names anything
        but NumPy arrays, dtypes and scalars.
    """
    try:
        with open(path, "rb") as stream:
            version = npy_format.read_magic(stream)
            if version not in _HEADER_READERS:
                raise ValueError(f"unsupported .npy format version {version}")
            shape, _order, dtype = _HEADER_READERS[version](stream)
            if not dtype.hasobject:
                stream.seek(0)
                return np.load(stream, allow_pickle=False)
            payload = stream.read()
    except FileNotFoundError:
        raise DataError(f"{path}: no such file") from None
    except (OSError, ValueError) as exc:
        raise DataError(f"{path}: not a NumPy .npy file ({exc})") from None
    try:
        array = _ArraysOnly(io.BytesIO(payload)).load()
    except (pickle.UnpicklingError, EOFError, ValueError, TypeError, AttributeError, IndexError) as exc:
        raise DataError(f"{path}: refused: the object array's pickle is not plain data ({exc})") from None
    if not isinstance(array, np.ndarray) or array.shape != shape:
        raise DataError(f"{path}: the object array's pickle does not hold the {shape} array its header declares")
    return array
