"""Following a track: each frame of a chunk fitted from its predecessor's fit.

Between frames a particle moves little (the paper's rod: a few degrees and tens of
nanometres), so the previous frame's fit is a start inside the right basin and the library's
starts are needed only where that fails. Along one chunk of a track (frames in time order):

1. The chunk opens with a library fit (:func:`holofit.fit.rescue.library_fit`: the library's
   starts and the mirror) of the frame the library reads best (``open_at_best``), or from a
   given fit (``start``) at its first frame. The track is followed from there to the chunk's
   end and, from the opening frame again, back to its start: "frame k-1" below is the
   previous frame along that direction.
2. Frame k is fitted from frame k-1's accepted fit (:meth:`ChunkFitter.warm`): position moved
   by the recent drift, orientation, alpha and statics as they are, its mirror runner-up
   carried along (:mod:`holofit.fit.warm`).
3. The warm fit is accepted when it is ``ok``, under the movie's bar (``chi2_bar``) and its
   step from the accepted predecessor is smooth (:func:`holofit.fit.follower.step_limits`).
4. A frame that fails is *re-acquired*: fitted from the library's starts as an independent
   frame; the better of the two fits is kept. One still above the bar becomes ``poor_fit``
   (:func:`holofit.quality.flag_above_bar`); one whose step is not smooth is flagged
   (``follow_jump`` 1 and a message), never silently ``ok``.
5. A frame whose fit raises is an ``error`` row; the next frame starts from the last accepted
   fit.
6. A frame the initial pass fitted too is checked against that fit
   (:func:`holofit.fit.rescue.check_against_initial`).
7. A fit whose axis ends near the optical axis is probed
   (:func:`holofit.fit.rescue.probe_near_pole`).
8. A library fit far from the data is tried from other heights
   (:func:`holofit.fit.rescue.library_fit`).
9. Once a frame is accepted, the warm frame before it is rechecked from between its
   neighbours where it lies near the pole and its successor turned far
   (:func:`holofit.fit.rescue.recheck_between`), up to :data:`RECHECK_DEPTH` frames back.

Each row has the fit table's columns (:func:`holofit.holomodel.result.result_row`, with
:data:`holofit.fit.frame.RUNNER_UP_COLUMNS`) and :data:`FOLLOW_COLUMNS`. Chunks are planned
and stitched by :mod:`holofit.fit.chunks`.
"""

from __future__ import annotations

import math
import traceback
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd

from holofit.fit.follower import (
    ChunkFitter,
    ChunkFrame,
    Followed,
    step_limits,
    step_of,
)
from holofit.fit.problem import state_of
from holofit.fit.rescue import (
    InitialCheck,
    check_against_initial,
    library_fit,
    note_changed,
    probe_near_pole,
    recheck_between,
)
from holofit.fit.settings import FollowSettings
from holofit.holomodel.result import FitResult, result_row
from holofit.optics import Optics
from holofit.particles import ParticleModel
from holofit.quality import flag_above_bar, join_message, under_bar
from holofit.scattering.theory import ScatteringEngine
from holofit.status import ERROR, OK

__all__ = ["FOLLOW_COLUMNS", "RECHECK_DEPTH", "follow_chunk"]

#: what a followed row adds to the fit table's columns: how the frame was obtained
#: (``library``: a chunk's first frame; ``warm``; ``reacquired``), whether its step from the
#: accepted predecessor broke the smoothness limits, whether the runner-up was refitted, the
#: step itself (um, rad), what the check against the frame's initial-pass fit did
#: (:data:`holofit.fit.rescue.INITIAL_CHECK`) and by how much the initial row's pose beat the
#: frame's fit there (chi^2 units; NaN: not checked), what the probes near the optical axis
#: did (:data:`holofit.fit.rescue.POLE_PROBE`) and what the recheck did
#: (:data:`holofit.fit.rescue.RECHECK`)
FOLLOW_COLUMNS = ("follow_source", "follow_jump", "runner_up_refit", "follow_step_um",
                  "follow_step_axis_rad", "follow_initial", "follow_initial_dchi2",
                  "follow_pole", "follow_recheck")
#: frames a recheck goes back along the track from the frame just accepted (each changed frame
#: is the next one's start)
RECHECK_DEPTH = 3


def _row(f: ChunkFrame, result: FitResult, source: str, jump: bool, step: tuple[float, float],
         n_eval: int, check: InitialCheck | None = None, pole: int = -1) -> dict[str, Any]:
    result.n_eval = n_eval
    row = result_row(f.frame, f.time_s, result)
    row.update(follow_source=source, follow_jump=int(jump), follow_step_um=step[0],
               follow_step_axis_rad=step[1],
               follow_initial=-1 if check is None else check.code,
               follow_initial_dchi2=math.nan if check is None else check.beat,
               follow_pole=pole, follow_recheck=-1)
    row.setdefault("runner_up_refit", 2 if result.extra.get("n_starts", 1) > 1 else -1)
    return row


def follow_chunk(
    frames: Sequence[ChunkFrame],
    fitter: ChunkFitter,
    chi2_bar: float | None,
    start: dict[str, float] | None = None,
) -> pd.DataFrame:
    """Fit the frames of one chunk of a track, each from its predecessor (module docstring).

    Parameters
    ----------
    frames : sequence of ChunkFrame
        The chunk's frames in time order.
    fitter : ChunkFitter
        The chunk's engine, model, optics, pixel size, free parameters and settings
        (:meth:`chunk_fitter` makes one).
    chi2_bar : float or None
        The movie's bar on the reduced chi^2 (None or NaN: only the fit's status counts).
    start : dict, optional
        A fit's values (``x_um, y_um, z_um, theta_rad, psi_rad[, phi_rad], alpha``) the first
        frame starts from warm; None: the first frame is a library fit.

    Returns
    -------
    pandas.DataFrame
        One row per frame: the fit table's columns and :data:`FOLLOW_COLUMNS`.
    """
    opts, model = fitter.opts, fitter.model
    acc: Followed | None = None
    if start is not None and frames:
        acc = Followed(frames[0].frame - 1, state_of(start, model), None, [], [])
    k = _opening(frames) if start is None and opts.warm and opts.open_at_best else 0
    rows: list[dict[str, Any]] = []
    opened = _follow_run(fitter, frames[k:], acc, chi2_bar, rows)
    if k:  # the frames before the opening one, backward from it (fresh history)
        acc = None if opened is None else Followed(opened.frame, opened.state,
                                                   opened.runner_up, [], [])
        back: list[dict[str, Any]] = []
        _follow_run(fitter, frames[:k][::-1], acc, chi2_bar, back)
        rows = back[::-1] + rows
    return pd.DataFrame(rows)


def chunk_fitter(theory: ScatteringEngine, model: ParticleModel, optics: Optics,
                 pixel_size_um: float, free: Sequence[str],
                 options: FollowSettings | None = None) -> ChunkFitter:
    """The :class:`~holofit.fit.follower.ChunkFitter` of a chunk (default settings)."""
    return ChunkFitter(theory, model, optics, pixel_size_um, tuple(free),
                       options or FollowSettings())


@dataclass
class _Done:
    """A frame followed: its fit (None: an ``error`` row), its row's index, and the track's
    state it started from."""

    frame: ChunkFrame
    result: FitResult | None
    index: int
    before: Followed | None


def _follow_run(fitter: ChunkFitter, frames: Sequence[ChunkFrame], acc: Followed | None,
                chi2_bar: float | None, rows: list[dict[str, Any]]) -> Followed | None:
    """Follow ``frames`` (in the order given) from ``acc``, appending their rows to ``rows``
    and rechecking the frames before each accepted one (step 9); the track's state after the
    first frame (None where it was not accepted)."""
    recent: list[_Done] = []
    first: Followed | None = None
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


def _recheck_back(fitter: ChunkFitter, recent: list[_Done], rows: list[dict[str, Any]]) -> None:
    """Step 9: the warm frames before the last of ``recent`` (just accepted), each refitted
    from the next one's orientation while that changes it; their rows replaced."""
    for j in range(len(recent) - 1, 0, -1):
        later, done = recent[j], recent[j - 1]
        if (later.result is None or done.result is None
                or abs(later.frame.frame - done.frame.frame) != 1
                or rows[done.index].get("follow_source") != "warm"):
            return
        new, code, n_eval = recheck_between(
            fitter, done.frame, done.result, later.result,
            None if done.before is None else done.before.state)
        old = rows[done.index]
        if code < 0:
            return
        if code == 0:
            old.update(n_eval=int(old["n_eval"]) + n_eval, follow_recheck=0)
            return
        rows[done.index] = _recheck_row(fitter, done, new, old, n_eval)
        done.result = new


def _recheck_row(fitter: ChunkFitter, done: _Done, new: FitResult, old: dict[str, Any],
                 n_eval: int) -> dict[str, Any]:
    """The row of a frame the recheck changed: its step from the state it started from
    (a jump flagged as for a re-acquisition), the checks' columns as they were."""
    step, jump = (math.nan, math.nan), False
    if done.before is not None:
        step = step_of(done.before, state_of(new.values, fitter.model), fitter.model)
        lim = step_limits(done.before, fitter.opts, abs(done.frame.frame - done.before.frame))
        jump = not (step[0] <= lim[0] and step[1] <= lim[1])
        if jump:
            new.message = join_message(new.message, _jump_note(step, done.before.frame, lim))
    row = _row(done.frame, new, "warm", jump, step, int(old["n_eval"]) + n_eval)
    row.update({k: old[k] for k in ("follow_initial", "follow_initial_dchi2", "follow_pole")},
               follow_recheck=1)
    return row


def _jump_note(step: tuple[float, float], frame: int, lim: tuple[float, float]) -> str:
    return (f"jump of {step[0]:.3g} um and {math.degrees(step[1]):.3g} deg from frame {frame} "
            f"(limits {lim[0]:.3g} um, {math.degrees(lim[1]):.3g} deg)")


def _follow(fitter: ChunkFitter, f: ChunkFrame, acc: Followed | None, chi2_bar: float | None
            ) -> tuple[Followed | None, dict[str, Any], FitResult | None]:
    """:func:`_follow_frame`, an exception making the frame an ``error`` row (the track goes
    on from the last accepted fit); the fit kept (None for an ``error`` row)."""
    try:
        row, acc, res = _follow_frame(fitter, f, acc, chi2_bar)
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
    where = traceback.extract_tb(exc.__traceback__)[-1]
    return {"frame": f.frame, "time_s": f.time_s, "status": ERROR,
            "message": f"{type(exc).__name__}: {exc} "
                       f"(at {Path(where.filename).name}:{where.lineno})"}


def _follow_frame(fitter: ChunkFitter, f: ChunkFrame, acc: Followed | None,
                  chi2_bar: float | None) -> tuple[dict[str, Any], Followed | None, FitResult]:
    """One frame: warm fit, checks, re-acquisition; the row and the track's new state."""
    model, opts = fitter.model, fitter.opts
    nan2 = (math.nan, math.nan)
    if acc is None or not opts.warm:  # a chunk's first frame: the library's starts
        lib, runner, pole = probe_near_pole(fitter, f, library_fit(fitter, f, chi2_bar), None)
        res, runner, check = check_against_initial(fitter, f, lib, runner)
        if check.code == 2:
            note_changed(fitter, res, lib, check, "library")
        good = under_bar(res, chi2_bar)
        flag_above_bar(res, chi2_bar)
        new = (Followed.start(f.frame, res, runner, model) if good or res.status == OK
               else None)
        return (_row(f, res, "library", False, nan2, lib.n_eval + check.n_eval, check, pole),
                new, res)
    warm = fitter.warm(f, acc)
    first, carried, pole = probe_near_pole(fitter, f, warm.result, warm.carried, acc)
    n_warm = first.n_eval
    res, runner, check = check_against_initial(fitter, f, first, carried)
    step = step_of(acc, state_of(res.values, model), model)
    lim = step_limits(acc, opts, abs(f.frame - acc.frame))
    smooth = step[0] <= lim[0] and step[1] <= lim[1]
    if check.code != 2 and under_bar(res, chi2_bar) and smooth:
        return (_row(f, res, "warm", False, step, n_warm + check.n_eval, check, pole),
                acc.after(f.frame, res, runner, model, opts.history), res)
    # re-acquisition: the frame as an independent one; the better fit kept. A warm fit under
    # the bar that stepped too far needs the library's other starts, not other heights
    lib = library_fit(fitter, f, chi2_bar, retry=not under_bar(res, chi2_bar))
    again, again_runner, again_pole = probe_near_pole(fitter, f, lib, None, acc)
    n_eval = n_warm + check.n_eval + again.n_eval
    if not res.chi2 <= again.chi2:
        res, runner, pole = again, again_runner, again_pole
    if check.code == 2:
        note_changed(fitter, res, first, check, "warm")
    step = step_of(acc, state_of(res.values, model), model)
    smooth = step[0] <= lim[0] and step[1] <= lim[1]
    good = under_bar(res, chi2_bar)
    flag_above_bar(res, chi2_bar)
    if good and not smooth:
        res.message = join_message(res.message, _jump_note(step, acc.frame, lim))
    new = acc.after(f.frame, res, runner, model, opts.history) if good else acc
    return _row(f, res, "reacquired", not smooth, step, n_eval, check, pole), new, res
