"""How a frame is fitted (:class:`FrameFitSettings`) and how a track is followed from frame to
frame (:class:`FollowSettings`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from holofit.quality import QualityLimits

__all__ = ["REOPEN_DZ_UM", "FollowSettings", "FrameFitSettings"]

#: the heights (um, off the prefit's) a library fit far from the data is tried from again, in
#: turn: near focus a prefit may take the twin height on the other side of the focal plane
REOPEN_DZ_UM = (-1.5, 1.5, -3.0, 3.0, -4.5, 4.5)


@dataclass(frozen=True)
class FrameFitSettings:
    """How a frame is fitted (:mod:`holofit.fit.frame`, :mod:`holofit.fit.warm`).

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
        The fits from a known state (:func:`holofit.fit.warm.fit_frame_warm`) also stop where
        the Gauss-Newton step predicts a chi^2 decrease of at most this (units of the pixel
        noise; :func:`holofit.holomodel.leastsq.solve_least_squares`'s ``stop_rss``): the fit
        is then that close to its minimum, and MINPACK's confirming iteration is saved. 0:
        MINPACK's tests alone.
    stop_chi2 : float
        The same stopping rule for every fit on all pixels, a library start's too (the larger
        of the two applies to warm fits); 0: none. The initial pass sets it
        (:data:`holofit.fit.passes.INITIAL_STOP_CHI2`): there one frame's static parameters
        scatter from the movie's median by far more than a chi^2 unit means.
    quality : QualityLimits
        When a converged fit is still not ``ok`` (:func:`holofit.quality.judge_fit`).
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


@dataclass(frozen=True)
class FollowSettings:
    """How a track is followed from frame to frame (:mod:`holofit.fit.follow`; the steps
    named below are that module's).

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
        Move the start by the recent velocity (the mean displacement per frame over the last
        ``history`` steps: a drift such as sinking), once ``min_history`` are known.
    refit_margin_chi2 : float
        The runner-up is fitted on all pixels when its screening is within
        ``ambiguity_chi2 + refit_margin_chi2`` of the best
        (:func:`holofit.fit.warm.fit_frame_warm`).
    initial_margin_chi2 : float
        A frame's fit is refitted from its initial-pass row's pose where that pose's chi^2
        (one evaluation, this pass's statics) is lower by more than this (step 6): a competing
        minimum lower by less is not distinguishable at the noise level.
    warm : bool
        False: every frame is an independent library fit (``--independent-frames``).
    initial : bool
        The fit stage's initial pass (sizes free) follows the track too (with ``warm``).
    pole_rad : float
        A fit whose axis is this close to the optical axis (either pole) is probed (step 7)
        and rechecked (step 9); 0: never. Near the pole the misfit has minima that hold a
        warm start.
    pole_probes : int
        Probes of such a fit (0: none), the first two along the meridian.
    pole_probe_rad : float
        How far each probe's axis is tilted from the warm fit's.
    pole_min_gain_chi2 : float
        A probe replaces the warm fit where its minimum is lower by more than this (chi^2
        units of the pixel noise).
    pole_probe_nfev : int
        Most holograms of one probe's fit (it stops within
        :data:`holofit.fit.rescue.PROBE_STOP_CHI2` of its minimum).
    pole_probe_symmetric : bool
        Probe and recheck head-tail symmetric particles (rods) too.
    recheck_rad : float
        A warm frame near the optical axis is refitted from its neighbours' side where the
        next accepted frame's axis is farther than this from its own (step 9); 0: never.
    reopen_dz_um : tuple of float
        A library fit (a chunk's opening, a re-acquisition) that is not ``ok`` under the bar
        is tried again from these heights off the prefit's, in turn, until one is (step 8);
        empty: never.
    open_at_best : bool
        A chunk opens with the library fit of its frame whose best library candidate has the
        highest R^2 (not of its first frame), and reaches the frames before it backward in
        time: a library fit from a poor prefit height settles far off, and carries its
        chunk with it. False: the first frame opens.
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
            raise ValueError("follow: recheck_rad >= 0 needed")
        if not (self.step_factor > 0 and self.history >= self.min_history >= 1
                and self.refit_margin_chi2 >= 0 and self.initial_margin_chi2 >= 0):
            raise ValueError("follow: step_factor > 0, history >= min_history >= 1, "
                             "refit_margin_chi2 >= 0 and initial_margin_chi2 >= 0 needed")
        if not (0 <= self.pole_rad < math.pi / 2 and self.pole_probes >= 0
                and 0 < self.pole_probe_rad < math.pi / 2 and self.pole_min_gain_chi2 >= 0
                and self.pole_probe_nfev >= 1):
            raise ValueError("follow: 0 <= pole_rad < pi/2, pole_probes >= 0, "
                             "0 < pole_probe_rad < pi/2, pole_min_gain_chi2 >= 0 and "
                             "pole_probe_nfev >= 1 needed")
