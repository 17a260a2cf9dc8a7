"""Residuals and Jacobian of the exact Lorenz-Mie hologram of a sphere on a set of pixels.

Parameters, in this order (:data:`SPHERE_PARAMETERS`): full-frame position ``x_um, y_um,
z_um`` (um), ``radius_um`` (um), real ``index`` (absolute), and the scattered-field scaling
``alpha``. Any subset can be held fixed.

The Jacobian is exact for alpha (``dI/dalpha = 2 Re[(e_pol + alpha E) . E*]``) and uses
one-sided finite differences for the others, one hologram each, with the solved sphere reused
for the position columns (a position change moves the field, not the sphere). Each new
``(radius, index)`` costs one Lorenz-Mie solve (~0.1 ms), cached.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from holofit.fitting.mie_pixels import mie_field_on_pixels
from holofit.models import Sphere
from holofit.optics import Optics
from holofit.scattering.mie import MieWave

__all__ = ["FD_STEPS", "SPHERE_PARAMETERS", "InvalidParameters", "SphereResiduals"]

SPHERE_PARAMETERS: tuple[str, ...] = ("x_um", "y_um", "z_um", "radius_um", "index", "alpha")

#: finite-difference steps (um for lengths; index and alpha are dimensionless)
FD_STEPS: NDArray[np.float64] = np.array([1e-5, 1e-5, 1e-5, 1e-5, 1e-5, 1e-5])


class InvalidParameters(ValueError):
    """The parameters describe no valid hologram (negative radius, detector inside sphere)."""


@dataclass
class _Eval:
    key: tuple[float, ...]
    ex: NDArray[np.complex128]
    ey: NDArray[np.complex128]
    model: NDArray[np.float64]


class SphereResiduals:
    """``model - data`` of a sphere hologram on chosen pixels, and its Jacobian.

    Parameters
    ----------
    data : ndarray, shape (N,)
        Normalised intensities of the pixels used.
    xs_um, ys_um : ndarray, shape (N,)
        Full-frame sample-plane coordinates of those pixels, um.
    optics : Optics
        Illumination.
    free : sequence of bool, length 6
        Which of :data:`SPHERE_PARAMETERS` vary.
    fixed : array_like, length 6
        Values of all parameters; the free ones are overwritten by the optimiser's vector.
    index_imag : float
        Imaginary part of the index (held fixed; >= 0).
    """

    def __init__(
        self,
        data: NDArray[np.float64],
        xs_um: NDArray[np.float64],
        ys_um: NDArray[np.float64],
        optics: Optics,
        free: tuple[bool, ...] = (True,) * 6,
        fixed: NDArray[np.float64] | None = None,
        index_imag: float = 0.0,
    ) -> None:
        self.data = np.ascontiguousarray(data, dtype=float)
        self.xs = np.ascontiguousarray(xs_um, dtype=float)
        self.ys = np.ascontiguousarray(ys_um, dtype=float)
        if not self.data.shape == self.xs.shape == self.ys.shape:
            raise ValueError("data and pixel coordinates must have the same length")
        self.optics = optics
        self.free = np.asarray(free, dtype=bool)
        self.base = np.array(fixed if fixed is not None else np.zeros(6), dtype=float)
        self.index_imag = float(index_imag)
        self.n_holograms = 0
        self._waves: OrderedDict[tuple[float, float], MieWave] = OrderedDict()
        self._last: _Eval | None = None
        cp = np.cos(optics.polarization_rad)
        sp = np.sin(optics.polarization_rad)
        self._pol = (cp, sp)

    # -- parameter vectors ---------------------------------------------------------------
    def full(self, p_free: NDArray[np.float64]) -> NDArray[np.float64]:
        """All six parameters from the free ones."""
        p = self.base.copy()
        p[self.free] = p_free
        return p

    def free_part(self, p_full: NDArray[np.float64]) -> NDArray[np.float64]:
        """The free parameters of a full vector."""
        return np.asarray(p_full, dtype=float)[self.free]

    # -- model ---------------------------------------------------------------------------
    def wave(self, radius_um: float, index: float) -> MieWave:
        """Solved sphere, cached for the last few ``(radius, index)``."""
        key = (float(radius_um), float(index))
        wave = self._waves.get(key)
        if wave is None:
            if not (radius_um > 0 and index > 0):
                raise InvalidParameters(f"radius {radius_um} um / index {index} not physical")
            wave = MieWave(Sphere(key[0], complex(key[1], self.index_imag)), self.optics)
            self._waves[key] = wave
            if len(self._waves) > 8:
                self._waves.popitem(last=False)
        return wave

    def fields(self, p: NDArray[np.float64]) -> tuple[NDArray, NDArray]:
        """Scattered field (x, y) at the pixels for full parameters ``p``."""
        if not abs(p[2]) > 1.0001 * p[3]:
            raise InvalidParameters(f"|z| = {abs(p[2]):.4g} um within the sphere ({p[3]:.4g} um)")
        wave = self.wave(p[3], p[4])
        self.n_holograms += 1
        return mie_field_on_pixels(wave, p[:3], self.xs, self.ys)

    def _intensity(self, ex: NDArray, ey: NDArray, alpha: float) -> NDArray[np.float64]:
        cp, sp = self._pol
        a_r = cp + alpha * ex.real
        a_i = alpha * ex.imag
        b_r = sp + alpha * ey.real
        b_i = alpha * ey.imag
        return a_r * a_r + a_i * a_i + b_r * b_r + b_i * b_i

    def evaluate(self, p: NDArray[np.float64]) -> _Eval:
        """Fields and model intensities at full parameters ``p`` (cached for the last ``p``)."""
        key = tuple(float(v) for v in p)
        if self._last is not None and self._last.key == key:
            return self._last
        ex, ey = self.fields(p)
        ev = _Eval(key, ex, ey, self._intensity(ex, ey, p[5]))
        self._last = ev
        return ev

    def model(self, p: NDArray[np.float64]) -> NDArray[np.float64]:
        """Model intensities at full parameters ``p``."""
        return self.evaluate(p).model

    # -- what the optimiser calls ---------------------------------------------------------
    def residuals(self, p_free: NDArray[np.float64]) -> NDArray[np.float64]:
        """``model - data`` for free parameters ``p_free``.

        Invalid parameters (a step that puts the detector inside the sphere or makes the
        radius negative) give a large constant residual, so that a trust-region step is
        rejected instead of aborting the fit.
        """
        try:
            return self.model(self.full(p_free)) - self.data
        except InvalidParameters:
            return np.full(self.data.shape, 1e3)

    def jacobian(self, p_free: NDArray[np.float64]) -> NDArray[np.float64]:
        """d(model)/d(free parameters), shape (N, n_free)."""
        p = self.full(p_free)
        try:
            base = self.evaluate(p)
        except InvalidParameters:
            return np.zeros((self.data.size, int(self.free.sum())))
        cols = []
        for i in np.flatnonzero(self.free):
            if i == 5:
                cp, sp = self._pol
                a = p[5]
                ex, ey = base.ex, base.ey
                col = 2.0 * (
                    (cp + a * ex.real) * ex.real
                    + a * ex.imag * ex.imag
                    + (sp + a * ey.real) * ey.real
                    + a * ey.imag * ey.imag
                )
            else:
                q = p.copy()
                h = FD_STEPS[i] * (1.0 if p[i] >= 0 else -1.0)
                q[i] += h
                try:
                    ex, ey = self.fields(q)
                except InvalidParameters:
                    q[i] = p[i] - h
                    h = -h
                    ex, ey = self.fields(q)
                col = (self._intensity(ex, ey, p[5]) - base.model) / h
            cols.append(col)
        return np.stack(cols, axis=1)
