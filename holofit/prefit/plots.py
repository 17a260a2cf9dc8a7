"""Summary plot of a prefit table: what a person looks at before the DDA stages."""

from __future__ import annotations

from pathlib import Path

from holofit.holomodel.plots import plot_table

__all__ = ["PREFIT_PANELS", "plot_prefit"]

PREFIT_PANELS = (
    ("x_um", "x (um)"),
    ("y_um", "y (um)"),
    ("z_um", "z (um)"),
    ("radius_um", "radius (um)"),
    ("n", "index"),
    ("alpha", "alpha"),
    ("r2", "R^2"),
    ("fit_time_s", "fit time per frame (s)"),
)


def plot_prefit(table_path: str | Path, png_path: str | Path) -> Path:
    """Plot x, y, z, radius, index, alpha, R^2 and fit time against frame (``prefit.png``)."""
    return plot_table(table_path, png_path, PREFIT_PANELS, "holofit prefit", "prefit.csv")
