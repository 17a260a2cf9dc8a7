"""What a fit stage does to its complete table: flag the movie's outlier frames.

The batch runner applies it to the complete table just before writing it
(:func:`holofit.batch.runner.run_batch`'s ``finish``), so the table that appears under its own
name is already flagged: a run killed at any moment never leaves an unflagged table that looks
complete.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pandas as pd

from holofit.holomodel.result import flag_outliers

__all__ = ["outlier_rule", "outlier_sidecar"]


def outlier_rule(factor: float) -> Callable[[pd.DataFrame], Any]:
    """The table finisher that flags outliers at ``factor`` times the movie's median."""

    def finish(table: pd.DataFrame) -> int:
        return flag_outliers(table, factor)

    return finish


def outlier_sidecar(factor: float) -> dict[str, Any]:
    """How the rule is recorded in a fit table's sidecar."""
    return {"outlier_factor": factor,
            "rule": "ok rows whose chi2_red exceeds outlier_factor x the median chi2_red of the "
                    "converged rows become poor_fit"}
