"""Polar sampling of a crop about a centre: the frame in which turning the particle about the
optical axis is a cyclic shift.

Samples sit at radii ``rho_i = (i + 1/2) * step`` (one pixel apart by default) and
``n_phi`` equally spaced azimuths ``phi_j = 2 pi j / n_phi`` (phi from lab x toward lab y, as
``psi``); each sample stands for the area ``rho_i * step * 2 pi / n_phi``, so weighted sums
over the samples approximate sums over the crop's pixels within the largest inscribed circle.
Values come from bilinear interpolation of the crop; a sample touching a NaN pixel gets weight
zero.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["PolarGrid", "polar_grid", "sample_crop"]


@dataclass(frozen=True)
class PolarGrid:
    """Polar sample points about a centre.

    Attributes
    ----------
    rho_um : ndarray, shape (n_rho,)
        Radii, um.
    phi : ndarray, shape (n_phi,)
        Azimuths, rad.
    xs_um, ys_um : ndarray, shape (n_rho, n_phi)
        Full-frame coordinates of the samples, um.
    area_um2 : ndarray, shape (n_rho, 1)
        Area each sample stands for, um^2.
    """

    rho_um: NDArray[np.float64]
    phi: NDArray[np.float64]
    xs_um: NDArray[np.float64]
    ys_um: NDArray[np.float64]
    area_um2: NDArray[np.float64]

    @property
    def shape(self) -> tuple[int, int]:
        return (self.rho_um.size, self.phi.size)


def polar_grid(centre_xy_um: tuple[float, float], rho_max_um: float, step_um: float,
               n_phi: int) -> PolarGrid:
    """Samples about ``centre_xy_um`` out to ``rho_max_um`` every ``step_um``, ``n_phi``
    azimuths."""
    if n_phi < 8 or rho_max_um <= step_um:
        raise ValueError(f"polar grid needs n_phi >= 8 and rho_max > step, got {n_phi}, "
                         f"{rho_max_um}, {step_um}")
    n_rho = int(np.floor(rho_max_um / step_um))
    rho = (np.arange(n_rho, dtype=float) + 0.5) * step_um
    phi = 2.0 * np.pi * np.arange(n_phi) / n_phi
    xs = centre_xy_um[0] + rho[:, None] * np.cos(phi)[None, :]
    ys = centre_xy_um[1] + rho[:, None] * np.sin(phi)[None, :]
    area = (rho * step_um * 2.0 * np.pi / n_phi)[:, None]
    return PolarGrid(rho, phi, xs, ys, area)


def sample_crop(crop: NDArray, corner_rc: tuple[int, int], pixel_size_um: float,
                grid: PolarGrid) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Bilinear samples of ``crop`` at the grid points, and their weights.

    Returns
    -------
    values : ndarray, shape ``grid.shape``
        Interpolated intensities (0 where the weight is 0).
    weights : ndarray, shape ``grid.shape``
        The samples' areas, 0 where a neighbouring pixel is NaN or outside the crop.
    """
    data = np.asarray(crop, dtype=float)
    rows, cols = data.shape
    r = grid.ys_um / pixel_size_um - corner_rc[0]
    c = grid.xs_um / pixel_size_um - corner_rc[1]
    r0 = np.floor(r).astype(int)
    c0 = np.floor(c).astype(int)
    fr, fc = r - r0, c - c0
    inside = (r0 >= 0) & (c0 >= 0) & (r0 + 1 < rows) & (c0 + 1 < cols)
    r0c, c0c = np.clip(r0, 0, rows - 2), np.clip(c0, 0, cols - 2)
    v00 = data[r0c, c0c]
    v01 = data[r0c, c0c + 1]
    v10 = data[r0c + 1, c0c]
    v11 = data[r0c + 1, c0c + 1]
    values = ((1 - fr) * ((1 - fc) * v00 + fc * v01) + fr * ((1 - fc) * v10 + fc * v11))
    good = inside & np.isfinite(values)
    weights = np.where(good, np.broadcast_to(grid.area_um2, values.shape), 0.0)
    return np.where(good, values, 0.0), weights
