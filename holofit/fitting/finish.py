"""What a fit stage does once its batch is complete: flag the movie's outlier frames.

The batch runner writes the table only when every frame is done; this step then reads it,
applies :func:`holofit.fitting.result.flag_outliers` (it needs the whole movie) and rewrites
table and sidecar atomically, recording the rule in the sidecar. It changes nothing on a
second run, so a rerun of a finished stage leaves the table as it was.
"""

from __future__ import annotations

import json
from pathlib import Path

from holofit.fitting.result import flag_outliers
from holofit.io.tables import read_table, sidecar_path, write_table

__all__ = ["finish_fit_table"]


def finish_fit_table(path: str | Path, outlier_factor: float) -> int:
    """Flag outlier frames of a complete fit table in place; returns how many were flagged."""
    path = Path(path)
    table = read_table(path)
    n = flag_outliers(table, outlier_factor)
    side = sidecar_path(path)
    meta = json.loads(side.read_text()) if side.exists() else {}
    rule = {"outlier_factor": outlier_factor,
            "rule": "ok rows whose chi2_red exceeds outlier_factor x the median chi2_red of "
                    "the converged rows become poor_fit"}
    if n or meta.get("quality") != rule:
        meta["quality"] = rule
        write_table(path, table, meta)
    return n
