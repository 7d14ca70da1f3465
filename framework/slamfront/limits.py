"""Bounds on what one input may make slamfront allocate.

A few hundred bytes of YAML, a sweep file or a log can ask for terabytes (an alias
bomb, a grid of 10^9 runs, a chunk declaring 4 GB of content, a source of 10^13
frames). Every such size is checked against a limit here *before* anything is
allocated, and the error names the field, the value and the limit.

The defaults are far above anything the shipped recipes need. Raise one for a single
command with the environment variable ``SLAMFRONT_LIMITS``, a comma-separated list of
``name=value`` (``SLAMFRONT_LIMITS="frames=5e6,sweep_runs=50000"``); the names are the
fields of :class:`Limits`. The variable is read on every check, so there is no global
state to reset.
"""

from __future__ import annotations

import os
from typing import NamedTuple

from slamfront.errors import SlamfrontError

LIMITS_ENV = "SLAMFRONT_LIMITS"


class Limits(NamedTuple):
    """The limits in force (defaults, or as ``SLAMFRONT_LIMITS`` sets them); each is > 0.

    A named tuple, not a pydantic model or a dataclass: reading a recipe's size limit must
    not cost those imports (``slamfront recipes`` lists files in a few tens of ms).
    """

    frames: int = 1_000_000
    image_pixels: int = 50_000_000
    world_length_m: float = 100_000.0
    sweep_runs: int = 10_000
    yaml_nodes: int = 200_000
    text_bytes: int = 16 << 20
    chunk_bytes: int = 256 << 20
    model_bytes: int = 2 << 30


LIMIT_DESCRIPTIONS = {
    "frames": "frames one generated source may produce",
    "image_pixels": "pixels of one image: generated, or declared by a file's or a logged image's header",
    "world_length_m": "length of a generated world's route, metres",
    "sweep_runs": "runs one sweep file may expand to",
    "yaml_nodes": "nodes of a YAML document with its aliases expanded",
    "text_bytes": "size of a recipe or sweep file, bytes",
    "chunk_bytes": "uncompressed size of one MCAP chunk, bytes",
    "model_bytes": "size of one model file a descriptor loads (ONNX), bytes",
}
"""What each limit bounds."""


def current_limits() -> Limits:
    """The limits, with ``$SLAMFRONT_LIMITS`` applied.

    :raises SlamfrontError: the variable is malformed (names the bad item).
    """
    text = os.environ.get(LIMITS_ENV, "").strip()
    if not text:
        return Limits()
    kinds = Limits._field_defaults  # a limit is an int where its default is one
    values: dict[str, float] = {}
    for item in text.split(","):
        name, sep, value = item.strip().partition("=")
        if not sep or name not in kinds:
            raise SlamfrontError(
                f"${LIMITS_ENV}: {item.strip()!r}: expected NAME=VALUE with NAME one of {', '.join(kinds)}"
            )
        try:
            number = float(value)
        except ValueError:
            raise SlamfrontError(f"${LIMITS_ENV}: {item.strip()!r}: {value!r} is not a number") from None
        if not number > 0:
            raise SlamfrontError(f"${LIMITS_ENV}: {name}: must be greater than 0, got {value}")
        values[name] = int(number) if isinstance(kinds[name], int) else number
    return Limits()._replace(**values)


def over_limit(name: str, value: float, what: str) -> str | None:
    """Why ``value`` (of ``what``) is too large for limit ``name``, or None when it is within it."""
    limit = getattr(current_limits(), name)
    if value <= limit:
        return None
    return f"{what} is {value:,.0f}, over the limit of {limit:,.0f} (allow more with {LIMITS_ENV}={name}=N)"


def check_limit(name: str, value: float, what: str) -> None:
    """Raise ``ValueError`` (for pydantic validators: the error then names the field)
    when ``value`` exceeds limit ``name``."""
    problem = over_limit(name, value, what)
    if problem:
        raise ValueError(problem)
