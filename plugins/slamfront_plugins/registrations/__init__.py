"""Built-in registrations."""

from slamfront import hookimpl
from slamfront_plugins.registrations.feature_icp import FeatureIcp


@hookimpl
def slamfront_registrations() -> list[type]:
    return [FeatureIcp]
