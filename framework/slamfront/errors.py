"""Errors a user can cause and fix.

The CLI turns every :class:`SlamfrontError` into one line on stderr and exit code 2.
Anything else is a bug in slamfront or in a plugin and keeps its traceback.
"""


class SlamfrontError(Exception):
    """A user-facing error: the message names the file and the field at fault."""


class RecipeError(SlamfrontError):
    """A recipe (or a ``--set`` override) is missing, malformed or invalid."""


class PluginError(SlamfrontError):
    """A plugin is unknown, badly declared, or incompatible with the rest of the recipe."""


class DataError(SlamfrontError):
    """Input data (images, depth, ground truth, pose graphs) is missing or unreadable."""


class LogError(SlamfrontError):
    """An MCAP log is missing, truncated or not a slamfront log."""
