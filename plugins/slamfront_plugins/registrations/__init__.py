"""Built-in registrations, their messages and their evaluation."""

from slamfront import hookimpl
from slamfront_plugins.registrations.feature_icp import FeatureIcp


@hookimpl
def slamfront_registrations() -> list[type]:
    return [FeatureIcp]


@hookimpl
def slamfront_message_types() -> list[type]:
    from slamfront_plugins.registrations.messages import CloudRegistration, RegisteredTrajectory

    return [CloudRegistration, RegisteredTrajectory]


@hookimpl
def slamfront_evaluations(kinds: frozenset[str]) -> list:
    from slamfront_plugins.registrations.evaluation import RegistrationEvaluation

    return [RegistrationEvaluation()] if "registration" in kinds else []
