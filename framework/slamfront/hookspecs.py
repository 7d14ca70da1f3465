"""The hooks a plugin module implements to contribute plugins to slamfront.

A *plugin module* is any importable module registered under the ``slamfront``
entry-point group (or named in a recipe's ``plugin_modules``). It implements one or
more of the hooks below with ``@slamfront.hookimpl``; each hook returns the plugin
classes of one kind. slamfront's own built-ins are registered exactly this way.

All hooks are called with keyword arguments only, once, when the plugin registry is
built (the first time a command needs plugins). Every implementation's results are
collected (no first-result dispatch); the order between modules is not meaningful,
because plugin names must be unique within a kind.

Added in slamfront 0.1.0.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import pluggy

if TYPE_CHECKING:
    from slamfront.plugin import (
        Backend,
        Descriptor,
        Localizer,
        LoopDetector,
        PlaceMap,
        Registration,
        Source,
    )

PROJECT = "slamfront"
hookspec = pluggy.HookspecMarker(PROJECT)
hookimpl = pluggy.HookimplMarker(PROJECT)


# --- data -------------------------------------------------------------------------------


@hookspec
def slamfront_sources() -> Sequence[type[Source]]:
    """Contribute source plugins: things that yield frames.

    :returns: classes deriving from :class:`slamfront.Source`, each with a unique
        ``name``, a docstring and a nested pydantic ``Config``.
    """


# --- front end --------------------------------------------------------------------------


@hookspec
def slamfront_descriptors() -> Sequence[type[Descriptor]]:
    """Contribute descriptor plugins: frame -> global vector and/or local features.

    :returns: classes deriving from :class:`slamfront.Descriptor`.
    """


@hookspec
def slamfront_place_maps() -> Sequence[type[PlaceMap]]:
    """Contribute place-map plugins: incremental topological maps with nearest-neighbour search.

    :returns: classes deriving from :class:`slamfront.PlaceMap`.
    """


@hookspec
def slamfront_loop_detectors() -> Sequence[type[LoopDetector]]:
    """Contribute loop-detector plugins: query frame -> match and confidence, or no answer.

    :returns: classes deriving from :class:`slamfront.LoopDetector`.
    """


@hookspec
def slamfront_localizers() -> Sequence[type[Localizer]]:
    """Contribute localizer plugins: frame -> pose or node in a keyframe map.

    :returns: classes deriving from :class:`slamfront.Localizer`.
    """


@hookspec
def slamfront_registrations() -> Sequence[type[Registration]]:
    """Contribute registration plugins: point clouds -> relative transforms and a global model.

    :returns: classes deriving from :class:`slamfront.Registration`.
    """


# --- back end ---------------------------------------------------------------------------


@hookspec
def slamfront_backends() -> Sequence[type[Backend]]:
    """Contribute back-end plugins: odometry and loop closures -> optimised trajectory.

    :returns: classes deriving from :class:`slamfront.Backend`.
    """
