"""Lorenz-Mie fit of one crop: (x, y, z, radius, n, alpha) from an automatic start.

The start needs no manual guess: x, y come from the crop stage's centre, z, radius, index and
alpha from the radial-profile estimator (:mod:`holofit.prefit.estimate`). Where that estimate
is ambiguous (several heights explain the profile about equally well), each candidate is fitted
briefly on a random subset of the pixels and the best one is fitted on all of them.

With an objective lens in the optics (a numerical aperture), the model, the start estimator's
profiles and the fit all use the lens image (:mod:`holofit.scattering.lens`), which is defined
at every height, below the focal plane too; the NA can also be fitted (``fit_na``: an optics
parameter, :mod:`holofit.holomodel.parameters`), starting from the optics' NA (at most the
medium's index), and so can the objective's spherical-aberration coefficients
(``fit_aberration``, :mod:`holofit.aberration`), starting from the optics' aberration.

The fit is holofit's one least-squares fit (:func:`holofit.holomodel.leastsq.solve_least_squares`)
of the forward model (:class:`holofit.holomodel.forward.HologramModel` with the exact Lorenz-Mie
engine) to the unmasked pixels: NaN pixels (masked or saturated by the crop stage) and pixels at
or above an optional saturation level are left out, and an optional random subset keeps only a
fraction of the rest (seeded, so a fit is reproducible). The result is a
:class:`~holofit.holomodel.result.FitResult`, the same type the DDA fit returns; a converged fit
whose parameters leave the search range, or that is far from the data, is ``poor_fit``.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from holofit.aberration import SPHERICAL_NAMES
from holofit.holomodel.aperture import aperture_start
from holofit.holomodel.forward import HologramModel, InvalidParameters
from holofit.holomodel.leastsq import Solution, solve_least_squares
from holofit.holomodel.parameters import ParameterSpace, State
from holofit.holomodel.pixels import select_pixels
from holofit.holomodel.result import FitResult, fit_result
from holofit.holomodel.statistics import estimate_noise_sd
from holofit.optics import Optics
from holofit.particles import Sphere
from holofit.prefit.estimate import ProfileStart, SearchSpace, estimate_starts, profile_table
from holofit.prefit.profile import radial_profile
from holofit.quality import QualityLimits, flag_small_crop
from holofit.scattering.mie import LorenzMie

__all__ = ["SPHERE_COLUMNS", "SphereFitSettings", "fit_sphere_crop"]

#: the fitted quantities of a sphere, in table order
SPHERE_COLUMNS = ("x_um", "y_um", "z_um", "radius_um", "n", "alpha")
#: finite-difference steps: Lorenz-Mie is exact, so they can be tiny
EXACT_STEPS = {"radius_um": 1e-5, "n": 1e-5}
#: the automatic start, recorded with every fit
#: an ok fit's crop holds at least this fraction of the first Fresnel zone about its centre
#: (``reach^2 / (lambda_medium z)``; a good 201-px crop of a sphere 85 um away: 0.80)
MIN_FRESNEL_FRACTION = 0.7
START_COLUMNS = ("n_starts", "start_z_um", "start_radius_um", "start_n", "start_alpha")


@dataclass(frozen=True)
class SphereFitSettings:
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
        Most residual evaluations of the final fit.
    ftol, xtol : float
        Convergence tolerances of the final fit (``scipy.optimize.least_squares``).
    quality : QualityLimits
        When a converged fit is still not ``ok`` (reduced chi^2, R^2); radius and index must
        also end inside the search space (with 5 % margin).
    fit_na : bool
        Fit the objective's numerical aperture too (the optics must have one: the start).
    fit_aberration : tuple of str
        Fit these spherical-aberration coefficients too (``"sa4_rad"``, ``"sa6_rad"``, ...;
        :mod:`holofit.aberration`), from the optics' aberration (the optics must have an NA).
    seed_only : bool
        Seed x, y, z and alpha only (a non-spherical particle, whose sizes the DDA fit's
        initial pass finds): radius and index stay at the radial-profile table's entry (its
        least-squares refinement, slow on a profile no sphere explains, is skipped), the
        estimator's starts are compared by one evaluation each on ``screen_pixels`` pixels,
        and position and alpha are fitted on all pixels with at most ``seed_nfev`` residual
        evaluations to the relative cost change ``seed_ftol`` (:func:`fit_sphere_crop`).
    seed_nfev : int
        Most residual evaluations of a seed fit (each adds a Jacobian of 3 more).
    seed_ftol : float
        Convergence tolerance of a seed fit.
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
    quality: QualityLimits = field(default_factory=QualityLimits)
    fit_na: bool = False
    fit_aberration: tuple[str, ...] = ()
    seed_only: bool = False
    seed_nfev: int = 8
    seed_ftol: float = 1e-3

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
        if self.seed_nfev < 1 or not self.seed_ftol > 0:
            raise ValueError("seed_nfev must be >= 1 and seed_ftol > 0")
        if self.seed_only and self.fit_na:
            raise ValueError("seed_only fits no numerical aperture (fit_na)")
        object.__setattr__(self, "fit_aberration", tuple(self.fit_aberration))
        unknown = [n for n in self.fit_aberration if n not in SPHERICAL_NAMES]
        if unknown:
            raise ValueError(f"unknown aberration coefficient(s) {', '.join(unknown)}; known: "
                             f"{', '.join(SPHERICAL_NAMES)}")
        if self.seed_only and self.fit_aberration:
            raise ValueError("seed_only fits no aberration (fit_aberration)")


def _limits(opts: SphereFitSettings, n_medium: float) -> QualityLimits:
    """The quality limits with the search space's radius and index range (5 % margin)."""
    space = opts.search
    a0, a1 = space.radius_range_um
    if space.index_range is not None:
        n0, n1 = space.index_range
    else:
        n0, n1 = (m * n_medium for m in space.relative_index_range)
    ranges = {"radius_um": (0.95 * a0, 1.05 * a1), "n": (n0 - 0.05 * (n1 - n0) - 1e-3,
                                                        n1 + 0.05 * (n1 - n0) + 1e-3)}
    ranges.update(opts.quality.ranges)
    return dataclasses.replace(opts.quality, ranges=ranges)


def _crop_too_small(values: dict[str, float], shape: tuple[int, ...],
                    corner_rc: tuple[int, int], pixel_size_um: float,
                    wavelength_medium_um: float) -> str:
    """Why the crop cannot tell this fit's height ('' if it can).

    The height is read from the fringes' curvature; a crop that holds less than
    :data:`MIN_FRESNEL_FRACTION` of the first Fresnel zone (``rho^2 <= lambda z``) about the
    fitted centre shows too little of it, and converged, close-looking fits land far from the
    truth (measured: 101-px crops of spheres 55-85 um from focus, 0.048 um pixels, ended at
    z = 50-55 um with reduced chi^2 ~1 and errors 40-250 times the reported ones).
    """
    z = abs(values["z_um"])
    x = values["x_um"] / pixel_size_um - corner_rc[1]
    y = values["y_um"] / pixel_size_um - corner_rc[0]
    rows, cols = shape[:2]
    reach_um = pixel_size_um * max(0.0, min(x + 0.5, cols - 0.5 - x, y + 0.5, rows - 0.5 - y))
    shown = reach_um**2 / (wavelength_medium_um * z) if z > 0 else np.inf
    if shown >= MIN_FRESNEL_FRACTION:
        return ""
    return (f"the crop reaches {reach_um:.2f} um from the fitted centre, {shown:.2f} of the first "
            f"Fresnel zone at z = {z:.1f} um (at least {MIN_FRESNEL_FRACTION} needed): too small "
            "to tell the height; crop larger (holofit crop --size)")


def fit_sphere_crop(
    crop: NDArray,
    corner_rc: tuple[int, int],
    centre_xy_um: tuple[float, float],
    optics: Optics,
    pixel_size_um: float,
    options: SphereFitSettings | None = None,
    seed: int = 0,
) -> FitResult:
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
    options : SphereFitSettings, optional
        Fit settings (``seed_only``: the short seed fit of a non-spherical particle).
    seed : int
        Seed of the random pixel subsets (use the frame number for reproducible batches).

    Returns
    -------
    FitResult
        Values ``x_um, y_um, z_um, radius_um, n, alpha`` (and ``numerical_aperture``,
        ``sa4_rad``, ... if fitted) with errors; ``extra`` holds the
        automatic start (``n_starts, start_z_um, start_radius_um, start_n, start_alpha``),
        ``n_masked`` and the one-time set-up this fit paid (``setup_time_s``).

    Raises
    ------
    ValueError
        If too few pixels are left, no start can be found, the z range is one the model cannot
        describe (:meth:`SearchSpace.check_heights`), or the NA is to be fitted and the optics
        have none.
    """
    t0 = time.perf_counter()
    opts = options or SphereFitSettings()
    opts.search.check_heights(optics.numerical_aperture is not None)
    rng = np.random.default_rng(seed)
    crop_fit = _CropFit(crop, corner_rc, centre_xy_um, optics, pixel_size_um, opts, rng)
    if opts.seed_only:
        space, sol, chosen = crop_fit.seed()
    else:
        space, sol, chosen = crop_fit.full()
    data = crop_fit.data
    noise = opts.noise_sd if opts.noise_sd is not None else estimate_noise_sd(
        data, crop_fit.pix.valid)
    result = fit_result(space, sol, crop_fit.pix.data, noise, _limits(opts, optics.n_medium))
    if result.ok:
        why = _crop_too_small(result.values, data.shape, corner_rc, pixel_size_um,
                              optics.wavelength_medium_um)
        flag_small_crop(result, why)
    result.extra = {
        "n_starts": len(crop_fit.starts),
        "start_z_um": chosen.z_um,
        "start_radius_um": chosen.radius_um,
        "start_n": chosen.index,
        "start_alpha": chosen.alpha,
        "n_masked": crop_fit.pix.n_masked,
        "setup_time_s": crop_fit.setup_s,
    }
    result.time_s = time.perf_counter() - t0 - crop_fit.setup_s
    return result


class _CropFit:
    """One crop's pixels, its automatic starts, and the fits from them."""

    def __init__(self, crop: NDArray, corner_rc: tuple[int, int],
                 centre_xy_um: tuple[float, float], optics: Optics, pixel_size_um: float,
                 opts: SphereFitSettings, rng: np.random.Generator) -> None:
        self.optics, self.opts, self.rng = optics, opts, rng
        self.na_start = aperture_start(optics) if opts.fit_na else None
        if opts.fit_aberration and optics.numerical_aperture is None:
            raise ValueError("fitting the aberration needs an objective: the optics have no "
                             "numerical_aperture")
        self.aberration_start = optics.aberration if opts.fit_aberration else None
        self.data = np.asarray(crop, dtype=float)
        n_free = 6 - (opts.fix_alpha is not None) + opts.fit_na + len(opts.fit_aberration)
        self.pix = select_pixels(self.data, corner_rc, pixel_size_um,
                                 saturation=opts.saturation, fraction=opts.pixel_fraction,
                                 rng=rng, min_pixels=max(100, 10 * n_free))
        self.xc, self.yc = (float(v) for v in centre_xy_um)
        self.starts, self.setup_s = self._automatic_starts(corner_rc, pixel_size_um)
        self.screen_free = ("x_um", "y_um", "z_um", "radius_um", "n") + (
            ("alpha",) if opts.fix_alpha is None else ())
        self.theory = LorenzMie()

    def _automatic_starts(self, corner_rc: tuple[int, int], pixel_size_um: float
                          ) -> tuple[list[ProfileStart], float]:
        """The radial-profile estimator's starts about the crop stage's centre, and the
        seconds its table took (one-time set-up)."""
        opts, data = self.opts, self.data
        centre_rc = (self.yc / pixel_size_um - corner_rc[0],
                     self.xc / pixel_size_um - corner_rc[1])
        n_bins = min(data.shape) // 2 - 1
        search = opts.search.for_crop(n_bins * pixel_size_um,
                                      self.optics.wavelength_medium_um)
        t_setup = time.perf_counter()
        table = profile_table(self.optics, float(pixel_size_um), n_bins, search)
        setup_s = time.perf_counter() - t_setup
        prof = radial_profile(data, self.pix.valid, centre_rc, n_bins)
        starts = estimate_starts(table, prof, fix_alpha=opts.fix_alpha,
                                 index_imag=opts.index_imag, max_starts=opts.max_starts,
                                 ambiguity_ratio=opts.ambiguity_ratio,
                                 refine=not opts.seed_only)
        if not starts:
            raise ValueError("no automatic start found (the radial profile has no minimum)")
        return starts, setup_s

    def space_from(self, s: ProfileStart, names: tuple[str, ...]) -> ParameterSpace:
        opts = self.opts
        alpha = s.alpha if opts.fix_alpha is None else opts.fix_alpha
        sphere = Sphere(s.radius_um, complex(s.index, opts.index_imag))
        state = State((self.xc, self.yc, s.z_um), None, alpha,
                      (("radius_um", s.radius_um), ("n", s.index)), self.na_start,
                      self.aberration_start)
        return ParameterSpace(sphere, names, state, step_overrides=EXACT_STEPS)

    def _subset(self) -> NDArray[np.intp]:
        d = self.pix.data
        m = min(self.opts.screen_pixels, d.size)
        return np.sort(self.rng.choice(d.size, size=m, replace=False))

    def _model(self, space: ParameterSpace, index: NDArray[np.intp] | None = None
               ) -> HologramModel:
        pix = self.pix
        xs, ys = (pix.xs_um, pix.ys_um) if index is None else (pix.xs_um[index],
                                                               pix.ys_um[index])
        return HologramModel(self.theory, space, self.optics, xs, ys)

    def full(self) -> tuple[ParameterSpace, Solution, ProfileStart]:
        """Every start screened on a subset (if several), the best fitted on all pixels."""
        opts, d = self.opts, self.pix.data
        n_eval = 0
        chosen = self.starts[0]
        space = self.space_from(chosen, self.screen_free)
        vector = space.initial_vector()
        if len(self.starts) > 1:
            sub = self._subset()
            best_cost = np.inf
            for s in self.starts:
                cand = self.space_from(s, self.screen_free)
                sol = solve_least_squares(self._model(cand, sub), d[sub],
                                          cand.initial_vector(), max_nfev=40, ftol=1e-6,
                                          xtol=1e-6)
                n_eval += sol.n_eval
                if np.isfinite(sol.rss) and sol.rss < best_cost:
                    best_cost, chosen, space, vector = sol.rss, s, cand, sol.vector
        if opts.fit_na or opts.fit_aberration:
            # the screened state, the aperture (holofit.holomodel.leastsq) and the aberration
            # free
            free = (*self.screen_free, *(("numerical_aperture",) if opts.fit_na else ()),
                    *opts.fit_aberration)
            space = ParameterSpace(space.model, free, space.state(vector),
                                   step_overrides=EXACT_STEPS)
            vector = space.initial_vector()
        sol = solve_least_squares(self._model(space), d, vector, max_nfev=opts.max_nfev,
                                  ftol=opts.ftol, xtol=opts.xtol)
        sol.n_eval += n_eval
        return space, sol, chosen

    def seed(self) -> tuple[ParameterSpace, Solution, ProfileStart]:
        """``seed_only``: position and alpha fitted briefly from the best start (each start
        evaluated once on a subset), radius and index held at the estimate."""
        opts, d = self.opts, self.pix.data
        names = tuple(n for n in self.screen_free if n not in ("radius_um", "n"))
        n_eval = 0
        chosen = self.starts[0]
        if len(self.starts) > 1:
            sub = self._subset()
            costs = []
            for s in self.starts:
                model = self._model(self.space_from(s, names), sub)
                try:
                    r = model.hologram(model.space.initial_vector()) - d[sub]
                    costs.append(float(r @ r))
                except InvalidParameters:
                    costs.append(np.inf)
                n_eval += model.n_holograms
            chosen = self.starts[int(np.argmin(costs))]
        space = self.space_from(chosen, names)
        sol = solve_least_squares(self._model(space), d, space.initial_vector(),
                                  max_nfev=opts.seed_nfev, ftol=opts.seed_ftol,
                                  xtol=opts.seed_ftol)
        sol.n_eval += n_eval
        return space, sol, chosen
