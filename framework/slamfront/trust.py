"""A log is data, never code: what a recipe from elsewhere may not do without consent.

A recipe the user wrote (a file given on the command line) is trusted: it may import
plugin modules and read files anywhere. A recipe embedded in a log (``replay``,
``inspect``) came from whoever wrote the log, so it is data. Replaying it never
imports a module it names and never reads a path outside the data root, unless the
user passes ``--trust-log``. The fields that would are found here, by what their
values are, so the check needs no plugin (and imports none):

- ``plugin_modules``: any entry would be imported;
- any string in a stage's or the source's ``params`` that is an absolute path, starts
  with ``~``, or has a ``..`` component: relative paths resolve under the data root (or
  under a dataset folder that itself does), so only these can leave it.
"""

from __future__ import annotations

import re
from collections.abc import Iterator, Mapping
from typing import Any

from slamfront.errors import RecipeError
from slamfront.plugin import KINDS
from slamfront.text import shorten

TRUST_FLAG = "--trust-log"
_ESCAPING = re.compile(r"^(/|~|\\\\|[A-Za-z]:[\\/])|(^|[\\/])\.\.([\\/]|$)")


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
    modules = recipe.get("plugin_modules") or []
    if modules:
        found.append(("plugin_modules", f"would import {', '.join(map(str, modules))}"))
    for kind in KINDS:
        spec = recipe.get(kind)
        if not isinstance(spec, Mapping):
            continue
        for field, value in _strings(spec.get("params", {}), f"{kind}.params"):
            if _ESCAPING.search(value):
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
