"""Reading YAML files (recipes, sweep files) safely and cheaply.

``yaml.safe_load`` with what a hostile document can cost bounded (aliases, nesting,
size: :mod:`slamfront.limits`) and one-line errors naming the file and line. Kept apart
from :mod:`slamfront.recipe` so that listing the shipped recipes imports PyYAML and
nothing heavier (no pydantic, no plugins).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from slamfront.errors import RecipeError, SlamfrontError
from slamfront.limits import current_limits, over_limit
from slamfront.text import shorten

_SAFE_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
MAX_DEPTH = 100
"""Mappings and lists nested deeper than this are refused (a recipe needs fewer than 10)."""


def _expanded_nodes(data: Any, limit: int) -> int | None:
    """Nodes of ``data`` counting every alias as a copy of what it names, stopping past
    ``limit``; None when an alias refers to a node that contains it (a cycle).

    :raises ValueError: mappings and lists nest more than :data:`MAX_DEPTH` deep.

    PyYAML shares one object between an anchor and its aliases, so a few hundred bytes
    parse into a small graph that is a huge tree: anything that walks it as a tree
    (validation, copies, error messages) would expand it.
    """
    sizes: dict[int, int] = {}
    ancestors: set[int] = set()
    stack: list[tuple[Any, bool]] = [(data, False)]
    while stack:
        node, leaving = stack.pop()
        children = list(node.values()) if isinstance(node, dict) else node if isinstance(node, list) else None
        if children is None:
            continue
        key = id(node)
        if leaving:
            ancestors.discard(key)
            sizes[key] = 1 + sum(sizes.get(id(child), 1) for child in children)
            if sizes[key] > limit:
                return sizes[key]
            continue
        if key in sizes:
            continue
        if key in ancestors:
            return None
        ancestors.add(key)  # the mappings and lists on the path to this one
        if len(ancestors) > MAX_DEPTH:  # libyaml parses any depth; what walks it recursively would not
            raise ValueError(": not valid YAML: nested too deeply")
        stack.append((node, True))
        stack.extend((child, False) for child in children)
    return sizes.get(id(data), 1)


def _check_events(text: str, limit: int) -> None:
    """Walk the document's parser events (no recursion, nothing built) and refuse nesting
    past :data:`MAX_DEPTH` and more than ``limit`` nodes with aliases expanded *before*
    the composer sees it: libyaml's composer recurses once per level, so a 40,000-deep
    list crashes the interpreter (a segfault, no message) before any later check runs.

    :raises ValueError: the reason, short (with ``:LINE`` first).
    :raises yaml.YAMLError: the text does not parse.
    """
    loader = _SAFE_LOADER(text)
    opened: list[tuple[str | None, int]] = []  # (anchor, node count when it opened) per open collection
    sizes: dict[str, int] = {}  # an anchor's node count, aliases inside it expanded
    nodes = 0
    try:
        while loader.check_event():
            event = loader.get_event()
            line = f":{event.start_mark.line + 1}" if event.start_mark is not None else ""
            if isinstance(event, yaml.AliasEvent):
                if event.anchor not in sizes and any(anchor == event.anchor for anchor, _ in opened):
                    raise ValueError(f"{line}: an alias refers to a node that contains it (a recursive document)")
                nodes += sizes.get(event.anchor, 1)
            elif isinstance(event, yaml.NodeEvent):
                nodes += 1
                if isinstance(event, yaml.CollectionStartEvent):
                    opened.append((event.anchor, nodes - 1))
                    if len(opened) > MAX_DEPTH:
                        raise ValueError(f"{line}: not valid YAML: nested too deeply (over {MAX_DEPTH} levels)")
                elif event.anchor is not None:
                    sizes[event.anchor] = 1
            elif isinstance(event, yaml.CollectionEndEvent) and opened:
                anchor, start = opened.pop()
                if anchor is not None:
                    sizes[anchor] = nodes - start
            if nodes > limit:
                raise ValueError(f"{line}: {over_limit('yaml_nodes', nodes, 'the number of nodes with aliases expanded')}")
    finally:
        loader.dispose()


def _bounded_yaml(text: str) -> Any:
    """``yaml.safe_load`` with what a hostile document can cost bounded.

    :raises ValueError: the reason, short (with ``:LINE`` first when known).
    """
    limit = current_limits().yaml_nodes
    try:
        _check_events(text, limit)
        # libyaml's parser when PyYAML has it (its wheels do): the same safe constructor, ~10x faster
        data = yaml.load(text, Loader=_SAFE_LOADER)  # noqa: S506 - a safe loader
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = f":{mark.line + 1}" if mark is not None else ""
        raise ValueError(f"{line}: not valid YAML: {shorten(str(getattr(exc, 'problem', None) or exc))}") from None
    except RecursionError:
        raise ValueError(": not valid YAML: nested too deeply") from None
    nodes = _expanded_nodes(data, limit)
    if nodes is None:
        raise ValueError(": an alias refers to a node that contains it (a recursive document)")
    if nodes > limit:
        raise ValueError(f": {over_limit('yaml_nodes', nodes, 'the number of nodes with aliases expanded')}")
    return data


def load_yaml(text: str, where: str, error: type[SlamfrontError] = RecipeError) -> Any:
    """Parse YAML with aliases bounded to ``yaml_nodes`` expanded nodes
    (:mod:`slamfront.limits`), recursive aliases and absurd nesting refused, and short
    error messages.

    :param where: the file (or other origin) named in errors.
    :raises SlamfrontError: of type ``error``, one line naming ``where``.
    """
    try:
        return _bounded_yaml(text)
    except ValueError as exc:
        raise error(f"{where}{exc}") from None


def read_yaml_mapping(path: Path, what: str = "recipe") -> dict[str, Any]:
    """Parse a YAML file that must hold a mapping, with the file (and line) named in any error."""
    try:
        size = path.stat().st_size
        problem = over_limit("text_bytes", size, "its size in bytes")
        if problem:
            raise RecipeError(f"{path}: {problem}")
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise RecipeError(f"{path}: cannot read {what}: {exc.strerror or exc}") from exc
    except UnicodeDecodeError as exc:
        raise RecipeError(f"{path}: a {what} must be UTF-8 text (byte {exc.start} is not)") from None
    raw = load_yaml(text, str(path))
    if not isinstance(raw, dict):
        raise RecipeError(f"{path}: a {what} must be a YAML mapping, got {type(raw).__name__}")
    raw.setdefault("name", path.stem)
    return raw
