"""Built-in back ends, their messages (loop constraints, the pose graph) and their evaluation."""

from slamfront import hookimpl
from slamfront_plugins.backends.gtsam_pose_graph import GtsamPoseGraph


@hookimpl
def slamfront_backends() -> list[type]:
    return [GtsamPoseGraph]


@hookimpl
def slamfront_message_types() -> list[type]:
    from slamfront_plugins.backends.messages import LoopConstraint, PoseGraphState

    return [LoopConstraint, PoseGraphState]


@hookimpl
def slamfront_evaluations(kinds: frozenset[str]) -> list:
    from slamfront_plugins.backends.evaluation import BackendEvaluation

    return [BackendEvaluation()] if "backend" in kinds else []
