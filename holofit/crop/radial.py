"""Sub-pixel hologram centres from circular symmetry, for centres near the frame's edge.

Point symmetry (:mod:`holofit.crop.symmetry`) needs both pixels of a pair inside the frame;
within ~10 px of an edge the only pairs left lie in a thin strip along the edge, which pins the
centre along the edge but hardly across it. The rings themselves still cover a half-disc there.
This module finds the centre whose rings are most circular: the point ``m`` that minimises the
*radial variance*

    V(m) = sum_pixels (f - <f>_ring(m))^2 / N ,

the scatter of the intensity about its mean on quarter-pixel-wide rings around ``m`` (pixels
within ``radius`` of ``m``, valid ones only). ``V`` is evaluated on a grid of trial centres,
coarse then fine (~130 trial centres), and a quadratic fit to its
minimum gives the sub-pixel centre. Rings must be circular: for elongated holograms (tilted
rods) the point-symmetry centre is the better one, which is why this is the edge fallback.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from holofit.crop.symmetry import quadratic_peak

__all__ = ["RadialFit", "radial_variance", "refine_center_radial"]

#: Ring width is 1 / BINS_PER_PX pixels: finer rings leave less of the intensity slope inside a
#: ring, which matters where only part of each ring is in the frame.
BINS_PER_PX = 4


@dataclass(frozen=True)
class RadialFit:
    """Result of :func:`refine_center_radial` (full-frame pixels; ``converged``: the minimum
    lies inside the searched area)."""

    x_px: float
    y_px: float
    converged: bool


def radial_variance(
    values: NDArray, cols: NDArray, rows: NDArray, x: float, y: float, radius: float
) -> float:
    """Mean squared deviation of ``values`` from their ring means around ``(x, y)``.

    Parameters
    ----------
    values, cols, rows : ndarray, 1-D
        Pixel values and their full-frame column and row indices.
    x, y : float
        Trial centre, full-frame pixels.
    radius : float
        Pixels farther than this from the trial centre are left out, pixels.
    """
    r = np.hypot(cols - x, rows - y)
    inside = r < radius
    ring = (r[inside] * BINS_PER_PX).astype(np.intp)
    v = values[inside]
    n = np.bincount(ring)
    s1 = np.bincount(ring, v)
    s2 = np.bincount(ring, v * v)
    used = n > 0
    return float(np.sum(s2[used] - s1[used] ** 2 / n[used]) / max(int(inside.sum()), 1))


def _grid_minimum(
    values: NDArray,
    cols: NDArray,
    rows: NDArray,
    x0: float,
    y0: float,
    radius: float,
    reach: float,
    step: float,
) -> tuple[float, float, bool]:
    offsets = np.arange(-reach, reach + 0.5 * step, step)
    table = np.array(
        [
            [radial_variance(values, cols, rows, x0 + dx, y0 + dy, radius) for dx in offsets]
            for dy in offsets
        ]
    )
    i, j = np.unravel_index(int(np.argmin(table)), table.shape)
    di, dj = quadratic_peak(-table, int(i), int(j))
    interior = 0 < i < len(offsets) - 1 and 0 < j < len(offsets) - 1
    return (float(x0 + (offsets[j] + dj * step)), float(y0 + (offsets[i] + di * step)),
            bool(interior))


def refine_center_radial(
    image: NDArray,
    x0: float,
    y0: float,
    *,
    valid: NDArray | None = None,
    radius: float = 60.0,
    reach: float = 3.0,
    max_iterations: int = 3,
) -> RadialFit:
    """Refine a hologram centre by making its rings as circular as possible.

    Parameters
    ----------
    image : ndarray, shape (rows, cols)
        Normalised hologram (non-finite pixels are ignored).
    x0, y0 : float
        Starting centre, full-frame pixels (x = column, y = row).
    valid : ndarray of bool, optional
        False marks pixels to ignore.
    radius : float
        Rings out to this radius are used, pixels.
    reach : float
        Trial centres within this distance (per axis) of the start, 1 px apart, then 0.25 px
        apart within 1 px of the best; the coarse grid is re-centred up to ``max_iterations``
        times if the best lies on its border.
    max_iterations : int
        Most coarse grids.

    Returns
    -------
    RadialFit
    """
    rows_n, cols_n = image.shape
    span = radius + reach * max_iterations + 2
    i0, i1 = max(int(y0 - span), 0), min(int(y0 + span) + 1, rows_n)
    j0, j1 = max(int(x0 - span), 0), min(int(x0 + span) + 1, cols_n)
    if i0 >= i1 or j0 >= j1:
        return RadialFit(float(x0), float(y0), False)
    block = np.asarray(image[i0:i1, j0:j1], dtype=np.float64)
    ok = np.isfinite(block)
    if valid is not None:
        ok &= np.asarray(valid[i0:i1, j0:j1], dtype=bool)
    rows, cols = np.nonzero(ok)
    if rows.size < 50:
        return RadialFit(float(x0), float(y0), False)
    values = block[ok]
    rows = (rows + i0).astype(np.float64)
    cols = (cols + j0).astype(np.float64)
    x, y, interior = float(x0), float(y0), False
    for _ in range(max_iterations):
        x, y, interior = _grid_minimum(values, cols, rows, x, y, radius, reach, 1.0)
        if interior:
            break
    if not interior:
        return RadialFit(x, y, False)
    x, y, interior = _grid_minimum(values, cols, rows, x, y, radius, 1.0, 0.25)
    return RadialFit(x, y, interior)
