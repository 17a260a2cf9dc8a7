"""Automatic initial guesses for a sphere fit: z, radius, index and alpha from the radial
profile, with no manual input.

The crop's azimuthal average about the centre found by the crop stage is compared with a
precomputed table of exact azimuthally averaged Lorenz-Mie holograms
(:mod:`holofit.prefit.profile`) over a grid of heights z (uniform in 1/z, fine enough that the
fringe phase at the crop's edge moves by at most ``phase_step_rad`` between neighbours), radii
(geometric) and indices. For every table entry the best alpha is found in closed form, so the
whole search is a handful of matrix-vector products per frame. The distinct minima along z
(a hologram can look alike at two heights, with other sizes) are then refined by a small
least-squares fit of the profile, and all of them are returned, best first: the caller fits
the full hologram from each plausible one and keeps the best chi^2.

The table depends only on the optics, the pixel size, the number of radial bins and the search
space, so it is built once per worker process and reused for every frame
(:func:`profile_table`).
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from holofit.optics import Optics
from holofit.particles import Sphere
from holofit.prefit.profile import RadialProfile, annulus_mean_radius, profile_terms
from holofit.scattering.lens_lines import SphereLensLines
from holofit.scattering.mie import MieWave

__all__ = [
    "ProfileStart",
    "ProfileTable",
    "SearchSpace",
    "estimate_starts",
    "profile_table",
]


#: lowest height searched by default, um
Z_MIN_UM = 2.0
#: the default upper end of the search is at least this, um
Z_MAX_MIN_UM = 50.0


@dataclass(frozen=True)
class SearchSpace:
    """Where the automatic start looks for a sphere.

    Attributes
    ----------
    z_range_um : tuple of float, optional
        Lowest and highest height above the focal plane, um; both of the same sign (a
        particle below the focus has z < 0: meaningful with the objective lens in the model,
        :meth:`check_heights`). Default (None): from :data:`Z_MIN_UM` up to what the crop can
        show (:meth:`for_crop`).
    radius_range_um : tuple of float
        Smallest and largest radius, um.
    relative_index_range : tuple of float
        Smallest and largest index relative to the medium, ``n_particle / n_medium``.
    index_range : tuple of float, optional
        Smallest and largest absolute index; replaces ``relative_index_range`` if given.
    n_radii, n_indices : int
        Grid points in radius (geometric spacing) and index (uniform).
    phase_step_rad : float
        Largest change of the fringe phase at the crop's edge between neighbouring z values.
    """

    z_range_um: tuple[float, float] | None = None
    radius_range_um: tuple[float, float] = (0.2, 1.6)
    relative_index_range: tuple[float, float] = (1.02, 1.30)
    index_range: tuple[float, float] | None = None
    n_radii: int = 11
    n_indices: int = 8
    phase_step_rad: float = 1.0

    def __post_init__(self) -> None:
        a0, a1 = self.radius_range_um
        if not 0 < a0 <= a1:
            raise ValueError(f"radius range must be positive and increasing, got {a0}, {a1} um")
        if self.z_range_um is not None:
            self._check_z(*self.z_range_um)
        m0, m1 = self.relative_index_range
        if not 0 < m0 <= m1:
            raise ValueError(f"relative index range must be positive, got {m0}, {m1}")
        if self.index_range is not None and not 0 < self.index_range[0] <= self.index_range[1]:
            raise ValueError(f"index range must be positive and increasing, got {self.index_range}")
        if self.n_radii < 1 or self.n_indices < 1 or self.phase_step_rad <= 0:
            raise ValueError("n_radii, n_indices and phase_step_rad must be positive")

    def _check_z(self, z0: float, z1: float) -> None:
        if not (z0 < z1 and (z0 > 0 or z1 < 0)):
            raise ValueError(
                f"z range must be increasing and not cross the focal plane, got ({z0}, {z1}) um"
            )

    def check_heights(self, lens: bool) -> None:
        """Refuse a z range the hologram model cannot describe.

        The ideal model (no objective lens) records the field in the focal plane itself: the
        plane must stay outside every sphere searched (``|z| > 1.05`` times the largest
        radius), and a particle below the focus (``z < 0``) would need the field of a virtual
        image, which only the lens model gives. Through the lens every height is meaningful.

        Raises
        ------
        ValueError
            Naming the range and why.
        """
        if lens or self.z_range_um is None:
            return
        z0, z1 = self.z_range_um
        a1 = self.radius_range_um[1]
        if z1 < 0:
            raise ValueError(
                f"z range ({z0:g}, {z1:g}) um lies below the focal plane: only the objective "
                "lens model describes a particle there (give the instrument a "
                "numerical_aperture)")
        if min(abs(z0), abs(z1)) <= 1.05 * a1:
            raise ValueError(
                f"z range ({z0:g}, {z1:g}) um reaches into the largest sphere (radius {a1:g} "
                "um): the ideal model needs the focal plane outside it (or use the objective "
                "lens model: give the instrument a numerical_aperture)")

    def for_crop(self, rho_max_um: float, wavelength_medium_um: float) -> SearchSpace:
        """This space with the z range filled in for a crop reaching ``rho_max_um`` from the
        hologram's centre, if none was given.

        A hologram shows at least its first fringe inside the crop while the first Fresnel
        zone, radius ``sqrt(lambda z)``, fits in it: ``z <= rho_max^2 / lambda`` (lambda in
        the medium). That is the default upper end (at least 50 um), so particles far from
        focus (Grier-lab set-ups put them 50-85 um away) are searched when the crop can show
        them; the lower end is :data:`Z_MIN_UM` (or just above the largest sphere).
        """
        if self.z_range_um is not None:
            return self
        z0 = max(Z_MIN_UM, 1.1 * self.radius_range_um[1])
        z1 = max(Z_MAX_MIN_UM, rho_max_um**2 / wavelength_medium_um)
        return dataclasses.replace(self, z_range_um=(z0, z1))


@dataclass(frozen=True)
class ProfileStart:
    """One candidate start: a minimum of the profile misfit, refined.

    Attributes
    ----------
    z_um, radius_um, index, alpha : float
        Parameters.
    profile_chi2 : float
        Weighted sum of squared profile residuals (pixels times intensity^2).
    """

    z_um: float
    radius_um: float
    index: float
    alpha: float
    profile_chi2: float


class ProfileTable:
    """Exact azimuthally averaged sphere holograms on a (radius, index, z) grid.

    Parameters
    ----------
    optics : Optics
        Illumination and medium.
    pixel_size_um : float
        Pixel pitch, um.
    n_bins : int
        Radial bins (one pixel wide) of the profiles.
    space : SearchSpace
        Grid limits.
    """

    def __init__(
        self, optics: Optics, pixel_size_um: float, n_bins: int, space: SearchSpace
    ) -> None:
        self.optics = optics
        self.pixel_size_um = pixel_size_um
        self.n_bins = n_bins
        self.space = space
        self.rho_um = annulus_mean_radius(n_bins) * pixel_size_um
        self.z_um = z_grid(space, optics.k, float(self.rho_um[-1]))
        a0, a1 = space.radius_range_um
        self.radius_um = np.geomspace(a0, a1, space.n_radii)
        if space.index_range is not None:
            self.index = np.linspace(*space.index_range, space.n_indices)
        else:
            m0, m1 = space.relative_index_range
            self.index = np.linspace(m0, m1, space.n_indices) * optics.n_medium
        shape = (self.radius_um.size, self.index.size, self.z_um.size, n_bins)
        lin = np.empty(shape, dtype=np.float32)
        quad = np.empty(shape, dtype=np.float32)
        lines = None
        if optics.numerical_aperture is not None:  # the lens image: shared set-up
            order = int(MieWave(Sphere(float(self.radius_um[-1]), float(self.index[-1])),
                                optics).a.size)  # the series length grows with the size only
            lines = SphereLensLines(optics, self.z_um, self.rho_um, order)
        for i, a in enumerate(self.radius_um):
            for j, n in enumerate(self.index):
                wave = MieWave(Sphere(float(a), float(n)), optics)
                lin[i, j], quad[i, j] = profile_terms(wave, self.z_um, self.rho_um, lines)
        flat = (-1, n_bins)
        self._l = lin.reshape(flat)
        self._q = quad.reshape(flat)
        self._ll = self._l * self._l
        self._lq = self._l * self._q
        self._qq = self._q * self._q
        self.shape = shape[:3]

    @property
    def nbytes(self) -> int:
        """Memory held by the table, bytes."""
        return sum(t.nbytes for t in (self._l, self._q, self._ll, self._lq, self._qq))

    def misfit(
        self,
        profile: RadialProfile,
        alpha: float | None = None,
        alpha_bounds: tuple[float, float] = (0.2, 1.5),
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Weighted profile misfit of every table entry, with its best alpha.

        Parameters
        ----------
        profile : RadialProfile
            Measured profile (``n_bins`` long).
        alpha : float, optional
            Fixed alpha; by default the best alpha of each entry, from the linear least-squares
            fit of ``d - 1 = c1 (2 L) + c2 Q`` clipped to ``alpha_bounds``.
        alpha_bounds : tuple of float
            Range of alpha.

        Returns
        -------
        chi2, alpha : ndarray, shape (n_radii, n_indices, n_z)
            ``sum_b w_b (d_b - 1 - 2 alpha L_b - alpha^2 Q_b)^2`` with ``w_b`` the pixel count.
        """
        w = np.where(np.isfinite(profile.mean), profile.counts, 0.0)
        d = np.where(w > 0, profile.mean - 1.0, 0.0)
        wf = w.astype(np.float32)
        wd = (w * d).astype(np.float32)
        s_ll = (self._ll @ wf).astype(float)
        s_lq = (self._lq @ wf).astype(float)
        s_qq = (self._qq @ wf).astype(float)
        s_dl = (self._l @ wd).astype(float)
        s_dq = (self._q @ wd).astype(float)
        s_dd = float(np.sum(w * d * d))
        if alpha is None:
            # d ~ c1 (2L) + c2 Q: normal equations of the two-term linear fit; alpha = c1
            a11, a12, a22 = 4 * s_ll, 2 * s_lq, s_qq
            det = a11 * a22 - a12 * a12
            with np.errstate(invalid="ignore", divide="ignore"):
                c1 = (a22 * 2 * s_dl - a12 * s_dq) / det
            c1 = np.where(np.isfinite(c1), c1, 1.0)
            al = np.clip(c1, *alpha_bounds)
        else:
            al = np.full(s_ll.shape, float(alpha))
        chi2 = (
            s_dd
            - 4 * al * s_dl
            - 2 * al**2 * s_dq
            + 4 * al**2 * s_ll
            + 4 * al**3 * s_lq
            + al**4 * s_qq
        )
        return chi2.reshape(self.shape), al.reshape(self.shape)


def z_grid(space: SearchSpace, k: float, rho_max_um: float) -> NDArray[np.float64]:
    """Heights uniform in 1/z: the fringe phase ``k rho^2 / (2 z)`` at ``rho_max_um`` changes
    by at most ``space.phase_step_rad`` between neighbours."""
    if space.z_range_um is None:
        raise ValueError("the search space has no z range yet (SearchSpace.for_crop)")
    z0, z1 = space.z_range_um
    u0, u1 = 1.0 / z1, 1.0 / z0  # same sign, u0 < u1
    step = space.phase_step_rad / (0.5 * k * rho_max_um**2)
    n = max(int(np.ceil(abs(u1 - u0) / step)) + 1, 2)
    return np.sort(1.0 / np.linspace(u0, u1, n))


@functools.lru_cache(maxsize=4)
def profile_table(
    optics: Optics, pixel_size_um: float, n_bins: int, space: SearchSpace
) -> ProfileTable:
    """The :class:`ProfileTable` for these settings, built once per process."""
    return ProfileTable(optics, pixel_size_um, n_bins, space)


def _local_minima(curve: NDArray[np.float64]) -> NDArray[np.intp]:
    """Indices of the local minima of a 1-D curve (ends included), best first."""
    c = np.where(np.isfinite(curve), curve, np.inf)
    left = np.concatenate([[np.inf], c[:-1]])
    right = np.concatenate([c[1:], [np.inf]])
    idx = np.flatnonzero((c <= left) & (c <= right) & np.isfinite(c))
    return idx[np.argsort(c[idx])]


def _refine(
    table: ProfileTable,
    profile: RadialProfile,
    start: tuple[float, float, float, float],
    fix_alpha: float | None,
    index_imag: float,
) -> ProfileStart:
    """Least-squares fit of the exact averaged model to the profile, from a table entry."""
    w = np.where(np.isfinite(profile.mean), profile.counts, 0.0)
    keep = w > 0
    sw = np.sqrt(w[keep])
    d = profile.mean[keep]
    rho = table.rho_um[keep]
    free_alpha = fix_alpha is None
    optics = table.optics
    a_lo = 0.5 * table.space.radius_range_um[0]
    # the ideal model needs the focal plane outside the sphere; the lens image is defined anywhere
    z_clear = 0.0 if optics.numerical_aperture is not None else 1.05

    def residuals(p: NDArray[np.float64]) -> NDArray[np.float64]:
        z, a, n = p[0], p[1], p[2]
        alpha = p[3] if fix_alpha is None else fix_alpha
        if not (a > a_lo and n > 0.5 and abs(z) > z_clear * a):
            return np.full(d.size, 10.0) * sw
        wave = MieWave(Sphere(float(a), complex(n, index_imag)), optics)
        lin, quad = profile_terms(wave, [z], rho)
        return sw * (1.0 + 2 * alpha * lin[0] + alpha**2 * quad[0] - d)

    p0 = np.array(start if free_alpha else start[:3], dtype=float)
    try:
        sol = least_squares(residuals, p0, method="lm", x_scale="jac", max_nfev=60 * p0.size)
        p = sol.x
        cost = float(2 * sol.cost)
    except (ValueError, np.linalg.LinAlgError):  # pragma: no cover - defensive
        p = p0
        cost = float(np.sum(residuals(p0) ** 2))
    alpha = float(p[3]) if fix_alpha is None else float(fix_alpha)
    return ProfileStart(float(p[0]), float(p[1]), float(p[2]), alpha, cost)


def estimate_starts(
    table: ProfileTable,
    profile: RadialProfile,
    *,
    fix_alpha: float | None = None,
    index_imag: float = 0.0,
    max_starts: int = 3,
    ambiguity_ratio: float = 3.0,
    refine: bool = True,
) -> list[ProfileStart]:
    """Candidate ``(z, radius, index, alpha)`` starts for a sphere fit, best first.

    Parameters
    ----------
    table : ProfileTable
        Precomputed profiles for the instrument and crop size.
    profile : RadialProfile
        The crop's radial profile about the crop stage's centre.
    fix_alpha : float, optional
        Use this alpha instead of fitting it.
    index_imag : float
        Imaginary part of the index (held fixed).
    max_starts : int
        Most distinct minima along z to return.
    ambiguity_ratio : float
        A secondary minimum is kept only if its table misfit is at most this multiple of the
        best one (otherwise the estimate is not ambiguous and one start is returned).
    refine : bool
        Refine each kept minimum by a least-squares fit of the profile.

    Returns
    -------
    list of ProfileStart
        Sorted by profile misfit, duplicates (same z within 2 %) removed.
    """
    chi2, alpha = table.misfit(profile, alpha=fix_alpha)
    flat = chi2.reshape(-1, chi2.shape[2])  # (radius x index, z)
    best_an = np.argmin(flat, axis=0)
    curve = flat[best_an, np.arange(flat.shape[1])]
    minima = _local_minima(curve)
    if minima.size == 0:
        return []
    best = max(float(curve[minima[0]]), 1e-300)
    starts: list[ProfileStart] = []
    for iz in minima[: 2 * max_starts]:
        if curve[iz] > ambiguity_ratio * best or len(starts) == max_starts:
            break
        ia, jn = np.unravel_index(best_an[iz], chi2.shape[:2])
        entry = (
            float(table.z_um[iz]),
            float(table.radius_um[ia]),
            float(table.index[jn]),
            float(alpha[ia, jn, iz]),
        )
        if refine:
            cand = _refine(table, profile, entry, fix_alpha, index_imag)
        else:
            cand = ProfileStart(*entry, float(curve[iz]))
        if all(abs(cand.z_um - s.z_um) > 0.02 * abs(s.z_um) for s in starts):
            starts.append(cand)
    starts.sort(key=lambda s: s.profile_chi2)
    return starts
