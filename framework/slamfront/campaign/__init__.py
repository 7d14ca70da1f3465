"""Campaigns: many runs from one sweep file, on a local process pool or a Ray cluster.

- :mod:`~slamfront.campaign.sweepfile`: the sweep file's pydantic model.
- :mod:`~slamfront.campaign.plan`: expanding it into validated runs with resume keys.
- :mod:`~slamfront.campaign.task`: :func:`run_one`, the function every backend executes.
- :mod:`~slamfront.campaign.backends`: the local process pool and Ray.
- :mod:`~slamfront.campaign.store`, :mod:`~slamfront.campaign.results`,
  :mod:`~slamfront.campaign.plots`, :mod:`~slamfront.campaign.report`: what a campaign writes.
- :mod:`~slamfront.campaign.campaign`: :func:`run_campaign`, tying them together.
"""

from slamfront.campaign.backends import LocalBackend, RayBackend, start_ray
from slamfront.campaign.campaign import CampaignResult, plan_campaign, run_campaign
from slamfront.campaign.plan import PlannedRun, plan_runs
from slamfront.campaign.sweepfile import Sweep, find_sweep, read_sweep
from slamfront.campaign.task import RunOutcome, RunTask, run_one

__all__ = [
    "CampaignResult",
    "LocalBackend",
    "PlannedRun",
    "RayBackend",
    "RunOutcome",
    "RunTask",
    "Sweep",
    "find_sweep",
    "plan_campaign",
    "plan_runs",
    "read_sweep",
    "run_campaign",
    "run_one",
    "start_ray",
]
