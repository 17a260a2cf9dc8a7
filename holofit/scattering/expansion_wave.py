"""A scattered wave known by its outgoing multipole expansion about the particle centre.

:class:`ExpansionWave` evaluates the expansion (:mod:`holofit.scattering.multipole`, lab frame)
outside ``NEAR_ZONE`` times the circumscribing radius (on a camera plane through the
interpolated multipole grid) and asks for the exact near field at points closer in. Every
engine whose wave has such an expansion derives from it: the T-matrix wave
(:class:`holofit.scattering.tmatrix_wave.TMatrixWave`), the built-in DDA's wave
(:class:`holofit.dda.engine.DDAWave`, near field by direct dipole sums) and the derivative waves
of a T-matrix. A subclass may build its expansion lazily by overriding :attr:`expansion`.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from holofit.cache import LRUCache
from holofit.conventions import incident_phase_at
from holofit.optics import Optics
from holofit.scattering.multipole import (
    NEAR_ZONE,
    MultipoleExpansion,
    PlaneGrid,
    evaluate_plane_at,
    plane_grid,
)
from holofit.scattering.theory import ScatteredWave

__all__ = ["NEAR_ZONE", "ExpansionWave", "NearField"]

#: ``points (N, 3) lab, relative to the centre -> field (N, 3)``, exact near the particle
NearField = Callable[[NDArray[np.float64]], NDArray[np.complex128]]


class ExpansionWave(ScatteredWave):
    """A field given by its outgoing expansion (lab frame) about the particle centre.

    Parameters
    ----------
    optics : Optics
        The illumination (for the wavenumber and the incident phase at the particle).
    expansion : MultipoleExpansion or None
        The field outside the circumscribing sphere; None for a subclass that builds it on first
        use (it overrides :attr:`expansion` and gives ``radius_um``).
    near_field : callable, optional
        Exact field at points within ``NEAR_ZONE * radius`` (lab, relative to the centre);
        without it (and without an override of ``_near_field``) such points raise
        ``ValueError``.
    radius_um : float, optional
        Circumscribing radius, um; default the expansion's.
    """

    exact_near_field = True

    def __init__(self, optics: Optics, expansion: MultipoleExpansion | None,
                 near_field: NearField | None = None, radius_um: float | None = None) -> None:
        self.optics = optics
        self._expansion = expansion
        if radius_um is None:
            if expansion is None:
                raise ValueError("an ExpansionWave built without its expansion needs radius_um")
            radius_um = expansion.radius_um
        self.radius_um = float(radius_um)
        self._near = near_field
        self._grids: LRUCache[tuple, PlaneGrid] = LRUCache(4)

    @property
    def expansion(self) -> MultipoleExpansion:
        """Outgoing multipole expansion about the particle centre (lab frame)."""
        assert self._expansion is not None, "a lazy ExpansionWave overrides `expansion`"
        return self._expansion

    def far_field_amplitude(self, directions: ArrayLike) -> NDArray[np.complex128]:
        """``F(n)`` (lab frame) at lab unit directions, ``E_sca = exp(ikr)/(-ikr) F``."""
        return -1j * self.expansion.far_amplitude(directions)

    def _near_field(self, points: NDArray) -> NDArray[np.complex128]:
        if self._near is None:
            raise ValueError(
                f"points within {NEAR_ZONE * self.radius_um:.3g} um of the particle centre need "
                "the dipoles; this wave only has its multipole expansion"
            )
        return self._near(points)

    def field_at(self, points_um: ArrayLike, far_field: bool = False) -> NDArray[np.complex128]:
        pts = np.atleast_2d(np.asarray(points_um, dtype=float))
        r = np.linalg.norm(pts, axis=1)
        if far_field:
            k = self.optics.k
            f = self.far_field_amplitude(pts / r[:, None])
            return f * (np.exp(1j * k * r) / (-1j * k * r))[:, None]
        out = np.empty((pts.shape[0], 3), dtype=complex)
        near = r < NEAR_ZONE * self.radius_um
        if np.any(near):
            out[near] = self._near_field(pts[near])
        if np.any(~near):
            out[~near] = self.expansion.field_at(pts[~near])
        return out

    def _plane_grid(self, z_p: float, delta_max: float, far: bool) -> PlaneGrid:
        key = (z_p, far)
        grid = self._grids.get(key)
        if grid is None or grid.delta_max < delta_max:
            margin = min(0.03 * delta_max + 0.01, 0.5 * (np.pi / 2 - delta_max))
            grid = self._grids.put(key, plane_grid(self.expansion, z_p, delta_max + margin, far))
        return grid

    def _pixel_geometry(self, position_um: ArrayLike, xs_um: ArrayLike, ys_um: ArrayLike,
                        far_field: bool) -> tuple:
        """Offsets, height, widest angle, incident phase and near-zone mask of the pixels."""
        xp, yp, zp = (float(v) for v in np.asarray(position_um, dtype=float))
        dx = np.asarray(xs_um, dtype=float).ravel() - xp
        dy = np.asarray(ys_um, dtype=float).ravel() - yp
        rho_max = float(np.sqrt(np.max(dx * dx + dy * dy))) if dx.size else 0.0
        delta_max = float(np.arctan2(rho_max, abs(zp)))
        phase = complex(incident_phase_at(zp, self.optics.k))
        skip = None
        if not far_field and abs(zp) < NEAR_ZONE * self.radius_um:
            skip = dx * dx + dy * dy + zp * zp < (NEAR_ZONE * self.radius_um) ** 2
        return dx, dy, zp, delta_max, phase, skip

    def _fill_near(self, ex: NDArray, ey: NDArray, dx: NDArray, dy: NDArray, zp: float,
                   phase: complex, skip: NDArray | None) -> None:
        if skip is not None and np.any(skip):
            idx = np.flatnonzero(skip)
            pts = np.column_stack([dx[idx], dy[idx], np.full(idx.size, -zp)])
            e = self._near_field(pts) * phase
            ex[idx] = e[:, 0]
            ey[idx] = e[:, 1]

    def field_on_pixels(
        self, position_um: ArrayLike, xs_um: ArrayLike, ys_um: ArrayLike, far_field: bool = False
    ) -> tuple[NDArray[np.complex128], NDArray[np.complex128]]:
        """Transverse field at pixel centres, incident phase included: the interpolated
        multipole grid of the camera plane, the near-field callable for pixels within the near
        zone."""
        dx, dy, zp, delta_max, phase, skip = self._pixel_geometry(position_um, xs_um, ys_um,
                                                                  far_field)
        if dx.size == 0:
            return np.zeros(0, dtype=complex), np.zeros(0, dtype=complex)
        pg = self._plane_grid(zp, delta_max, far_field)
        ex, ey = evaluate_plane_at(pg, dx, dy, phase, skip)
        self._fill_near(ex, ey, dx, dy, zp, phase, skip)
        return ex, ey
