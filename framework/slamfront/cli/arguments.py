"""Argument types whose bad values are one-line errors (exit 2), like every other user error."""

from __future__ import annotations

from slamfront.errors import SlamfrontError


def frame_count(text: str) -> int:
    """``--max-frames N``: a whole number of frames, at least 1 (0 or -1 would run nothing and report success)."""
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise SlamfrontError(f"--max-frames {text}: must be a whole number of frames, at least 1")
    return value
