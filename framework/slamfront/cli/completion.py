"""Shell completion with argcomplete: shipped recipe names, and the keys ``--set`` takes.

Enable it once per shell (bash; zsh after ``autoload -U bashcompinit && bashcompinit``)::

    eval "$(register-python-argcomplete slamfront)"

The completers run only when the shell asks (argcomplete sets ``_ARGCOMPLETE``), so
they cost nothing to an ordinary command. They never raise: a recipe that does not load
yet simply completes nothing.
"""

from __future__ import annotations

import argparse
from typing import Any

from slamfront.errors import SlamfrontError


def complete_recipes(prefix: str, **_: Any) -> list[str]:
    """Shipped recipe names and YAML files starting with ``prefix``."""
    from argcomplete.completers import FilesCompleter

    from slamfront.recipe import recipes_dir

    names = [path.stem for path in sorted(recipes_dir().glob("*.yaml")) if path.stem.startswith(prefix)]
    return names + list(FilesCompleter(("yaml", "yml"))(prefix))


def complete_overrides(prefix: str, parsed_args: argparse.Namespace, **_: Any) -> list[str]:
    """``KEY=`` for every key ``--set`` takes with the recipe given so far on the line."""
    from slamfront.recipe import load_recipe, override_keys
    from slamfront.registry import PluginRegistry

    given = getattr(parsed_args, "recipe", None)
    if not given:
        return []
    try:
        recipe, _path = load_recipe(given)
        keys = override_keys(recipe, PluginRegistry(modules=getattr(parsed_args, "plugin_module", None) or ()))
    except (SlamfrontError, OSError):
        return []
    return [f"{key}=" for key in keys if key.startswith(prefix)]
