"""Showing text that came from elsewhere (a log, a recipe, a data file) on a terminal.

A log from a stranger can carry terminal escape sequences in a topic name, a metadata
value or its embedded recipe: printed raw, they can retitle the window, hide lines or
rewrite what the user sees. Everything slamfront prints from such text goes through
:func:`printable`; anything quoted in an error message goes through :func:`shorten` too.
"""

from __future__ import annotations

import re

_CONTROL = re.compile(r"[\x00-\x08\x0b-\x1f\x7f-\x9f\u200e\u200f\u202a-\u202e\u2066-\u2069]")
_CONTROL_OR_NEWLINE = re.compile(r"[\x00-\x1f\x7f-\x9f\u200e\u200f\u202a-\u202e\u2066-\u2069]")


def _escape(match: re.Match[str]) -> str:
    return match.group().encode("unicode_escape").decode("ascii")


def printable(text: str, keep_newlines: bool = True) -> str:
    """``text`` with control characters (escape sequences, carriage returns, bidi
    overrides) shown as Python escapes (``\\x1b``); tabs and, unless told otherwise,
    newlines kept."""
    pattern = _CONTROL if keep_newlines else _CONTROL_OR_NEWLINE
    return pattern.sub(_escape, text.expandtabs(4) if keep_newlines else text)


def shorten(text: str, width: int = 200) -> str:
    """``text`` printable on one line, cut to ``width`` characters (foreign values in messages)."""
    flat = printable(" ".join(text.split()), keep_newlines=False)
    return flat if len(flat) <= width else flat[: width - 3] + "..."
