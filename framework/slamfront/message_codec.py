"""How slamfront messages are written as JSON and read back bit-exactly.

NumPy arrays are stored as ``{"dtype": "<f4", "shape": [...], "data": <base64 of the raw
bytes>}`` and floats as JSON numbers (Python prints the shortest repr that round-trips)
or, when not finite, as the strings ``"nan"``, ``"inf"``, ``"-inf"``: decoding gives back
identical bits. :class:`slamfront.messages.Message` uses these functions; nothing here
knows a message type.
"""

from __future__ import annotations

import base64
import functools
import json
import math
import types
import typing
from typing import Any

import numpy as np

NONFINITE = {"nan": math.nan, "inf": math.inf, "-inf": -math.inf}

PLAIN_SUFFIX = "_values"
"""Suffix of the plain-number copy of an array field (see ``Message.plain_fields``)."""


@functools.cache
def type_hints(cls: type) -> dict[str, Any]:
    """``typing.get_type_hints`` of a message class, resolved once: evaluating the string
    annotations again for every decoded message took a tenth of a Nordland replay."""
    return typing.get_type_hints(cls)


def decode_any(data: bytes | str) -> dict[str, Any]:
    """Decode any slamfront JSON message to a dict, arrays as NumPy arrays.

    Works without knowing the message class, so ``inspect`` and ``diff`` can read logs
    written by plugins that are not installed.
    """
    return {key: decode_value(value, Any) for key, value in json.loads(data).items()}


def encode_value(value: Any) -> Any:
    """A field value as JSON data (arrays as dtype, shape and base64 bytes; non-finite floats as strings)."""
    if isinstance(value, np.ndarray):
        array = np.ascontiguousarray(value)
        return {
            "dtype": array.dtype.str,
            "shape": list(array.shape),
            "data": base64.b64encode(array.tobytes()).decode("ascii"),
        }
    if isinstance(value, (float, np.floating)):
        value = float(value)
        if math.isfinite(value):
            return value
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf")
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, dict):
        return {str(k): encode_value(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [encode_value(v) for v in value]
    return value


@functools.cache
def _json_encoder() -> json.JSONEncoder:
    """The encoder ``json.dumps(..., separators=(",", ":"), allow_nan=False)`` builds on every call, built once."""
    return json.JSONEncoder(separators=(",", ":"), allow_nan=False)


def encode_object(values: dict[str, Any], encoded: dict[str, Any] | None = None) -> bytes:
    """The compact UTF-8 JSON of ``{k: encode_value(v)}`` for ``values``, then the already
    JSON-ready ``encoded``: the bytes of ``json.dumps(..., separators=(",", ":"),
    allow_nan=False)``. An array's base64 text is put in as is rather than scanned by the
    JSON encoder (its alphabet never needs escaping): for a 1,152-float descriptor that scan
    was half of the message's encoding."""
    encode = _json_encoder().encode
    parts, run = [], {}
    for name, value in values.items():
        if isinstance(value, np.ndarray):
            if run:
                parts.append(encode(run)[1:-1])
                run = {}
            array = np.ascontiguousarray(value)
            parts.append(f'{encode(name)}:{{"dtype":{encode(array.dtype.str)},"shape":{encode(list(array.shape))},'
                         f'"data":"{base64.b64encode(array.tobytes()).decode("ascii")}"}}')
        else:
            run[name] = encode_value(value)
    if encoded:
        run.update(encoded)
    if not parts:
        return encode(run).encode()
    if run:
        parts.append(encode(run)[1:-1])
    return ("{" + ",".join(parts) + "}").encode()


def plain_values(value: Any) -> list[float | int | None] | None:
    """An array as a flat row-major list of JSON numbers (None where not finite)."""
    if value is None:
        return None
    flat = np.asarray(value).ravel()
    if flat.dtype.kind in "iub":
        return [int(v) for v in flat]
    return [float(v) if math.isfinite(v) else None for v in flat.astype(np.float64)]


def _is_array_payload(value: Any) -> bool:
    return isinstance(value, dict) and value.keys() == {"dtype", "shape", "data"}


def decode_value(value: Any, hint: Any) -> Any:
    """What :func:`encode_value` wrote, back as the type ``hint`` names (``Any``: as the data says)."""
    if value is None:
        return None
    if _is_array_payload(value):
        array = np.frombuffer(base64.b64decode(value["data"]), dtype=np.dtype(value["dtype"]))
        return array.reshape(value["shape"]).copy()
    if isinstance(value, str) and value in NONFINITE and _accepts_float(hint):
        return NONFINITE[value]
    if isinstance(value, dict):
        inner = _dict_value_hint(hint)
        return {k: decode_value(v, inner) for k, v in value.items()}
    if isinstance(value, list):
        inner = _list_item_hint(hint)
        decoded = [decode_value(v, inner) for v in value]
        return tuple(decoded) if typing.get_origin(strip_optional(hint)) is tuple else decoded
    if isinstance(value, int) and strip_optional(hint) is float:
        return float(value)
    return value


def strip_optional(hint: Any) -> Any:
    """``X | None`` -> ``X``; any other type hint unchanged."""
    if isinstance(hint, types.UnionType) or typing.get_origin(hint) is typing.Union:
        args = [a for a in typing.get_args(hint) if a is not type(None)]
        if len(args) == 1:
            return args[0]
    return hint


def _accepts_float(hint: Any) -> bool:
    if hint is Any or hint is float:
        return True
    if isinstance(hint, types.UnionType) or typing.get_origin(hint) is typing.Union:
        return any(_accepts_float(a) for a in typing.get_args(hint))
    return False


def _list_item_hint(hint: Any) -> Any:
    args = typing.get_args(strip_optional(hint))
    return args[0] if args else Any


def _dict_value_hint(hint: Any) -> Any:
    args = typing.get_args(strip_optional(hint))
    return args[1] if len(args) == 2 else Any


_ARRAY_SCHEMA = {
    "type": "object",
    "description": "NumPy array: dtype string, shape, raw little/big-endian bytes in base64",
    "properties": {
        "dtype": {"type": "string"},
        "shape": {"type": "array", "items": {"type": "integer"}},
        "data": {"type": "string", "contentEncoding": "base64"},
    },
}


PLAIN_SCHEMA = {
    "anyOf": [{"type": "array", "items": {"type": ["number", "null"]}}, {"type": "null"}],
    "description": "the array field of the same name as a flat row-major list of plain numbers "
    "(null where not finite), for plots; a 4x4 pose's x, y, z are items 3, 7, 11",
}


def schema_for(hint: Any) -> dict[str, Any]:
    """The JSON Schema of a field with type ``hint``, as :func:`encode_value` writes it."""
    origin = typing.get_origin(hint)
    if isinstance(hint, types.UnionType) or origin is typing.Union:
        options = [schema_for(a) for a in typing.get_args(hint) if a is not type(None)]
        nullable = type(None) in typing.get_args(hint)
        schema = options[0] if len(options) == 1 else {"anyOf": options}
        return {"anyOf": [schema, {"type": "null"}]} if nullable else schema
    if hint is np.ndarray:
        return _ARRAY_SCHEMA
    if hint is bool:
        return {"type": "boolean"}
    if hint is int:
        return {"type": "integer"}
    if hint is float:
        return {"anyOf": [{"type": "number"}, {"enum": list(NONFINITE)}]}
    if hint is str:
        return {"type": "string"}
    if origin in (list, tuple):
        return {"type": "array", "items": schema_for(_list_item_hint(hint))}
    if origin is dict:
        return {"type": "object", "additionalProperties": schema_for(_dict_value_hint(hint))}
    return {}
