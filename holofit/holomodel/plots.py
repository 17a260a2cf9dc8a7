"""Pictures of fits: parameters against frame for a whole table, and data / model / residual
images of single frames (the first thing to look at when a fit looks wrong)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from holofit.io.atomic import atomic_path
from holofit.io.tables import read_table
from holofit.status import OK

__all__ = ["plot_frame_fit", "plot_table"]


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, png_path: str | Path, dpi: int = 90) -> Path:
    png_path = Path(png_path)
    with atomic_path(png_path) as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")
    _pyplot().close(fig)
    return png_path


def plot_table(table_path: str | Path, png_path: str | Path,
               panels: Sequence[tuple[str, str]], title: str, table_name: str | None = None
               ) -> Path:
    """Plot columns of a fit table against frame, ``ok`` rows in blue, the others as red x.

    Parameters
    ----------
    table_path : str or Path
        The table (CSV).
    png_path : str or Path
        Output PNG, written atomically.
    panels : sequence of (column, label)
        What to plot; columns missing from the table are skipped.
    title : str
        Figure title (the counts of ok and other rows are appended).
    table_name : str, optional
        The table's name in the title (default: ``table_path``'s; a stage drawing from the
        table before it is published gives the name it will have).
    """
    plt = _pyplot()
    table = read_table(table_path)
    panels = [(c, label) for c, label in panels if c in table.columns]
    ok = (table["status"] == OK).to_numpy()
    frame = table["frame"].to_numpy()
    n_rows = max((len(panels) + 1) // 2, 1)
    fig, axes = plt.subplots(n_rows, 2, figsize=(10, 2.2 * n_rows + 0.6), sharex=True,
                             squeeze=False)
    for ax, (col, label) in zip(axes.ravel(), panels, strict=False):
        values = table[col].to_numpy(dtype=float)
        ax.plot(frame[ok], values[ok], ".", ms=3, color="C0", label="ok")
        bad = ~ok & np.isfinite(values)
        if bad.any():
            ax.plot(frame[bad], values[bad], "x", ms=4, color="C3", label="not ok")
        ax.set_ylabel(label)
    for ax in axes.ravel()[len(panels):]:
        ax.set_visible(False)
    for ax in axes[-1]:
        ax.set_xlabel("frame")
    fig.suptitle(f"{title}: {int(ok.sum())} frame(s) ok, {int((~ok).sum())} not ok "
                 f"({table_name or Path(table_path).name})")
    fig.tight_layout()
    return _save(fig, png_path)


def plot_frame_fit(data: NDArray, model: NDArray, png_path: str | Path, title: str,
                   notes: Sequence[str] = ()) -> Path:
    """Data, model and residual images of one fitted crop, side by side.

    Parameters
    ----------
    data, model : ndarray, shape (rows, cols)
        Normalised crop and the fitted hologram on the same pixels (NaN where not fitted).
    png_path : str or Path
        Output PNG, written atomically.
    title : str
        Figure title (frame, status).
    notes : sequence of str
        Lines printed under the title (fitted values, R^2, chi^2).
    """
    plt = _pyplot()
    residual = data - model
    finite = np.isfinite(data)
    lo, hi = (np.nanpercentile(data[finite], [0.5, 99.5]) if finite.any() else (0.0, 2.0))
    span = float(np.nanmax(np.abs(residual))) if np.isfinite(residual).any() else 1.0
    fig, axes = plt.subplots(1, 3, figsize=(12, 4.4))
    for ax, img, name, kw in (
        (axes[0], data, "data", {"cmap": "gray", "vmin": lo, "vmax": hi}),
        (axes[1], model, "model", {"cmap": "gray", "vmin": lo, "vmax": hi}),
        (axes[2], residual, "data - model", {"cmap": "RdBu_r", "vmin": -span, "vmax": span}),
    ):
        im = ax.imshow(img, origin="upper", interpolation="nearest", **kw)
        ax.set_title(name)
        ax.set_xticks([])
        ax.set_yticks([])
        fig.colorbar(im, ax=ax, fraction=0.046, pad=0.03)
    fig.suptitle(title + ("\n" + "\n".join(notes) if notes else ""), fontsize=9)
    fig.tight_layout()
    return _save(fig, png_path)
