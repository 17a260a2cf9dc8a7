"""Scattered waves from references independent of holofit's engines, for tests and benchmarks:
far fields from pytmatrixc (Mishchenko's EBCM Fortran), from the extended-precision EBCM of
:mod:`tests.ebcm_reference`, and from holofit's DDA extrapolated to ``d -> 0``.

Each is a :class:`~holofit.scattering.theory.ScatteredWave` that knows only its far-field
amplitude (as ADDA's), so holograms are made from it by holofit's own camera and lens code
(:func:`holofit.hologram.calc_hologram`; with an objective NA, the lens image built from the
far field alone is exact at any distance): the imaging code is shared with the fitted model,
the scattering is not.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from holofit.conventions import euler_zyz
from holofit.optics import Optics
from holofit.particles import Cylinder, ParticleModel, Spherocylinder, Spheroid
from holofit.scattering.theory import Orientation, ScatteredWave

#: ``amplitude(k_in, e_in, dirs) -> A`` (N, 3), particle frame, ``A = lim kr exp(-ikr) E_s``
Amplitude = Callable[[NDArray, NDArray, NDArray], NDArray]

__all__ = ["ExtrapolatedWave", "FarFieldWave", "ld_ebcm_amplitude", "pytmatrix_amplitude"]


class FarFieldWave(ScatteredWave):
    """A wave known by its particle-frame far-field amplitude ``amplitude``."""

    exact_near_field = False

    def __init__(self, model: ParticleModel, optics: Optics, orientation: Orientation,
                 amplitude: Amplitude) -> None:
        self.model, self.optics, self.orientation = model, optics, orientation
        self.radius_um = float(model.bounding_radius_um)
        self._rot = euler_zyz(*orientation.as_tuple())
        self._amplitude = amplitude
        pol = optics.polarization_rad
        self._k_in = self._rot.T @ np.array([0.0, 0.0, -1.0])
        self._e_in = self._rot.T @ np.array([np.cos(pol), np.sin(pol), 0.0])

    def far_field_amplitude(self, directions: ArrayLike) -> NDArray[np.complex128]:
        """``F`` (lab frame, ``E_s = exp(ikr) / (-ikr) F``) at unit ``directions`` (N, 3)."""
        dirs = np.atleast_2d(np.asarray(directions, dtype=float))
        a = self._amplitude(self._k_in, self._e_in, dirs @ self._rot)  # rows R^T n
        return -1j * (a @ self._rot.T)

    def field_at(self, points_um: ArrayLike, far_field: bool = False) -> NDArray[np.complex128]:
        """The asymptotic field (the reference knows only the far field)."""
        p = np.atleast_2d(np.asarray(points_um, dtype=float))
        r = np.linalg.norm(p, axis=1)
        k = self.optics.k
        return self.far_field_amplitude(p / r[:, None]) * (np.exp(1j * k * r) / (-1j * k * r))[
            :, None]


class ExtrapolatedWave(ScatteredWave):
    """The far field of DDA waves at dipole sizes ``d_i`` extrapolated to ``d = 0``, linearly
    (two waves) or quadratically (three), as a far-field-only wave."""

    exact_near_field = False

    def __init__(self, waves: Sequence[ScatteredWave], sizes_um: Sequence[float]) -> None:
        self.waves, self.sizes = list(waves), np.asarray(sizes_um, dtype=float)
        self.model = getattr(waves[0], "model", None)
        self.optics = waves[0].optics
        self.radius_um = max(float(getattr(w, "radius_um", 0.0) or 0.0) for w in waves) or None
        # Lagrange weights of the values at the sizes for the polynomial's value at 0
        s = self.sizes
        self.weights = np.array([np.prod([sj / (sj - si) for j, sj in enumerate(s) if j != i])
                                 for i, si in enumerate(s)])

    def far_field_amplitude(self, directions: ArrayLike) -> NDArray[np.complex128]:
        return sum(w * wave.far_field_amplitude(directions)
                   for w, wave in zip(self.weights, self.waves, strict=True))

    def field_at(self, points_um: ArrayLike, far_field: bool = False) -> NDArray[np.complex128]:
        p = np.atleast_2d(np.asarray(points_um, dtype=float))
        r = np.linalg.norm(p, axis=1)
        k = self.optics.k
        return self.far_field_amplitude(p / r[:, None]) * (np.exp(1j * k * r) / (-1j * k * r))[
            :, None]


def _spherical(v: NDArray) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    """Polar and azimuthal angles (deg) and the unit vectors theta^, phi^ of unit rows ``v``."""
    th = np.arccos(np.clip(v[:, 2], -1.0, 1.0))
    ph = np.arctan2(v[:, 1], v[:, 0])
    th_hat = np.stack([np.cos(th) * np.cos(ph), np.cos(th) * np.sin(ph), -np.sin(th)], -1)
    ph_hat = np.stack([-np.sin(ph), np.cos(ph), np.zeros_like(ph)], -1)
    # azimuths in [0, 360): Mishchenko's Fortran stops the process on a negative one
    return np.degrees(th), np.mod(np.degrees(ph), 360.0), th_hat, ph_hat


def pytmatrix_amplitude(model: ParticleModel, optics: Optics, ddelt: float | None = None
                        ) -> Amplitude:
    """The far field of a spheroid or a flat-ended cylinder from pytmatrixc's amplitude matrix.

    Its ``S`` relates the scattered ``(E_theta, E_phi)`` to the incident ones in the particle
    frame (axis along z, ``alpha = beta = 0``), ``E_s = exp(ikr)/r S E_0``, so ``A = k S E_0``
    (checked against holofit's exact spheroid to its own accuracy, ``ddelt``: 1e-8 for the
    spheroid, 1e-6 for the cylinder; tighter values stop its Fortran).
    """
    from pytmatrix.fortran_tm import pytmatrix as fortran
    from pytmatrix.tmatrix import Scatterer

    m = complex(model.index) / optics.n_medium  # type: ignore[attr-defined]
    if isinstance(model, Spheroid):
        shape, radius, ratio = -1, (model.a_um**2 * model.c_um) ** (1 / 3), model.a_um / model.c_um
        ddelt, ndgs = ddelt or 1e-8, 8
    elif isinstance(model, Cylinder):
        shape, ratio = -2, model.radius_um / model.half_length_um
        radius = (1.5 * model.radius_um**2 * model.half_length_um) ** (1 / 3)
        ddelt, ndgs = ddelt or 1e-6, 4
    else:
        raise TypeError(f"pytmatrixc has no {model.kind}")
    lam = optics.wavelength_medium_um
    s = Scatterer(radius=radius, wavelength=lam, m=m, axis_ratio=ratio, shape=shape,
                  ddelt=ddelt, ndgs=ndgs)
    s.get_S()  # builds its T-matrix (nmax)
    k = optics.k

    def amplitude(k_in: NDArray, e_in: NDArray, dirs: NDArray) -> NDArray:
        t0, p0, tv0, th0 = _spherical(np.asarray(k_in, float)[None, :])
        e0 = np.array([e_in @ tv0[0], e_in @ th0[0]])
        t, p, tv, th = _spherical(np.asarray(dirs, float))
        out = np.empty((t.size, 3), dtype=complex)
        for i in range(t.size):
            amp, _ = fortran.calcampl(s.nmax, lam, t0[0], t[i], p0[0], p[i], 0.0, 0.0)
            es = np.asarray(amp) @ e0
            out[i] = k * (es[0] * tv[i] + es[1] * th[i])
        return out

    return amplitude


def ld_ebcm_amplitude(model: ParticleModel, optics: Optics, order: int,
                      nodes: int | None = None, cache: Path | None = None) -> Amplitude:
    """The far field of :class:`tests.ebcm_reference.LongDoubleEBCM` for a spherocylinder,
    spheroid or flat-ended cylinder (real index) at ``order``; with ``cache`` (a folder), its
    blocks are kept there (a build at order 54 takes about two minutes)."""
    from tests.ebcm_reference import LongDoubleEBCM, capsule, cylinder, spheroid

    if isinstance(model, Spherocylinder):
        surface = capsule(model.a_um, model.b_um)
    elif isinstance(model, Spheroid):
        surface = spheroid(model.a_um, model.c_um)
    elif isinstance(model, Cylinder):
        surface = cylinder(model.radius_um, model.half_length_um)
    else:
        raise TypeError(f"no extended-precision EBCM for {model.kind}")
    m = float(np.real(complex(model.index))) / optics.n_medium
    path = None
    blocks = None
    if cache is not None:
        tag = f"{surface.kind}_{surface.p1:.6f}_{surface.p2:.6f}_{m:.8f}_{optics.k:.8f}"
        path = Path(cache) / f"ld_ebcm_{tag}_L{order}_n{nodes or 0}.npz"
        if path.exists():
            with np.load(path) as f:
                blocks = [f[f"m{i}"] for i in range(order + 1)]
    ebcm = LongDoubleEBCM(surface, m, optics.k, order, nodes, blocks)
    if path is not None and blocks is None:
        path.parent.mkdir(parents=True, exist_ok=True)
        np.savez(path, **{f"m{i}": b for i, b in enumerate(ebcm.blocks)})
    return ebcm.amplitude
