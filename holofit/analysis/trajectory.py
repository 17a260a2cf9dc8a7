"""A fit table as a regular time series: one slot per frame, gaps where a frame is missing."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from holofit.analysis.errors import AnalysisError
from holofit.tables.fit import AXIS_COLUMNS, POSITION_COLUMNS, FitTable

__all__ = ["Trajectory"]


@dataclass
class Trajectory:
    """Positions and axes on a regular frame grid.

    Attributes
    ----------
    frame_interval_s : float
        Time between frames, s.
    first_frame : int
        Frame number of slot 0.
    position_um : ndarray, shape (N, 3)
        ``(x, y, z)`` per frame, um; NaN in gaps.
    axis : ndarray, shape (N, 3) or None
        Unit symmetry axis per frame; NaN in gaps; None without orientation.
    valid : ndarray of bool, shape (N,)
        Frames with a successful fit.
    static : dict
        Static-parameter summaries of the table (median, std, count per column).
    source : str
        Where it came from.
    n_ambiguous : int
        Frames left out because the fit flagged them ``ambiguous``.
    """

    frame_interval_s: float
    first_frame: int
    position_um: NDArray[np.float64]
    axis: NDArray[np.float64] | None
    valid: NDArray[np.bool_]
    static: dict[str, dict[str, float]] = field(default_factory=dict)
    source: str = "<trajectory>"
    n_ambiguous: int = 0

    @property
    def n_frames(self) -> int:
        """Number of slots (first to last frame)."""
        return int(self.valid.size)

    @property
    def frames(self) -> NDArray[np.int64]:
        """Frame number of every slot."""
        return self.first_frame + np.arange(self.n_frames)

    @property
    def time_s(self) -> NDArray[np.float64]:
        """Time of every slot from the first frame, s."""
        return np.arange(self.n_frames, dtype=np.float64) * self.frame_interval_s

    @classmethod
    def from_arrays(
        cls,
        position_um: NDArray[np.float64],
        axis: NDArray[np.float64] | None,
        frame_interval_s: float,
        valid: NDArray[np.bool_] | None = None,
        static: dict[str, dict[str, float]] | None = None,
        source: str = "<arrays>",
    ) -> Trajectory:
        """Wrap arrays (one row per frame); rows with a non-finite value count as gaps."""
        pos = np.array(position_um, dtype=float)
        ok = np.all(np.isfinite(pos), axis=1)
        ax = None
        if axis is not None:
            ax = np.array(axis, dtype=float)
            ok &= np.all(np.isfinite(ax), axis=1)
        if valid is not None:
            ok &= np.asarray(valid, bool)
        pos[~ok] = np.nan
        if ax is not None:
            ax[~ok] = np.nan
        return cls(float(frame_interval_s), 0, pos, ax, ok, static or {}, source)

    @classmethod
    def from_fit_table(cls, fit: FitTable, drop_ambiguous: bool = False) -> Trajectory:
        """Place the ok rows of a validated fit table on the frame grid (without the rows
        flagged ``ambiguous`` if ``drop_ambiguous``)."""
        df = fit.table
        ok = fit.ok
        n_ambiguous = 0
        if drop_ambiguous and "ambiguous" in df.columns:
            amb = ok & (df["ambiguous"].fillna(0).to_numpy(dtype=float) > 0)
            n_ambiguous = int(amb.sum())
            ok = ok & ~amb
        frames = df["frame"].to_numpy()
        if not ok.any():
            raise AnalysisError(f"{fit.source}: no frame has status 'ok'")
        first, last = int(frames[ok].min()), int(frames[ok].max())
        n = last - first + 1
        pos = np.full((n, 3), np.nan)
        valid = np.zeros(n, bool)
        slots = frames[ok] - first
        if not all(c in df.columns for c in POSITION_COLUMNS):
            raise AnalysisError(f"{fit.source}: the analysis needs columns x_um, y_um, z_um")
        pos[slots] = df.loc[ok, list(POSITION_COLUMNS)].to_numpy(dtype=float)
        axis = None
        if fit.has_orientation:
            axis = np.full((n, 3), np.nan)
            axis[slots] = df.loc[ok, list(AXIS_COLUMNS)].to_numpy(dtype=float)
        valid[slots] = True
        return cls(fit.frame_interval_s, first, pos, axis, valid, fit.static_summary(), fit.source,
                   n_ambiguous)
