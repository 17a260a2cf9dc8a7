"""The fit of one frame from the library's candidate orientations, with the runner-up and the
ambiguity flag; and the per-crop fitting core every fit of a frame shares (:class:`FrameFit`).

1. Starts: the library's best candidates (``n_starts``) and, for the known degeneracy, the
   mirror image of the best one through the x-y plane (``theta -> pi - theta``: the paper found
   this second minimum for a Janus particle, z shifted by 0.19 um).
2. Screening: each start's orientation is solved once and held while position and alpha are
   fitted on a random subset of the pixels (a position change needs no new solve), so the
   starts compare at their best placement for the cost of one solve each.
3. The best screened start is fitted on all pixels with the pass's free parameters; so is the
   second (the runner-up), unless both end in the same minimum.
4. ``delta_chi2 = (rss_runner_up - rss_best) / noise_sd^2``: below ``ambiguity_chi2`` the two
   are not distinguishable at the noise level and the frame is flagged ``ambiguous``.

Fits from a known state (a neighbouring frame's fit) are :mod:`holofit.fit.warm`'s.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from holofit.cache import LRUCache
from holofit.conventions import euler_zyz
from holofit.fit.problem import FrameProblem
from holofit.fit.settings import FrameFitSettings
from holofit.holomodel.aperture import aperture_start
from holofit.holomodel.forward import HologramModel, InvalidParameters
from holofit.holomodel.leastsq import Solution, solve_least_squares
from holofit.holomodel.parameters import APERTURE, ParameterSpace, State, static_values
from holofit.holomodel.pixels import PixelSelection, select_pixels
from holofit.holomodel.result import FitResult, fit_result
from holofit.holomodel.statistics import estimate_noise_sd
from holofit.library.search import Candidate
from holofit.particles import ParticleModel

__all__ = [
    "RUNNER_UP_COLUMNS",
    "SAME_BASIN_RAD",
    "SAME_BASIN_Z_UM",
    "Branch",
    "FrameFit",
    "branch_rss",
    "branch_state",
    "challenge",
    "fit_frame",
    "frame_result",
    "mirrored",
    "same_basin",
]

#: what every DDA fit row records about its starts and its runner-up
RUNNER_UP_COLUMNS = (
    "n_solves", "n_starts", "start_theta_rad", "start_psi_rad", "library_r2", "chi2_runner_up",
    "delta_chi2", "ambiguous", "runner_up_theta_rad", "runner_up_psi_rad", "runner_up_z_um",
)
#: two fitted orientations closer than this (rad) are the same basin
SAME_BASIN_RAD = math.radians(5.0)
#: ... unless their heights differ by more than this (um)
SAME_BASIN_Z_UM = 0.1


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
class Branch:
    """One start's fit: where it started, its parameter space and its solution."""

    start: Candidate | None
    space: ParameterSpace
    solution: Solution


class FrameFit:
    """One crop's pixels, noise and engine, and the fits run on them (counted): what every
    fit of a :class:`~holofit.fit.problem.FrameProblem` shares."""

    def __init__(self, problem: FrameProblem, rng: np.random.Generator | None = None) -> None:
        opts, crop = problem.settings, problem.crop
        rng = np.random.default_rng(problem.seed) if rng is None else rng
        self.theory, self.model, self.optics, self.opts, self.rng = (
            problem.theory, problem.model, problem.optics, opts, rng)
        free = problem.free
        self.pix = select_pixels(crop, problem.corner, problem.pixel_size_um,
                                 saturation=opts.saturation, fraction=opts.pixel_fraction,
                                 rng=rng, min_pixels=200)
        # a fixed field added to the model's (a neighbour's hologram), on the fit's pixels
        self.extra: tuple[NDArray, NDArray] | None = None
        extra_field = problem.extra_field
        if extra_field is not None:
            fx, fy = (np.asarray(f, dtype=complex) for f in extra_field)
            if fx.shape != np.shape(crop) or fy.shape != np.shape(crop):
                raise ValueError(f"extra_field must have the crop's shape {np.shape(crop)}")
            self.extra = (fx.ravel()[self.pix.index], fy.ravel()[self.pix.index])
        self.noise = (opts.noise_sd if opts.noise_sd is not None
                      else estimate_noise_sd(crop, self.pix.valid))
        self.statics = static_values(problem.model)
        self.na_start = aperture_start(problem.optics) if APERTURE.name in free else None
        self.models: list[HologramModel] = []
        self.waves: LRUCache | None = None
        self.n_eval = 0

    def state_at(self, start: Candidate | None, position_um: Sequence[float],
                 alpha: float) -> State:
        """The start state of a library candidate at the given placement."""
        rot = None if start is None else euler_zyz(start.psi, start.theta, start.phi)
        return State(tuple(position_um), rot, alpha, self.statics,  # type: ignore[arg-type]
                     self.na_start)

    def _extra(self, index: NDArray[np.intp] | None) -> tuple[NDArray, NDArray] | None:
        if self.extra is None or index is None:
            return self.extra
        return self.extra[0][index], self.extra[1][index]

    def run(self, space: ParameterSpace, index: NDArray[np.intp] | None, nfev: int,
            tol: float, stop_chi2: float = 0.0) -> Solution:
        """Fit ``space`` from its start on all pixels (``index`` None) or a subset; with
        ``stop_chi2`` > 0 also stopping where the predicted chi^2 decrease is below it."""
        pix = self.pix
        xs, ys, data = ((pix.xs_um, pix.ys_um, pix.data) if index is None
                        else (pix.xs_um[index], pix.ys_um[index], pix.data[index]))
        m = HologramModel(self.theory, space, self.optics, xs, ys,
                          far_field=self.opts.far_field, waves=self.waves,
                          extra_field=self._extra(index))
        self.waves = m.waves  # every fit of the crop shares the solved waves
        self.models.append(m)
        stop = (stop_chi2 * self.noise**2 if stop_chi2 > 0 and self.noise > 0 else None)
        sol = solve_least_squares(m, data, space.initial_vector(), max_nfev=nfev, ftol=tol,
                                  xtol=tol, stop_rss=stop)
        self.n_eval += sol.n_eval
        return sol

    def evaluate(self, state: State, index: NDArray[np.intp]) -> Branch:
        """``state`` evaluated once on the pixels ``index`` (nothing fitted)."""
        pix = self.pix
        space = ParameterSpace(self.model, [], state)
        m = HologramModel(self.theory, space, self.optics, pix.xs_um[index], pix.ys_um[index],
                          far_field=self.opts.far_field, waves=self.waves,
                          extra_field=self._extra(index))
        self.models.append(m)
        try:
            res = m.hologram_of(state) - pix.data[index]
        except InvalidParameters:
            res = np.full(index.size, np.inf)
        self.n_eval += m.n_holograms
        rss = float(res @ res)
        return Branch(None, space, Solution(np.empty(0), res, np.empty((index.size, 0)), rss,
                                             m.n_holograms, True, "evaluated"))

    def screen(self, state: State, free: Sequence[str], sub: NDArray[np.intp],
               start: Candidate | None = None) -> Branch:
        """Hold the orientation (one solve), fit position and alpha on the pixels ``sub``."""
        held = [n for n in ("x_um", "y_um", "z_um", "alpha") if n in free]
        space = ParameterSpace(self.model, held, state)
        return Branch(start, space, self.run(space, sub, self.opts.screen_nfev, 1e-4))

    def refine(self, state: State, free: Sequence[str], start: Candidate | None,
               statics: tuple | None = None, warm: bool = False) -> Branch:
        """A fit on all pixels from ``state``; with ``statics``, those are held there (the
        runner-up then differs from the best in placement and orientation only, which is
        what the ambiguity is); ``warm``: with the stopping rule of ``warm_stop_chi2``."""
        names = list(free)
        if statics is not None:
            state = replace(state, statics=statics)
            static_names = {name for name, _ in statics}
            names = [n for n in free if n not in static_names]
        stop = max(self.opts.warm_stop_chi2 if warm else 0.0, self.opts.stop_chi2)
        space = ParameterSpace(self.model, names, state)
        return Branch(start, space, self.run(space, None, self.opts.max_nfev, self.opts.ftol,
                                              stop))

    @property
    def n_solves(self) -> int:
        return sum(m.n_solves for m in self.models)


def branch_state(branch: Branch) -> State:
    return branch.space.state(branch.solution.vector)


def branch_rss(branch: Branch) -> float:
    rss = branch.solution.rss
    return rss if np.isfinite(rss) else np.inf


def _library_starts(model: ParticleModel, candidates: Sequence[Candidate],
                    opts: FrameFitSettings) -> list[Candidate | None]:
    """The distinct starts of a frame: the best candidates and the mirror of the first."""
    if not model.anisotropic:
        return [None]
    if not candidates:
        raise ValueError("no starting orientation for an anisotropic particle")
    ranked = list(candidates[: opts.n_starts])
    if opts.mirror:
        ranked.append(mirrored(ranked[0]))
    return list(_distinct_starts(ranked, model))


def same_basin(a: State, b: State, model: ParticleModel) -> bool:
    return (_axis_angle(a, b, model.head_tail_symmetric) < SAME_BASIN_RAD
            and abs(a.position[2] - b.position[2]) < SAME_BASIN_Z_UM)


def challenge(fit: FrameFit, best: Branch, runner: Branch, free: Sequence[str]
               ) -> tuple[Branch, Branch | None]:
    """Compare the refined runner-up with the best: one minimum (no runner-up), or the better
    of two (the challenger refitted with every parameter of the pass if it held some)."""
    if same_basin(branch_state(best), branch_state(runner), fit.model):
        return best, None  # both starts led to the same minimum: nothing to confuse
    if runner.solution.rss < best.solution.rss:
        challenger = (fit.refine(branch_state(runner), free, runner.start)
                      if set(runner.space.names) != set(best.space.names) else runner)
        return challenger, best
    return best, runner


def frame_result(fit: FrameFit, best: Branch, runner: Branch | None, n_starts: int,
                  runner_rss: float | None = None) -> FitResult:
    """The best fit's result with the runner-up columns (``runner_rss``: the runner-up's
    residual sum of squares on all pixels, if not its own solution's)."""
    pix, opts, noise = fit.pix, fit.opts, fit.noise
    result = fit_result(best.space, best.solution, pix.data, noise, opts.quality,
                        n_solves=fit.n_solves)
    result.n_eval = fit.n_eval
    extra: dict[str, float | int] = {c: math.nan for c in RUNNER_UP_COLUMNS}
    extra.update(n_starts=n_starts, n_masked=pix.n_masked, ambiguous=0,
                 n_solves=result.n_solves)
    if best.start is not None:
        extra.update(start_theta_rad=best.start.theta, start_psi_rad=best.start.psi,
                     library_r2=best.start.r2)
    if runner is not None:
        rss_runner = runner.solution.rss if runner_rss is None else runner_rss
        delta = (rss_runner - best.solution.rss) / noise**2 if noise > 0 else math.nan
        rs = branch_state(runner)
        psi, theta, _ = rs.angles()
        extra.update(chi2_runner_up=rss_runner / pix.size, delta_chi2=delta,
                     ambiguous=int(delta < opts.ambiguity_chi2), runner_up_theta_rad=theta,
                     runner_up_psi_rad=psi, runner_up_z_um=rs.position[2])
    result.extra = extra
    return result


def fit_frame(problem: FrameProblem, position_um: tuple[float, float, float], alpha: float,
              candidates: Sequence[Candidate]) -> FitResult:
    """Fit one crop from the library's starts (module docstring).

    Parameters
    ----------
    problem : FrameProblem
        The crop, its engine and model, what is fitted and how.
    position_um : tuple of float
        Start ``(x, y, z)`` (the prefit's), um.
    alpha : float
        Start alpha.
    candidates : sequence of Candidate
        Starting orientations, best first (the library's); ignored for isotropic particles.

    Returns
    -------
    FitResult
        With ``extra`` = :data:`RUNNER_UP_COLUMNS` and ``n_masked``.
    """
    t0 = time.perf_counter()
    opts, model, free = problem.settings, problem.model, problem.free
    rng = np.random.default_rng(problem.seed)
    fit = FrameFit(problem, rng)
    starts = _library_starts(model, candidates, opts)
    # screening: each start's orientation held (one solve each), position and alpha fitted on
    # a pixel subset (no further solves), so that starts compare at their best placement
    screened: list[Branch] = []
    if len(starts) > 1:
        sub = subset(fit.pix, opts.screen_pixels, rng)
        screened = sorted((fit.screen(fit.state_at(s, position_um, alpha), free, sub, s)
                           for s in starts), key=branch_rss)
    first = (branch_state(screened[0]) if screened
             else fit.state_at(starts[0], position_um, alpha))
    best = fit.refine(first, free, screened[0].start if screened else starts[0])
    best, runner, runner_rss = _runner_up(fit, best, screened, free, opts)
    result = frame_result(fit, best, runner, len(starts), runner_rss)
    result.time_s = time.perf_counter() - t0
    return result


def _runner_up(fit: FrameFit, best: Branch, screened: list[Branch], free: Sequence[str],
               opts: FrameFitSettings) -> tuple[Branch, Branch | None, float | None]:
    """The second screened start refined into the runner-up (which may displace the best), or
    taken as screened with its residual scaled to all pixels; none with one start."""
    if len(screened) < 2:
        return best, None, None
    if opts.refine_runner_up:
        runner = fit.refine(branch_state(screened[1]), free, screened[1].start,
                            branch_state(best).statics)
        best, challenger = challenge(fit, best, runner, free)
        return best, challenger, None
    runner = screened[1]  # screened on a subset: scale to all pixels
    return best, runner, runner.solution.rss * (fit.pix.size / max(
        runner.solution.residuals.size, 1))


def subset(pix: PixelSelection, n: int, rng: np.random.Generator) -> NDArray[np.intp]:
    if pix.size <= n:
        return np.arange(pix.size)
    return np.sort(rng.choice(pix.size, size=n, replace=False))
