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
"""The Foxglove layout for ``run.mcap`` of loop closure and the back end (a tab each)."""
LAYOUTS_BY_STAGE = {"localizer": "slamfront-localization.json", "registration": "slamfront-registration.json"}
"""The layout for runs with these stages; every other run opens with :data:`LAYOUT`."""


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


def layout_path(name: str = LAYOUT) -> Path:
    """A shipped Foxglove layout file, by file name or stem (default: :data:`LAYOUT`).

    :raises SlamfrontError: no shipped layout has that name (the message lists them).
    """
    file_name = name if name.endswith(SUFFIX["foxglove"]) else name + SUFFIX["foxglove"]
    path = shipped_dir("foxglove") / file_name
    known = [p.name for p in shipped_files("foxglove")]
    if file_name not in known and known:
        raise SlamfrontError(f"no shipped Foxglove layout named {name!r}; the layouts are {', '.join(known)}")
    return path


def layout_for(kinds: set[str]) -> str:
    """The file name of the layout whose panels show a run with the stages ``kinds``."""
    return next((LAYOUTS_BY_STAGE[kind] for kind in LAYOUTS_BY_STAGE if kind in kinds), LAYOUT)
