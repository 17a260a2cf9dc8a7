"""The objective's numerical aperture in a fit: the instrument's, another one, none, or fitted.

A fit images its model through the objective of the instrument (:mod:`holofit.scattering.lens`)
when the instrument has a ``numerical_aperture``, and uses the ideal model (the field in the
focal plane itself) when it has none. A stage can replace that NA (another value, or none:
:mod:`holofit.batch.aperture`) and
can fit it, starting from the NA in force. A fitted NA starts at most at the medium's index:
beyond it the lens collects every propagating wave and the hologram no longer changes.

The hologram does not change smoothly with the NA alone: the hard edge of the pupil sends a
weak diffracted wave over the whole image (the rings of the objective's point-spread
function), whose phase turns with the aperture angle, so the misfit as a function of NA has a
local minimum every few hundredths of NA. A local optimiser started anywhere stays in the
nearest one; :func:`scan_aperture` therefore looks over a grid of NAs (every other parameter
held) for the best starts of the fit, and :func:`aperture_minima` picks its few deepest local
minima: with the other parameters held the scan ranks them, but once those are fitted again
the order can change, so each is fitted (docs: validation, "the lens in the fits").
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from holofit.holomodel.forward import HologramModel, InvalidParameters
from holofit.holomodel.parameters import APERTURE
from holofit.optics import Optics

__all__ = [
    "aperture_minima",
    "aperture_start",
    "scan_aperture",
]

#: the grid :func:`scan_aperture` looks over: from this NA up to the medium's index
SCAN_LOWEST = 0.2
#: ... in steps of this (the misfit's local minima are 0.03-0.06 apart)
SCAN_STEP = 0.01
#: the scan looks at most at this many pixels (an evenly spread subset of larger crops)
SCAN_PIXELS = 20000
#: the scan's deepest local minima that are each fitted
MAX_STARTS = 3

def aperture_start(optics: Optics) -> float:
    """Start value of a fitted NA: the optics' NA, at most the medium's index.

    Raises
    ------
    ValueError
        If the optics have no NA.
    """
    if optics.numerical_aperture is None:
        raise ValueError("fitting the numerical aperture needs a start value: the optics have "
                         "no numerical_aperture")
    return float(min(optics.numerical_aperture, optics.n_medium))


def scan_aperture(model: HologramModel, data: NDArray[np.float64], vector: NDArray[np.float64],
                  lowest: float = SCAN_LOWEST, step: float = SCAN_STEP,
                  max_pixels: int = SCAN_PIXELS
                  ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """The start vector with the NA of least misfit on a grid, every other parameter held.

    Parameters
    ----------
    model : HologramModel
        A forward model whose parameters include ``numerical_aperture``.
    data : ndarray, shape (N,)
        The data on the model's pixels.
    vector : ndarray
        The start (the other parameters' values are kept).
    lowest, step : float
        The grid: ``lowest, lowest + step, ...`` up to the medium's index, and the start's
        own NA.
    max_pixels : int
        Larger pixel sets are scanned on every k-th pixel (at most this many).

    Returns
    -------
    best : ndarray
        ``vector`` with the best NA of the grid.
    grid, rss : ndarray
        The NAs tried and their residual sums of squares (inf where invalid; scaled to all
        pixels when a subset was scanned).
    """
    names = model.space.names
    if APERTURE.name not in names:
        return np.asarray(vector, dtype=float), np.empty(0), np.empty(0)
    i = names.index(APERTURE.name)
    v = np.asarray(vector, dtype=float)
    top = model.optics.n_medium
    grid = np.unique(np.concatenate([np.arange(lowest, top, step), [top, min(v[i], top)]]))
    stride = -(-model.n_pixels // max_pixels)  # ceil
    scan, d = model, np.asarray(data, dtype=float)
    if stride > 1:
        every = np.arange(0, model.n_pixels, stride)
        scan, d = model.restricted(every), d[every]
    rss = np.full(grid.size, np.inf)
    for j, na in enumerate(grid):
        q = v.copy()
        q[i] = na
        try:
            r = scan.hologram(q) - d
        except InvalidParameters:
            continue
        rss[j] = float(r @ r) * stride
    model.n_holograms += scan.n_holograms if scan is not model else 0
    best = v.copy()
    if np.isfinite(rss).any():
        best[i] = grid[int(np.argmin(rss))]
    return best, grid, rss


def aperture_minima(grid: NDArray[np.float64], rss: NDArray[np.float64],
                    limit: int = MAX_STARTS) -> list[float]:
    """The NAs of a scan's deepest local minima, best first (empty if none was valid).

    Parameters
    ----------
    grid, rss : ndarray
        The scan (:func:`scan_aperture`).
    limit : int
        Most minima returned.
    """
    ok = np.isfinite(rss)
    if not ok.any():
        return []
    r = np.where(ok, rss, np.inf)
    left = np.concatenate([[np.inf], r[:-1]])
    right = np.concatenate([r[1:], [np.inf]])
    minima = np.flatnonzero((r <= left) & (r <= right) & ok)
    minima = minima[np.argsort(r[minima], kind="stable")]
    return [float(grid[i]) for i in minima[:limit]]
