"""The hooks a plugin module implements to contribute plugins to slamfront.

A *plugin module* is any importable module registered under the ``slamfront``
entry-point group (or named in a recipe's ``plugin_modules``). It implements one or
more of the hooks below with ``@slamfront.hookimpl``: each stage hook returns the plugin
classes of one kind, :func:`slamfront_message_types` the message types the module's
plugins log and :func:`slamfront_evaluations` what scores their outputs. slamfront's
own built-ins are registered exactly this way.

All hooks are called with keyword arguments only. The stage hooks are called once, when
the plugin registry is built (the first time a command needs plugins);
:func:`slamfront_message_types` when a command reads a log's messages, and
:func:`slamfront_evaluations` once per run. Every implementation's results are
collected (no first-result dispatch); plugin names are unique within a kind and schema
names unique over all modules.

Added in slamfront 0.1.0.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import pluggy

if TYPE_CHECKING:
    from slamfront.evaluation.base import Evaluation
    from slamfront.messages import Message
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


# --- what plugins log and how it is scored ------------------------------------------------


@hookspec
def slamfront_message_types() -> Sequence[type[Message]]:
    """Declare the message types this module's plugins log.

    Tools that read logs (``inspect --validate``, ``diff``, ``replay``, ``optimize``)
    decode a message with the class declared for its schema name; a log never makes them
    import a module. A type no installed package declares is checked against the JSON
    Schema the log embeds and reported as not installed.

    :returns: frozen dataclasses deriving from :class:`slamfront.messages.Message`, each
        with its own ``schema_name`` (unique over every installed package; keep it stable,
        logs written earlier are decoded by it).
    """


@hookspec
def slamfront_evaluations(kinds: frozenset[str]) -> Sequence[Evaluation]:
    """Contribute evaluations for one run: each watches the run's messages and, at the end,
    returns metrics for ``metrics.json``, a section of ``report.md`` and plots.

    :param kinds: the kinds of plugin the run's recipe has (``source``, ``descriptor``,
        ...); return nothing for a run your evaluations cannot score.
    :returns: fresh :class:`slamfront.Evaluation` objects (a new one per call: each keeps
        the state of one run).
    """
