"""The rescue steps of a wrong minimum while a track is followed, each a function of its own.

A warm start inside the right basin is what following a track buys; these steps catch the
frames where it is not (the step numbers are :mod:`holofit.fit.follow`'s):

- :func:`library_fit` (step 8, *other heights*): a library fit not ``ok`` under the movie's
  bar is tried again from heights off the prefit's, in turn: near focus a prefit may take the
  twin height on the other side of the focal plane;
- :func:`check_against_initial` (step 6): a frame the initial pass fitted independently is
  evaluated once at that fit's pose, and refitted from there where the pose beats the
  track's fit by more than the margin (an evaluation bounds its basin's minimum from above);
- :func:`probe_near_pole` (step 7, *pole probes*): a fit whose axis ends near the optical
  axis is repeated from starts tilted away from it, since near the pole the misfit has minima
  that hold a warm start;
- :func:`recheck_between` (step 9, *recheck*): a warm frame near the pole whose successor
  turned far is refitted from midway between its neighbours' axes, the likeliest place of a
  diffusing axis between two known ones.

The continuity sweeps after a pass (:mod:`holofit.fit.continuity`) are the last rescue.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from holofit.conventions import rotation_from_vector
from holofit.fit.follower import ChunkFitter, ChunkFrame, Followed, axis_step
from holofit.fit.frame import SAME_BASIN_RAD, SAME_BASIN_Z_UM
from holofit.fit.problem import state_of
from holofit.fit.settings import FollowSettings
from holofit.fit.warm import CarriedRunnerUp, evaluate_frame, fit_frame_warm
from holofit.holomodel.parameters import APERTURE, State
from holofit.holomodel.result import FitResult
from holofit.particles import ParticleModel
from holofit.quality import join_message, under_bar
from holofit.status import OK

__all__ = [
    "INITIAL_CHECK",
    "INITIAL_POSE",
    "POLE_PROBE",
    "PROBE_STOP_CHI2",
    "RECHECK",
    "REOPEN_MAX_FAILURES",
    "InitialCheck",
    "between",
    "check_against_initial",
    "library_fit",
    "near_pole",
    "note_changed",
    "pole_probes",
    "probe_fit",
    "probe_near_pole",
    "recheck_between",
    "take_runner_up",
]

#: a chunk stops trying other heights after this many frames in a row for which none worked:
#: a stretch no height fits costs seven library fits a frame only this often
REOPEN_MAX_FAILURES = 3
#: a probe's fit stops where the Gauss-Newton step predicts a chi^2 decrease of at most this:
#: it decides between minima 9 chi^2 units apart, and the one it picks is refitted fully
PROBE_STOP_CHI2 = 1.0
#: the codes of ``follow_pole`` (:func:`probe_near_pole`)
POLE_PROBE = {
    -1: "not probed (not near the optical axis, not above the track's recent level, or a "
        "head-tail symmetric particle)",
    0: "probed: no probe ended lower than the warm fit",
    1: "probed: a probe ended lower; the frame was refitted from it",
}
#: the codes of ``follow_recheck`` (:func:`recheck_between`)
RECHECK = {
    -1: "not rechecked (not a warm fit near the optical axis, or the next frame along the "
        "track is near it)",
    0: "refitted from between its neighbours' orientations: no lower minimum",
    1: "refitted from between its neighbours' orientations: a lower minimum, kept (the frame "
       "changed)",
}
#: the codes of ``follow_initial`` (:func:`check_against_initial`)
INITIAL_CHECK = {
    -1: "no initial-pass row for this frame",
    0: "checked: the initial row's pose does not beat the frame's fit by the margin",
    1: "the initial row's pose beat the frame's fit: refitted from it, the frame's own "
       "minimum was the lower and is kept",
    2: "the initial row's pose beat the frame's fit: refitted from it, its minimum kept "
       "(the frame changed)",
}
#: the pose columns of an initial-pass row the check uses (``phi_rad`` where the model has it)
INITIAL_POSE = ("x_um", "y_um", "z_um", "psi_rad", "theta_rad", "phi_rad", "alpha")


def library_fit(fitter: ChunkFitter, f: ChunkFrame, chi2_bar: float | None = None,
                retry: bool = True) -> FitResult:
    """Frame ``f``'s library fit from the prefit's position; where it is not ``ok`` under
    ``chi2_bar`` (and ``retry``), again from heights ``reopen_dz_um`` off the prefit's, in
    turn, until one is (step 8); the lowest fit, ``n_eval`` counting all. After
    :data:`REOPEN_MAX_FAILURES` frames in a row for which no height worked, the chunk stops
    trying."""
    opts = fitter.opts
    best = fitter.library_at(f, 0.0)
    n_eval = best.n_eval
    retry = (retry and opts.warm and bool(opts.reopen_dz_um)
             and fitter.reopen_failures < REOPEN_MAX_FAILURES
             and not under_bar(best, chi2_bar))
    for dz in opts.reopen_dz_um if retry else ():
        alt = fitter.library_at(f, dz)
        n_eval += alt.n_eval
        if alt.status == OK and (best.status != OK or alt.chi2 < best.chi2):
            alt.message = join_message(alt.message, f"library fit from {dz:+.3g} um off the "
                                       "prefit's height (from the prefit's: reduced chi^2 "
                                       f"{best.chi2_red:.3g}, {best.status})")
            best = alt
        if under_bar(best, chi2_bar):
            break
    if retry:
        fitter.reopen_failures = (0 if under_bar(best, chi2_bar)
                                  else fitter.reopen_failures + 1)
    best.n_eval = n_eval
    return best


def pole_probes(state: State, n: int, tilt_rad: float) -> list[State]:
    """``n`` copies of ``state`` whose axes are tilted by ``tilt_rad`` from its own, evenly
    around it (the rotation ``exp([w]x) R`` with ``w`` perpendicular to the axis), the first
    along the meridian (its polar angle theta larger by ``tilt_rad``; with ``n`` even, one
    probe also smaller by it). On the optical axis the meridian is the x-z plane's."""
    assert state.rotation is not None
    axis = state.rotation[:, 2]
    e1 = np.cross((0.0, 0.0, 1.0), axis)  # turning about it moves the axis along theta
    if np.linalg.norm(e1) < 1e-6:
        e1 = np.array([0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    out = []
    for k in range(n):
        phase = 2 * math.pi * k / n
        w = tilt_rad * (math.cos(phase) * e1 + math.sin(phase) * e2)
        out.append(replace(state, rotation=rotation_from_vector(w) @ state.rotation))
    return out


def near_pole(state: State, opts: FollowSettings) -> bool:
    """The axis of ``state`` lies within ``opts.pole_rad`` of the optical axis (either pole)."""
    assert state.rotation is not None
    return abs(float(state.rotation[2, 2])) >= math.cos(opts.pole_rad)


def between(own: State, before: State | None, later: State, head_tail: bool) -> State:
    """``own`` turned so that its axis lies midway between ``before``'s and ``later``'s (a
    diffusing axis's likeliest place between two known ones), or on ``later``'s where
    ``before`` is None or the two are nearly opposite."""
    assert own.rotation is not None and later.rotation is not None
    target = later.rotation[:, 2]
    if before is not None and before.rotation is not None:
        a = before.rotation[:, 2]
        if head_tail and float(np.dot(a, target)) < 0:
            a = -a
        mid = a + target
        if np.linalg.norm(mid) > 0.1:
            target = mid / np.linalg.norm(mid)
    axis = own.rotation[:, 2]
    if head_tail and float(np.dot(axis, target)) < 0:
        target = -target
    w = np.cross(axis, target)
    s, c = float(np.linalg.norm(w)), float(np.dot(axis, target))
    if s < 1e-12:
        return own
    return replace(own, rotation=rotation_from_vector(w / s * math.atan2(s, c)) @ own.rotation)


def probe_fit(fitter: ChunkFitter, f: ChunkFrame, start: State) -> FitResult:
    """A probe's fit of ``f`` from ``start``: no mirror, at most ``pole_probe_nfev``
    holograms, stopping within :data:`PROBE_STOP_CHI2` of its minimum."""
    opts = fitter.opts
    quiet = replace(opts.frame, mirror=False,
                    max_nfev=min(opts.frame.max_nfev, opts.pole_probe_nfev),
                    stop_chi2=max(opts.frame.stop_chi2, PROBE_STOP_CHI2))
    return fit_frame_warm(fitter.problem(f).with_settings(quiet), start).result


def take_runner_up(new: FitResult, old: FitResult, model: ParticleModel,
                   ambiguity_chi2: float) -> None:
    """``old``, a minimum ``new`` replaced, as ``new``'s runner-up where it is a distinct
    minimum closer than the runner-up ``new`` reports (the ambiguity flag's runner-up is the
    nearest real competing minimum)."""
    a, b = state_of(new.values, model), state_of(old.values, model)
    if (axis_step(a, b, model.head_tail_symmetric) < SAME_BASIN_RAD
            and abs(a.position[2] - b.position[2]) < SAME_BASIN_Z_UM):
        return
    delta = (old.rss - new.rss) / new.noise_sd**2
    reported = float(new.extra.get("delta_chi2", math.nan))
    if math.isfinite(reported) and reported <= delta:
        return
    psi, theta, _ = b.angles()
    new.extra.update(chi2_runner_up=old.rss / max(new.n_pixels, 1), delta_chi2=delta,
                     ambiguous=int(delta < ambiguity_chi2), runner_up_theta_rad=theta,
                     runner_up_psi_rad=psi, runner_up_z_um=b.position[2], runner_up_refit=2)


def probe_near_pole(fitter: ChunkFitter, f: ChunkFrame, res: FitResult,
                    runner: CarriedRunnerUp | None, acc: Followed | None = None
                    ) -> tuple[FitResult, CarriedRunnerUp | None, int]:
    """Step 7: the fit ``res`` (and the runner-up it carries), or the refit from the lowest
    probe where that is lower by more than ``pole_min_gain_chi2``; what was done
    (:data:`POLE_PROBE`). Only a fit near the pole, above the track's recent level (``acc``),
    of a particle that is not head-tail symmetric (unless ``pole_probe_symmetric``) is
    probed. The returned fit's ``n_eval`` counts the probes' holograms."""
    opts, model = fitter.opts, fitter.model
    state = state_of(res.values, model) if np.isfinite(res.rss) else None
    if (not opts.pole_probes or not opts.warm or state is None or state.rotation is None
            or not res.noise_sd > 0
            or (model.head_tail_symmetric and not opts.pole_probe_symmetric)
            or not near_pole(state, opts)):
        return res, runner, -1
    level = None if acc is None else acc.level(opts.min_history)
    if level is not None and not res.chi2_red > level:
        return res, runner, -1
    n_eval, best = res.n_eval, None
    for start in pole_probes(state, opts.pole_probes, opts.pole_probe_rad):
        probe = probe_fit(fitter, f, start)
        n_eval += probe.n_eval
        if np.isfinite(probe.rss) and (best is None or probe.rss < best.rss):
            best = probe
    if best is None or not (res.rss - best.rss) / res.noise_sd**2 > opts.pole_min_gain_chi2:
        res.n_eval = n_eval
        return res, runner, 0
    again = fitter.refit(f, state_of(best.values, model))
    new = again.result
    if not new.rss < res.rss:  # the refit from the probe's minimum went elsewhere
        res.n_eval = n_eval + new.n_eval
        return res, runner, 0
    new.message = join_message(new.message, "the fit ended near the optical axis, "
                               f"{(res.rss - new.rss) / new.noise_sd**2:.4g} chi^2 above the "
                               "minimum a probe tilted from it found")
    take_runner_up(new, res, model, opts.frame.ambiguity_chi2)
    new.n_eval = n_eval + new.n_eval
    return new, again.carried, 1


def recheck_between(fitter: ChunkFitter, f: ChunkFrame, res: FitResult, later: FitResult,
                    before: State | None = None) -> tuple[FitResult, int, int]:
    """Step 9: frame ``f``'s warm fit ``res`` refitted from the orientation between
    ``before`` (the accepted fit it started from; None: ``later``'s orientation alone) and
    ``later``, the next frame's accepted fit along the track, where ``res`` is near the pole
    and ``later`` turned more than ``recheck_rad`` from it. Returns the fit kept, the code
    (:data:`RECHECK`) and the holograms computed."""
    opts, model = fitter.opts, fitter.model
    if not (opts.warm and opts.recheck_rad > 0 and res.status == OK
            and np.isfinite(res.rss) and res.noise_sd > 0 and np.isfinite(later.rss)
            and (opts.pole_probe_symmetric or not model.head_tail_symmetric)):
        return res, -1, 0
    own, nxt = state_of(res.values, model), state_of(later.values, model)
    if (own.rotation is None or not near_pole(own, opts)
            or not axis_step(own, nxt, model.head_tail_symmetric) > opts.recheck_rad):
        return res, -1, 0
    start = between(own, before, nxt, model.head_tail_symmetric)
    probe = probe_fit(fitter, f, start)
    n_eval = probe.n_eval
    if not (np.isfinite(probe.rss)
            and (res.rss - probe.rss) / res.noise_sd**2 > opts.pole_min_gain_chi2):
        return res, 0, n_eval
    again = fitter.refit(f, state_of(probe.values, model))
    new = again.result
    n_eval += new.n_eval
    if not new.rss < res.rss:
        return res, 0, n_eval
    new.message = join_message(new.message, "refitted from between its neighbours' "
                               "orientations along the track: "
                               f"{(res.rss - new.rss) / new.noise_sd**2:.4g} chi^2 below the "
                               "warm fit")
    take_runner_up(new, res, model, opts.frame.ambiguity_chi2)
    return new, 1, n_eval


@dataclass(frozen=True)
class InitialCheck:
    """What :func:`check_against_initial` did: ``code`` (:data:`INITIAL_CHECK`), the
    holograms it computed, and by how much the initial pose beat the frame's fit (chi^2
    units; NaN: not checked)."""

    code: int
    n_eval: int
    beat: float


def _initial_state(fitter: ChunkFitter, f: ChunkFrame, res: FitResult) -> State:
    """The pose of ``f``'s initial-pass row with this pass's statics (the model's) and,
    where the aperture is fitted, the frame's fitted aperture."""
    assert f.initial is not None
    pose = {k: v for k, v in f.initial.items() if k in INITIAL_POSE}
    state = state_of(pose, fitter.model)
    if APERTURE.name in fitter.free and APERTURE.name in res.values:
        state = replace(state, numerical_aperture=float(res.values[APERTURE.name]))
    return state


def check_against_initial(fitter: ChunkFitter, f: ChunkFrame, res: FitResult,
                          runner: CarriedRunnerUp | None
                          ) -> tuple[FitResult, CarriedRunnerUp | None, InitialCheck]:
    """Step 6: the frame's fit ``res`` against the pose of its initial-pass row (evaluated
    once with this pass's statics); where that beats ``res`` by more than
    ``initial_margin_chi2``, the frame is refitted from it and the lower minimum kept. The
    fit kept, its runner-up to carry, and what was done."""
    if f.initial is None or not np.isfinite(res.rss) or not res.noise_sd > 0:
        return res, runner, InitialCheck(-1, 0, math.nan)
    start = _initial_state(fitter, f, res)
    chi2_initial, n_eval = evaluate_frame(fitter.problem(f), start)
    beat = res.rss / res.noise_sd**2 - chi2_initial
    if not beat > fitter.opts.initial_margin_chi2:
        return res, runner, InitialCheck(0, n_eval, beat)
    alt = fitter.refit(f, start)
    n_eval += alt.result.n_eval
    if not alt.result.rss < res.rss:
        return res, runner, InitialCheck(1, n_eval, beat)
    return alt.result, alt.carried, InitialCheck(2, n_eval, beat)


def note_changed(fitter: ChunkFitter, res: FitResult, old: FitResult, check: InitialCheck,
                 source: str) -> None:
    """The note and the runner-up of a frame :func:`check_against_initial` changed
    (``old``: its fit before)."""
    res.message = join_message(res.message, f"{source} fit replaced: the initial pass's pose "
                               f"of this frame was {check.beat:.4g} chi^2 below it; refitted "
                               f"from there, now {(old.rss - res.rss) / res.noise_sd**2:.4g} "
                               "below")
    take_runner_up(res, old, fitter.model, fitter.opts.frame.ambiguity_chi2)
