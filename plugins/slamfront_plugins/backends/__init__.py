"""Built-in backends."""

from slamfront import hookimpl
from slamfront_plugins.backends.gtsam_pose_graph import GtsamPoseGraph


@hookimpl
def slamfront_backends() -> list[type]:
    return [GtsamPoseGraph]
