"""The plugin kinds, in the order a run calls them (a module of its own so that the
command line can name them without importing the plugin machinery)."""

from __future__ import annotations

from typing import Literal

Kind = Literal[
    "source", "descriptor", "place_map", "loop_detector", "localizer", "registration", "backend"
]
STAGE_KINDS: tuple[Kind, ...] = (
    "descriptor",
    "place_map",
    "loop_detector",
    "localizer",
    "registration",
    "backend",
)
"""Processing stages in the order a run calls them."""
KINDS: tuple[Kind, ...] = ("source", *STAGE_KINDS)
