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

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from slamfront.errors import SlamfrontError

LIMITS_ENV = "SLAMFRONT_LIMITS"


class Limits(BaseModel):
    """The limits in force (defaults, or as ``SLAMFRONT_LIMITS`` sets them)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    frames: int = Field(1_000_000, gt=0, description="frames one generated source may produce")
    image_pixels: int = Field(
        50_000_000, gt=0, description="pixels of one image: generated, or declared by a file's or a logged image's header"
    )
    world_length_m: float = Field(100_000.0, gt=0, description="length of a generated world's route, metres")
    sweep_runs: int = Field(10_000, gt=0, description="runs one sweep file may expand to")
    yaml_nodes: int = Field(200_000, gt=0, description="nodes of a YAML document with its aliases expanded")
    text_bytes: int = Field(16 << 20, gt=0, description="size of a recipe or sweep file, bytes")
    chunk_bytes: int = Field(256 << 20, gt=0, description="uncompressed size of one MCAP chunk, bytes")


def current_limits() -> Limits:
    """The limits, with ``$SLAMFRONT_LIMITS`` applied.

    :raises SlamfrontError: the variable is malformed (names the bad item).
    """
    text = os.environ.get(LIMITS_ENV, "").strip()
    if not text:
        return Limits()
    values: dict[str, float] = {}
    for item in text.split(","):
        name, sep, value = item.strip().partition("=")
        if not sep or name not in Limits.model_fields:
            raise SlamfrontError(
                f"${LIMITS_ENV}: {item.strip()!r}: expected NAME=VALUE with NAME one of {', '.join(Limits.model_fields)}"
            )
        try:
            values[name] = float(value)
        except ValueError:
            raise SlamfrontError(f"${LIMITS_ENV}: {item.strip()!r}: {value!r} is not a number") from None
    integral = {k: int(v) if Limits.model_fields[k].annotation is int else v for k, v in values.items()}
    try:
        return Limits(**integral)
    except ValidationError as exc:
        raise SlamfrontError(f"${LIMITS_ENV}: {exc.errors()[0]['loc'][0]}: {exc.errors()[0]['msg']}") from None


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
