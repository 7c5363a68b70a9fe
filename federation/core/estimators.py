"""The clock-offset estimators an agent can use, by name (``--estimator``)."""

from __future__ import annotations

from federation.core.clockfilter import ClockFilter
from federation.core.sync import DEFAULT_WINDOW, Estimator, PaperEstimator

__all__ = ["DEFAULT_ESTIMATOR", "ESTIMATORS", "make_estimator"]

ESTIMATORS = ("clockfilter", "mean", "median")
"""``clockfilter``: offset and drift from delay-weighted regression (the default);
``mean`` and ``median``: the paper's Eq. 6 over the first ``window`` seconds."""

DEFAULT_ESTIMATOR = "clockfilter"


def make_estimator(name: str, window: float = DEFAULT_WINDOW) -> Estimator:
    if name == "clockfilter":
        return ClockFilter(lock_after=window)
    if name == "mean":
        return PaperEstimator("mean", window)
    if name == "median":
        return PaperEstimator("median", window)
    raise ValueError(f"unknown estimator {name!r}: choose one of {', '.join(ESTIMATORS)}")
