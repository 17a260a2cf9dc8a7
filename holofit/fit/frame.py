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

from holofit.cache import LRUCache
from holofit.conventions import euler_zyz
from holofit.holomodel.aperture import aperture_start
from holofit.holomodel.forward import HologramModel, InvalidParameters
from holofit.holomodel.leastsq import Solution, solve_least_squares
from holofit.holomodel.parameters import APERTURE, ParameterSpace, State, static_values
from holofit.holomodel.pixels import PixelSelection, select_pixels
from holofit.holomodel.result import FitResult, QualityLimits, fit_result
from holofit.holomodel.statistics import estimate_noise_sd
from holofit.library.search import Candidate
from holofit.optics import Optics
from holofit.particles import ParticleModel
from holofit.scattering.theory import ScatteringTheory

__all__ = [
    "RUNNER_UP_COLUMNS",
    "CarriedRunnerUp",
    "FrameFitSettings",
    "WarmFit",
    "evaluate_frame",
    "fit_frame",
    "fit_frame_warm",
    "mirror_state",
]

#: what every DDA fit row records about its starts and its runner-up
RUNNER_UP_COLUMNS = (
    "n_solves", "n_starts", "start_theta_rad", "start_psi_rad", "library_r2", "chi2_runner_up",
    "delta_chi2", "ambiguous", "runner_up_theta_rad", "runner_up_psi_rad", "runner_up_z_um",
)
#: a carried runner-up's bound may exceed its last fitted delta_chi2 by this fraction (plus
#: the refit margin) before it is screened again (:func:`fit_frame_warm`)
CARRY_DRIFT = 0.25
#: two fitted orientations closer than this (rad) are the same basin
SAME_BASIN_RAD = math.radians(5.0)
#: ... unless their heights differ by more than this (um)
SAME_BASIN_Z_UM = 0.1


@dataclass(frozen=True)
class FrameFitSettings:
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
    warm_stop_chi2 : float
        The fits of :func:`fit_frame_warm` also stop where the Gauss-Newton step predicts a
        chi^2 decrease of at most this (units of the pixel noise;
        :func:`holofit.holomodel.leastsq.solve_least_squares`'s ``stop_rss``): the fit is then
        that close to its minimum, and MINPACK's confirming iteration (one hologram and one
        Jacobian of a warm frame's ~4) is saved. ``ftol`` 1e-6 on a 140 x 140 crop is ~0.02
        chi^2 units too. 0: MINPACK's tests alone.
    stop_chi2 : float
        The stopping rule of ``warm_stop_chi2`` for every fit on all pixels, a library start's
        too (the larger of the two applies to warm fits); 0: none. The initial pass sets it
        (:data:`holofit.fit.stage.INITIAL_STOP_CHI2`): there the static parameters of one
        frame scatter from the movie's median by far more than the uncertainty a chi^2 unit
        means, so the fit's last steps along their flat valley buy nothing.
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
    warm_stop_chi2: float = 0.02
    stop_chi2: float = 0.0
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
        if not self.stop_chi2 >= 0:
            raise ValueError(f"stop_chi2 must be >= 0, got {self.stop_chi2}")
        if not self.warm_stop_chi2 >= 0:
            raise ValueError(f"warm_stop_chi2 must be >= 0, got {self.warm_stop_chi2}")


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


class _FrameFit:
    """One crop's pixels, noise and engine, and the fits run on them (counted)."""

    def __init__(self, crop: NDArray, corner_rc: tuple[int, int], pixel_size_um: float,
                 theory: ScatteringTheory, model: ParticleModel, optics: Optics,
                 opts: FrameFitSettings, rng: np.random.Generator, free: Sequence[str],
                 extra_field: tuple[NDArray, NDArray] | None = None) -> None:
        self.theory, self.model, self.optics, self.opts, self.rng = (
            theory, model, optics, opts, rng)
        self.pix = select_pixels(crop, corner_rc, pixel_size_um, saturation=opts.saturation,
                                 fraction=opts.pixel_fraction, rng=rng, min_pixels=200)
        # a fixed field added to the model's (a neighbour's hologram), on the fit's pixels
        self.extra: tuple[NDArray, NDArray] | None = None
        if extra_field is not None:
            fx, fy = (np.asarray(f, dtype=complex) for f in extra_field)
            if fx.shape != np.shape(crop) or fy.shape != np.shape(crop):
                raise ValueError(f"extra_field must have the crop's shape {np.shape(crop)}")
            self.extra = (fx.ravel()[self.pix.index], fy.ravel()[self.pix.index])
        self.noise = (opts.noise_sd if opts.noise_sd is not None
                      else estimate_noise_sd(crop, self.pix.valid))
        self.statics = static_values(model)
        self.na_start = aperture_start(optics) if APERTURE.name in free else None
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

    def evaluate(self, state: State, index: NDArray[np.intp]) -> _Branch:
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
        return _Branch(None, space, Solution(np.empty(0), res, np.empty((index.size, 0)), rss,
                                             m.n_holograms, True, "evaluated"))

    def screen(self, state: State, free: Sequence[str], sub: NDArray[np.intp],
               start: Candidate | None = None) -> _Branch:
        """Hold the orientation (one solve), fit position and alpha on the pixels ``sub``."""
        held = [n for n in ("x_um", "y_um", "z_um", "alpha") if n in free]
        space = ParameterSpace(self.model, held, state)
        return _Branch(start, space, self.run(space, sub, self.opts.screen_nfev, 1e-4))

    def refine(self, state: State, free: Sequence[str], start: Candidate | None,
               statics: tuple | None = None, warm: bool = False) -> _Branch:
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
        return _Branch(start, space, self.run(space, None, self.opts.max_nfev, self.opts.ftol,
                                              stop))

    @property
    def n_solves(self) -> int:
        return sum(m.n_solves for m in self.models)


def _state(branch: _Branch) -> State:
    return branch.space.state(branch.solution.vector)


def _rss(branch: _Branch) -> float:
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


def _same_basin(a: State, b: State, model: ParticleModel) -> bool:
    return (_axis_angle(a, b, model.head_tail_symmetric) < SAME_BASIN_RAD
            and abs(a.position[2] - b.position[2]) < SAME_BASIN_Z_UM)


def _challenge(fit: _FrameFit, best: _Branch, runner: _Branch, free: Sequence[str]
               ) -> tuple[_Branch, _Branch | None]:
    """Compare the refined runner-up with the best: one minimum (no runner-up), or the better
    of two (the challenger refitted with every parameter of the pass if it held some)."""
    if _same_basin(_state(best), _state(runner), fit.model):
        return best, None  # both starts led to the same minimum: nothing to confuse
    if runner.solution.rss < best.solution.rss:
        challenger = (fit.refine(_state(runner), free, runner.start)
                      if set(runner.space.names) != set(best.space.names) else runner)
        return challenger, best
    return best, runner


def _frame_result(fit: _FrameFit, best: _Branch, runner: _Branch | None, n_starts: int,
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
        rs = _state(runner)
        psi, theta, _ = rs.angles()
        extra.update(chi2_runner_up=rss_runner / pix.size, delta_chi2=delta,
                     ambiguous=int(delta < opts.ambiguity_chi2), runner_up_theta_rad=theta,
                     runner_up_psi_rad=psi, runner_up_z_um=rs.position[2])
    result.extra = extra
    return result


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
    options: FrameFitSettings | None = None,
    seed: int = 0,
    extra_field: tuple[NDArray, NDArray] | None = None,
) -> FitResult:
    """Fit the DDA hologram of ``model`` to one crop from the library's starts.

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
    options : FrameFitSettings, optional
        Settings.
    seed : int
        Seed of the random pixel subsets.
    extra_field : tuple of ndarray, optional
        A fixed field ``(Ex, Ey)`` of the crop's shape (complex, incident units, its own
        alpha applied) added to the model's before the intensity: an overlapping neighbour's
        recorded field (:class:`holofit.holomodel.forward.HologramModel`); default none.

    Returns
    -------
    FitResult
        With ``extra`` = :data:`RUNNER_UP_COLUMNS` and ``n_masked``.
    """
    t0 = time.perf_counter()
    opts = options or FrameFitSettings()
    rng = np.random.default_rng(seed)
    fit = _FrameFit(crop, corner_rc, pixel_size_um, theory, model, optics, opts, rng, free,
                    extra_field)
    starts = _library_starts(model, candidates, opts)
    # screening: each start's orientation held (one solve each), position and alpha fitted on
    # a pixel subset (no further solves), so that starts compare at their best placement
    screened: list[_Branch] = []
    if len(starts) > 1:
        sub = _subset(fit.pix, opts.screen_pixels, rng)
        screened = sorted((fit.screen(fit.state_at(s, position_um, alpha), free, sub, s)
                           for s in starts), key=_rss)
    first = (_state(screened[0]) if screened
             else fit.state_at(starts[0], position_um, alpha))
    best = fit.refine(first, free, screened[0].start if screened else starts[0])
    best, runner, runner_rss = _runner_up(fit, best, screened, free, opts)
    result = _frame_result(fit, best, runner, len(starts), runner_rss)
    result.time_s = time.perf_counter() - t0
    return result


def _runner_up(fit: _FrameFit, best: _Branch, screened: list[_Branch], free: Sequence[str],
               opts: FrameFitSettings) -> tuple[_Branch, _Branch | None, float | None]:
    """The second screened start refined into the runner-up (which may displace the best), or
    taken as screened with its residual scaled to all pixels; none with one start."""
    if len(screened) < 2:
        return best, None, None
    if opts.refine_runner_up:
        runner = fit.refine(_state(screened[1]), free, screened[1].start, _state(best).statics)
        best, runner = _challenge(fit, best, runner, free)
        return best, runner, None
    runner = screened[1]  # screened on a subset: scale to all pixels
    return best, runner, runner.solution.rss * (fit.pix.size / max(
        runner.solution.residuals.size, 1))


@dataclass(frozen=True)
class CarriedRunnerUp:
    """The mirror runner-up of a frame, as the next frame starts it: its placement relative
    to the best fit, its alpha and its ``delta_chi2`` when it was last fitted."""

    offset_um: tuple[float, float, float]
    alpha: float
    delta_chi2: float


@dataclass
class WarmFit:
    """A frame fitted from a known state (:func:`fit_frame_warm`).

    Attributes
    ----------
    result : FitResult
        The best fit, with :data:`RUNNER_UP_COLUMNS`, ``n_masked`` and ``runner_up_refit``
        (2: the runner-up was fitted on all pixels; 1: screened on a subset; 0: evaluated
        once where it was carried to; its chi^2 is then an upper bound of its minimum's).
    carried : CarriedRunnerUp or None
        The mirror runner-up for the next frame.
    """

    result: FitResult
    carried: CarriedRunnerUp | None


def mirror_state(state: State) -> State:
    """``state`` with its orientation mirrored through the x-y plane (``theta -> pi - theta``)."""
    if state.rotation is None:
        return state
    psi, theta, phi = state.angles()
    return replace(state, rotation=euler_zyz(psi, math.pi - theta, phi))


def fit_frame_warm(
    crop: NDArray,
    corner_rc: tuple[int, int],
    pixel_size_um: float,
    theory: ScatteringTheory,
    model: ParticleModel,
    optics: Optics,
    start: State,
    free: Sequence[str],
    options: FrameFitSettings | None = None,
    seed: int = 0,
    carried: CarriedRunnerUp | None = None,
    refit_margin_chi2: float = 16.0,
    extra_field: tuple[NDArray, NDArray] | None = None,
) -> WarmFit:
    """Fit one crop from a known state (a neighbouring frame's fit), and find its mirror
    runner-up without a second full fit where none is needed.

    1. The fit on all pixels from ``start`` (position, orientation, alpha and statics).
    2. The runner-up (the fit's mirror through the x-y plane, ``theta -> pi - theta``): with
       ``carried``, evaluated once (one solve) at the mirror placed as the previous frame's
       runner-up was; its excess chi^2 over the best on ``screen_pixels`` pixels, scaled to
       all pixels, is an upper bound of ``delta_chi2`` (any point of a basin is at or above
       its minimum). If that comes within ``ambiguity_chi2 + refit_margin_chi2``, or has
       drifted up by more than ``refit_margin_chi2`` plus :data:`CARRY_DRIFT` of its value
       since it was last fitted (the bound would grow loose), or nothing is carried, the
       mirror is screened (orientation held, position and alpha fitted on the
       subset, one solve).
    3. Where the screening's ``delta_chi2`` is within ``ambiguity_chi2 + refit_margin_chi2``
       the runner-up is fitted on all pixels (and replaces the best if lower, as in
       :func:`fit_frame`); otherwise the frame is decisive and the bound is reported.

    Parameters are those of :func:`fit_frame`, with ``start`` (a :class:`State`) in place of
    the placement and candidates; ``options.mirror`` False skips steps 2-3.

    Returns
    -------
    WarmFit
    """
    t0 = time.perf_counter()
    opts = options or FrameFitSettings()
    rng = np.random.default_rng(seed)
    fit = _FrameFit(crop, corner_rc, pixel_size_um, theory, model, optics, opts, rng, free,
                    extra_field)
    if fit.na_start is not None and start.numerical_aperture is None:
        start = replace(start, numerical_aperture=fit.na_start)
    best = fit.refine(start, free, None, warm=True)
    runner: _Branch | None = None
    runner_rss = None
    how = -1
    if model.anisotropic and opts.mirror and np.isfinite(best.solution.rss):
        runner, runner_rss, how = _warm_runner_up(fit, best, free, carried, refit_margin_chi2)
        if how == 2:
            best, runner = _challenge(fit, best, runner, free)
            runner_rss = None
    result = _frame_result(fit, best, runner, 1 + int(runner is not None), runner_rss)
    result.extra["runner_up_refit"] = how
    result.time_s = time.perf_counter() - t0
    return WarmFit(result, _carry(best, runner, result))


def evaluate_frame(
    crop: NDArray,
    corner_rc: tuple[int, int],
    pixel_size_um: float,
    theory: ScatteringTheory,
    model: ParticleModel,
    optics: Optics,
    state: State,
    free: Sequence[str],
    options: FrameFitSettings | None = None,
    seed: int = 0,
    extra_field: tuple[NDArray, NDArray] | None = None,
) -> tuple[float, int]:
    """One state's chi^2 on a crop, nothing fitted: the residual sum of squares in units of
    the pixel noise, on the pixels (and with the noise) a fit of this crop with the same
    ``options`` and ``seed`` uses (:func:`fit_frame_warm`), so that it compares with that
    fit's ``rss / noise_sd**2``. Returns the chi^2 (inf where the state is invalid) and the
    holograms computed (1)."""
    opts = options or FrameFitSettings()
    fit = _FrameFit(crop, corner_rc, pixel_size_um, theory, model, optics, opts,
                    np.random.default_rng(seed), free, extra_field)
    if fit.na_start is not None and state.numerical_aperture is None:
        state = replace(state, numerical_aperture=fit.na_start)
    rss = _rss(fit.evaluate(state, np.arange(fit.pix.size)))
    noise2 = fit.noise**2 if fit.noise > 0 else math.nan
    return rss / noise2, fit.n_eval


def _carry(best: _Branch, runner: _Branch | None, result: FitResult) -> CarriedRunnerUp | None:
    if runner is None or not np.isfinite(result.extra["delta_chi2"]):
        return None
    b, r = _state(best), _state(runner)
    offset = tuple(float(v) for v in np.subtract(r.position, b.position))
    return CarriedRunnerUp(offset, r.alpha, float(result.extra["delta_chi2"]))  # type: ignore


def _warm_runner_up(fit: _FrameFit, best: _Branch, free: Sequence[str],
                    carried: CarriedRunnerUp | None, margin: float
                    ) -> tuple[_Branch, float, int]:
    """Steps 2-3 of :func:`fit_frame_warm`: the runner-up branch, its rss on all pixels (the
    screening's or the evaluation's excess, scaled), and how it was found (2, 1, 0)."""
    best_state = _state(best)
    sub = _subset(fit.pix, fit.opts.screen_pixels, fit.rng)
    scale = fit.pix.size / max(sub.size, 1)
    best_sub = float(np.sum(best.solution.residuals[sub] ** 2))
    noise2 = fit.noise**2 if fit.noise > 0 else math.nan
    bar = fit.opts.ambiguity_chi2 + margin
    mirror = mirror_state(best_state)
    if carried is not None:
        guess = replace(mirror, position=tuple(np.add(best_state.position, carried.offset_um)),
                        alpha=carried.alpha)
        once = fit.evaluate(guess, sub)
        delta = (once.solution.rss - best_sub) * scale / noise2
        if delta >= bar and delta <= (1 + CARRY_DRIFT) * carried.delta_chi2 + margin:
            return once, best.solution.rss + delta * noise2, 0
    screened = fit.screen(mirror, free, sub)
    delta = (float(screened.solution.rss) - best_sub) * scale / noise2
    if not delta >= bar:  # close (or unknown): fit it on all pixels
        return (fit.refine(_state(screened), free, None, best_state.statics, warm=True),
                math.nan, 2)
    return screened, best.solution.rss + delta * noise2, 1


def _subset(pix: PixelSelection, n: int, rng: np.random.Generator) -> NDArray[np.intp]:
    if pix.size <= n:
        return np.arange(pix.size)
    return np.sort(rng.choice(pix.size, size=n, replace=False))
