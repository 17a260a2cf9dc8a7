"""Holograms through the objective lens: the scattered field of any engine, imaged by an ideal
objective of numerical aperture NA (the physics is in :mod:`holofit.scattering.lens_pupil`).

The image at a pixel a lateral distance ``(rho, ph_rho)`` from the particle, particle height
``z_p`` above the focal plane, relative to the incident field and with the incident phase
``exp(-i k z_p)`` included (as :meth:`ScatteredWave.field_on_detector`, so the hologram formula
of :mod:`holofit.conventions` is unchanged), is

    E = -exp(-i k z_p)/(2 pi) Int_0^{th_max} sin th dth Int dph T(th, ph)
        exp(i k rho sin th cos(ph - ph_rho) + i k z_p cos th).

With the imaged pupil field ``T`` in azimuthal Fourier modes, ``T = sum_m t_m(th) exp(i m ph)``,
the azimuthal integral gives Bessel functions:

    E = -exp(-i k z_p) sum_m i^m exp(i m ph_rho) G_m(rho),
    G_m(rho) = Int_0^{th_max} sin th t_m(th) J_m(k rho sin th) exp(i k z_p cos th) dth,

one Hankel-type transform per mode (:mod:`holofit.scattering.lens_transform`), sampled on a
radial grid and interpolated to each pixel (:mod:`holofit.scattering.lens_kernels`):

* spheres (:class:`~holofit.scattering.mie.MieWave`): orders 0 and +-2 only, two radial tables
  per height and a 1-D interpolation per pixel;
* everything else: the far field as an outgoing multipole expansion of order L
  (:mod:`holofit.scattering.lens_sources`), ``|m| <= L + 1``, the modes summed on a polar grid
  (an FFT over ``m``) and the pixels interpolated from it in 2-D.

Only the far-field amplitude enters: the image is exact for an engine that knows only the far
field (ADDA), and it is defined at every height, the focal plane and below it included (for
``z_p < 0`` the lens images the converging-then-diverging wave the particle sends downstream).

An aberrated objective (:class:`~holofit.aberration.Aberration`, carried by the optics or given
per call as the NA is) multiplies ``T`` by ``exp(i Phi(th))``, a phase that depends on ``th``
only (spherical aberration): it joins the nodes' factor ``exp(i k z_p cos th)`` and changes no
mode, so it costs one complex factor per pupil node. Its exact derivative with respect to a
coefficient ``c_k`` is the same transform with ``i dPhi/dc_k`` in the factor
(:meth:`LensImage.field_derivatives`, with the height's ``i k (cos th - 1)`` alike), all in one
pass over the Bessel table. Zero coefficients leave every number as it was.

What can be re-used is: the pupil field of a wave per aperture, the radial tables per height
(a lateral move costs only the pixel interpolation), and the Bessel tables across waves,
heights and particles.
"""

from __future__ import annotations

import threading
import weakref
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from holofit.aberration import SPHERICAL_NAMES, Aberration, spherical_basis
from holofit.conventions import DetectorGrid, incident_phase_at
from holofit.scattering.lens_kernels import polar_coordinates, polar_pixels, sphere_pixels
from holofit.scattering.lens_pupil import aperture_angle, check_apodization, pupil_nodes
from holofit.scattering.lens_sources import ExpansionPupil, SpherePupil, pupil_source
from holofit.scattering.lens_transform import (
    STENCIL,
    STEP,
    node_count,
    polar_grid,
    polar_grids,
    sphere_table_columns,
    sphere_tables,
)
from holofit.scattering.theory import ScatteredWave

__all__ = ["DERIVATIVE_NAMES", "LensImage", "lens_field_on_detector", "lens_field_on_pixels",
           "lens_fields_on_pixels", "lens_image"]

#: parameters :meth:`LensImage.field_derivatives` differentiates the image by exactly: the
#: height and the spherical-aberration coefficients
DERIVATIVE_NAMES = ("z_um", *SPHERICAL_NAMES)

#: aplanatic lenses with cos(th_max) below this integrate in the sqrt-regularised variable
SQRT_SWITCH = 0.5
#: azimuthal orders whose pupil field stays below this fraction of the largest are dropped
MODE_FLOOR = 1e-9
#: apertures (pupil fields) and heights (tables) kept per image
KEEP_PUPILS = 4
KEEP_TABLES = 4


@dataclass(frozen=True)
class _Pupil:
    """Quadrature nodes over an aperture, with the wave's imaged pupil field there."""

    theta_max: float
    theta: NDArray[np.float64]
    weights: NDArray[np.float64]
    modes: tuple[NDArray[np.complex128], NDArray[np.complex128]]
    key: tuple


@dataclass(frozen=True)
class _Tables:
    """What the pixels of one height are interpolated from: a sphere's two radial tables
    (``a, b``, 1-D complex), or any image's polar grid (``a``, shape ``(rows, columns, 4)``:
    the four real planes interleaved; ``b`` None)."""

    step: float
    n_rho: int
    a: NDArray
    b: NDArray[np.complex128] | None


class LensImage:
    """A solved particle as seen through the objective: its image at any position and NA.

    Parameters
    ----------
    wave : ScatteredWave
        Any engine's solution that gives far-field amplitudes (Lorenz-Mie, the built-in DDA,
        ADDA). For ADDA this costs one ADDA run (on a multipole quadrature grid), which then
        serves every position and aperture.
    apodization : {"aplanatic", "none"}
        The lens model (:mod:`holofit.scattering.lens_pupil`).

    Notes
    -----
    The image keeps the wave's far field (Mie coefficients or a multipole expansion), not the
    wave itself.
    """

    def __init__(self, wave: ScatteredWave, apodization: str = "aplanatic") -> None:
        self.optics = wave.optics
        self.apodization = check_apodization(apodization)
        self.source: SpherePupil | ExpansionPupil = pupil_source(wave)
        self._pupils: OrderedDict[tuple, _Pupil] = OrderedDict()
        self._tables: OrderedDict[tuple, _Tables] = OrderedDict()
        self._lock = threading.Lock()

    def aperture_angle(self, numerical_aperture: float | None = None) -> float:
        """Largest collected angle for ``numerical_aperture`` (default: the optics'), rad."""
        na = self.optics.numerical_aperture if numerical_aperture is None else numerical_aperture
        if na is None:
            raise ValueError(
                "no numerical aperture for the lens model: give one, or set numerical_aperture "
                "in the instrument"
            )
        return aperture_angle(na, self.optics.n_medium)

    def _pupil(self, theta_max: float, n_nodes: int) -> _Pupil:
        sqrt_end = bool(self.apodization == "aplanatic" and np.cos(theta_max) < SQRT_SWITCH)
        key = (theta_max, n_nodes, sqrt_end)
        with self._lock:
            pupil = self._pupils.get(key)
        if pupil is None:
            theta, w = pupil_nodes(theta_max, n_nodes, sqrt_end)
            modes = self.source.modes(theta, self.apodization)
            if isinstance(self.source, ExpansionPupil):
                modes = _trim_modes(*modes)
            pupil = _Pupil(theta_max, theta, w, modes, key)
            with self._lock:
                self._pupils[key] = pupil
                while len(self._pupils) > KEEP_PUPILS:
                    self._pupils.popitem(last=False)
        return pupil

    def aberration_for(self, aberration: Aberration | None = None) -> Aberration:
        """The pupil's aberration: ``aberration`` if given, else the optics'."""
        return self.optics.aberration if aberration is None else aberration

    def _tables_for(self, z: float, rho_max: float, theta_max: float,
                    aberration: Aberration) -> _Tables:
        k = self.optics.k
        n_nodes = node_count(k, z, rho_max, theta_max, self.source.order,
                             aberration.variation(theta_max))
        step = STEP / (k * np.sin(theta_max))
        n_rho = int(np.ceil(rho_max / step)) + STENCIL // 2 + 2
        key = (z, theta_max, n_nodes, aberration.key)
        with self._lock:
            tables = self._tables.get(key)
            if tables is not None and tables.n_rho >= n_rho:
                self._tables.move_to_end(key)
                return tables
        if tables is not None:
            n_rho = max(n_rho, int(1.3 * tables.n_rho))
        pupil = self._pupil(theta_max, n_nodes)
        x_step = k * step * np.sin(pupil.theta)
        base = _node_factor(pupil, k, z, aberration)
        bkey = (round(k * step, 12), *pupil.key)
        a: NDArray
        b: NDArray[np.complex128] | None
        if isinstance(self.source, SpherePupil):
            a, b = sphere_tables(*pupil.modes, base, x_step, n_rho, bkey)
        else:
            a, b = polar_grid(*pupil.modes, base, x_step, n_rho, bkey,
                              self.source.order + 1), None
        tables = _Tables(step, n_rho, a, b)
        with self._lock:
            self._tables[key] = tables
            while len(self._tables) > KEEP_TABLES:
                self._tables.popitem(last=False)
        return tables

    def field_on_pixels(
        self, position_um: ArrayLike, xs_um: ArrayLike, ys_um: ArrayLike,
        numerical_aperture: float | None = None, aberration: Aberration | None = None,
    ) -> tuple[NDArray[np.complex128], NDArray[np.complex128]]:
        """Imaged transverse field ``(E_x, E_y)`` at pixel centres, incident phase included.

        Parameters
        ----------
        position_um : array_like, shape (3,)
            Full-frame particle centre ``(x, y, z)``, um; any ``z`` (below focus too).
        xs_um, ys_um : array_like
            Full-frame sample-plane coordinates of the pixel centres, um (any equal shapes:
            a masked list, a random subset, a grid).
        numerical_aperture : float, optional
            The objective's NA; default the optics' ``numerical_aperture``.
        aberration : Aberration, optional
            The objective's pupil phase (:mod:`holofit.aberration`); default the optics'.

        Returns
        -------
        e_x, e_y : ndarray of complex, the shape of ``xs_um``
        """
        (xp, yp, zp), xs, ys = _pixel_arrays(position_um, xs_um, ys_um)
        shape = xs.shape
        ex = np.empty(xs.size, dtype=complex)
        ey = np.empty(xs.size, dtype=complex)
        if xs.size == 0:
            return ex.reshape(shape), ey.reshape(shape)
        theta_max = self.aperture_angle(numerical_aperture)
        dx = xs.ravel() - xp
        dy = ys.ravel() - yp
        r2 = dx * dx + dy * dy
        tables = self._tables_for(zp, float(np.sqrt(r2.max())), theta_max,
                                  self.aberration_for(aberration))
        if isinstance(self.source, SpherePupil):
            assert tables.b is not None  # a sphere's tables have both a and b
            self._sphere_pixels(tables.a, tables.b, tables.step, dx, dy, r2, ex, ey)
        else:
            _polar_field(tables.a, tables.step, dx, dy, ex, ey)
        return ex.reshape(shape), ey.reshape(shape)

    def _sphere_pixels(self, a: NDArray, b: NDArray, step: float, dx: NDArray, dy: NDArray,
                       r2: NDArray, ex: NDArray, ey: NDArray) -> None:
        """A sphere's image at the pixels ``(dx, dy)`` from its radial tables ``a, b``."""
        t = np.sqrt(r2) * (1.0 / step) + STENCIL
        # E_x = cos b A + cos(2 ph - b) B, E_y = sin b A + sin(2 ph - b) B, b the
        # polarisation angle; A, B the tables
        beta = self.optics.polarization_rad
        cb, sb = np.cos(beta), np.sin(beta)
        inv = np.divide(1.0, r2, out=np.zeros_like(r2), where=r2 > 0)
        c2 = (dx * dx - dy * dy) * inv
        c2[r2 == 0] = 1.0
        s2 = 2.0 * dx * dy * inv
        sphere_pixels(t, c2 * cb + s2 * sb, s2 * cb - c2 * sb, cb, sb, a, b, STENCIL, ex, ey)

    def field_derivatives(
        self, position_um: ArrayLike, xs_um: ArrayLike, ys_um: ArrayLike,
        names: Sequence[str], numerical_aperture: float | None = None,
        aberration: Aberration | None = None,
    ) -> list[tuple[NDArray[np.complex128], NDArray[np.complex128]]]:
        """Exact derivatives of :meth:`field_on_pixels` with respect to the height and the
        pupil's spherical-aberration coefficients, in one pass.

        Both enter the image only through the phase of each pupil node, ``k z_p (cos th - 1)``
        and ``Phi(th) = sum_k c_k dPhi/dc_k`` (:mod:`holofit.aberration`), so each derivative is
        the image with the nodes' factor times ``i k (cos th - 1)`` or ``i dPhi/dc_k``; the
        transforms share one read of the Bessel table (nothing is cached: a fit's Jacobian is
        computed once per point).

        Parameters
        ----------
        position_um, xs_um, ys_um, numerical_aperture, aberration
            As :meth:`field_on_pixels`.
        names : sequence of str
            Parameters from :data:`DERIVATIVE_NAMES`: ``z_um`` (per um) and ``sa4_rad``,
            ``sa6_rad``, ... (per rad).

        Returns
        -------
        list of (e_x, e_y)
            Per name, arrays of the shape of ``xs_um``.

        Raises
        ------
        ValueError
            For a name that is not in :data:`DERIVATIVE_NAMES`.
        """
        unknown = [n for n in names if n not in DERIVATIVE_NAMES]
        if unknown:
            raise ValueError(f"no exact lens derivative for {', '.join(unknown)}; known: "
                             f"{', '.join(DERIVATIVE_NAMES)}")
        (xp, yp, zp), xs, ys = _pixel_arrays(position_um, xs_um, ys_um)
        shape = xs.shape
        if xs.size == 0 or not names:
            return [(np.empty(shape, dtype=complex), np.empty(shape, dtype=complex))
                    for _ in names]
        ab = self.aberration_for(aberration)
        theta_max = self.aperture_angle(numerical_aperture)
        k = self.optics.k
        dx = xs.ravel() - xp
        dy = ys.ravel() - yp
        r2 = dx * dx + dy * dy
        rho_max = float(np.sqrt(r2.max()))
        n_nodes = node_count(k, zp, rho_max, theta_max, self.source.order,
                             ab.variation(theta_max))
        step = STEP / (k * np.sin(theta_max))
        n_rho = int(np.ceil(rho_max / step)) + STENCIL // 2 + 2
        pupil = self._pupil(theta_max, n_nodes)
        base = _node_factor(pupil, k, zp, ab)
        n_terms = max([SPHERICAL_NAMES.index(n) + 1 for n in names if n != "z_um"], default=0)
        # no spherical term asked: an empty basis (never indexed)
        basis = (spherical_basis(pupil.theta, n_terms) if n_terms
                 else np.empty((0, pupil.theta.size)))
        factors = [base * (1j * k * (np.cos(pupil.theta) - 1.0)) if n == "z_um"
                   else base * (1j * basis[SPHERICAL_NAMES.index(n)]) for n in names]
        x_step = k * step * np.sin(pupil.theta)
        bkey = (round(k * step, 12), *pupil.key)
        out = []
        if isinstance(self.source, SpherePupil):
            for a, b in sphere_table_columns(*pupil.modes, factors, x_step, n_rho, bkey):
                ex = np.empty(dx.size, dtype=complex)
                ey = np.empty(dx.size, dtype=complex)
                self._sphere_pixels(a, b, step, dx, dy, r2, ex, ey)
                out.append((ex.reshape(shape), ey.reshape(shape)))
            return out
        grids = polar_grids([(*pupil.modes, f) for f in factors], x_step, n_rho, bkey,
                            self.source.order + 1)
        for grid in grids:
            ex = np.empty(dx.size, dtype=complex)
            ey = np.empty(dx.size, dtype=complex)
            _polar_field(grid, step, dx, dy, ex, ey)
            out.append((ex.reshape(shape), ey.reshape(shape)))
        return out

    def field_on_detector(
        self, position_um: ArrayLike, grid: DetectorGrid, numerical_aperture: float | None = None,
        aberration: Aberration | None = None,
    ) -> tuple[NDArray[np.complex128], NDArray[np.complex128]]:
        """:meth:`field_on_pixels` at every pixel of ``grid`` (arrays of ``grid.shape``)."""
        x, y = grid.coordinates()
        return self.field_on_pixels(position_um, x, y, numerical_aperture, aberration)


def _node_factor(pupil: _Pupil, k: float, z: float, aberration: Aberration
                 ) -> NDArray[np.complexfloating]:
    """What multiplies the pupil field at each node: the quadrature weight, ``sin th``, the
    phase of each plane wave at the focal plane, the incident phase at the particle and, for
    an aberrated objective, ``exp(i Phi(th))`` (left out for the ideal one: no operation, so
    its numbers are the unaberrated ones bit for bit)."""
    base = (pupil.weights * np.sin(pupil.theta)
            * np.exp(1j * k * z * np.cos(pupil.theta)) * complex(incident_phase_at(z, k)))
    if not aberration.is_zero:
        base = base * np.exp(1j * aberration.phase(pupil.theta))
    return base


def _polar_field(grid: NDArray, step: float, dx: NDArray, dy: NDArray, ex: NDArray,
                 ey: NDArray) -> None:
    """An image at the pixels ``(dx, dy)`` from its polar grid (interleaved planes)."""
    n_phi = grid.shape[1] - 2 * STENCIL
    t = np.empty(dx.size)
    u = np.arctan2(dy, dx)
    polar_coordinates(dx, dy, 1.0 / step, n_phi, STENCIL, t, u)
    polar_pixels(t, u, grid, ex, ey)


def _trim_modes(t_plus: NDArray, t_minus: NDArray) -> tuple[NDArray, NDArray]:
    """Drop the outer azimuthal orders below :data:`MODE_FLOOR` of the largest over the pupil."""
    mag = np.maximum(np.abs(t_plus).max(axis=0), np.abs(t_minus).max(axis=0))
    mmax = (mag.size - 1) // 2
    orders = np.abs(np.arange(-mmax, mmax + 1))
    keep = int(orders[mag > MODE_FLOOR * mag.max()].max()) if mag.max() > 0 else 0
    sl = slice(mmax - keep, mmax + keep + 1)
    return np.ascontiguousarray(t_plus[:, sl]), np.ascontiguousarray(t_minus[:, sl])


# -- plain functions -------------------------------------------------------------------------

_IMAGES: weakref.WeakKeyDictionary[ScatteredWave, dict[str, LensImage]] = (
    weakref.WeakKeyDictionary())
_IMAGES_LOCK = threading.Lock()


def lens_image(wave: ScatteredWave, apodization: str = "aplanatic") -> LensImage:
    """The :class:`LensImage` of ``wave``, kept as long as the wave lives: repeated calls for
    the same wave (new positions, another NA) re-use its pupil field and tables."""
    try:
        with _IMAGES_LOCK:
            image = _IMAGES.get(wave, {}).get(apodization)
    except TypeError:  # a wave that cannot be weakly referenced or hashed: no re-use
        return LensImage(wave, apodization)
    if image is None:
        image = LensImage(wave, apodization)
        with _IMAGES_LOCK:
            image = _IMAGES.setdefault(wave, {}).setdefault(apodization, image)
    return image


def lens_field_on_pixels(
    wave: ScatteredWave, position_um: ArrayLike, xs_um: ArrayLike, ys_um: ArrayLike,
    numerical_aperture: float | None = None, apodization: str = "aplanatic",
    aberration: Aberration | None = None,
) -> tuple[NDArray[np.complex128], NDArray[np.complex128]]:
    """Transverse field of ``wave`` at pixel centres, imaged through the objective.

    Same conventions as :meth:`ScatteredWave.field_on_detector` (relative to the incident
    field, incident phase ``exp(-i k z_p)`` included), so the hologram is
    :func:`holofit.conventions.hologram_intensity` of the result.

    Parameters
    ----------
    wave : ScatteredWave
        A solved particle (Lorenz-Mie, built-in DDA, ADDA).
    position_um : array_like, shape (3,)
        Full-frame particle centre ``(x, y, z)``, um; any ``z``.
    xs_um, ys_um : array_like
        Full-frame pixel-centre coordinates, um (any equal shapes, e.g. a masked list).
    numerical_aperture : float, optional
        NA of the objective; default ``wave.optics.numerical_aperture``.
    apodization : {"aplanatic", "none"}
        The lens model (:mod:`holofit.scattering.lens_pupil`).
    aberration : Aberration, optional
        The objective's pupil phase (:mod:`holofit.aberration`); default the wave's optics'.

    Returns
    -------
    e_x, e_y : ndarray of complex, the shape of ``xs_um``
    """
    return lens_image(wave, apodization).field_on_pixels(position_um, xs_um, ys_um,
                                                         numerical_aperture, aberration)


def lens_field_on_detector(
    wave: ScatteredWave, position_um: ArrayLike, grid: DetectorGrid,
    numerical_aperture: float | None = None, apodization: str = "aplanatic",
    aberration: Aberration | None = None,
) -> tuple[NDArray[np.complex128], NDArray[np.complex128]]:
    """:func:`lens_field_on_pixels` on every pixel of ``grid`` (arrays of ``grid.shape``)."""
    return lens_image(wave, apodization).field_on_detector(position_um, grid,
                                                           numerical_aperture, aberration)


def lens_fields_on_pixels(
    waves: list[ScatteredWave], position_um: ArrayLike, xs_um: ArrayLike, ys_um: ArrayLike,
    numerical_aperture: float | None = None, apodization: str = "aplanatic",
    height_derivative: Sequence[bool] = (), aberration: Aberration | None = None,
) -> list[tuple[NDArray[np.complex128], NDArray[np.complex128]]]:
    """:func:`lens_field_on_pixels` of several waves at one position, in one pass.

    For waves of the same optics given by multipole expansions (e.g. a T-matrix wave's
    orientation derivatives, :mod:`holofit.scattering.tmatrix_wave`), the pupil nodes, the
    Bessel-table product (one read of the table for all waves: the product is bound by that
    read), the FFT call and the pixels' interpolation weights are shared; the results equal
    the separate images'. Other waves (spheres, mixed optics) are imaged one by one. Nothing
    is cached for the waves (a fit's derivative waves are imaged once).

    ``height_derivative[i]`` True (expansion waves only) gives instead the exact derivative of
    wave ``i``'s image with respect to the particle's height ``z_p`` (per um): the height
    enters the image only through ``exp(i k z_p (cos th - 1))`` at each pupil node
    (:mod:`holofit.scattering.lens`'s formula), so its derivative is the image with the nodes'
    factor times ``i k (cos th - 1)``. ``aberration`` (default: the first wave's optics') is
    the objective's pupil phase, the same for every wave.

    Returns
    -------
    list of (e_x, e_y)
        Per wave, arrays of the shape of ``xs_um``.
    """
    images = [lens_image(w, apodization) for w in waves]
    dz = [bool(v) for v in height_derivative] + [False] * (len(images) - len(height_derivative))
    if any(not isinstance(im.source, ExpansionPupil) or im.optics != images[0].optics
           for im in images):
        if any(dz):
            raise ValueError("height derivatives of the lens image need waves of one optics "
                             "given by multipole expansions")
        return [im.field_on_pixels(position_um, xs_um, ys_um, numerical_aperture, aberration)
                for im in images]
    first = images[0]
    ab = first.aberration_for(aberration)
    (xp, yp, zp), xs, ys = _pixel_arrays(position_um, xs_um, ys_um)
    shape = xs.shape
    if xs.size == 0:
        return [(np.empty(shape, dtype=complex), np.empty(shape, dtype=complex))
                for _ in images]
    theta_max = first.aperture_angle(numerical_aperture)
    k = first.optics.k
    dx = xs.ravel() - xp
    dy = ys.ravel() - yp
    r2 = dx * dx + dy * dy
    rho_max = float(np.sqrt(r2.max()))
    order = max(im.source.order for im in images)
    n_nodes = node_count(k, zp, rho_max, theta_max, order, ab.variation(theta_max))
    step = STEP / (k * np.sin(theta_max))
    n_rho = int(np.ceil(rho_max / step)) + STENCIL // 2 + 2
    pupils = [im._pupil(theta_max, n_nodes) for im in images]
    pupil = pupils[0]
    x_step = k * step * np.sin(pupil.theta)
    base = _node_factor(pupil, k, zp, ab)
    bkey = (round(k * step, 12), *pupil.key)
    base_dz = base * (1j * k * (np.cos(pupil.theta) - 1.0))
    grids = polar_grids([(*p.modes, base_dz if d else base) for p, d in zip(pupils, dz,
                                                                              strict=True)],
                        x_step, n_rho, bkey, order + 1)
    n_phi = grids.shape[2] - 2 * STENCIL
    t = np.empty(dx.size)
    u = np.arctan2(dy, dx)
    polar_coordinates(dx, dy, 1.0 / step, n_phi, STENCIL, t, u)
    out = []
    # one grid at a time: the single-grid kernel on the interleaved grids is faster per grid
    # than the several-grid loop of polar_interpolate (measured, 40k pixels)
    for grid in grids:
        ex = np.empty(dx.size, dtype=complex)
        ey = np.empty(dx.size, dtype=complex)
        polar_pixels(t, u, grid, ex, ey)
        out.append((ex.reshape(shape), ey.reshape(shape)))
    return out


def _pixel_arrays(position_um: ArrayLike, xs_um: ArrayLike, ys_um: ArrayLike
                  ) -> tuple[tuple[float, float, float], NDArray[np.float64], NDArray[np.float64]]:
    """The particle position as floats and the pixel coordinates as arrays of one shape."""
    xp, yp, zp = (float(v) for v in np.asarray(position_um, dtype=float))
    xs = np.asarray(xs_um, dtype=float)
    ys = np.asarray(ys_um, dtype=float)
    if xs.shape != ys.shape:
        raise ValueError(f"xs_um {xs.shape} and ys_um {ys.shape} differ in shape")
    return (xp, yp, zp), xs, ys
