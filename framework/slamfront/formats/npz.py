"""A message as a NumPy ``.npz`` file: data only, read without pickle.

Runs log their messages to MCAP; a message that is worth keeping on its own (a keyframe
map a later run localizes against) is also written as an ``.npz`` archive, one array per
field, so any NumPy program can read it. Strings are stored as unicode arrays and
fields that are None are left out; reading uses ``allow_pickle=False``, so a file that
came from elsewhere can only ever give arrays and strings back. Arrays round-trip bit
for bit.
"""

from __future__ import annotations

import dataclasses
import io
import typing
import zipfile
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from slamfront.errors import DataError
from slamfront.messages import Message, strip_optional
from slamfront.outputs import write_atomically

M = TypeVar("M", bound=Message)

SCHEMA_KEY = "__schema__"
"""The archive member naming the message type (its schema name)."""


def write_message_npz(path: Path, message: Message) -> Path:
    """Write ``message`` to ``path`` (through a temporary file, so a crash leaves no half archive)."""
    arrays: dict[str, np.ndarray] = {SCHEMA_KEY: np.array(message.schema_name)}
    for f in dataclasses.fields(message):
        value = getattr(message, f.name)
        if value is None:
            continue
        if isinstance(value, (list, tuple)):
            arrays[f.name] = np.array([str(v) for v in value], dtype=np.str_).reshape(-1)
        else:
            arrays[f.name] = np.asarray(value)
    path = Path(path)
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    return write_atomically(path, buffer.getvalue())


def read_message_npz(path: Path, cls: type[M]) -> M:
    """The ``cls`` message stored in ``path`` by :func:`write_message_npz`.

    :raises DataError: missing or unreadable file, another message type, a field of the
        wrong kind (naming the file and the field).
    """
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as archive:
            stored = {name: archive[name] for name in archive.files}
    except FileNotFoundError:
        raise DataError(f"{path}: no such file") from None
    except (OSError, ValueError, zipfile.BadZipFile) as exc:
        raise DataError(f"{path}: not a readable .npz archive ({exc})") from None
    schema = stored.pop(SCHEMA_KEY, None)
    if schema is None or str(schema) != cls.schema_name:
        found = "no message type" if schema is None else f"a {schema} message"
        raise DataError(f"{path}: holds {found}, expected {cls.schema_name}")
    hints = typing.get_type_hints(cls)
    values: dict[str, Any] = {}
    for f in dataclasses.fields(cls):
        if f.name not in stored:
            continue
        try:
            values[f.name] = _field(stored[f.name], hints[f.name])
        except (TypeError, ValueError) as exc:
            raise DataError(f"{path}: {f.name}: {exc}") from None
    try:
        return cls(**values)
    except TypeError as exc:
        raise DataError(f"{path}: {exc}") from None


def _field(array: np.ndarray, hint: Any) -> Any:
    """One stored array back as the field's type."""
    kind = strip_optional(hint)
    if kind is np.ndarray:
        return array
    if typing.get_origin(kind) in (list, tuple):
        if array.dtype.kind != "U":
            raise TypeError(f"expected strings, got {array.dtype}")
        return [str(v) for v in array.reshape(-1)]
    if array.shape != ():
        raise ValueError(f"expected one value, got shape {array.shape}")
    if kind is str:
        if array.dtype.kind != "U":
            raise TypeError(f"expected a string, got {array.dtype}")
        return str(array)
    if kind in (int, float, bool):
        return kind(array)
    raise TypeError(f"cannot read a field of type {hint}")
