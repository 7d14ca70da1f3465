"""The one exception type of :mod:`slamfront.core`."""

from slamfront.errors import DataError


class CoreError(DataError, ValueError):
    """Inputs to a core function are inconsistent (shapes, lengths, ranges)."""
