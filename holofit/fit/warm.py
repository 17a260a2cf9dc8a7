"""A frame fitted from a known state (a neighbouring frame's fit), and one state evaluated.

:func:`fit_frame_warm`:

1. The fit on all pixels from ``start`` (position, orientation, alpha and statics).
2. The runner-up (the fit's mirror through the x-y plane, ``theta -> pi - theta``): with
   ``carried``, evaluated once (one solve) at the mirror placed as the previous frame's
   runner-up was; its excess chi^2 over the best on ``screen_pixels`` pixels, scaled to all
   pixels, is an upper bound of ``delta_chi2`` (any point of a basin is at or above its
   minimum). If that comes within ``ambiguity_chi2 + refit_margin_chi2``, or has drifted up by
   more than ``refit_margin_chi2`` plus :data:`CARRY_DRIFT` of its value since it was last
   fitted (the bound would grow loose), or nothing is carried, the mirror is screened
   (orientation held, position and alpha fitted on the subset, one solve).
3. Where the screening's ``delta_chi2`` is within ``ambiguity_chi2 + refit_margin_chi2`` the
   runner-up is fitted on all pixels (and replaces the best if lower, as in
   :func:`holofit.fit.frame.fit_frame`); otherwise the frame is decisive and the bound is
   reported.

:func:`evaluate_frame`: one state's chi^2 on the pixels and noise a fit of the same problem
uses, so that it compares with that fit's.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace

import numpy as np

from holofit.conventions import euler_zyz
from holofit.fit.frame import (
    Branch,
    FrameFit,
    branch_rss,
    branch_state,
    challenge,
    frame_result,
    subset,
)
from holofit.fit.problem import FrameProblem
from holofit.holomodel.parameters import State
from holofit.holomodel.result import FitResult

__all__ = [
    "CARRY_DRIFT",
    "CarriedRunnerUp",
    "WarmFit",
    "evaluate_frame",
    "fit_frame_warm",
    "mirror_state",
]

#: a carried runner-up's bound may exceed its last fitted delta_chi2 by this fraction (plus
#: the refit margin) before it is screened again (:func:`fit_frame_warm`)
CARRY_DRIFT = 0.25


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
        The best fit, with :data:`holofit.fit.frame.RUNNER_UP_COLUMNS`, ``n_masked`` and
        ``runner_up_refit`` (2: the runner-up was fitted on all pixels; 1: screened on a
        subset; 0: evaluated once where it was carried to; its chi^2 is then an upper bound of
        its minimum's).
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


def fit_frame_warm(problem: FrameProblem, start: State,
                   carried: CarriedRunnerUp | None = None,
                   refit_margin_chi2: float = 16.0) -> WarmFit:
    """Fit one crop from a known state and find its mirror runner-up without a second full
    fit where none is needed (module docstring).

    Parameters
    ----------
    problem : FrameProblem
        The crop, its engine and model, what is fitted and how (``settings.mirror`` False
        skips the runner-up).
    start : State
        Where the fit starts (a neighbouring frame's fit).
    carried : CarriedRunnerUp, optional
        The previous frame's mirror runner-up.
    refit_margin_chi2 : float
        The runner-up is fitted on all pixels when its screening is within
        ``ambiguity_chi2 + refit_margin_chi2`` of the best.

    Returns
    -------
    WarmFit
    """
    t0 = time.perf_counter()
    opts, model, free = problem.settings, problem.model, problem.free
    fit = FrameFit(problem)
    if fit.na_start is not None and start.numerical_aperture is None:
        start = replace(start, numerical_aperture=fit.na_start)
    best = fit.refine(start, free, None, warm=True)
    runner: Branch | None = None
    runner_rss = None
    how = -1
    if model.anisotropic and opts.mirror and np.isfinite(best.solution.rss):
        runner, runner_rss, how = _warm_runner_up(fit, best, free, carried, refit_margin_chi2)
        if how == 2:
            best, runner = challenge(fit, best, runner, free)
            runner_rss = None
    result = frame_result(fit, best, runner, 1 + int(runner is not None), runner_rss)
    result.extra["runner_up_refit"] = how
    result.time_s = time.perf_counter() - t0
    return WarmFit(result, _carry(best, runner, result))


def evaluate_frame(problem: FrameProblem, state: State) -> tuple[float, int]:
    """One state's chi^2 on a crop, nothing fitted: the residual sum of squares in units of
    the pixel noise, on the pixels (and with the noise) a fit of the same problem uses
    (:func:`fit_frame_warm`), so that it compares with that fit's ``rss / noise_sd**2``.
    Returns the chi^2 (inf where the state is invalid) and the holograms computed (1)."""
    fit = FrameFit(problem)
    if fit.na_start is not None and state.numerical_aperture is None:
        state = replace(state, numerical_aperture=fit.na_start)
    rss = branch_rss(fit.evaluate(state, np.arange(fit.pix.size)))
    noise2 = fit.noise**2 if fit.noise > 0 else math.nan
    return rss / noise2, fit.n_eval


def _carry(best: Branch, runner: Branch | None, result: FitResult) -> CarriedRunnerUp | None:
    if runner is None or not np.isfinite(result.extra["delta_chi2"]):
        return None
    b, r = branch_state(best), branch_state(runner)
    offset = tuple(float(v) for v in np.subtract(r.position, b.position))
    return CarriedRunnerUp(offset, r.alpha, float(result.extra["delta_chi2"]))  # type: ignore


def _warm_runner_up(fit: FrameFit, best: Branch, free: tuple[str, ...],
                    carried: CarriedRunnerUp | None, margin: float
                    ) -> tuple[Branch, float, int]:
    """Steps 2-3 of :func:`fit_frame_warm`: the runner-up branch, its rss on all pixels (the
    screening's or the evaluation's excess, scaled), and how it was found (2, 1, 0)."""
    best_state = branch_state(best)
    sub = subset(fit.pix, fit.opts.screen_pixels, fit.rng)
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
        return (fit.refine(branch_state(screened), free, None, best_state.statics, warm=True),
                math.nan, 2)
    return screened, best.solution.rss + delta * noise2, 1
