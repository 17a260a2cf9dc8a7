"""Tests of a trajectory against the Brownian motion its analysis assumes.

Each test turns the drift-removed steps between consecutive frames with a fit into one
statistic whose distribution is known if the particle diffuses freely with a constant drift
(sedimentation, which the analysis removes) and white localisation noise, and returns its
p-value with the numbers that explain a failure. All p-values are two-sided where a departure
either way is not Brownian.

* :func:`diffusivity_change` (sticking, a changing environment): the cumulative sum of the
  squared steps' deviations from their mean, ``S_k``; its range ``V = (max S - min S) /
  (sigma sqrt(n))`` is Kuiper-distributed for a constant diffusivity (the range of a Brownian
  bridge; Inclan & Tiao, JASA 89, 913, 1994, use its maximum for variance changes; the range
  detects a stretch that starts and ends inside the run, as sticking does). ``sigma^2`` is the
  long-run variance of the squared steps: their sample variance plus twice the lag-1
  covariance that the localisation noise gives consecutive steps, ``2 d eps^4``. The stretch
  between the extremes of ``S`` is reported with its diffusivity relative to the rest.
* :func:`drift_change` (a flow that changes, directed transport for a while): each coordinate
  after the end-to-end drift removal, pinned at both ends, is a Brownian bridge; its largest
  excursion over ``sigma sqrt(M)`` is Kolmogorov-distributed (``sigma^2`` the steps' mean
  square).
* :func:`body_frame_drift` (self-propulsion along the particle's axis): the sum of the steps'
  projections on the axis. A body-frame velocity along a turning axis is not removed with the
  lab-frame drift; under Brownian motion the sum has mean zero and the exact variance
  ``sum_j a_j^T C_j a_j`` (``a_j`` the axis of step ``j`` less the share that the drift removal
  takes, ``C_j`` the step's covariance), so ``z`` is standard normal.
* :func:`increment_kurtosis` (hopping, intermittent sticking, fit outliers): the excess
  kurtosis of the steps' components (along and across a rod's axis; x and y for a sphere),
  each scaled by its own spread. Its null distribution depends on the numbers of steps and
  components only: up to :data:`KURTOSIS_MC_STEPS` steps it is simulated (D'Agostino's
  approximation, ``scipy.stats.kurtosistest``, fails 2.2 times too often at p < 0.002 for 30
  frames), beyond with D'Agostino's test; the lag-1 correlation ``rho`` of steps with
  localisation noise widens the statistic's spread by ``sqrt(1 + 2 rho^4)``, which the
  deviation is divided by.
* :func:`msd_shape` (confinement, swimming, anomalous diffusion): the generalised chi-square
  of the bridged straight line ``k (D tau (1 - tau/T) + eps^2)`` fitted over lags up to a tenth
  of the run, with the MSDs' analytic covariance (:mod:`holofit.analysis.linefit`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from numpy.typing import NDArray
from scipy import stats

from holofit.analysis.linefit import fit_lag_statistics, linear_msd_model
from holofit.analysis.msd import LagStatistics, Observables

__all__ = [
    "TestResult",
    "body_frame_drift",
    "consecutive_steps",
    "diffusivity_change",
    "drift_change",
    "increment_kurtosis",
    "kuiper_sf",
    "msd_shape",
]

#: fewest steps a test needs (fewer: p = NaN, the test is skipped)
MIN_STEPS = 10
#: the shape test fits lags up to this fraction of the run (at least MIN_SHAPE_LAGS lags) ...
SHAPE_FRACTION = 0.1
MIN_SHAPE_LAGS = 5
#: ... and at most this many of the computed lags
MAX_SHAPE_LAGS = 100
#: up to this many steps the kurtosis test's null distribution is simulated ...
KURTOSIS_MC_STEPS = 400
#: ... with this many samples
KURTOSIS_MC_SIMS = 10_000


@dataclass(frozen=True)
class TestResult:
    """One test of a track: its statistic, p-value and the numbers behind it.

    Attributes
    ----------
    name : str
        Short name (``diffusivity change``, ``size D_t``, ...).
    statistic : float
        The test statistic (``V``, ``K``, ``z``, ``chi^2``: see ``detail``).
    p_value : float
        Probability of a statistic at least this extreme for a track that obeys the model
        (NaN: not computed, e.g. too few steps).
    detail : str
        One line with the numbers, for messages and the summary table.
    values : dict
        The numbers by name (frames, ratios, errors).
    sizes : str
        A size test's hydrodynamic and optical sizes in words ('' for the other tests).
    """

    name: str
    statistic: float
    p_value: float
    detail: str
    values: dict[str, float] = field(default_factory=dict)
    sizes: str = ""


def _skipped(name: str, why: str) -> TestResult:
    return TestResult(name, math.nan, math.nan, f"not tested: {why}")


def kuiper_sf(v: float) -> float:
    """``P(V > v)`` for the range of a standard Brownian bridge (Kuiper's distribution)."""
    if not math.isfinite(v):
        return math.nan
    if v < 0.4:
        return 1.0
    k = np.arange(1, 101)
    terms = 2.0 * (4.0 * k**2 * v**2 - 1.0) * np.exp(-2.0 * k**2 * v**2)
    return float(min(max(np.sum(terms), 0.0), 1.0))


def consecutive_steps(position_um: NDArray[np.float64], valid: NDArray[np.bool_]
                      ) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Steps ``r(t + 1) - r(t)`` between consecutive valid frames, and their start frames."""
    ok = valid[1:] & valid[:-1]
    t = np.flatnonzero(ok)
    return position_um[t + 1] - position_um[t], t


def diffusivity_change(steps: NDArray[np.float64], start: NDArray[np.int64], noise_var: float,
                       name: str = "diffusivity change") -> TestResult:
    """Kuiper range test of the squared steps (module docstring).

    Parameters
    ----------
    steps : ndarray, shape (n, d)
        Drift-removed steps between consecutive frames (um, or unit-axis components).
    start : ndarray of int, shape (n,)
        Their start frames (slots of the trajectory).
    noise_var : float
        Localisation noise variance per coordinate (um^2), for the steps' lag-1 covariance.
    """
    n, d = steps.shape
    if n < MIN_STEPS:
        return _skipped(name, f"{n} steps")
    y = np.einsum("ij,ij->i", steps, steps)
    mean = float(y.mean())
    g0 = float(np.var(y))
    lr = g0 + 2.0 * (2.0 * d * max(noise_var, 0.0) ** 2)
    if not lr > 0:
        return _skipped(name, "the steps do not vary")
    s = np.concatenate([[0.0], np.cumsum(y - mean)])
    i_hi, i_lo = int(np.argmax(s)), int(np.argmin(s))
    v = float((s[i_hi] - s[i_lo]) / math.sqrt(lr * n))
    lo, hi = sorted((i_hi, i_lo))
    inside = np.zeros(n, bool)
    inside[lo:hi] = True
    floor = 2.0 * d * max(noise_var, 0.0)
    m_in = float(y[inside].mean()) if inside.any() else math.nan
    m_out = float(y[~inside].mean()) if (~inside).any() else math.nan
    ratio = (m_in - floor) / (m_out - floor) if m_out - floor > 0 else math.nan
    first, last = int(start[lo]), int(start[hi - 1]) + 1 if hi > lo else int(start[lo])
    p = kuiper_sf(v)
    detail = (f"V = {v:.2f} (p = {p:.2g}): slots {first}-{last} ({hi - lo} of {n} steps) "
              f"diffuse {max(ratio, 0.0):.2f} x as fast as the rest (mean squared step "
              f"{m_in:.3g} vs {m_out:.3g})")
    return TestResult(name, v, p, detail, {"first_slot": first, "last_slot": last,
                                           "steps_inside": float(hi - lo),
                                           "diffusivity_ratio": ratio})


def drift_change(position_um: NDArray[np.float64], valid: NDArray[np.bool_],
                 name: str = "drift change") -> TestResult:
    """Kolmogorov test of each drift-removed coordinate as a Brownian bridge (module
    docstring); the smallest p-value over the coordinates, Sidak-combined.

    ``sigma^2`` is the steps' own mean square. Scaled by the run's own steps, the statistic's
    tail is at or below Kolmogorov's (the scaled path does not depend on the steps' overall
    size); the localisation noise's share ``2 eps^2`` of each step, which cancels in their sums,
    is left in, which keeps the test valid (conservative) for noisy runs: subtracting a short
    run's noisy estimate of it made 30-frame runs with 35 nm of noise fail 8 % of the time at
    p < 1 %.
    """
    idx = np.flatnonzero(valid)
    if idx.size < MIN_STEPS + 1:
        return _skipped(name, f"{idx.size} frames")
    a, b = int(idx[0]), int(idx[-1])
    steps, _ = consecutive_steps(position_um, valid)
    if steps.shape[0] < MIN_STEPS:
        return _skipped(name, f"{steps.shape[0]} steps")
    x = position_um[idx]
    frac = ((idx - a) / (b - a))[:, None]
    bridge = x - x[0] - frac * (x[-1] - x[0])
    lr = np.mean(steps**2, axis=0)
    k = np.max(np.abs(bridge), axis=0) / np.sqrt(lr * (b - a))
    p_each = stats.kstwobign.sf(k)
    worst = int(np.argmin(p_each))
    p = float(1.0 - (1.0 - p_each[worst]) ** k.size)
    at = int(idx[int(np.argmax(np.abs(bridge[:, worst])))])
    axis_name = "xyz"[worst]
    detail = (f"K = {k[worst]:.2f} on {axis_name} (p = {p:.2g}, {k.size} coordinates): the "
              f"drift-removed path strays {bridge[:, worst][idx == at][0] * 1e3:+.0f} nm from "
              f"its end-to-end line at slot {at}")
    return TestResult(name, float(k[worst]), p, detail,
                      {"coordinate": float(worst), "slot": float(at),
                       "excursion_um": float(np.max(np.abs(bridge[:, worst])))})


def body_frame_drift(
    position_um: NDArray[np.float64], direction: NDArray[np.float64], valid: NDArray[np.bool_],
    frame_interval_s: float, d_par: float, d_perp: float, noise_var: float,
    name: str = "body-frame drift",
) -> TestResult:
    """The axis-projected steps' sum against its exact Brownian variance (module docstring).

    Parameters
    ----------
    position_um : ndarray, shape (N, d)
        Drift-removed positions (the drift from the first and last valid frame).
    direction : ndarray, shape (N, d)
        The axis (unit; its sign kept consistent along the track) per frame.
    d_par, d_perp : float
        Diffusion coefficients along and across the axis, um^2/s.
    noise_var : float
        Localisation noise variance per coordinate, um^2.
    """
    steps, t = consecutive_steps(position_um, valid)
    idx = np.flatnonzero(valid)
    if t.size < MIN_STEPS:
        return _skipped(name, f"{t.size} steps")
    a, b = int(idx[0]), int(idx[-1])
    m = b - a
    u = direction[t]
    y = np.einsum("ij,ij->i", steps, u)
    total = float(y.sum())
    # a_j: the axis of each step used, less the share every step of the span has in the sum
    # through the drift estimate; steps in gaps take the share only
    share = u.sum(axis=0) / m
    coef = np.tile(-share, (m, 1))
    coef[t - a] += u
    ok = valid & np.all(np.isfinite(direction), axis=1)
    known = np.flatnonzero(ok)
    step_axis = np.stack([np.interp(np.arange(a, b), known, direction[known, c])
                          for c in range(direction.shape[1])], axis=1)
    step_axis /= np.maximum(np.linalg.norm(step_axis, axis=1, keepdims=True), 1e-12)
    along = np.einsum("ij,ij->i", coef, step_axis)
    var_steps = 2.0 * frame_interval_s * (
        d_perp * np.einsum("ij,ij->i", coef, coef) + (d_par - d_perp) * along**2)
    du = np.diff(direction[idx], axis=0)
    ends = direction[idx[0]] - share, direction[idx[-1]] - share
    var_noise = max(noise_var, 0.0) * (float(np.sum(du**2)) + float(ends[0] @ ends[0])
                                       + float(ends[1] @ ends[1]))
    var = float(var_steps.sum()) + var_noise
    if not var > 0:
        return _skipped(name, "no variance")
    z = total / math.sqrt(var)
    p = float(2.0 * stats.norm.sf(abs(z)))
    span_s = m * frame_interval_s
    v = total / span_s
    detail = (f"z = {z:+.2f} (p = {p:.2g}): mean velocity along the axis {v * 1e3:+.0f} "
              f"+- {math.sqrt(var) / span_s * 1e3:.0f} nm/s after the lab-frame drift removal")
    return TestResult(name, z, p, detail, {"velocity_um_s": v,
                                           "velocity_err_um_s": math.sqrt(var) / span_s})


@lru_cache(maxsize=64)
def _kurtosis_null(n: int, c: int) -> NDArray[np.float64]:
    """Sorted excess kurtoses of :data:`KURTOSIS_MC_SIMS` samples of ``n`` Gaussian steps of
    ``c`` components, standardised and pooled as :func:`increment_kurtosis` does (seeded)."""
    rng = np.random.default_rng(20_240_000 + 1000 * c + n)
    out = np.empty(KURTOSIS_MC_SIMS)
    chunk = max(1, 2_000_000 // (n * c))
    for i in range(0, KURTOSIS_MC_SIMS, chunk):
        m = min(chunk, KURTOSIS_MC_SIMS - i)
        x = rng.standard_normal((m, n, c), dtype=np.float32)
        x -= x.mean(axis=1, keepdims=True)
        x2 = x * x
        var = x2.mean(axis=1)
        out[i:i + m] = np.mean(np.mean(x2 * x2, axis=1) / (var * var), axis=1) - 3.0
    out.sort()
    return out


def increment_kurtosis(components: NDArray[np.float64], name: str = "increment kurtosis"
                       ) -> TestResult:
    """D'Agostino's kurtosis test of the pooled, per-component standardised steps.

    Parameters
    ----------
    components : ndarray, shape (n, c)
        The steps' components (each Gaussian with its own variance under the model).
    """
    n, c = components.shape
    if n < MIN_STEPS or n * c < 20:
        return _skipped(name, f"{n} steps")
    x = components - components.mean(axis=0)
    sd = x.std(axis=0)
    if not np.all(sd > 0):
        return _skipped(name, "a component does not vary")
    z_all = (x / sd).ravel()
    excess = float(np.mean(z_all**4) - 3.0)
    rho = float(np.mean(np.sum(x[1:] * x[:-1], axis=0) / (n * sd**2))) if n > 1 else 0.0
    rho = min(max(rho, -0.5), 0.5)
    widen = math.sqrt(1.0 + 2.0 * rho**4)
    if n <= KURTOSIS_MC_STEPS:
        # the simulated null of the nearest shorter run on a 10 % grid (one simulation serves
        # many lengths; a shorter run's null is a little wider: the test stays valid)
        grid = int(MIN_STEPS * 1.1 ** math.floor(math.log(n / MIN_STEPS, 1.1) + 1e-9))
        null = _kurtosis_null(max(MIN_STEPS, min(grid, n)), c)
        mid = float(np.median(null))
        k = mid + (excess - mid) / widen
        below = np.searchsorted(null, k, side="right") / null.size
        above = 1.0 - np.searchsorted(null, k, side="left") / null.size
        p = float(min(1.0, 2.0 * max(min(below, above), 0.5 / null.size)))
        z = float(stats.norm.isf(p / 2.0)) * (1.0 if k >= mid else -1.0)
    else:
        zk, _ = stats.kurtosistest(z_all)
        z = float(zk) / widen
        p = float(2.0 * stats.norm.sf(abs(z)))
    detail = (f"excess kurtosis {excess:+.2f} of {n} steps x {c} components (z = {z:+.2f}, "
              f"p = {p:.2g}; 0 for Gaussian steps)")
    return TestResult(name, z, p, detail, {"excess_kurtosis": excess, "lag1_correlation": rho})


def msd_shape(stats_: LagStatistics, components: int, obs: Observables, first_lag_fit: int,
              last_lag_fit: int, duration_s: float | None, name: str = "MSD shape"
              ) -> TestResult:
    """Generalised chi-square of the bridged straight line over the extended lags.

    Parameters
    ----------
    stats_ : LagStatistics
        A lab-frame translational MSD (``xy``: 2 components, ``lab_3d``: 3) at every lag
        computed.
    components : int
        Coordinates in it.
    obs : Observables
        The pairs (for the covariance's masks).
    first_lag_fit, last_lag_fit : int
        The diffusion fit's range (the shape test reaches at least one lag beyond it).
    duration_s : float, optional
        The span of the drift removal (None: no drift removed).
    """
    n = obs.valid.size
    top = max(MIN_SHAPE_LAGS, last_lag_fit + 2, int(SHAPE_FRACTION * n))
    lags = stats_.lags[(stats_.lags >= first_lag_fit) & (stats_.lags <= top)
                       & np.isfinite(stats_.mean) & (stats_.count >= 2)]
    lags = lags[:MAX_SHAPE_LAGS]
    if lags.size < 4:
        return _skipped(name, f"{lags.size} lags")
    model = linear_msd_model(2 * components, stats_.name, duration_s)
    try:
        f = fit_lag_statistics(stats_.at(lags), model, obs)
    except ValueError as exc:
        return _skipped(name, str(exc))
    dof = lags.size - 2
    chi2 = f.chi2_reduced * dof
    p_hi = float(stats.chi2.sf(chi2, dof))
    p = min(1.0, 2.0 * min(p_hi, 1.0 - p_hi))
    curvature = float(f.data[-1] / f.curve(f.tau_s[-1:])[0] - 1.0)
    detail = (f"chi^2 {chi2:.1f} on {dof} dof (p = {p:.2g}) for the straight line over lags "
              f"{int(lags[0])}-{int(lags[-1])}; the MSD at lag {int(lags[-1])} is "
              f"{100 * curvature:+.0f} % off the line")
    return TestResult(name, chi2, p, detail, {"chi2": chi2, "dof": float(dof),
                                              "last_lag": float(lags[-1]),
                                              "end_deviation": curvature})
