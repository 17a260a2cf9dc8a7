"""The analysis's error type: a trajectory that cannot be analysed as asked."""

from __future__ import annotations

__all__ = ["AnalysisError"]


class AnalysisError(ValueError):
    """The trajectory cannot be analysed as asked (too few frames, no orientation for a model
    that needs it, a fit range longer than the data, ...).

    The message names the trajectory's source once: the steps of the analysis raise it
    without the source, and ``analyze_trajectory``, which knows the source, adds it.
    """
