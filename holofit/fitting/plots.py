"""Summary plot of a prefit table: what a person looks at before the DDA stages."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from holofit.io.atomic import atomic_path
from holofit.io.tables import read_table

__all__ = ["plot_prefit"]


def plot_prefit(table_path: str | Path, png_path: str | Path) -> Path:
    """Plot x, y, z, radius, index, alpha and R^2 against frame (failed frames in red).

    Parameters
    ----------
    table_path : str or Path
        ``prefit.csv``.
    png_path : str or Path
        Output PNG, written atomically.

    Returns
    -------
    Path
        The PNG.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    table = read_table(table_path)
    ok = (table["status"] == "ok").to_numpy()
    frame = table["frame"].to_numpy()
    panels = [
        ("x_um", "x (um)"),
        ("y_um", "y (um)"),
        ("z_um", "z (um)"),
        ("radius_um", "radius (um)"),
        ("index", "index"),
        ("alpha", "alpha"),
        ("r2", "R^2"),
        ("fit_time_s", "fit time per frame (s)"),
    ]
    fig, axes = plt.subplots(4, 2, figsize=(10, 9), sharex=True)
    for ax, (col, label) in zip(axes.ravel(), panels, strict=True):
        values = table[col].to_numpy(dtype=float)
        ax.plot(frame[ok], values[ok], ".", ms=3, color="C0", label="ok")
        bad = ~ok & np.isfinite(values)
        if bad.any():
            ax.plot(frame[bad], values[bad], "x", ms=4, color="C3", label="not ok")
        ax.set_ylabel(label)
    for ax in axes[-1]:
        ax.set_xlabel("frame")
    n_bad = int((~ok).sum())
    fig.suptitle(f"holofit prefit: {ok.sum()} frame(s) ok, {n_bad} not ok  ({Path(table_path)})")
    fig.tight_layout()
    png_path = Path(png_path)
    with atomic_path(png_path) as tmp:
        fig.savefig(tmp, dpi=90, format="png")
    plt.close(fig)
    return png_path
