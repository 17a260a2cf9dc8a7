"""What following a track is made of: its frames (:class:`ChunkFrame`), its state after the
last accepted fit (:class:`Followed`), and the fits a chunk runs (:class:`ChunkFitter`).

The loop that uses them is :mod:`holofit.fit.follow`; the rescue steps of a wrong minimum are
:mod:`holofit.fit.rescue`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from holofit.fit.frame import fit_frame
from holofit.fit.problem import FrameProblem, state_of
from holofit.fit.settings import FollowSettings
from holofit.fit.warm import CarriedRunnerUp, WarmFit, fit_frame_warm
from holofit.holomodel.parameters import State
from holofit.holomodel.result import FitResult
from holofit.library.search import Candidate
from holofit.optics import Optics
from holofit.particles import ParticleModel
from holofit.scattering.theory import ScatteringEngine

__all__ = [
    "ChunkFitter",
    "ChunkFrame",
    "Followed",
    "axis_step",
    "step_limits",
    "step_of",
]


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
        The prefit's ``(x, y, z)``, um (a library fit's start).
    alpha : float
        The prefit's alpha.
    candidates : tuple of Candidate
        The library's orientations for this frame, best first.
    time_s : float
        Time of the frame, s (NaN: unknown).
    initial : dict, optional
        The initial pass's fit of this frame (a converged row's
        :data:`holofit.fit.rescue.INITIAL_POSE` values), the independent check of
        :func:`holofit.fit.rescue.check_against_initial`; None: the initial pass did not fit
        this frame.
    """

    frame: int
    crop: NDArray
    corner: tuple[int, int]
    position_um: tuple[float, float, float]
    alpha: float
    candidates: tuple[Candidate, ...]
    time_s: float = math.nan
    initial: dict[str, float] | None = None


@dataclass
class Followed:
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

    def after(self, frame: int, result: FitResult, runner: CarriedRunnerUp | None,
              model: ParticleModel, history: int) -> Followed:
        """The track's state once ``result`` is accepted for ``frame``: its step (per
        ``sqrt(gap)``, diffusive) and move (per frame) joined to the last ``history``."""
        state = state_of(result.values, model)
        dist, ang = step_of(self, state, model)
        gap = max(abs(frame - self.frame), 1)  # a move per frame along the track's direction
        move = np.subtract(state.position, self.state.position) / gap
        return Followed(frame, state, runner,
                        [*self.steps_um, dist / math.sqrt(gap)][-history:],
                        [*self.steps_rad, ang / math.sqrt(gap)][-history:],
                        [*self.moves, move][-history:],
                        [*self.levels, result.chi2_red][-history:])

    @classmethod
    def start(cls, frame: int, result: FitResult, runner: CarriedRunnerUp | None,
              model: ParticleModel) -> Followed:
        """The state of a track whose first accepted fit is ``result`` (no history yet)."""
        return cls(frame, state_of(result.values, model), runner, [], [], [],
                   [result.chi2_red])


def axis_step(a: State, b: State, head_tail: bool) -> float:
    """The angle between two states' axes, rad (u and -u one axis where ``head_tail``)."""
    if a.rotation is None or b.rotation is None:
        return 0.0
    c = float(np.dot(a.rotation[:, 2], b.rotation[:, 2]))
    return math.acos(min(1.0, abs(c) if head_tail else max(-1.0, c)))


def step_of(acc: Followed, state: State, model: ParticleModel) -> tuple[float, float]:
    """A state's step from the track's last accepted one: position (um) and axis (rad)."""
    d = np.subtract(state.position, acc.state.position)
    return float(np.linalg.norm(d)), axis_step(acc.state, state, model.head_tail_symmetric)


def step_limits(acc: Followed, opts: FollowSettings, gap: int) -> tuple[float, float]:
    """Largest smooth position (um) and axis (rad) steps over ``gap`` frames: given, or
    ``step_factor`` times the median of the recent steps (floored), grown as ``sqrt(gap)``
    (a diffusive step)."""
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


@dataclass
class ChunkFitter:
    """What every fit of a chunk shares (engine, model, optics, pixel size, free parameters,
    settings), and the basic fits of one of its frames.

    Attributes
    ----------
    reopen_failures : int
        The chunk's frames in a row for which no other height worked
        (:func:`holofit.fit.rescue.library_fit`).
    """

    theory: ScatteringEngine
    model: ParticleModel
    optics: Optics
    pixel_size_um: float
    free: tuple[str, ...]
    opts: FollowSettings
    reopen_failures: int = 0

    def problem(self, f: ChunkFrame) -> FrameProblem:
        """Frame ``f``'s fitting problem with this chunk's settings."""
        return FrameProblem(f.crop, f.corner, self.pixel_size_um, self.theory, self.model,
                            self.optics, self.free, self.opts.frame, seed=f.frame)

    def library_at(self, f: ChunkFrame, dz: float) -> FitResult:
        """``f``'s library fit from the prefit's position, ``dz`` um higher."""
        x, y, z = f.position_um
        return fit_frame(self.problem(f), (x, y, z + dz), f.alpha, f.candidates)

    def warm(self, f: ChunkFrame, acc: Followed) -> WarmFit:
        """``f`` fitted from the track's last accepted fit, moved by the recent drift (next
        frame only), its runner-up carried."""
        gap = abs(f.frame - acc.frame)  # frames along the track, either way in time
        state = acc.state
        if self.opts.extrapolate and gap == 1:
            drift = acc.velocity(self.opts.min_history)
            state = replace(state, position=tuple(np.add(state.position, drift)))
        return self.refit(f, state, carried=acc.runner_up if gap == 1 else None)

    def refit(self, f: ChunkFrame, start: State, carried: CarriedRunnerUp | None = None
              ) -> WarmFit:
        """A full warm fit of ``f`` from ``start`` (``carried``: the previous frame's
        runner-up)."""
        return fit_frame_warm(self.problem(f), start, carried=carried,
                              refit_margin_chi2=self.opts.refit_margin_chi2)
