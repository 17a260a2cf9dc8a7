"""Cleaning orientation trajectories from frame-by-frame fits (the paper, section 3).

Frames are fitted independently, so two artefacts appear that a sequential tracker would not
make:

* **head-tail flips**: for a particle whose ``u`` and ``-u`` look alike (rod, dimer) the fit
  returns either; we choose, frame by frame, the sign closer to the previous kept frame
  (a real rotation by more than 90 degrees in one frame interval has probability ~0 at the
  diffusion coefficients of colloids);
* **improbable jumps** (a fit in a secondary minimum, e.g. ``u`` mirrored about the x-y
  plane): a jump is *improbable* when the tail probability of its angle (the probability of
  turning by that angle **or more**, :func:`~holofit.analysis.rotational_diffusion.angle_tail`)
  under isotropic rotational diffusion with ``D_est``, plus the measured angular noise, is below
  ``probability`` (1e-4 by default). Two rules use it:

  1. *frame rejection*: a short run (at most :data:`MAX_RUN` frames) whose axis jumps
     improbably away from the last good frame and back again is dropped (becomes a gap);
  2. *pair rejection* (the paper's rule): at every lag, the pairs of frames whose angle is
     improbable at that lag are left out of every average at that lag.

``D_est`` is estimated from the data unless given: the median of the squared turning angle at
lags of 1-5 frames (``median / ln 2`` is the mean for the small-angle Rayleigh law, and the
median ignores outliers), fitted by ``4 D tau + 2 eps_r^2``; the intercept gives the rms angular
noise ``eps_r`` per frame, which enters the threshold as ``D tau -> D tau + eps_r^2 / 2``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from holofit.analysis.errors import AnalysisError
from holofit.analysis.rotational_diffusion import angle_threshold

__all__ = [
    "MAX_RUN",
    "AngleThresholds",
    "OrientationCleaning",
    "RotationEstimate",
    "axis_angles",
    "clean_orientations",
    "correct_flips",
    "estimate_rotational_diffusion",
    "find_outlier_frames",
]

#: longest run of consecutive frames that frame rejection may drop as one excursion
MAX_RUN = 3
#: lags (frames) used to estimate D_est
ESTIMATE_LAGS = (1, 2, 3, 4, 5)
#: the estimate needs this many valid pairs at each of at least MIN_ESTIMATE_LAGS lags
MIN_ESTIMATE_PAIRS = 8
MIN_ESTIMATE_LAGS = 2


def axis_angles(u1: NDArray, u2: NDArray, head_tail: bool = False) -> NDArray[np.float64]:
    """Angle between unit vectors (rows), rad; for ``head_tail`` the angle between the lines."""
    dot = np.sum(u1 * u2, axis=-1)
    if head_tail:
        dot = np.abs(dot)
    return np.arccos(np.clip(dot, -1.0, 1.0))


@dataclass(frozen=True)
class RotationEstimate:
    """``D_est`` (1/s) and rms angular noise per frame ``eps_r`` (rad) used for the rejection."""

    d_est: float
    eps_r: float
    source: str


def estimate_rotational_diffusion(
    axis: NDArray, valid: NDArray, frame_interval_s: float, head_tail: bool
) -> RotationEstimate:
    """Robust estimate of the rotational diffusion coefficient and the angular noise.

    Raises
    ------
    AnalysisError
        Fewer than :data:`MIN_ESTIMATE_PAIRS` valid pairs at all but one of the lags
        :data:`ESTIMATE_LAGS`.
    """
    lags, msd, found = [], [], []
    for lag in ESTIMATE_LAGS:
        ok = valid[:-lag] & valid[lag:]
        found.append(f"lag {lag}: {int(ok.sum())}")
        if ok.sum() < MIN_ESTIMATE_PAIRS:
            continue
        th = axis_angles(axis[:-lag][ok], axis[lag:][ok], head_tail)
        lags.append(lag)
        msd.append(np.median(th**2) / math.log(2.0))
    if len(lags) < MIN_ESTIMATE_LAGS:
        raise AnalysisError(
            "too few valid frame pairs to estimate the rotational diffusion for the rejection of "
            f"improbable jumps: it needs at least {MIN_ESTIMATE_PAIRS} pairs at each of "
            f"{MIN_ESTIMATE_LAGS} of the lags 1-{ESTIMATE_LAGS[-1]} frames (found "
            f"{', '.join(found)}); give D_est (--d-est) or turn the rejection off (--no-reject)")
    tau = np.array(lags) * frame_interval_s
    slope, intercept = np.polyfit(tau, np.array(msd), 1)
    d_est = slope / 4.0
    if not d_est > 0:
        raise AnalysisError(
            "could not estimate D_est from the data (the turning angle does not grow with lag);"
            " give it explicitly"
        )
    return RotationEstimate(float(d_est), float(math.sqrt(max(intercept, 0.0) / 2.0)), "estimated")


@dataclass
class AngleThresholds:
    """Largest probable turning angle at each lag, cached.

    ``threshold(lag)`` solves ``P(Theta >= theta) = probability`` for
    ``D tau = d_est * lag * dt + eps_r**2 / 2``.
    """

    d_est: float
    eps_r: float
    frame_interval_s: float
    probability: float
    _cache: dict[int, float] = field(default_factory=dict, repr=False)

    def __call__(self, lag: int) -> float:
        lag = int(lag)
        if lag not in self._cache:
            x = self.d_est * lag * self.frame_interval_s + 0.5 * self.eps_r**2
            self._cache[lag] = angle_threshold(x, self.probability)
        return self._cache[lag]

    def many(self, lags: NDArray) -> NDArray[np.float64]:
        """Thresholds for an array of lags."""
        lags = np.asarray(lags, dtype=int)
        uniq, inv = np.unique(lags, return_inverse=True)
        return np.array([self(int(k)) for k in uniq])[inv]


def find_outlier_frames(
    axis: NDArray,
    valid: NDArray,
    thresholds: AngleThresholds,
    head_tail: bool,
    max_run: int = MAX_RUN,
) -> NDArray[np.bool_]:
    """Frames that jump improbably away from the trajectory and come back (frame rejection).

    Walks the valid frames in order with a reference (the last good frame). A frame whose angle
    from the reference is improbable starts an excursion; if a frame within ``max_run`` frames
    is probable again from the reference, the excursion is dropped. If none is, the particle
    really moved (or ``D_est`` is too small) and the walk goes on from the new frame; a
    reference that had no accepted successor (an isolated first frame) is then dropped.
    """
    v = np.flatnonzero(valid)
    out = np.zeros(valid.size, bool)
    if v.size < 3:
        return out
    steps = axis_angles(axis[v[:-1]], axis[v[1:]], head_tail)
    step_ok = np.ones(v.size, bool)
    step_ok[1:] = steps <= thresholds.many(np.diff(v))

    def probable(i: int, j: int) -> bool:
        ang = axis_angles(axis[i], axis[j], head_tail)
        return bool(ang <= thresholds(j - i))

    ref, run_len = 0, 1  # indices into v
    j = 1
    while j < v.size:
        if ref == j - 1 and step_ok[j]:
            ref, run_len, j = j, run_len + 1, j + 1
            continue
        if probable(v[ref], v[j]):
            ref, run_len, j = j, run_len + 1, j + 1
            continue
        back = None
        for m in range(j + 1, min(j + 1 + max_run, v.size)):
            if probable(v[ref], v[m]):
                back = m
                break
        if back is not None:
            out[v[j:back]] = True
            ref, run_len, j = back, run_len + 1, back + 1
            continue
        if run_len == 1 and j + 1 < v.size and probable(v[j], v[j + 1]):
            out[v[ref]] = True
        ref, run_len, j = j, 1, j + 1
    return out


def correct_flips(axis: NDArray, valid: NDArray) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Choose the sign of ``u`` in each valid frame to agree with the previous valid frame.

    Returns
    -------
    axis : ndarray, shape (N, 3)
        Corrected axes (gaps stay NaN).
    flipped : ndarray of bool, shape (N,)
        Frames whose sign was changed relative to the input.
    """
    out = np.array(axis, dtype=float)
    v = np.flatnonzero(valid)
    flipped = np.zeros(valid.size, bool)
    if v.size < 2:
        return out, flipped
    dots = np.sum(out[v[1:]] * out[v[:-1]], axis=1)
    step_sign = np.where(dots < 0, -1.0, 1.0)
    sign = np.concatenate([[1.0], np.cumprod(step_sign)])
    out[v] *= sign[:, None]
    flipped[v] = sign < 0
    return out, flipped


@dataclass
class OrientationCleaning:
    """What cleaning did to an orientation trajectory."""

    axis: NDArray[np.float64]
    valid: NDArray[np.bool_]
    flipped: NDArray[np.bool_]
    outliers: NDArray[np.bool_]
    estimate: RotationEstimate | None
    thresholds: AngleThresholds | None

    def pair_mask(self, lag: int) -> NDArray[np.bool_] | None:
        """Pairs ``(t, t + lag)`` whose angle is probable at that lag (None: no rejection)."""
        if self.thresholds is None:
            return None
        a, b = self.axis[:-lag], self.axis[lag:]
        with np.errstate(invalid="ignore"):
            ang = axis_angles(a, b)
        return ~(ang > self.thresholds(lag))


def clean_orientations(
    axis: NDArray,
    valid: NDArray,
    frame_interval_s: float,
    *,
    head_tail: bool,
    reject: bool,
    probability: float = 1e-4,
    d_est: float | None = None,
    eps_r: float | None = None,
    estimate: RotationEstimate | None = None,
) -> OrientationCleaning:
    """Flip correction and improbable-jump rejection (see the module docstring).

    Parameters
    ----------
    axis : ndarray, shape (N, 3)
        Unit axes (NaN in gaps).
    valid : ndarray of bool
        Frames with a fit.
    frame_interval_s : float
        s.
    head_tail : bool
        ``u`` and ``-u`` are the same particle: correct flips, compare lines when rejecting.
    reject : bool
        Apply frame and pair rejection.
    probability : float
        Tail-probability threshold.
    d_est, eps_r : float, optional
        Override the estimated rotational diffusion coefficient (1/s) and angular noise (rad).
    estimate : RotationEstimate, optional
        A previous estimate to reuse (``d_est`` / ``eps_r`` still override it).
    """
    valid = np.asarray(valid, bool).copy()
    axis = np.asarray(axis, dtype=float)
    thresholds = None
    outliers = np.zeros(valid.size, bool)
    if reject:
        if estimate is None and (d_est is None or eps_r is None):
            estimate = estimate_rotational_diffusion(axis, valid, frame_interval_s, head_tail)
        base_d = estimate.d_est if estimate is not None else float("nan")
        base_e = estimate.eps_r if estimate is not None else 0.0
        given = d_est is not None or eps_r is not None
        estimate = RotationEstimate(
            float(d_est) if d_est is not None else base_d,
            float(eps_r) if eps_r is not None else base_e,
            "given" if given and d_est is not None else "estimated",
        )
        if not estimate.d_est > 0:
            raise ValueError(f"D_est must be positive, got {estimate.d_est}")
        thresholds = AngleThresholds(estimate.d_est, estimate.eps_r, frame_interval_s, probability)
        outliers = find_outlier_frames(axis, valid, thresholds, head_tail)
        valid &= ~outliers
    cleaned = axis.copy()
    cleaned[~valid] = np.nan
    flipped = np.zeros(valid.size, bool)
    if head_tail:
        cleaned, flipped = correct_flips(cleaned, valid)
    return OrientationCleaning(cleaned, valid, flipped, outliers, estimate, thresholds)
