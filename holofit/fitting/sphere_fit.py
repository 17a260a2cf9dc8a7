"""Lorenz-Mie fit of one crop: (x, y, z, radius, index, alpha) from an automatic start.

The start needs no manual guess: x, y come from the crop stage's centre, z, radius, index and
alpha from the radial-profile estimator (:mod:`holofit.fitting.estimate`). Where that estimate
is ambiguous (several heights explain the profile about equally well), each candidate is fitted
briefly on a random subset of the pixels and the best one is fitted on all of them.

The fit is a Levenberg-Marquardt least-squares fit (``scipy.optimize.least_squares``,
MINPACK) of the exact hologram to the unmasked pixels: NaN pixels (masked or saturated by the
crop stage) and pixels at or above an optional saturation level are left out, and an optional
random subset keeps only a fraction of the rest (seeded, so a fit is reproducible).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from holofit.conventions import r_squared
from holofit.fitting.estimate import (
    ProfileStart,
    SearchSpace,
    estimate_starts,
    profile_table,
)
from holofit.fitting.pixels import select_pixels
from holofit.fitting.profile import radial_profile
from holofit.fitting.residuals import SPHERE_PARAMETERS, SphereResiduals
from holofit.fitting.statistics import covariance_from_jacobian, estimate_noise_sd
from holofit.optics import Optics

__all__ = ["FitOptions", "SphereFit", "fit_sphere_crop"]

#: least_squares status codes that mean convergence (1: gtol, 2: ftol, 3: xtol, 4: both)
CONVERGED = (1, 2, 3, 4)


@dataclass(frozen=True)
class FitOptions:
    """Settings of a sphere fit.

    Attributes
    ----------
    fix_alpha : float, optional
        Hold alpha at this value (e.g. 1 for pylorenzmie's model); fitted by default.
    index_imag : float
        Imaginary part of the particle index, held fixed (>= 0).
    saturation : float, optional
        Leave out pixels whose normalised value is at or above this level (NaN pixels are
        always left out).
    pixel_fraction : float
        Fit a random subset with this fraction of the unmasked pixels (1: all).
    noise_sd : float, optional
        Pixel noise (normalised units) for chi^2; estimated from each crop if not given.
    search : SearchSpace
        Where the automatic start looks.
    max_starts : int
        Most candidate starts fitted when the estimate is ambiguous.
    ambiguity_ratio : float
        A secondary profile minimum is a candidate if its misfit is within this factor of the
        best.
    screen_pixels : int
        Pixels used to screen several candidates before the full fit.
    max_nfev : int
        Most model evaluations of the final fit (Jacobians count one each).
    ftol, xtol : float
        Convergence tolerances of the final fit (``scipy.optimize.least_squares``).
    """

    fix_alpha: float | None = None
    index_imag: float = 0.0
    saturation: float | None = None
    pixel_fraction: float = 1.0
    noise_sd: float | None = None
    search: SearchSpace = field(default_factory=SearchSpace)
    max_starts: int = 3
    ambiguity_ratio: float = 3.0
    screen_pixels: int = 3000
    max_nfev: int = 200
    ftol: float = 1e-8
    xtol: float = 1e-8

    def __post_init__(self) -> None:
        if not 0 < self.pixel_fraction <= 1:
            raise ValueError(f"pixel_fraction must be in (0, 1], got {self.pixel_fraction}")
        if self.index_imag < 0:
            raise ValueError(f"index_imag must be >= 0 (absorption), got {self.index_imag}")
        if self.fix_alpha is not None and not self.fix_alpha > 0:
            raise ValueError(f"fix_alpha must be positive, got {self.fix_alpha}")
        if self.noise_sd is not None and not self.noise_sd > 0:
            raise ValueError(f"noise_sd must be positive, got {self.noise_sd}")
        if self.max_starts < 1 or self.max_nfev < 1 or self.screen_pixels < 10:
            raise ValueError("max_starts, max_nfev and screen_pixels must be positive")


@dataclass
class SphereFit:
    """Result of :func:`fit_sphere_crop`.

    Attributes
    ----------
    values, sigmas : dict
        Best-fit value and one-sigma uncertainty of each of
        :data:`~holofit.fitting.residuals.SPHERE_PARAMETERS` (sigma NaN for fixed ones).
    rss : float
        Residual sum of squares over the fitted pixels.
    noise_sd : float
        Pixel noise used for chi^2 (given or estimated).
    chi2, chi2_red : float
        ``rss / noise_sd^2`` and that divided by the degrees of freedom.
    r2 : float
        Coefficient of determination on the fitted pixels.
    n_pixels, n_masked : int
        Pixels fitted; pixels left out as NaN or saturated.
    n_holograms : int
        Model holograms computed (all starts, Jacobian columns included).
    n_starts : int
        Candidate starts fitted.
    start : ProfileStart
        The start the final fit came from.
    converged : bool
        The final fit met its tolerances.
    message : str
        Optimiser message.
    time_s : float
        Wall time of the fit, automatic start included, one-time set-up excluded.
    setup_s : float
        One-time set-up of this process paid by this fit (building the estimator's table for
        a new instrument or crop size; 0 when it was already built).
    """

    values: dict[str, float]
    sigmas: dict[str, float]
    rss: float
    noise_sd: float
    chi2: float
    chi2_red: float
    r2: float
    n_pixels: int
    n_masked: int
    n_holograms: int
    n_starts: int
    start: ProfileStart
    converged: bool
    message: str
    time_s: float
    setup_s: float = 0.0


def _lm(
    res: SphereResiduals, p0: NDArray[np.float64], max_nfev: int, ftol: float, xtol: float
):  # scipy OptimizeResult
    return least_squares(
        res.residuals,
        res.free_part(p0),
        jac=res.jacobian,
        method="lm",
        x_scale="jac",
        max_nfev=max_nfev,
        ftol=ftol,
        xtol=xtol,
    )


def fit_sphere_crop(
    crop: NDArray,
    corner_rc: tuple[int, int],
    centre_xy_um: tuple[float, float],
    optics: Optics,
    pixel_size_um: float,
    options: FitOptions | None = None,
    seed: int = 0,
) -> SphereFit:
    """Fit the exact Lorenz-Mie hologram to one normalised crop, from an automatic start.

    Parameters
    ----------
    crop : ndarray, shape (rows, cols)
        Normalised hologram (background 1); NaN marks pixels to leave out.
    corner_rc : tuple of int
        Full-frame ``(row, column)`` of the crop's pixel ``[0, 0]``.
    centre_xy_um : tuple of float
        Full-frame ``(x, y)`` of the hologram centre from the crop stage, um: the x, y start.
    optics : Optics
        Illumination and medium.
    pixel_size_um : float
        Pixel pitch in the sample plane, um.
    options : FitOptions, optional
        Fit settings.
    seed : int
        Seed of the random pixel subsets (use the frame number for reproducible batches).

    Returns
    -------
    SphereFit

    Raises
    ------
    ValueError
        If too few pixels are left or no start can be found.
    """
    t0 = time.perf_counter()
    opts = options or FitOptions()
    data = np.asarray(crop, dtype=float)
    n_free = 6 - (opts.fix_alpha is not None)
    rng = np.random.default_rng(seed)
    pix = select_pixels(
        data,
        corner_rc,
        pixel_size_um,
        saturation=opts.saturation,
        fraction=opts.pixel_fraction,
        rng=rng,
        min_pixels=max(100, 10 * n_free),
    )
    valid, n_masked = pix.valid, pix.n_masked
    d, xs, ys = pix.data, pix.xs_um, pix.ys_um

    # automatic start: radial profile about the crop stage's centre
    xc, yc = (float(v) for v in centre_xy_um)
    centre_rc = (yc / pixel_size_um - corner_rc[0], xc / pixel_size_um - corner_rc[1])
    n_bins = min(data.shape) // 2 - 1
    t_setup = time.perf_counter()
    table = profile_table(optics, float(pixel_size_um), n_bins, opts.search)
    setup_s = time.perf_counter() - t_setup
    prof = radial_profile(data, valid, centre_rc, n_bins)
    starts = estimate_starts(
        table,
        prof,
        fix_alpha=opts.fix_alpha,
        index_imag=opts.index_imag,
        max_starts=opts.max_starts,
        ambiguity_ratio=opts.ambiguity_ratio,
    )
    if not starts:
        raise ValueError("no automatic start found (the radial profile has no minimum)")

    free = (True, True, True, True, True, opts.fix_alpha is None)
    alpha0 = opts.fix_alpha

    def vector(s: ProfileStart) -> NDArray[np.float64]:
        a = s.alpha if alpha0 is None else alpha0
        return np.array([xc, yc, s.z_um, s.radius_um, s.index, a], dtype=float)

    n_holograms = 0
    chosen = starts[0]
    p0 = vector(chosen)
    if len(starts) > 1:
        # screen the candidates on a random subset, keep the best
        m = min(opts.screen_pixels, d.size)
        sub = np.sort(rng.choice(d.size, size=m, replace=False))
        best_cost = np.inf
        for s in starts:
            res = SphereResiduals(
                d[sub], xs[sub], ys[sub], optics, free, vector(s), opts.index_imag
            )
            sol = _lm(res, vector(s), max_nfev=40, ftol=1e-6, xtol=1e-6)
            n_holograms += res.n_holograms
            if np.isfinite(sol.cost) and sol.cost < best_cost:
                best_cost = sol.cost
                chosen = s
                p0 = res.full(sol.x)
    res = SphereResiduals(d, xs, ys, optics, free, p0, opts.index_imag)
    sol = _lm(res, p0, max_nfev=opts.max_nfev, ftol=opts.ftol, xtol=opts.xtol)
    n_holograms += res.n_holograms
    p = res.full(sol.x)
    resid = sol.fun
    rss = float(resid @ resid)
    cov = covariance_from_jacobian(np.asarray(sol.jac), rss, d.size)
    sig_free = np.sqrt(np.clip(np.diag(cov), 0, None))
    sigmas = np.full(6, np.nan)
    sigmas[np.asarray(free)] = sig_free
    noise = opts.noise_sd if opts.noise_sd is not None else estimate_noise_sd(data, valid)
    chi2 = rss / noise**2 if noise > 0 else float("nan")
    dof = max(d.size - sol.x.size, 1)
    model = d + resid
    return SphereFit(
        values={k: float(v) for k, v in zip(SPHERE_PARAMETERS, p, strict=True)},
        sigmas={k: float(v) for k, v in zip(SPHERE_PARAMETERS, sigmas, strict=True)},
        rss=rss,
        noise_sd=float(noise),
        chi2=float(chi2),
        chi2_red=float(chi2 / dof),
        r2=float(r_squared(d, model)),
        n_pixels=int(d.size),
        n_masked=int(n_masked),
        n_holograms=int(n_holograms),
        n_starts=len(starts),
        start=chosen,
        converged=bool(sol.status in CONVERGED),
        message=str(sol.message),
        time_s=time.perf_counter() - t0 - setup_s,
        setup_s=setup_s,
    )
