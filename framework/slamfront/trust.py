"""A log is data, never code: what a recipe from elsewhere may not do without consent.

A recipe the user wrote (a file given on the command line) is trusted: it may import
plugin modules and read files anywhere. A recipe embedded in a log (``replay``,
``inspect``) came from whoever wrote the log, so it is data. Replaying it never
imports a module it names and never reads a path outside the data root, unless the
user passes ``--trust-log``. The fields that would are found here, by what their
values are, so the check needs no plugin (and imports none):

- ``plugin_modules``: any entry would be imported;
- any string in a stage's or the source's ``params`` that has a ``..`` component, or is
  an absolute path (``~`` included) outside the data root: relative paths resolve under
  the data root (or under a dataset folder that itself does), so only these can leave it.
"""

from __future__ import annotations

import re
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

from slamfront.data import data_root
from slamfront.errors import RecipeError
from slamfront.plugin import KINDS
from slamfront.text import shorten

TRUST_FLAG = "--trust-log"
_PARENT = re.compile(r"(^|[\\/])\.\.([\\/]|$)")
_ABSOLUTE = re.compile(r"^(/|~|\\\\|[A-Za-z]:[\\/])")


def _leaves_data_root(value: str, root: Path) -> bool:
    if _PARENT.search(value):
        return True
    if not _ABSOLUTE.match(value):
        return False
    try:
        return not Path(value).expanduser().resolve().is_relative_to(root)
    except (OSError, RuntimeError, ValueError):  # an unresolvable path (a loop of links, a NUL): refuse it
        return True


def _strings(value: Any, path: str) -> Iterator[tuple[str, str]]:
    if isinstance(value, str):
        yield path, value
    elif isinstance(value, Mapping):
        for key, item in value.items():
            yield from _strings(item, f"{path}.{key}")
    elif isinstance(value, list):
        for position, item in enumerate(value):
            yield from _strings(item, f"{path}.{position}")


def untrusted_fields(recipe: Mapping[str, Any]) -> list[tuple[str, str]]:
    """``(field, why)`` for every field of a foreign recipe that would reach code, or
    the file system outside the data root."""
    found = []
    root = data_root().resolve()
    modules = recipe.get("plugin_modules") or []
    if modules:
        found.append(("plugin_modules", f"would import {', '.join(map(str, modules))}"))
    for kind in KINDS:
        spec = recipe.get(kind)
        if not isinstance(spec, Mapping):
            continue
        for field, value in _strings(spec.get("params", {}), f"{kind}.params"):
            if _leaves_data_root(value, root):
                found.append((field, f"names a path outside the data root ({value})"))
    return found


def refuse_untrusted(recipe: Mapping[str, Any], origin: str) -> None:
    """Raise on the first field of a foreign recipe that needs the user's consent.

    :param origin: where the recipe came from (``LOG:recipe.yaml``), for the message.
    :raises RecipeError: naming the field, what it would do and the flag that allows it.
    """
    for field, why in untrusted_fields(recipe):
        raise RecipeError(
            f"{origin}: {field}: {shorten(why, 160)}; a log's recipe is data, so this is refused "
            f"(pass {TRUST_FLAG} if you trust whoever wrote the log)"
        )
