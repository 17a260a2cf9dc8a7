"""Scattered waves served from a T-matrix: fields, holograms and exact orientation derivatives.

:class:`TMatrixWave` is an :class:`~holofit.scattering.expansion_wave.ExpansionWave` (a field
known by its outgoing multipole expansion about the particle centre), the wave of
one orientation (``o_lab = D T D^H a``, :mod:`holofit.scattering.tmatrix`); its
:meth:`~TMatrixWave.orientation_derivative` is again an :class:`ExpansionWave`, whose "field" is
the exact derivative of the scattered field with respect to one Euler angle (the expansion is
linear in its coefficients), so

    wave = theory.solve(model, optics, orientation)      # TMatrixWave
    e_x, e_y = wave.field_on_pixels(position, xs, ys)
    de_x, de_y = wave.orientation_derivative("theta").field_on_pixels(position, xs, ys)
    dr_x, dr_y = wave.rotation_derivative(axis).field_on_pixels(position, xs, ys)

gives the scattered field, its derivative with respect to the Euler angle theta, and its
derivative with respect to a rotation of the particle about a lab axis (``R -> exp(eps [axis]x)
R``, what :class:`holofit.holomodel.forward.HologramModel` uses), all per radian, incident phase
included, with the same conventions as every
:class:`~holofit.scattering.theory.ScatteredWave` (``field_on_detector`` and ``field_at`` too).
``wave.field_and_rotation_derivatives(position, xs, ys, axes)`` gives the field and the
rotation derivatives for several axes in one pass over the pixels (a fit's Jacobian columns:
cheaper than separate calls, which each pass over the pixels again).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from holofit.conventions import euler_zyz, euler_zyz_from_matrix
from holofit.optics import Optics
from holofit.particles import ParticleModel
from holofit.scattering.expansion_wave import ExpansionWave, NearField
from holofit.scattering.multipole import (
    evaluate_planes_at,
    plane_grid,
)
from holofit.scattering.theory import Orientation, ScatteredWave
from holofit.scattering.tmatrix import LabCoefficients, TMatrix
from holofit.scattering.vsw import pack
from holofit.scattering.wigner import EULER_ANGLES

__all__ = ["ExpansionWave", "NearField", "TMatrixWave"]  # the first two re-exported

#: step of the central differences that give derivatives of the near field, rad
NEAR_DERIVATIVE_STEP = 1e-4


class TMatrixWave(ExpansionWave):
    """The scattered wave of one orientation, from the particle's T-matrix.

    Parameters
    ----------
    model : ParticleModel
        The particle.
    optics : Optics
        The illumination.
    orientation : Orientation
        zyz Euler angles.
    tmatrix : TMatrix
        The particle's T-matrix (same model, lattice, optics and polarisability).
    direct : callable, optional
        ``orientation -> ScatteredWave`` by a direct DDA solve, used (lazily) for points within
        ``NEAR_ZONE`` circumscribing radii of the centre, where the expansion is not used.
    """

    def __init__(self, model: ParticleModel, optics: Optics, orientation: Orientation,
                 tmatrix: TMatrix,
                 direct: Callable[[Orientation], ScatteredWave] | None = None) -> None:
        self.model = model
        self.orientation = orientation
        self.tmatrix = tmatrix
        self.rotation = euler_zyz(*orientation.as_tuple())
        self._direct = direct
        self._direct_wave: ScatteredWave | None = None
        self._coefficients: LabCoefficients | None = None
        self._generators: NDArray[np.complex128] | None = None
        coeffs = tmatrix.lab_coefficients(orientation.as_tuple(), optics.polarization)
        super().__init__(optics, tmatrix.expansion(coeffs.vector),
                         self._direct_near if direct is not None else None)

    @property
    def coefficients(self) -> NDArray[np.complex128]:
        """Flat lab-frame outgoing coefficients (:mod:`holofit.scattering.vsw` layout)."""
        return pack(self.expansion.p, self.expansion.q)

    def _direct_near(self, points: NDArray) -> NDArray[np.complex128]:
        if self._direct_wave is None:
            assert self._direct is not None
            self._direct_wave = self._direct(self.orientation)
        return self._direct_wave.field_at(points)

    def coefficient_derivatives(self) -> dict[str, NDArray[np.complex128]]:
        """Exact derivatives of the lab outgoing coefficients with respect to ``psi``,
        ``theta``, ``phi`` (1/rad), from the Wigner-d derivatives (no solve)."""
        if self._coefficients is None:
            self._coefficients = self.tmatrix.lab_coefficients(
                self.orientation.as_tuple(), self.optics.polarization, derivatives=True)
        return self._coefficients.derivatives

    def orientation_derivative(self, angle: str) -> ExpansionWave:
        """The derivative of this wave with respect to one Euler angle, as a wave.

        Parameters
        ----------
        angle : {"psi", "theta", "phi"}
            The zyz Euler angle (:class:`~holofit.scattering.theory.Orientation`).

        Returns
        -------
        ExpansionWave
            Its ``field_on_detector``, ``field_at`` and ``far_field_amplitude`` give the exact
            derivatives (per radian) of this wave's. Near the particle (within ``NEAR_ZONE``
            radii) the derivative comes from central differences of direct solves.
        """
        if angle not in EULER_ANGLES:
            raise ValueError(f"orientation angle must be one of {EULER_ANGLES}, got {angle!r}")
        vec = self.coefficient_derivatives()[angle]
        near = None
        if self._direct is not None:
            near = self._near_derivative(angle)
        return ExpansionWave(self.optics, self.tmatrix.expansion(vec), near)

    def rotation_derivative(self, axis: ArrayLike) -> ExpansionWave:
        """The derivative of this wave with respect to a rotation of the particle about a lab
        axis, ``R -> exp(eps [axis]x) R`` at ``eps = 0``, as a wave (per radian; ``axis`` is
        normalised). Exact from the generator of rotations (no solve); near the particle,
        central differences of direct solves."""
        n = np.asarray(axis, dtype=float)
        n = n / np.linalg.norm(n)
        if self._generators is None:  # lab x, y, z: any axis is their combination
            self._generators = self.tmatrix.rotation_derivatives(self.orientation.as_tuple(),
                                                                 self.optics.polarization)
        vec = self._generators @ n
        near = None
        if self._direct is not None:
            near = self._near_rotation_derivative(n)
        return ExpansionWave(self.optics, self.tmatrix.expansion(vec), near)

    def field_and_rotation_derivatives(
        self, position_um: ArrayLike, xs_um: ArrayLike, ys_um: ArrayLike,
        axes: Sequence[ArrayLike], far_field: bool = False,
    ) -> tuple[tuple[NDArray, NDArray], list[tuple[NDArray, NDArray]]]:
        """The transverse field at pixel centres and its derivatives with respect to rotations
        about each lab axis (as :meth:`rotation_derivative`), in one pass over the pixels.

        Equal to ``field_on_pixels`` and ``rotation_derivative(axis).field_on_pixels`` for each
        axis; the pixels' angles, interpolation weights and ``exp(ikr)/kr`` are computed once
        for all of them. Returns ``((e_x, e_y), [(de_x, de_y) per axis])``.
        """
        dx, dy, zp, delta_max, phase, skip = self._pixel_geometry(position_um, xs_um, ys_um,
                                                                  far_field)
        waves = [self.rotation_derivative(axis) for axis in axes]
        if dx.size == 0:
            empty = (np.zeros(0, dtype=complex), np.zeros(0, dtype=complex))
            return empty, [empty for _ in waves]
        pg = self._plane_grid(zp, delta_max, far_field)
        grids = [pg] + [plane_grid(w.expansion, zp, pg.delta_max, far_field) for w in waves]
        fields = evaluate_planes_at(grids, dx, dy, phase, skip)
        for wave, (ex, ey) in zip([self, *waves], fields, strict=True):
            wave._fill_near(ex, ey, dx, dy, zp, phase, skip)
        return fields[0], fields[1:]

    def _near_rotation_derivative(self, axis: NDArray) -> NearField:
        direct = self._direct
        assert direct is not None
        h = NEAR_DERIVATIVE_STEP
        kx = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]],
                       [-axis[1], axis[0], 0.0]])

        def field(points: NDArray) -> NDArray[np.complex128]:
            out = []
            for sign in (1.0, -1.0):
                a = sign * h
                rot = np.eye(3) + np.sin(a) * kx + (1.0 - np.cos(a)) * (kx @ kx)
                angles = (float(v) for v in euler_zyz_from_matrix(rot @ self.rotation))
                out.append(direct(Orientation(*angles)).field_at(points))
            return (out[0] - out[1]) / (2 * h)

        return field

    def _near_derivative(self, angle: str) -> NearField:
        direct = self._direct
        assert direct is not None
        h = NEAR_DERIVATIVE_STEP
        j = EULER_ANGLES.index(angle)

        def field(points: NDArray) -> NDArray[np.complex128]:
            values = list(self.orientation.as_tuple())
            out = []
            for sign in (1.0, -1.0):
                shifted = values.copy()
                shifted[j] += sign * h
                out.append(direct(Orientation(*shifted)).field_at(points))
            return (out[0] - out[1]) / (2 * h)

        return field
