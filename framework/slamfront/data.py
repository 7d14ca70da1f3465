"""Where data lives: one rule for the data root, and recipe paths relative to it.

The data root is, in this order:

1. ``$SLAMFRONT_DATA`` when set;
2. ``shared/data`` beside the source checkout this package runs from, when that folder
   exists (a development checkout; an installed wheel has no checkout);
3. the per-user data directory (``platformdirs``: ``~/.local/share/slamfront`` on Linux,
   ``~/Library/Application Support/slamfront`` on macOS, ``%LOCALAPPDATA%\\slamfront``
   on Windows).

Downloads (``slamfront datasets download`` and ``fetch``) go to :func:`download_root`:
``$SLAMFRONT_DATA`` when set, else the per-user data directory, never into a
``shared/data`` folder beside a checkout (provided data is read, not written). A
relative path in a plugin config typed :data:`DataPath` is resolved against the data
root, so recipes stay portable between machines; one found only among the downloads
resolves there (a dataset fetched with ``slamfront datasets download``).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

from slamfront.errors import DataError

if TYPE_CHECKING:
    from pydantic import ValidationInfo

DATA_ENV = "SLAMFRONT_DATA"

MIRROR_ENV = "SLAMFRONT_DATA_MIRROR"
"""A mirror base URL used instead of the pinned origins by ``datasets fetch`` (``--url`` overrides it)."""


def source_checkout() -> Path | None:
    """The source checkout this package runs from (an editable install), or None (a wheel).

    ``framework/slamfront/data.py`` is two folders below the checkout's root; an installed
    package sits in ``site-packages`` instead, whose parent is no checkout.
    """
    root = Path(__file__).resolve().parents[2]
    is_checkout = (root / "pyproject.toml").is_file() and (root / "framework" / "slamfront").is_dir()
    return root if is_checkout else None


def user_data_dir() -> Path:
    """The per-user data directory (the platform's convention, via ``platformdirs``)."""
    import platformdirs  # ~20 ms: only when asked, not for every command's parser

    return platformdirs.user_data_path("slamfront", appauthor=False)


def _checkout_data() -> Path | None:
    checkout = source_checkout()
    shared = checkout.parent / "shared" / "data" if checkout is not None else None
    return shared.resolve() if shared is not None and shared.is_dir() else None


def data_root() -> Path:
    """``$SLAMFRONT_DATA``, else ``shared/data`` beside a source checkout, else the per-user data dir."""
    env = os.environ.get(DATA_ENV)
    if env:
        return Path(env).expanduser().resolve()
    return _checkout_data() or user_data_dir()


def download_root() -> Path:
    """Where downloads go: ``$SLAMFRONT_DATA``, else the per-user data dir."""
    env = os.environ.get(DATA_ENV)
    return Path(env).expanduser().resolve() if env else user_data_dir()


def _resolve_data_path(value: Path, info: ValidationInfo) -> Path:
    value = Path(value).expanduser()
    if value.is_absolute():
        return value
    root = (info.context or {}).get("data_root") if info.context else None
    resolved = (Path(root) if root is not None else data_root()) / value
    if not resolved.exists() and (download_root() / value).exists():
        return download_root() / value  # a downloaded dataset
    return resolved


def __getattr__(name: str) -> Any:
    # ``DataPath``, built on first use: pydantic is imported only by the configs that use
    # it, so `slamfront datasets --help` (which reads this module's names) stays light.
    if name == "DataPath":
        from pydantic import AfterValidator

        return Annotated[Path, AfterValidator(_resolve_data_path)]
    raise AttributeError(f"module 'slamfront.data' has no attribute {name!r}")


if TYPE_CHECKING:
    from pydantic import AfterValidator

    DataPath = Annotated[Path, AfterValidator(_resolve_data_path)]
    """A path in a plugin config: absolute as given, relative ones under the data root (or, when
    only there, among the downloads)."""


def path_inside(folder: Path, relative: str, where: str) -> Path:
    """``folder / relative``, refused when it leads outside ``folder`` (an absolute path,
    ``..``, or a symbolic link pointing out): a path *read from a data file* (a list of
    frames, say) names files of that dataset, never anything else on the disk.

    :param where: the file and line that named the path, for the message.
    :raises DataError: naming ``where`` and the path.
    """
    path = folder / relative
    base = folder.resolve()
    if not path.resolve().is_relative_to(base):
        raise DataError(f"{where}: {relative!r} leads outside the dataset folder {folder}")
    return path
