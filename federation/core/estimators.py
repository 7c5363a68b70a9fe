"""The clock-offset estimators an agent can use, by name (``--estimator``)."""

from __future__ import annotations

from typing import Literal, get_args

from federation.core.clockfilter import ClockFilter
from federation.core.sync import DEFAULT_WINDOW, Estimator, PaperEstimator

__all__ = ["DEFAULT_ESTIMATOR", "ESTIMATORS", "EstimatorName", "make_estimator"]

EstimatorName = Literal["clockfilter", "mean", "median"]
"""An estimator's name: the type of ``AgentConfig.estimator``."""

ESTIMATORS: tuple[EstimatorName, ...] = get_args(EstimatorName)
"""Every estimator's name, the one list (configuration, command line, benchmarks):
``clockfilter``: offset and drift from delay-weighted regression (the default);
``mean`` and ``median``: the paper's Eq. 6 over the first ``window`` seconds."""

DEFAULT_ESTIMATOR: EstimatorName = "clockfilter"


def make_estimator(name: str, window: float = DEFAULT_WINDOW) -> Estimator:
    """The estimator called ``name``; ``window``: seconds it averages or locks after."""
    if name == "clockfilter":
        return ClockFilter(lock_after=window)
    if name == "mean":
        return PaperEstimator("mean", window)
    if name == "median":
        return PaperEstimator("median", window)
    raise ValueError(f"unknown estimator {name!r}: choose one of {', '.join(ESTIMATORS)}")
