"""The tracking final pass: each frame of a track fitted from its predecessor's fit.

Between frames a particle moves little (the paper's rod: ~4 deg and ~80 nm), so the previous
frame's fit is a start inside the right basin and the library's starts are needed only where
that fails. Along one track (frames in time order):

1. A chunk opens with a full library fit (:func:`holofit.fit.frame.fit_frame`: the library's
   starts and the mirror) of the frame the library reads best (the highest R^2 of a best
   candidate, ``TrackOptions.open_at_best``), or from a given fit (``start``, at its first
   frame). The track is followed from there to the chunk's end and, from the opening frame
   again, back to its start: "frame k-1" below is the previous frame along that direction.
2. Frame k is fitted from frame k-1's accepted fit (:func:`holofit.fit.frame.fit_frame_warm`):
   position moved by the recent drift (the mean displacement per frame over the recent steps;
   consecutive frames only), orientation, alpha and the static parameters as they are; its
   mirror runner-up is evaluated where the previous frame's sat (carried along), screened
   where that comes close or drifts, and fitted on all pixels only where the screening comes
   close.
3. The warm fit is accepted when it is ``ok``, its reduced chi^2 is under the movie's bar
   (``chi2_bar``: :func:`holofit.fit.continuity.chi2_bar` of the library fits computes it)
   and its step from the accepted predecessor is smooth: position and axis steps within
   limits, given (e.g. a few times the diffusion scale ``sqrt(2 D dt)``) or else
   ``step_factor`` times the median of the recent accepted steps (never below the floors).
4. A frame that fails is re-acquired: fitted from the library's starts and the mirror as an
   independent frame; the better of the two fits (lower chi^2) is kept. A re-acquired frame
   that is still above the bar becomes ``poor_fit``; one whose step is not smooth keeps its
   status but is flagged (``track_jump`` 1 and a message), never silently ``ok``.
5. A frame whose fit raises is an ``error`` row; the next frame starts from the last
   accepted fit.
6. A frame the initial pass fitted too (``ChunkFrame.initial``: its converged row, fitted
   independently of this track with the statics free) is checked against that fit: the
   hologram at the initial row's position, orientation and alpha with this pass's statics is
   evaluated once on the frame's pixels. An evaluation is an upper bound of its basin's
   minimum, so where it beats the frame's fit (warm or library) by more than
   ``initial_margin_chi2`` a lower minimum exists that the track missed (a warm start that
   ran onto a wrong branch): the frame is refitted from the initial row's pose and the lower
   of the two minima kept. A warm frame so changed is then re-acquired as in step 4 (the
   library's starts join, the better fit is kept, the bar and the step flag it), and the
   track goes on from it. ``track_initial`` records what the check did.
7. A fit (warm, a chunk's opening, a re-acquisition; not with ``warm`` off) whose axis ends
   near the optical axis (within ``pole_rad`` of either pole) is probed: near the pole the
   misfit has minima that hold a warm start (a Janus replicate's frames fitted at theta 5-7
   deg with the truth at 18-23 deg, 500-1000 chi^2 units above the true minimum and still
   under the movie's bar, when the track came from a frame near the pole; on another, frames
   at 24-36 deg from the pole held 13-20 deg off the truth along the meridian). The fit is
   repeated from ``pole_probes`` starts whose axes are tilted ``pole_probe_rad`` from its
   own, evenly around it starting along the meridian (two: theta larger and smaller; the
   mirror not screened), and where one ends lower by more than ``pole_min_gain_chi2`` the
   frame is refitted from it (its mirror runner-up as in step 2) and the minimum it left
   becomes the runner-up where it is the nearest competing minimum.
   Only a fit above the median reduced chi^2 of the track's recent accepted fits is probed
   (once ``min_history`` are known: a held frame fits worse than its track, the replicate's
   8 by 0.1-6.6 % of their neighbours' median), and not a head-tail symmetric particle's
   (``pole_probe_symmetric``).
   ``track_pole`` records what the probes did.
8. A library fit (a chunk's opening, a re-acquisition of a frame whose warm fit is not under
   the bar) that is not ``ok`` under the bar is tried again from heights ``reopen_dz_um``
   off the prefit's, in turn, until one is; the lowest is kept. Near focus the prefit of a
   Janus particle took the twin height on the other side of the focal plane (2-5 um above
   the truth at -1 um), the library fits from there failed one frame after another (reduced
   chi^2 2-10), and a chunk that opens with no accepted fit has nothing to go on warm: on a
   Janus replicate 316 frames in a row were such library fits, left to the continuity
   sweeps (60 sweeps, 5 frames each). After :data:`REOPEN_MAX_FAILURES` frames in a row for
   which no height worked, the chunk stops trying.

9. Once a frame is accepted, the warm frame before it along the track, where its axis is near
   the optical axis (within ``pole_rad``) and the accepted frame's axis is more than
   ``recheck_rad`` from it, is refitted from the orientation midway between its own
   predecessor's and that accepted frame's axes (a diffusing axis's likeliest place between
   two known ones; a probe's fit, then a full one where it ends lower by more than
   ``pole_min_gain_chi2``); the lower minimum is kept, the one it left becomes the runner-up
   as in step 7, and a changed frame's step from its predecessor is checked as in step 4. A
   changed frame's own predecessor is rechecked in turn (at most :data:`RECHECK_DEPTH`
   frames back). A particle that turns ~10 deg a frame (a Janus replicate) left frames on a
   minimum 15-35 deg from the truth whose chi^2 sat at its track's level (the probes of step
   7 skip those) or whose error lay across the meridian, while the next frame, fitted from
   it, was back on the truth: a start from the next frame's side finds them.
   ``track_recheck`` records what the recheck did.

Chunks of one track overlap by a few frames; :func:`stitch_chunks` joins them and reports where
the overlaps disagree (position or axis beyond tolerance).

Each row has the fit table's columns (:func:`holofit.holomodel.result.result_row`, with
:data:`holofit.fit.frame.RUNNER_UP_COLUMNS`) and :data:`TRACK_COLUMNS`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from holofit.conventions import euler_zyz, rotation_from_vector
from holofit.fit.frame import (
    SAME_BASIN_RAD,
    SAME_BASIN_Z_UM,
    CarriedRunnerUp,
    FrameFitSettings,
    WarmFit,
    evaluate_frame,
    fit_frame,
    fit_frame_warm,
)
from holofit.holomodel.parameters import APERTURE, State, static_values
from holofit.holomodel.result import FitResult, result_row
from holofit.library.search import Candidate
from holofit.optics import Optics
from holofit.particles import ParticleModel
from holofit.scattering.theory import ScatteringTheory
from holofit.status import ERROR, OK, POOR_FIT

__all__ = [
    "INITIAL_CHECK",
    "INITIAL_POSE",
    "POLE_PROBE",
    "RECHECK",
    "TRACK_COLUMNS",
    "ChunkFrame",
    "TrackOptions",
    "stitch_chunks",
    "track_chunk",
]

#: what a tracked row adds to the fit table's columns: how the frame was obtained
#: (``library``: a chunk's first frame; ``warm``; ``reacquired``), whether its step from the
#: accepted predecessor broke the smoothness limits, whether the runner-up was refitted, the
#: step itself (um, rad), what the check against the frame's initial-pass fit did
#: (:data:`INITIAL_CHECK`) and by how much the initial row's pose beat the frame's fit there
#: (chi^2 units, the pixel noise's; negative: it did not; NaN: not checked), what the probes
#: near the optical axis did (:data:`POLE_PROBE`) and what the recheck did (:data:`RECHECK`)
TRACK_COLUMNS = ("track_source", "track_jump", "runner_up_refit", "track_step_um",
                 "track_step_axis_rad", "track_initial", "track_initial_dchi2", "track_pole",
                 "track_recheck")
#: a chunk stops trying other heights (module docstring, step 8) after this many frames in a
#: row for which none worked: a stretch no height fits (a wrong library, an artefact) costs
#: seven library fits a frame only this often
REOPEN_MAX_FAILURES = 3
#: the heights (um, off the prefit's) a failing library fit is tried from again, in turn
REOPEN_DZ_UM = (-1.5, 1.5, -3.0, 3.0, -4.5, 4.5)
#: a probe's fit stops where the Gauss-Newton step predicts a chi^2 decrease of at most this:
#: it decides between minima 9 chi^2 units apart, and the one it picks is refitted fully
PROBE_STOP_CHI2 = 1.0
#: the codes of ``track_pole`` (module docstring, step 7)
POLE_PROBE = {
    -1: "not probed (not near the optical axis, not above the track's recent level, or a "
        "head-tail symmetric particle)",
    0: "probed: no probe ended lower than the warm fit",
    1: "probed: a probe ended lower; the frame was refitted from it",
}
#: the codes of ``track_recheck`` (module docstring, step 9)
RECHECK = {
    -1: "not rechecked (not a warm fit near the optical axis, or the next frame along the "
        "track is near it)",
    0: "refitted from between its neighbours' orientations: no lower minimum",
    1: "refitted from between its neighbours' orientations: a lower minimum, kept (the frame "
       "changed)",
}
#: frames a recheck goes back along the track from the frame just accepted (each changed frame
#: is the next one's start)
RECHECK_DEPTH = 3
#: the codes of ``track_initial`` (module docstring, step 6)
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


@dataclass(frozen=True)
class ChunkFrame:
    """One frame of a track, as the fit stage has it.

    Attributes
    ----------
    frame : int
        Frame index in the movie (gaps mean dropped frames).
    crop : ndarray
        Normalised hologram crop.
    corner : tuple of int
        Full-frame ``(row, column)`` of the crop's pixel ``[0, 0]``.
    position_um : tuple of float
        The prefit's ``(x, y, z)``, um (re-acquisition's start).
    alpha : float
        The prefit's alpha.
    candidates : tuple of Candidate
        The library's orientations for this frame, best first.
    time_s : float
        Time of the frame, s (NaN: unknown).
    initial : dict, optional
        The initial pass's fit of this frame (a converged row's :data:`INITIAL_POSE`
        values), the independent check of the module docstring's step 6; None: the initial
        pass did not fit this frame.
    """

    frame: int
    crop: NDArray
    corner: tuple[int, int]
    position_um: tuple[float, float, float]
    alpha: float
    candidates: tuple[Candidate, ...]
    time_s: float = math.nan
    initial: dict[str, float] | None = None


@dataclass(frozen=True)
class TrackOptions:
    """How a track is followed.

    Attributes
    ----------
    frame : FrameFitSettings
        Each fit's settings (warm fits, library fits and re-acquisitions alike).
    max_step_um, max_axis_step_rad : float, optional
        Largest smooth step between consecutive frames (position, um; axis, rad), e.g. a few
        times the diffusion scale ``sqrt(2 D dt)``; None: from the recent steps.
    step_factor : float
        Without given limits: the limit is this many times the median of the recent steps.
    min_step_um, min_axis_step_rad : float
        Floors of the limits from the recent steps (noise alone moves a fit by some nm).
    first_step_um, first_axis_step_rad : float
        Limits before ``min_history`` steps are known.
    history : int
        Recent accepted steps the limits and the velocity are taken over.
    min_history : int
        Steps needed before the limits follow the recent steps.
    extrapolate : bool
        Move the start by the recent velocity: the mean displacement per frame over the
        last ``history`` steps (a drift such as sinking; a diffusive step averages out), once
        ``min_history`` are known.
    refit_margin_chi2 : float
        The runner-up is fitted on all pixels when its screening is within
        ``ambiguity_chi2 + refit_margin_chi2`` of the best (:func:`fit_frame_warm`).
    initial_margin_chi2 : float
        A frame's fit is refitted from its initial-pass row's pose where that pose's chi^2
        (one evaluation, this pass's statics) is lower by more than this (units of the pixel
        noise; module docstring, step 6). 9 is ``ambiguity_chi2``: a competing minimum lower
        by less is not distinguishable at the noise level anyway, while the evaluation of a
        pose in the fit's own basin cannot beat the fit's minimum by more than the warm
        fits' stopping rule (``warm_stop_chi2``, 0.02), so a right-branch frame is never
        switched.
    warm : bool
        False: every frame is an independent library fit (``--no-tracking``).
    initial : bool
        The fit stage's initial pass (sizes free) follows the track too (with ``warm``).
    pole_rad : float
        A fit whose axis is this close to the optical axis (either pole) is probed (module
        docstring, step 7) and rechecked (step 9); 0: never. 40 deg: within 20 deg, a Janus
        replicate (seed 12) kept 11 frames at 20-36 deg from the pole 12-34 deg off the
        truth (within 15 deg, another had a frame held at theta 19 deg, truth 11 deg).
    pole_probes : int
        Probes of such a fit (0: none), the first two along the meridian. Two: on the
        200-frame Janus track of the benchmarks four probes within 40 deg cost 24.3
        hologram evaluations a frame, two 18.6 (four within 20 deg: 17.9), and the
        replicate's frames held near the pole were off the truth along the meridian.
    pole_probe_rad : float
        How far each probe's axis is tilted from the warm fit's.
    pole_min_gain_chi2 : float
        A probe replaces the warm fit where its minimum is lower by more than this (chi^2
        units of the pixel noise). 9 is ``ambiguity_chi2``: near the pole the misfit is
        shallow in the axis, and with static parameters a little off (the replicate's cap
        4 nm thin) minima a few degrees apart differ by 6-20 chi^2 units, either way of the
        truth, while the minimum that holds warm starts is 500-1000 above the right one.
    pole_probe_nfev : int
        Most holograms of one probe's fit (it stops within :data:`PROBE_STOP_CHI2` of its
        minimum).
    pole_probe_symmetric : bool
        Probe head-tail symmetric particles (rods) too. Off: the rod replicates (4000
        frames, two seeds) had no frame on a wrong branch without the probes, which raised a
        200-frame rod track that wanders near the pole from 12.0 to 17.8 evaluations a
        frame (four probes; 21.0 with six).
    recheck_rad : float
        A warm frame near the optical axis is refitted from its neighbours' side where the
        next accepted frame's axis is farther than this from its own (module docstring, step
        9); 0: never. 15 deg is ``pole_probe_rad``: a neighbour farther off is a start the
        probes did not try (the Janus replicate's median step was 10 deg a frame; the
        benchmarks' track, 4 deg, never reaches it).
    reopen_dz_um : tuple of float
        A library fit (a chunk's opening, a re-acquisition) that is not ``ok`` under the bar
        is tried again from these heights off the prefit's, in turn, until one is (module
        docstring, step 8); empty: never.
    open_at_best : bool
        A chunk opens with the library fit of its frame whose best library candidate has the
        highest R^2 (not of its first frame), and reaches the frames before it warm, backward
        in time (:func:`track_chunk`; the same step limits, drift and carried runner-up, along
        the direction the track is followed). A library fit starts from the prefit's height,
        and where that is far off the library ranks orientations at the wrong height: on a
        Janus replicate the first two frames' prefit heights were 0.47 um off (library R^2
        0.88 against 0.95 for the next frames) and the initial pass's chunk opened there
        settled 26 deg off the truth, with its free static parameters dragged along; near
        focus (true height 0.8-1.5 um, prefit 1.2-1.6 um higher) the final pass's chunks
        opened with library fits at chi^2_red 4-10, one frame after another, while the
        previous chunk had followed the same heights warm at 1.03-1.05. False: the first
        frame opens.
    """

    frame: FrameFitSettings = field(default_factory=FrameFitSettings)
    max_step_um: float | None = None
    max_axis_step_rad: float | None = None
    step_factor: float = 5.0
    min_step_um: float = 0.1
    min_axis_step_rad: float = math.radians(5.0)
    first_step_um: float = 0.5
    first_axis_step_rad: float = math.radians(20.0)
    history: int = 8
    min_history: int = 3
    extrapolate: bool = True
    refit_margin_chi2: float = 16.0
    initial_margin_chi2: float = 9.0
    warm: bool = True
    initial: bool = True
    open_at_best: bool = True
    pole_rad: float = math.radians(40.0)
    pole_probes: int = 2
    pole_probe_rad: float = math.radians(15.0)
    pole_min_gain_chi2: float = 9.0
    pole_probe_nfev: int = 20
    reopen_dz_um: tuple[float, ...] = REOPEN_DZ_UM
    pole_probe_symmetric: bool = False
    recheck_rad: float = math.radians(15.0)

    def __post_init__(self) -> None:
        if not self.recheck_rad >= 0:
            raise ValueError("tracking: recheck_rad >= 0 needed")
        if not (self.step_factor > 0 and self.history >= self.min_history >= 1
                and self.refit_margin_chi2 >= 0 and self.initial_margin_chi2 >= 0):
            raise ValueError("tracking: step_factor > 0, history >= min_history >= 1, "
                             "refit_margin_chi2 >= 0 and initial_margin_chi2 >= 0 needed")
        if not (0 <= self.pole_rad < math.pi / 2 and self.pole_probes >= 0
                and 0 < self.pole_probe_rad < math.pi / 2 and self.pole_min_gain_chi2 >= 0
                and self.pole_probe_nfev >= 1):
            raise ValueError("tracking: 0 <= pole_rad < pi/2, pole_probes >= 0, "
                             "0 < pole_probe_rad < pi/2, pole_min_gain_chi2 >= 0 and "
                             "pole_probe_nfev >= 1 needed")


@dataclass
class _Accepted:
    """The last accepted fit of a track and what the next frame starts from."""

    frame: int
    state: State
    runner_up: CarriedRunnerUp | None
    steps_um: list[float]
    steps_rad: list[float]
    moves: list[NDArray[np.float64]] = field(default_factory=list)
    levels: list[float] = field(default_factory=list)

    def level(self, min_history: int) -> float | None:
        """Median reduced chi^2 of the recent accepted fits (None: too few yet)."""
        return float(np.median(self.levels)) if len(self.levels) >= min_history else None

    def velocity(self, min_history: int) -> NDArray[np.float64]:
        """Mean displacement per frame over the recent steps, um."""
        if len(self.moves) < min_history:
            return np.zeros(3)
        return np.mean(self.moves, axis=0)


def state_of(values: dict[str, float], model: ParticleModel) -> State:
    """The :class:`State` of a fit's values (position, orientation, alpha, statics)."""
    pos = (float(values["x_um"]), float(values["y_um"]), float(values["z_um"]))
    rot = None
    if model.anisotropic:
        rot = euler_zyz(float(values["psi_rad"]), float(values["theta_rad"]),
                        float(values.get("phi_rad", 0.0)))
    statics = tuple((name, float(values.get(name, v))) for name, v in static_values(model))
    return State(pos, rot, float(values["alpha"]), statics)


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


def _near_pole(state: State, opts: TrackOptions) -> bool:
    """The axis of ``state`` lies within ``opts.pole_rad`` of the optical axis (either pole)."""
    assert state.rotation is not None
    return abs(float(state.rotation[2, 2])) >= math.cos(opts.pole_rad)


def _between(own: State, before: State | None, later: State, head_tail: bool) -> State:
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


def _axis_step(a: State, b: State, head_tail: bool) -> float:
    if a.rotation is None or b.rotation is None:
        return 0.0
    c = float(np.dot(a.rotation[:, 2], b.rotation[:, 2]))
    return math.acos(min(1.0, abs(c) if head_tail else max(-1.0, c)))


def _limits(acc: _Accepted, opts: TrackOptions, gap: int) -> tuple[float, float]:
    """Largest smooth position and axis steps over ``gap`` frames (diffusive: sqrt(gap))."""
    grow = math.sqrt(max(gap, 1))
    if opts.max_step_um is not None:
        pos = opts.max_step_um
    elif len(acc.steps_um) >= opts.min_history:
        pos = max(opts.min_step_um, opts.step_factor * float(np.median(acc.steps_um)))
    else:
        pos = opts.first_step_um
    if opts.max_axis_step_rad is not None:
        ang = opts.max_axis_step_rad
    elif len(acc.steps_rad) >= opts.min_history:
        ang = max(opts.min_axis_step_rad,
                  opts.step_factor * float(np.median(acc.steps_rad)))
    else:
        ang = opts.first_axis_step_rad
    return pos * grow, ang * grow


def _step(acc: _Accepted, state: State, model: ParticleModel) -> tuple[float, float]:
    d = np.subtract(state.position, acc.state.position)
    return float(np.linalg.norm(d)), _axis_step(acc.state, state, model.head_tail_symmetric)


def _under_bar(result: FitResult, chi2_bar: float | None) -> bool:
    if result.status != OK:
        return False
    return chi2_bar is None or not math.isfinite(chi2_bar) or result.chi2_red <= chi2_bar


@dataclass
class _Fitter:
    """What every fit of a chunk shares."""

    theory: ScatteringTheory
    model: ParticleModel
    optics: Optics
    pixel_size_um: float
    free: tuple[str, ...]
    opts: TrackOptions
    #: the chunk's frames in a row whose other heights all failed (step 8)
    reopen_failures: int = 0

    def library(self, f: ChunkFrame, chi2_bar: float | None = None,
                retry: bool = True) -> FitResult:
        """The frame's library fit from the prefit's position; where it is not ``ok`` under
        ``chi2_bar`` (and ``retry``), again from heights ``reopen_dz_um`` off the prefit's,
        in turn, until one is (step 8 of the module docstring); the lowest fit, ``n_eval``
        counting all."""
        best = self._library_at(f, 0.0)
        n_eval = best.n_eval
        retry = (retry and self.opts.warm and bool(self.opts.reopen_dz_um)
                 and self.reopen_failures < REOPEN_MAX_FAILURES
                 and not _under_bar(best, chi2_bar))
        for dz in self.opts.reopen_dz_um if retry else ():
            alt = self._library_at(f, dz)
            n_eval += alt.n_eval
            if alt.status == OK and (best.status != OK or alt.chi2 < best.chi2):
                alt.message = _join(alt.message, f"library fit from {dz:+.3g} um off the "
                                    "prefit's height (from the prefit's: reduced chi^2 "
                                    f"{best.chi2_red:.3g}, {best.status})")
                best = alt
            if _under_bar(best, chi2_bar):
                break
        if retry:
            self.reopen_failures = 0 if _under_bar(best, chi2_bar) else self.reopen_failures + 1
        best.n_eval = n_eval
        return best

    def _library_at(self, f: ChunkFrame, dz: float) -> FitResult:
        x, y, z = f.position_um
        return fit_frame(f.crop, f.corner, self.pixel_size_um, self.theory, self.model,
                         self.optics, (x, y, z + dz), f.alpha, f.candidates, self.free,
                         self.opts.frame, seed=f.frame)

    def warm(self, f: ChunkFrame, acc: _Accepted) -> WarmFit:
        gap = abs(f.frame - acc.frame)  # frames along the track, either way in time
        state = acc.state
        if self.opts.extrapolate and gap == 1:
            drift = acc.velocity(self.opts.min_history)
            state = replace(state, position=tuple(np.add(state.position, drift)))
        return self._refit(f, state, carried=acc.runner_up if gap == 1 else None)

    def _refit(self, f: ChunkFrame, start: State, carried: CarriedRunnerUp | None = None
               ) -> WarmFit:
        """A full warm fit of ``f`` from ``start``, its mirror runner-up as in step 2
        (``carried``: the previous frame's)."""
        return fit_frame_warm(f.crop, f.corner, self.pixel_size_um, self.theory, self.model,
                              self.optics, start, self.free, self.opts.frame, seed=f.frame,
                              carried=carried, refit_margin_chi2=self.opts.refit_margin_chi2)

    def _probe(self, f: ChunkFrame, start: State) -> FitResult:
        """A probe's fit of ``f`` from ``start``: no mirror, at most ``pole_probe_nfev``
        holograms, stopping within :data:`PROBE_STOP_CHI2` of its minimum."""
        opts = self.opts
        quiet = replace(opts.frame, mirror=False,
                        max_nfev=min(opts.frame.max_nfev, opts.pole_probe_nfev),
                        stop_chi2=max(opts.frame.stop_chi2, PROBE_STOP_CHI2))
        return fit_frame_warm(f.crop, f.corner, self.pixel_size_um, self.theory, self.model,
                              self.optics, start, self.free, quiet, seed=f.frame).result

    def probe_pole(self, f: ChunkFrame, res: FitResult, runner: CarriedRunnerUp | None,
                   acc: _Accepted | None = None
                   ) -> tuple[FitResult, CarriedRunnerUp | None, int]:
        """Step 7 of the module docstring: the fit ``res`` (and the runner-up it carries), or
        the refit from the lowest probe where that is lower; what was done
        (:data:`POLE_PROBE`). The returned fit's ``n_eval`` counts the probes' holograms."""
        opts = self.opts
        state = state_of(res.values, self.model) if np.isfinite(res.rss) else None
        if (not opts.pole_probes or not opts.warm or state is None or state.rotation is None
                or not res.noise_sd > 0
                or (self.model.head_tail_symmetric and not opts.pole_probe_symmetric)
                or not _near_pole(state, opts)):
            return res, runner, -1
        level = None if acc is None else acc.level(opts.min_history)
        if level is not None and not res.chi2_red > level:
            return res, runner, -1
        n_eval, best = res.n_eval, None
        for start in pole_probes(state, opts.pole_probes, opts.pole_probe_rad):
            probe = self._probe(f, start)
            n_eval += probe.n_eval
            if np.isfinite(probe.rss) and (best is None or probe.rss < best.rss):
                best = probe
        if best is None or not (res.rss - best.rss) / res.noise_sd**2 > opts.pole_min_gain_chi2:
            res.n_eval = n_eval
            return res, runner, 0
        again = self._refit(f, state_of(best.values, self.model))
        new = again.result
        if not new.rss < res.rss:  # the refit from the probe's minimum went elsewhere
            res.n_eval = n_eval + new.n_eval
            return res, runner, 0
        new.message = _join(new.message, "the fit ended near the optical axis, "
                            f"{(res.rss - new.rss) / new.noise_sd**2:.4g} chi^2 above the "
                            "minimum a probe tilted from it found")
        _competitor(new, res, self.model, opts.frame.ambiguity_chi2)
        new.n_eval = n_eval + new.n_eval
        return new, again.carried, 1

    def recheck(self, f: ChunkFrame, res: FitResult, later: FitResult,
                before: State | None = None) -> tuple[FitResult, int, int]:
        """Step 9 of the module docstring: frame ``f``'s warm fit ``res`` refitted from the
        orientation between ``before`` (the accepted fit it started from; None: ``later``'s
        orientation alone) and ``later``, the next frame's accepted fit along the track.
        Returns the fit kept, the code (:data:`RECHECK`) and the holograms computed."""
        opts = self.opts
        if not (opts.warm and opts.recheck_rad > 0 and res.status == OK
                and np.isfinite(res.rss) and res.noise_sd > 0 and np.isfinite(later.rss)
                and (opts.pole_probe_symmetric or not self.model.head_tail_symmetric)):
            return res, -1, 0
        own, nxt = state_of(res.values, self.model), state_of(later.values, self.model)
        if (own.rotation is None or not _near_pole(own, opts)
                or not _axis_step(own, nxt, self.model.head_tail_symmetric)
                > opts.recheck_rad):
            return res, -1, 0
        start = _between(own, before, nxt, self.model.head_tail_symmetric)
        probe = self._probe(f, start)
        n_eval = probe.n_eval
        if not (np.isfinite(probe.rss)
                and (res.rss - probe.rss) / res.noise_sd**2 > opts.pole_min_gain_chi2):
            return res, 0, n_eval
        again = self._refit(f, state_of(probe.values, self.model))
        new = again.result
        n_eval += new.n_eval
        if not new.rss < res.rss:
            return res, 0, n_eval
        new.message = _join(new.message, "refitted from between its neighbours' orientations "
                            f"along the track: {(res.rss - new.rss) / new.noise_sd**2:.4g} "
                            "chi^2 below the warm fit")
        _competitor(new, res, self.model, opts.frame.ambiguity_chi2)
        return new, 1, n_eval

    def initial_state(self, f: ChunkFrame, res: FitResult) -> State:
        """The pose of ``f``'s initial-pass row with this pass's statics (the model's) and,
        where the aperture is fitted, the frame's fitted aperture."""
        assert f.initial is not None
        pose = {k: v for k, v in f.initial.items() if k in INITIAL_POSE}
        state = state_of(pose, self.model)
        if APERTURE.name in self.free and APERTURE.name in res.values:
            state = replace(state, numerical_aperture=float(res.values[APERTURE.name]))
        return state

    def check_initial(self, f: ChunkFrame, res: FitResult, runner: CarriedRunnerUp | None
                      ) -> tuple[FitResult, CarriedRunnerUp | None, _Check]:
        """Step 6 of the module docstring: the frame's fit ``res`` against the pose of its
        initial-pass row; the fit kept, its runner-up to carry, and what was done."""
        if f.initial is None or not np.isfinite(res.rss) or not res.noise_sd > 0:
            return res, runner, _Check(-1, 0, math.nan)
        start = self.initial_state(f, res)
        chi2_initial, n_eval = evaluate_frame(
            f.crop, f.corner, self.pixel_size_um, self.theory, self.model, self.optics,
            start, self.free, self.opts.frame, seed=f.frame)
        own = res.rss / res.noise_sd**2
        beat = own - chi2_initial
        if not beat > self.opts.initial_margin_chi2:
            return res, runner, _Check(0, n_eval, beat)
        alt = self._refit(f, start)
        n_eval += alt.result.n_eval
        if not alt.result.rss < res.rss:
            return res, runner, _Check(1, n_eval, beat)
        return alt.result, alt.carried, _Check(2, n_eval, beat)

    def changed(self, res: FitResult, old: FitResult, check: _Check, source: str) -> None:
        """The note and the runner-up of a frame the check changed (``old``: its fit before)."""
        res.message = _join(res.message, f"{source} fit replaced: the initial pass's pose of "
                            f"this frame was {check.beat:.4g} chi^2 below it; refitted from "
                            f"there, now {(old.rss - res.rss) / res.noise_sd**2:.4g} below")
        _competitor(res, old, self.model, self.opts.frame.ambiguity_chi2)


@dataclass(frozen=True)
class _Check:
    """What the check against the initial-pass row did: ``code`` (:data:`INITIAL_CHECK`),
    the holograms it computed, and by how much the initial pose beat the frame's fit
    (chi^2 units; NaN: not checked)."""

    code: int
    n_eval: int
    beat: float


def _competitor(new: FitResult, old: FitResult, model: ParticleModel,
                ambiguity_chi2: float) -> None:
    """``old``, a minimum ``new`` replaced, as ``new``'s runner-up where it is a distinct
    minimum closer than the runner-up ``new`` reports (the ambiguity flag's runner-up is the
    nearest real competing minimum)."""
    a, b = state_of(new.values, model), state_of(old.values, model)
    if (_axis_step(a, b, model.head_tail_symmetric) < SAME_BASIN_RAD
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


def _row(f: ChunkFrame, result: FitResult, source: str, jump: bool, step: tuple[float, float],
         n_eval: int, check: _Check | None = None, pole: int = -1) -> dict[str, Any]:
    result.n_eval = n_eval
    row = result_row(f.frame, f.time_s, result)
    row.update(track_source=source, track_jump=int(jump), track_step_um=step[0],
               track_step_axis_rad=step[1], track_initial=-1 if check is None else check.code,
               track_initial_dchi2=math.nan if check is None else check.beat, track_pole=pole,
               track_recheck=-1)
    row.setdefault("runner_up_refit", 2 if result.extra.get("n_starts", 1) > 1 else -1)
    return row


def _accept(acc: _Accepted | None, f: ChunkFrame, result: FitResult,
            runner: CarriedRunnerUp | None,
            model: ParticleModel, opts: TrackOptions) -> _Accepted:
    """The track's state after accepting ``result`` for frame ``f``."""
    state = state_of(result.values, model)
    if acc is None:
        return _Accepted(f.frame, state, runner, [], [], [], [result.chi2_red])
    dist, ang = _step(acc, state, model)
    gap = max(abs(f.frame - acc.frame), 1)  # a move per frame along the track's direction
    move = np.subtract(state.position, acc.state.position) / gap
    keep = opts.history
    return _Accepted(f.frame, state, runner, [*acc.steps_um, dist / math.sqrt(gap)][-keep:],
                     [*acc.steps_rad, ang / math.sqrt(gap)][-keep:],
                     [*acc.moves, move][-keep:], [*acc.levels, result.chi2_red][-keep:])


def track_chunk(
    frames: Sequence[ChunkFrame],
    theory: ScatteringTheory,
    model: ParticleModel,
    optics: Optics,
    pixel_size_um: float,
    free: Sequence[str],
    chi2_bar: float | None,
    options: TrackOptions | None = None,
    start: dict[str, float] | None = None,
) -> pd.DataFrame:
    """Fit the frames of one chunk of a track, each from its predecessor (module docstring).

    Parameters
    ----------
    frames : sequence of ChunkFrame
        The chunk's frames in time order.
    theory, model, optics, pixel_size_um, free
        As for :func:`holofit.fit.frame.fit_frame` (the final pass: statics fixed).
    chi2_bar : float or None
        The movie's bar on the reduced chi^2 (None or NaN: only the fit's status counts).
    options : TrackOptions, optional
        Settings.
    start : dict, optional
        A fit's values (``x_um, y_um, z_um, theta_rad, psi_rad[, phi_rad], alpha``) the first
        frame starts from warm; None: the first frame is a library fit.

    Returns
    -------
    pandas.DataFrame
        One row per frame: the fit table's columns and :data:`TRACK_COLUMNS`.
    """
    opts = options or TrackOptions()
    fitter = _Fitter(theory, model, optics, pixel_size_um, tuple(free), opts)
    acc: _Accepted | None = None
    if start is not None and frames:
        acc = _Accepted(frames[0].frame - 1, state_of(start, model), None, [], [])
    k = _opening(frames) if start is None and opts.warm and opts.open_at_best else 0
    rows: list[dict[str, Any]] = []
    opened = _follow_run(fitter, frames[k:], acc, chi2_bar, rows)
    if k:  # the frames before the opening one, backward from it (fresh history)
        acc = None if opened is None else _Accepted(opened.frame, opened.state,
                                                   opened.runner_up, [], [])
        back: list[dict[str, Any]] = []
        _follow_run(fitter, frames[:k][::-1], acc, chi2_bar, back)
        rows = back[::-1] + rows
    return pd.DataFrame(rows)


@dataclass
class _Done:
    """A frame followed: its fit (None: an ``error`` row), its row's index, and the track's
    state it started from."""

    frame: ChunkFrame
    result: FitResult | None
    index: int
    before: _Accepted | None


def _follow_run(fitter: _Fitter, frames: Sequence[ChunkFrame], acc: _Accepted | None,
                chi2_bar: float | None, rows: list[dict[str, Any]]) -> _Accepted | None:
    """Follow ``frames`` (in the order given) from ``acc``, appending their rows to ``rows``
    and rechecking the frames before each accepted one (step 9); the track's state after the
    first frame (None where it was not accepted)."""
    recent: list[_Done] = []
    first: _Accepted | None = None
    for i, f in enumerate(frames):
        before = acc
        acc, row, res = _follow(fitter, f, acc, chi2_bar)
        rows.append(row)
        if i == 0:
            first = acc
        recent = [*recent, _Done(f, res, len(rows) - 1, before)][-(RECHECK_DEPTH + 1):]
        if res is not None and acc is not None and acc.frame == f.frame:
            _recheck_back(fitter, recent, rows)
    return first


def _recheck_back(fitter: _Fitter, recent: list[_Done], rows: list[dict[str, Any]]) -> None:
    """Step 9: the warm frames before the last of ``recent`` (just accepted), each refitted
    from the next one's orientation while that changes it; their rows replaced."""
    for j in range(len(recent) - 1, 0, -1):
        later, done = recent[j], recent[j - 1]
        if (later.result is None or done.result is None
                or abs(later.frame.frame - done.frame.frame) != 1
                or rows[done.index].get("track_source") != "warm"):
            return
        new, code, n_eval = fitter.recheck(
            done.frame, done.result, later.result,
            None if done.before is None else done.before.state)
        old = rows[done.index]
        if code < 0:
            return
        if code == 0:
            old.update(n_eval=int(old["n_eval"]) + n_eval, track_recheck=0)
            return
        row = _recheck_row(fitter, done, new, old, n_eval)
        rows[done.index] = row
        done.result = new


def _recheck_row(fitter: _Fitter, done: _Done, new: FitResult, old: dict[str, Any],
                 n_eval: int) -> dict[str, Any]:
    """The row of a frame the recheck changed: its step from the state it started from
    (a jump flagged as for a re-acquisition), the checks' columns as they were."""
    step, jump = (math.nan, math.nan), False
    if done.before is not None:
        step = _step(done.before, state_of(new.values, fitter.model), fitter.model)
        lim = _limits(done.before, fitter.opts, abs(done.frame.frame - done.before.frame))
        jump = not (step[0] <= lim[0] and step[1] <= lim[1])
        if jump:
            new.message = _join(new.message, f"jump of {step[0]:.3g} um and "
                                f"{math.degrees(step[1]):.3g} deg from frame "
                                f"{done.before.frame} (limits {lim[0]:.3g} um, "
                                f"{math.degrees(lim[1]):.3g} deg)")
    row = _row(done.frame, new, "warm", jump, step, int(old["n_eval"]) + n_eval)
    row.update({k: old[k] for k in ("track_initial", "track_initial_dchi2", "track_pole")},
               track_recheck=1)
    return row


def _follow(fitter: _Fitter, f: ChunkFrame, acc: _Accepted | None, chi2_bar: float | None
            ) -> tuple[_Accepted | None, dict[str, Any], FitResult | None]:
    """:func:`_track_frame`, an exception making the frame an ``error`` row (the track goes
    on from the last accepted fit); the fit kept (None for an ``error`` row)."""
    try:
        row, acc, res = _track_frame(fitter, f, acc, chi2_bar)
    except Exception as exc:
        row, res = _error_row(f, exc), None
    return acc, row, res


def _opening(frames: Sequence[ChunkFrame]) -> int:
    """Index of the frame whose best library candidate has the highest R^2 (the first frame
    where none has one)."""
    best, k = -math.inf, 0
    for i, f in enumerate(frames):
        r2 = f.candidates[0].r2 if f.candidates else math.nan
        if math.isfinite(r2) and r2 > best:
            best, k = r2, i
    return k


def _error_row(f: ChunkFrame, exc: Exception) -> dict[str, Any]:
    """The ``error`` row of a frame whose fit raised (as the batch runner writes one)."""
    import traceback
    from pathlib import Path

    where = traceback.extract_tb(exc.__traceback__)[-1]
    return {"frame": f.frame, "time_s": f.time_s, "status": ERROR,
            "message": f"{type(exc).__name__}: {exc} "
                       f"(at {Path(where.filename).name}:{where.lineno})"}


def _track_frame(fitter: _Fitter, f: ChunkFrame, acc: _Accepted | None, chi2_bar: float | None
                 ) -> tuple[dict[str, Any], _Accepted | None, FitResult]:
    """One frame: warm fit, checks, re-acquisition; the row and the track's new state."""
    model, opts = fitter.model, fitter.opts
    nan2 = (math.nan, math.nan)
    if acc is None or not opts.warm:  # a chunk's first frame: the library's starts
        lib, runner, pole = fitter.probe_pole(f, fitter.library(f, chi2_bar), None)
        res, runner, check = fitter.check_initial(f, lib, runner)
        if check.code == 2:
            fitter.changed(res, lib, check, "library")
        good = _under_bar(res, chi2_bar)
        _flag_above_bar(res, good, chi2_bar)
        new = _accept(None, f, res, runner, model, opts) if good or res.status == OK else None
        return (_row(f, res, "library", False, nan2, lib.n_eval + check.n_eval, check, pole),
                new, res)
    warm = fitter.warm(f, acc)
    first, carried, pole = fitter.probe_pole(f, warm.result, warm.carried, acc)
    n_warm = first.n_eval
    res, runner, check = fitter.check_initial(f, first, carried)
    step = _step(acc, state_of(res.values, model), model)
    lim = _limits(acc, opts, abs(f.frame - acc.frame))
    smooth = step[0] <= lim[0] and step[1] <= lim[1]
    if check.code != 2 and _under_bar(res, chi2_bar) and smooth:
        return (_row(f, res, "warm", False, step, n_warm + check.n_eval, check, pole),
                _accept(acc, f, res, runner, model, opts), res)
    # re-acquisition: the frame as an independent one; the better fit kept
    # a warm fit under the bar that stepped too far needs the library's other starts, not
    # other heights: it has the frame's height already
    lib = fitter.library(f, chi2_bar, retry=not _under_bar(res, chi2_bar))
    again, again_runner, again_pole = fitter.probe_pole(f, lib, None, acc)
    n_eval = n_warm + check.n_eval + again.n_eval
    if not res.chi2 <= again.chi2:
        res, runner, pole = again, again_runner, again_pole
    if check.code == 2:
        fitter.changed(res, first, check, "warm")
    step = _step(acc, state_of(res.values, model), model)
    smooth = step[0] <= lim[0] and step[1] <= lim[1]
    good = _under_bar(res, chi2_bar)
    _flag_above_bar(res, good, chi2_bar)
    if good and not smooth:
        res.message = _join(res.message, f"jump of {step[0]:.3g} um and "
                            f"{math.degrees(step[1]):.3g} deg from frame {acc.frame} "
                            f"(limits {lim[0]:.3g} um, {math.degrees(lim[1]):.3g} deg)")
    new = _accept(acc, f, res, runner, model, opts) if good else acc
    return _row(f, res, "reacquired", not smooth, step, n_eval, check, pole), new, res


def _join(a: str, b: str) -> str:
    return b if not a or a == "converged" else f"{a}; {b}"


def _flag_above_bar(res: FitResult, good: bool, chi2_bar: float | None) -> None:
    """An ``ok`` fit above the movie's bar becomes ``poor_fit``."""
    if res.status == OK and not good:
        res.status = POOR_FIT
        res.message = _join(res.message, f"reduced chi^2 {res.chi2_red:.3g} above the "
                            f"movie's bar {chi2_bar:.3g}")


def stitch_chunks(
    chunks: Sequence[pd.DataFrame],
    head_tail: bool,
    position_tol_um: float = 0.02,
    axis_tol_rad: float = math.radians(2.0),
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Join the tables of overlapping chunks of one track (in time order).

    In an overlap the earlier chunk's row is kept (it was reached warm, along the track),
    unless the two disagree (position beyond ``position_tol_um`` or axis beyond
    ``axis_tol_rad``) and the later one has the lower chi^2.

    Parameters
    ----------
    chunks : sequence of pandas.DataFrame
        :func:`track_chunk` tables, in time order.
    head_tail : bool
        The particle's axis u and -u are one orientation.
    position_tol_um, axis_tol_rad : float
        When two fits of one frame agree.

    Returns
    -------
    table : pandas.DataFrame
        One row per frame.
    disagreements : pandas.DataFrame
        ``frame, chunk, position_diff_um, axis_diff_rad, chi2_earlier, chi2_later, kept``
        for every overlapping frame whose fits disagree.
    """
    rows: dict[int, dict[str, Any]] = {}
    where: dict[int, int] = {}
    bad = []
    for i, chunk in enumerate(chunks):
        for row in chunk.to_dict("records"):
            frame = int(row["frame"])
            old = rows.get(frame)
            if old is None:
                rows[frame], where[frame] = row, i
                continue
            dpos, dax = _row_difference(old, row, head_tail)
            if dpos <= position_tol_um and dax <= axis_tol_rad:
                continue
            later_better = float(row["chi2"]) < float(old["chi2"])
            bad.append({"frame": frame, "chunk": i, "position_diff_um": dpos,
                        "axis_diff_rad": dax, "chi2_earlier": float(old["chi2"]),
                        "chi2_later": float(row["chi2"]),
                        "kept": "later" if later_better else "earlier"})
            if later_better:
                rows[frame], where[frame] = row, i
    table = pd.DataFrame([rows[k] for k in sorted(rows)])
    cols = ["frame", "chunk", "position_diff_um", "axis_diff_rad", "chi2_earlier",
            "chi2_later", "kept"]
    return table, pd.DataFrame(bad, columns=cols)


def _row_difference(a: dict[str, Any], b: dict[str, Any], head_tail: bool
                    ) -> tuple[float, float]:
    dpos = math.dist([a["x_um"], a["y_um"], a["z_um"]], [b["x_um"], b["y_um"], b["z_um"]])
    if "ux" not in a:
        return dpos, 0.0
    c = float(np.dot([a["ux"], a["uy"], a["uz"]], [b["ux"], b["uy"], b["uz"]]))
    return dpos, math.acos(min(1.0, abs(c) if head_tail else max(-1.0, c)))
