"""Built-in localizers."""

from slamfront import hookimpl
from slamfront_plugins.localizers.keyframe import KeyframeLocalizer


@hookimpl
def slamfront_localizers() -> list[type]:
    return [KeyframeLocalizer]
