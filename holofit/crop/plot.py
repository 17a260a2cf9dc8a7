"""Overview figure of a crop run: where the particle is, what its crop looks like, how the
detection went frame by frame."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from holofit.io.atomic import atomic_path
from holofit.status import (
    CROP_EDGE,
    CROP_ERROR,
    CROP_NO_PARTICLE,
    CROP_OFF_TRACK,
    CROP_OK,
    FITTABLE_CROP_STATUSES,
)

__all__ = ["plot_overview"]

_STATUS_COLOURS = {CROP_OK: "tab:blue", CROP_EDGE: "tab:orange",
                   CROP_NO_PARTICLE: "tab:grey", CROP_ERROR: "tab:red",
                   CROP_OFF_TRACK: "tab:purple"}


def plot_overview(
    path: str | Path,
    preview: dict[str, Any],
    frames: pd.DataFrame,
    candidates: pd.DataFrame,
    size: int,
) -> Path:
    """Write a PNG with four panels.

    (a) the first frame with a particle, normalised, with its candidates (circles), the crop
    (square) and the whole track; (b) that crop; (c) x and y of the centre against frame;
    (d) detection score against frame, coloured by status.

    Parameters
    ----------
    path : str or Path
        PNG to write (atomically).
    preview : dict
        ``frame`` (index), ``image`` (normalised frame), ``corner`` (crop corner).
    frames : pandas.DataFrame
        The per-frame crop table.
    candidates : pandas.DataFrame
        All candidates.
    size : int
        Crop side, pixels.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    k = int(preview["frame"])
    tracks = (list(frames.groupby("particle")) if "particle" in frames.columns
              else [(0, frames)])
    fig, axes = plt.subplots(2, 2, figsize=(11, 9), constrained_layout=True)
    _frame_panel(axes[0, 0], preview, candidates[candidates["frame"] == k], tracks, size)
    _crop_panel(axes[0, 1], preview, frames, size)
    _centre_panel(axes[1, 0], tracks)
    _score_panel(axes[1, 1], frames)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=90, format="png")
    plt.close(fig)
    return path


def _frame_panel(ax: Any, preview: dict[str, Any], here: pd.DataFrame,
                 tracks: list[tuple[Any, pd.DataFrame]], size: int) -> None:
    """(a) the normalised frame, its candidates (circles), the crop (square), every track."""
    from matplotlib.patches import Rectangle

    image, k = preview["image"], int(preview["frame"])
    row0, col0 = preview["corner"]
    finite = image[np.isfinite(image)]
    lo, hi = np.percentile(finite, [1, 99]) if finite.size else (0.0, 2.0)
    ax.imshow(image, cmap="gray", vmin=lo, vmax=hi, interpolation="nearest")
    ax.scatter(here["x_px"], here["y_px"], s=120, facecolors="none", edgecolors="yellow",
               label="candidates")  # fmt: skip
    for i, (p, track) in enumerate(tracks):
        ax.plot(track["x_px"], track["y_px"], "-", color="tab:cyan", lw=1,
                label="track" if len(tracks) == 1 else ("tracks" if i == 0 else None))
        if len(tracks) > 1 and track["x_px"].notna().any():
            first = track[track["x_px"].notna()].iloc[0]
            ax.annotate(str(p), (first["x_px"], first["y_px"]), color="tab:cyan",
                        xytext=(6, 6), textcoords="offset points", fontsize=9)
    ax.add_patch(Rectangle((col0 - 0.5, row0 - 0.5), size, size, fill=False, ec="tab:red"))
    ax.set_title(f"frame {k}, normalised; crop {size} x {size}")
    ax.set_xlabel("x (column), px")
    ax.set_ylabel("y (row), px")
    ax.legend(loc="upper right", fontsize=8)


def _crop_panel(ax: Any, preview: dict[str, Any], frames: pd.DataFrame, size: int) -> None:
    """(b) the crop of the preview frame, with the centres inside it."""
    image, k = preview["image"], int(preview["frame"])
    row0, col0 = preview["corner"]
    crop = image[row0 : row0 + size, col0 : col0 + size]
    ax.imshow(crop, cmap="gray", interpolation="nearest",
              extent=(col0 - 0.5, col0 + size - 0.5, row0 + size - 0.5, row0 - 0.5))  # fmt: skip
    sel = frames.loc[(frames["frame"] == k) & frames["x_px"].between(col0, col0 + size - 1)
                     & frames["y_px"].between(row0, row0 + size - 1)]
    ax.plot(sel["x_px"], sel["y_px"], "+", color="tab:red", ms=14)
    ax.set_title(f"crop of frame {k} (+ = centre)")
    ax.set_xlabel("x (column), px")
    ax.set_ylabel("y (row), px")


def _centre_panel(ax: Any, tracks: list[tuple[Any, pd.DataFrame]]) -> None:
    """(c) x and y of every track's centre against frame."""
    for i, (_, track) in enumerate(tracks):
        ax.plot(track["frame"], track["x_px"], ".-", ms=3, color="tab:blue",
                label="x (column)" if i == 0 else None)
        ax.plot(track["frame"], track["y_px"], ".-", ms=3, color="tab:orange",
                label="y (row)" if i == 0 else None)
    ax.set_xlabel("frame")
    ax.set_ylabel("centre, px")
    ax.legend(fontsize=8)


def _score_panel(ax: Any, frames: pd.DataFrame) -> None:
    """(d) detection score against frame, coloured by status."""
    for status, colour in _STATUS_COLOURS.items():
        part = frames[frames["status"] == status]
        if len(part):
            scored = status in FITTABLE_CROP_STATUSES
            y = part["score"].fillna(1.0) if scored else np.ones(len(part))
            ax.scatter(part["frame"], y, s=8, color=colour, label=f"{status} ({len(part)})")
    ax.set_yscale("log")
    ax.set_xlabel("frame")
    ax.set_ylabel("detection score")
    ax.legend(fontsize=8)
