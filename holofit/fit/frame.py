"""DDA fit of one frame: from the library's candidate orientations to the best fit, with the
runner-up and the ambiguity flag.

1. Starts: the library's best candidates (``n_starts``) and, for the known degeneracy, the
   mirror image of the best one through the x-y plane (``theta -> pi - theta``; for a Janus
   particle the paper found this second minimum at R^2 = 0.9997 with z shifted by 0.19 um).
2. Screening: each start's orientation is solved once and held while position and alpha are
   fitted on a random subset of the pixels (a position change needs no new solve), so the
   starts compare at their best placement for the cost of one solve each.
3. The best screened start is fitted on all pixels with the pass's free parameters; so is the
   second (the runner-up), unless both end in the same minimum.
4. ``delta_chi2 = (rss_runner_up - rss_best) / noise_sd^2``: below ``ambiguity_chi2`` the two
   are not distinguishable at the noise level and the frame is flagged ``ambiguous``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from holofit.conventions import euler_zyz
from holofit.fitting.aperture import aperture_start
from holofit.fitting.forward import HologramModel
from holofit.fitting.leastsq import Solution, solve_least_squares
from holofit.fitting.parameters import APERTURE, ParameterSpace, State, static_values
from holofit.fitting.pixels import PixelSelection, select_pixels
from holofit.fitting.result import FitResult, QualityLimits, fit_result
from holofit.fitting.statistics import estimate_noise_sd
from holofit.library.search import Candidate
from holofit.models import ParticleModel
from holofit.optics import Optics
from holofit.scattering.theory import ScatteringTheory

__all__ = ["RUNNER_UP_COLUMNS", "FrameFitOptions", "fit_frame"]

#: what every DDA fit row records about its starts and its runner-up
RUNNER_UP_COLUMNS = (
    "n_solves", "n_starts", "start_theta_rad", "start_psi_rad", "library_r2", "chi2_runner_up",
    "delta_chi2", "ambiguous", "runner_up_theta_rad", "runner_up_psi_rad", "runner_up_z_um",
)
#: two fitted orientations closer than this (rad) are the same basin
SAME_BASIN_RAD = math.radians(5.0)
#: ... unless their heights differ by more than this (um)
SAME_BASIN_Z_UM = 0.1


@dataclass(frozen=True)
class FrameFitOptions:
    """How a frame is fitted.

    Attributes
    ----------
    n_starts : int
        Library candidates used as starts.
    mirror : bool
        Also start from the mirror image of the best candidate through the x-y plane.
    screen_pixels : int
        Pixels of the random subset the starts are screened on.
    screen_nfev : int
        Most residual evaluations of a screening fit (position and alpha only: no solves).
    refine_runner_up : bool
        Fit the runner-up on all pixels too (its chi^2 then compares exactly with the best's).
    pixel_fraction : float
        Fit a random subset with this fraction of the usable pixels (1: all).
    saturation : float, optional
        Leave out pixels at or above this normalised level (NaN pixels always are).
    noise_sd : float, optional
        Pixel noise; estimated from each crop if not given.
    max_nfev : int
        Most residual evaluations of the full fit.
    ftol, xtol : float
        Convergence tolerances of the full fit.
    ambiguity_chi2 : float
        Frames whose runner-up is within this chi^2 (in units of the pixel noise) are flagged
        ``ambiguous``.
    quality : QualityLimits
        When a converged fit is still not ``ok``.
    far_field : bool
        Asymptotic far-field form of the scattered field (as ADDA and the paper).
    """

    n_starts: int = 2
    mirror: bool = True
    screen_pixels: int = 3000
    screen_nfev: int = 20
    refine_runner_up: bool = True
    pixel_fraction: float = 1.0
    saturation: float | None = None
    noise_sd: float | None = None
    max_nfev: int = 100
    ftol: float = 1e-6
    xtol: float = 1e-6
    ambiguity_chi2: float = 9.0
    quality: QualityLimits = field(default_factory=QualityLimits)
    far_field: bool = False

    def __post_init__(self) -> None:
        if self.n_starts < 1:
            raise ValueError(f"n_starts must be >= 1, got {self.n_starts}")
        if not 0 < self.pixel_fraction <= 1:
            raise ValueError(f"pixel_fraction must be in (0, 1], got {self.pixel_fraction}")
        if self.screen_pixels < 100 or self.screen_nfev < 1 or self.max_nfev < 1:
            raise ValueError("screen_pixels >= 100, screen_nfev >= 1 and max_nfev >= 1 needed")
        if not self.ambiguity_chi2 >= 0:
            raise ValueError(f"ambiguity_chi2 must be >= 0, got {self.ambiguity_chi2}")


def mirrored(c: Candidate) -> Candidate:
    """The orientation mirrored through the x-y plane (the axis' z component flips)."""
    return replace(c, theta=math.pi - c.theta, r2=math.nan)


def _axis_angle(a: State, b: State, head_tail: bool) -> float:
    if a.rotation is None or b.rotation is None:
        return 0.0
    c = float(np.dot(a.rotation[:, 2], b.rotation[:, 2]))
    if head_tail:
        c = abs(c)
    return math.acos(max(-1.0, min(1.0, c)))


def _distinct_starts(cands: Sequence[Candidate], model: ParticleModel) -> list[Candidate]:
    out: list[Candidate] = []
    for c in cands:
        u = euler_zyz(c.psi, c.theta, c.phi)[:, 2]
        dup = False
        for o in out:
            v = euler_zyz(o.psi, o.theta, o.phi)[:, 2]
            dot = float(np.dot(u, v))
            if model.head_tail_symmetric:
                dot = abs(dot)
            if math.acos(max(-1.0, min(1.0, dot))) < SAME_BASIN_RAD and (
                    model.axisymmetric or abs(c.phi - o.phi) < SAME_BASIN_RAD):
                dup = True
                break
        if not dup:
            out.append(c)
    return out


@dataclass
class _Branch:
    start: Candidate | None
    space: ParameterSpace
    solution: Solution


def fit_frame(
    crop: NDArray,
    corner_rc: tuple[int, int],
    pixel_size_um: float,
    theory: ScatteringTheory,
    model: ParticleModel,
    optics: Optics,
    position_um: tuple[float, float, float],
    alpha: float,
    candidates: Sequence[Candidate],
    free: Sequence[str],
    options: FrameFitOptions | None = None,
    seed: int = 0,
) -> FitResult:
    """Fit the DDA hologram of ``model`` to one crop.

    Parameters
    ----------
    crop : ndarray, shape (rows, cols)
        Normalised hologram; NaN marks pixels to leave out.
    corner_rc : tuple of int
        Full-frame ``(row, column)`` of the crop's pixel ``[0, 0]``.
    pixel_size_um : float
        Pixel pitch, um.
    theory : ScatteringTheory
        The engine (kept across frames by the caller: its caches and warm starts pay).
    model : ParticleModel
        The particle; its static parameters are the start values (and the fixed values of the
        ones not in ``free``).
    optics : Optics
        Illumination.
    position_um : tuple of float
        Start ``(x, y, z)`` (the prefit's), um.
    alpha : float
        Start alpha.
    candidates : sequence of Candidate
        Starting orientations, best first (the library's); ignored for isotropic particles.
    free : sequence of str
        Fitted parameters: position and static names, ``alpha``, ``orientation``,
        ``numerical_aperture`` (starting from the optics' NA).
    options : FrameFitOptions, optional
        Settings.
    seed : int
        Seed of the random pixel subsets.

    Returns
    -------
    FitResult
        With ``extra`` = :data:`RUNNER_UP_COLUMNS` and ``n_masked``.
    """
    t0 = time.perf_counter()
    opts = options or FrameFitOptions()
    rng = np.random.default_rng(seed)
    pix = select_pixels(crop, corner_rc, pixel_size_um, saturation=opts.saturation,
                        fraction=opts.pixel_fraction, rng=rng, min_pixels=200)
    noise = opts.noise_sd if opts.noise_sd is not None else estimate_noise_sd(crop, pix.valid)
    statics = static_values(model)
    na_start = aperture_start(optics) if APERTURE.name in free else None
    if model.anisotropic:
        if not candidates:
            raise ValueError("no starting orientation for an anisotropic particle")
        ranked = list(candidates[: opts.n_starts])
        if opts.mirror:
            ranked.append(mirrored(ranked[0]))
        starts: list[Candidate | None] = list(_distinct_starts(ranked, model))
    else:
        starts = [None]

    def space_for(start: Candidate | State | None, names: Sequence[str]) -> ParameterSpace:
        if isinstance(start, State):
            state = start
        else:
            rot = None if start is None else euler_zyz(start.psi, start.theta, start.phi)
            state = State(tuple(position_um), rot, alpha, statics,  # type: ignore[arg-type]
                          na_start)
        return ParameterSpace(model, names, state)

    full = HologramModel(theory, space_for(starts[0], free), optics, pix.xs_um, pix.ys_um,
                         far_field=opts.far_field)
    models: list[HologramModel] = [full]
    n_eval = 0

    def run(space: ParameterSpace, index: NDArray[np.intp] | None, nfev: int,
            tol: float) -> Solution:
        nonlocal n_eval
        xs, ys, data = ((pix.xs_um, pix.ys_um, pix.data) if index is None
                        else (pix.xs_um[index], pix.ys_um[index], pix.data[index]))
        m = HologramModel(theory, space, optics, xs, ys, far_field=opts.far_field,
                          waves=full.waves)
        models.append(m)
        sol = solve_least_squares(m, data, space.initial_vector(), max_nfev=nfev, ftol=tol,
                                  xtol=tol)
        n_eval += sol.n_eval
        return sol

    # screening: each start's orientation held (one solve each), position and alpha fitted on
    # a pixel subset (no further solves), so that starts compare at their best placement
    screened: list[_Branch] = []
    if len(starts) > 1:
        sub = _subset(pix, opts.screen_pixels, rng)
        held = [n for n in ("x_um", "y_um", "z_um", "alpha") if n in free]
        for s in starts:
            space = space_for(s, held)
            screened.append(_Branch(s, space, run(space, sub, opts.screen_nfev, 1e-4)))
        screened.sort(key=lambda b: b.solution.rss if np.isfinite(b.solution.rss) else np.inf)

    def refine(branch: _Branch | None, statics: tuple | None = None) -> _Branch:
        start_state = (branch.space.state(branch.solution.vector) if branch is not None
                       else space_for(starts[0], free).start)
        names = free
        if statics is not None:
            # the runner-up takes the best fit's static parameters and keeps them: the two
            # then differ in placement and orientation only, which is what the ambiguity is
            start_state = replace(start_state, statics=statics)
            static_names = {name for name, _ in statics}
            names = [n for n in free if n not in static_names]
        space = space_for(start_state, names)
        sol = run(space, None, opts.max_nfev, opts.ftol)
        return _Branch(branch.start if branch is not None else starts[0], space, sol)

    best = refine(screened[0] if screened else None)
    runner: _Branch | None = None
    if len(screened) > 1:
        best_statics = best.space.state(best.solution.vector).statics
        runner = (refine(screened[1], best_statics) if opts.refine_runner_up
                  else screened[1])
        if opts.refine_runner_up:
            a = best.space.state(best.solution.vector)
            b = runner.space.state(runner.solution.vector)
            if (_axis_angle(a, b, model.head_tail_symmetric) < SAME_BASIN_RAD
                    and abs(a.position[2] - b.position[2]) < SAME_BASIN_Z_UM):
                runner = None  # both starts led to the same minimum: nothing to confuse
            elif runner.solution.rss < best.solution.rss:
                # the other branch is better: fit it with every parameter of the pass
                challenger = refine(runner) if set(runner.space.names) != set(
                    best.space.names) else runner
                best, runner = challenger, best

    result = fit_result(best.space, best.solution, pix.data, noise, opts.quality,
                        n_solves=sum(m.n_solves for m in models))
    result.n_eval = n_eval
    extra: dict[str, float | int] = {c: math.nan for c in RUNNER_UP_COLUMNS}
    extra.update(n_starts=len(starts), n_masked=pix.n_masked, ambiguous=0,
                 n_solves=result.n_solves)
    if best.start is not None:
        extra.update(start_theta_rad=best.start.theta, start_psi_rad=best.start.psi,
                     library_r2=best.start.r2)
    if runner is not None:
        rss_runner = runner.solution.rss
        if not opts.refine_runner_up:  # screened on a subset: scale to all pixels
            rss_runner *= pix.size / max(runner.solution.residuals.size, 1)
        delta = (rss_runner - best.solution.rss) / noise**2 if noise > 0 else math.nan
        rs = runner.space.state(runner.solution.vector)
        psi, theta, _ = rs.angles()
        extra.update(chi2_runner_up=rss_runner / pix.size, delta_chi2=delta,
                     ambiguous=int(delta < opts.ambiguity_chi2), runner_up_theta_rad=theta,
                     runner_up_psi_rad=psi, runner_up_z_um=rs.position[2])
    result.extra = extra
    result.time_s = time.perf_counter() - t0
    return result


def _subset(pix: PixelSelection, n: int, rng: np.random.Generator) -> NDArray[np.intp]:
    if pix.size <= n:
        return np.arange(pix.size)
    return np.sort(rng.choice(pix.size, size=n, replace=False))
