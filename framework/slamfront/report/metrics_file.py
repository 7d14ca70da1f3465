"""Writing ``metrics.json``: strict JSON, atomically (a module of its own, light to import)."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np


def write_json_atomically(
    path: Path, data: dict[str, Any], announce: Callable[[Path, int, str], None] | None = None
) -> Path:
    """Write to a temporary file and rename, so a crash never leaves half a metrics file
    (``announce``: see :func:`slamfront.outputs.write_atomically`)."""
    from slamfront.outputs import write_atomically

    text = json.dumps(_finite(data), indent=2, default=_json_default, allow_nan=False) + "\n"
    return write_atomically(path, text, announce)


def _finite(value: Any) -> Any:
    """NaN and infinities become null: metrics.json must be strict JSON for other tools."""
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    if isinstance(value, (float, np.floating)) and not np.isfinite(value):
        return None
    return value


def _json_default(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"cannot write {type(value).__name__} to metrics.json")
