"""The files slamfront ships besides code: recipes, sweep files and Foxglove layouts.

They are package data (the sub-packages ``slamfront.resources.recipes``, ``.sweeps`` and
``.foxglove``, packaged from the repository's top-level folders of those names) and are
read with :mod:`importlib.resources`, so an installed wheel finds them as a source
checkout does. A user's own file (a path, or a name in the current directory) always
wins over a shipped one: see :func:`slamfront.recipe.find_named_file`.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path
from typing import Literal

from slamfront.errors import SlamfrontError

Kind = Literal["recipes", "sweeps", "foxglove"]
SUFFIX: dict[Kind, str] = {"recipes": ".yaml", "sweeps": ".yaml", "foxglove": ".json"}
"""The files of each kind that are shipped (the packaging in setup.py ships the same)."""

LAYOUT = "slamfront-layout.json"
"""The Foxglove layout for ``run.mcap`` (camera image, 3-D map, loop closures, timings)."""


def shipped_dir(kind: Kind) -> Path:
    """The installed folder holding the shipped files of ``kind``.

    :raises SlamfrontError: the installation lacks them (a broken or partial install).
    """
    try:
        folder = resources.files(f"slamfront.resources.{kind}")
    except ModuleNotFoundError as exc:
        raise SlamfrontError(f"this slamfront installation has no shipped {kind} ({exc}); reinstall it") from exc
    # A wheel or an editable install unpacks to real files; a zipped install would not.
    if not isinstance(folder, Path):
        raise SlamfrontError(f"shipped {kind} are not plain files ({folder}); install slamfront unzipped")
    return folder


def shipped_files(kind: Kind) -> list[Path]:
    """The shipped files of ``kind``, sorted by name."""
    return sorted(shipped_dir(kind).glob(f"*{SUFFIX[kind]}"))


def layout_path() -> Path:
    """The shipped Foxglove layout file."""
    return shipped_dir("foxglove") / LAYOUT
