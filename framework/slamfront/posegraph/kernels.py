"""Robust kernels by name, and the outlier study's methods: plain data the command line
shows in its help, kept apart from the solver so that listing them does not import GTSAM."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Literal

KernelName = Literal["none", "huber", "cauchy", "dcs", "geman_mcclure", "tukey", "welsch", "gnc"]


@dataclass(frozen=True)
class Kernel:
    """A robust kernel GTSAM offers: what it does, its usual parameter, how to build it."""

    summary: str
    default_parameter: float
    build: Callable[[float], Any]


def _m_estimator(name: str) -> Callable[[float], Any]:
    """``gtsam.noiseModel.mEstimator.<name>.Create``, GTSAM imported when it is called."""

    def build(parameter: float) -> Any:
        import gtsam

        return getattr(gtsam.noiseModel.mEstimator, name).Create(parameter)

    return build


KERNELS: Mapping[str, Kernel] = {
    "huber": Kernel("quadratic up to k, then linear", 1.345, _m_estimator("Huber")),
    "cauchy": Kernel("log(1 + (r/c)^2)", 1.0, _m_estimator("Cauchy")),
    "dcs": Kernel("dynamic covariance scaling (Agarwal et al., ICRA 2013), phi", 1.0, _m_estimator("DCS")),
    "geman_mcclure": Kernel("Geman-McClure, c", 1.0, _m_estimator("GemanMcClure")),
    "tukey": Kernel("Tukey biweight (zero weight beyond c)", 4.685, _m_estimator("Tukey")),
    "welsch": Kernel("Welsch (exponential)", 2.9846, _m_estimator("Welsch")),
}
"""M-estimator kernels by name; ``none`` (least squares) and ``gnc`` are handled apart."""

METHODS: Mapping[str, dict[str, Any]] = {
    "none": {"kernel": "none"},
    "huber": {"kernel": "huber"},
    "cauchy": {"kernel": "cauchy"},
    "dcs": {"kernel": "dcs"},
    "geman_mcclure": {"kernel": "geman_mcclure"},
    "gnc": {"kernel": "gnc", "gnc_warm_start": "none"},
    "gnc_dcs_start": {"kernel": "gnc", "gnc_warm_start": "dcs"},
}
"""Outlier-study methods by label: solver options (kernels at their default parameters).
``gnc`` starts from the odometry; ``gnc_dcs_start`` from the DCS solution."""

RATES = (0.0, 0.1, 0.2, 0.5)
"""The outlier study's default rates of false loop closures."""
