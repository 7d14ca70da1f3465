"""slamfront: a plugin-based visual SLAM front-end framework.

The public names a plugin author needs are re-exported here; everything else lives
in the sub-modules named in docs/design.md.
"""

from importlib.metadata import PackageNotFoundError, version

from slamfront.errors import DataError, LogError, PluginError, RecipeError, SlamfrontError
from slamfront.frame import Camera, Frame
from slamfront.hookspecs import hookimpl
from slamfront.plugin import (
    Backend,
    Descriptor,
    Localizer,
    LoopDetector,
    PlaceMap,
    Plugin,
    PluginConfig,
    Registration,
    Source,
    Stage,
    StageInputs,
)

try:
    __version__ = version("slamfront")
except PackageNotFoundError:  # running from a source tree that was never installed
    __version__ = "0+unknown"

__all__ = [
    "Backend",
    "Camera",
    "DataError",
    "Descriptor",
    "Frame",
    "Localizer",
    "LogError",
    "LoopDetector",
    "PlaceMap",
    "Plugin",
    "PluginConfig",
    "PluginError",
    "RecipeError",
    "Registration",
    "SlamfrontError",
    "Source",
    "Stage",
    "StageInputs",
    "hookimpl",
    "__version__",
]
