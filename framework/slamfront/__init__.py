"""slamfront: a plugin-based visual SLAM front-end framework.

The public names a plugin author needs are re-exported here; everything else lives
in the sub-modules named in docs/design.md. The re-exports are loaded on first use
(PEP 562), so ``import slamfront`` (and ``slamfront --help``) does not import OpenCV,
pydantic and the plugin machinery until something asks for them.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from slamfront.errors import DataError, LogError, PluginError, RecipeError, SlamfrontError

if TYPE_CHECKING:
    from slamfront.evaluation.base import Evaluation, EvaluationContext, EvaluationReport
    from slamfront.frame import Camera, Frame
    from slamfront.hookspecs import hookimpl
    from slamfront.messages import Message
    from slamfront.plugin import (
        Backend,
        Descriptor,
        Localizer,
        LoopDetector,
        PlaceMap,
        Plugin,
        PluginConfig,
        Registration,
        SearchablePlaceMap,
        Source,
        Stage,
        StageInputs,
    )

_LAZY = {
    "Camera": "slamfront.frame",
    "Frame": "slamfront.frame",
    "hookimpl": "slamfront.hookspecs",
    "Message": "slamfront.messages",
    **{name: "slamfront.evaluation.base" for name in ("Evaluation", "EvaluationContext", "EvaluationReport")},
    **{
        name: "slamfront.plugin"
        for name in ("Backend", "Descriptor", "Localizer", "LoopDetector", "PlaceMap", "Plugin", "PluginConfig",
                     "Registration", "SearchablePlaceMap", "Source", "Stage", "StageInputs")
    },
}


def __getattr__(name: str) -> Any:
    if name == "__version__":
        from importlib.metadata import PackageNotFoundError, version

        try:
            return version("slamfront")
        except PackageNotFoundError:  # running from a source tree that was never installed
            return "0+unknown"
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'slamfront' has no attribute {name!r}")


__all__ = [
    "Backend",
    "Camera",
    "DataError",
    "Descriptor",
    "Evaluation",
    "EvaluationContext",
    "EvaluationReport",
    "Frame",
    "Localizer",
    "LogError",
    "LoopDetector",
    "Message",
    "PlaceMap",
    "Plugin",
    "PluginConfig",
    "PluginError",
    "RecipeError",
    "Registration",
    "SearchablePlaceMap",
    "SlamfrontError",
    "Source",
    "Stage",
    "StageInputs",
    "hookimpl",
    "__version__",
]
