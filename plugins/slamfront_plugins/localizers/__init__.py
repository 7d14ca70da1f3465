"""Built-in localizers, their messages (pose estimates, the keyframe map) and their evaluation."""

from slamfront import hookimpl
from slamfront_plugins.localizers.keyframe import KeyframeLocalizer


@hookimpl
def slamfront_localizers() -> list[type]:
    return [KeyframeLocalizer]


@hookimpl
def slamfront_message_types() -> list[type]:
    from slamfront_plugins.localizers.messages import KeyframeAdded, KeyframeMap, PoseEstimate

    return [PoseEstimate, KeyframeAdded, KeyframeMap]


@hookimpl
def slamfront_evaluations(kinds: frozenset[str]) -> list:
    from slamfront_plugins.localizers.evaluation import LocalizationEvaluation

    return [LocalizationEvaluation()] if "localizer" in kinds else []
