"""The library table (``library.csv``): the candidate starting orientations of every frame.

Written by :func:`holofit.library.stage.run_library` through the stage skeleton
(:func:`holofit.batch.stage.run_stage`: the batch runner writes the CSV and its sidecar
atomically, with :func:`library_columns` and :func:`library_units`); read back by the fit
stage through :func:`holofit.tables.inputs.read_stage_table` and :func:`candidate_values`.
"""

from __future__ import annotations

import math
from typing import Any

__all__ = [
    "UNITS",
    "candidate_columns",
    "candidate_values",
    "library_columns",
    "library_units",
    "n_candidate_columns",
]


def candidate_columns(n: int) -> tuple[str, ...]:
    """``c1_psi_rad, c1_theta_rad, c1_phi_rad, c1_r2, c2_...`` for ``n`` candidates."""
    return tuple(f"c{i}_{q}" for i in range(1, n + 1)
                 for q in ("psi_rad", "theta_rad", "phi_rad", "r2"))


def library_columns(n_candidates: int) -> tuple[str, ...]:
    """Columns of ``library.csv``, in order, for ``n_candidates`` candidates per frame."""
    return ("frame", "x_um", "y_um", "z_um", "alpha", "n_candidates",
            *candidate_columns(n_candidates), "fit_time_s", "status", "message")


#: units of the columns other than the candidates'
UNITS = {
    "frame": "index",
    "x_um": "um (prefit position: the library's centre)",
    "y_um": "um",
    "z_um": "um (prefit height: the library's holograms are computed there)",
    "alpha": "1 (prefit alpha, used for the library's holograms)",
    "n_candidates": "count",
    "fit_time_s": "s (wall time of the frame's search)",
    "status": "ok | skipped | error",
    "message": "text",
}


def library_units(n_candidates: int) -> dict[str, str]:
    """Unit of every column of ``library.csv``."""
    return {**UNITS, **{c: ("rad" if c.endswith("_rad") else "1 (R^2 of the candidate)")
                        for c in candidate_columns(n_candidates)}}


def n_candidate_columns(columns: Any) -> int:
    """How many candidates a library table's columns hold."""
    return sum(1 for c in columns if str(c).endswith("_theta_rad"))


def candidate_values(row: dict[str, Any] | None, n_max: int) -> list[tuple[float, ...]]:
    """``(psi, theta, phi, r2)`` of a library row's candidates with finite angles, in order."""
    if row is None:
        return []
    out = []
    for i in range(1, n_max + 1):
        vals = [row.get(f"c{i}_{q}") for q in ("psi_rad", "theta_rad", "phi_rad", "r2")]
        if all(isinstance(v, int | float) and math.isfinite(float(v)) for v in vals[:3]):
            out.append(tuple(float(v) for v in vals))  # type: ignore[arg-type]
    return out
