"""Did-you-mean hints for names a user typed: plugin names, recipe keys, params, hooks.

Every "unknown X" message in slamfront ends the same way, so a misspelt key reads
alike whether it is a plugin name, a stage key, a plugin parameter or a hook.
"""

from __future__ import annotations

import dataclasses
import difflib
import inspect
import types
import typing
from collections.abc import Iterable, Sequence
from typing import Any

from pydantic import BaseModel


def did_you_mean(name: str, known: Iterable[str], what: str = "names") -> str:
    """``did you mean 'x'?`` (up to three close names), else ``known <what>: a, b, c``."""
    known = sorted(set(known))
    # 0.6 (difflib's default): at 0.5 a short name shares enough letters with anything
    # (`treshold` was "did you mean 'rho'?"); a typo of a name stays above 0.8
    close = difflib.get_close_matches(name, known, n=3, cutoff=0.6)
    # a key typed short (`frames` for `frames_per_traversal`) is too far for difflib
    close += [k for k in known if len(name) >= 3 and name in k and k not in close][: 3 - len(close)]
    if close:
        return f"did you mean {' or '.join(repr(c) for c in close)}?"
    return f"known {what}: {', '.join(known) or 'none'}"


def model_keys_at(model: type[BaseModel], path: Sequence[str | int]) -> list[str] | None:
    """The keys a pydantic model accepts at ``path`` (a validation error's ``loc`` minus its
    last element), following nested models (pydantic models or dataclasses) through
    optional, list and union fields.

    :returns: the field names (aliases where set), or None when ``path`` does not lead to
        a model (a free-form dict, say).
    """
    current: type | None = model
    for part in path:
        if isinstance(part, int):  # a list index: the element model was unwrapped already
            continue
        fields = _fields(current) if current is not None else {}
        if part not in fields:
            return None
        current = _model_in(fields[part])
    if current is None:
        return None
    if issubclass(current, BaseModel):
        return [field.alias or name for name, field in current.model_fields.items()]
    return list(_fields(current))


def _fields(model: type) -> dict[str, Any]:
    """Field name -> annotation of a pydantic model or a dataclass."""
    if issubclass(model, BaseModel):
        return {name: field.annotation for name, field in model.model_fields.items()}
    return {field.name: typing.get_type_hints(model).get(field.name) for field in dataclasses.fields(model)}


def _model_in(annotation: Any) -> type | None:
    """The pydantic model or dataclass inside ``Model``, ``Model | None``, ``list[Model]`` and the like."""
    if inspect.isclass(annotation) and (issubclass(annotation, BaseModel) or dataclasses.is_dataclass(annotation)):
        return annotation
    if typing.get_origin(annotation) in (typing.Union, types.UnionType, list, tuple, typing.Annotated):
        for argument in typing.get_args(annotation):
            found = _model_in(argument)
            if found is not None:
                return found
    return None
