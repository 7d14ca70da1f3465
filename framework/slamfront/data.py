"""Where data lives: the data root and recipe paths relative to it.

The data root is ``$SLAMFRONT_DATA`` when set, else ``shared/data`` beside the source
checkout. A relative path in a plugin config typed :data:`DataPath` is resolved against
it, so recipes stay portable between machines; a path found only in the download cache
(``slamfront datasets download``) resolves there.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated

from pydantic import AfterValidator, ValidationInfo

DATA_ENV = "SLAMFRONT_DATA"


def checkout_root() -> Path:
    """The source checkout this package runs from (``framework/slamfront`` is two levels down)."""
    return Path(__file__).resolve().parents[2]


def data_root() -> Path:
    """``$SLAMFRONT_DATA``, else ``shared/data`` beside the source checkout."""
    env = os.environ.get(DATA_ENV)
    if env:
        return Path(env).expanduser().resolve()
    return (checkout_root().parent / "shared" / "data").resolve()


def cache_root() -> Path:
    """Where downloaded datasets go: ``$SLAMFRONT_CACHE``, else ``~/.cache/slamfront``."""
    env = os.environ.get("SLAMFRONT_CACHE")
    return Path(env).expanduser() if env else Path.home() / ".cache" / "slamfront"


def _resolve_data_path(value: Path, info: ValidationInfo) -> Path:
    value = Path(value).expanduser()
    if value.is_absolute():
        return value
    root = (info.context or {}).get("data_root") if info.context else None
    resolved = (Path(root) if root is not None else data_root()) / value
    if not resolved.exists() and (cache_root() / value).exists():
        return cache_root() / value  # a downloaded dataset
    return resolved


DataPath = Annotated[Path, AfterValidator(_resolve_data_path)]
"""A path in a plugin config: absolute as given, relative ones under the data root (or, when
only there, in the download cache)."""
