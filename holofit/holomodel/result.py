"""One result type for every hologram fit (prefit and DDA fit), how good it is, and the table row
it becomes.

Goodness of fit, the same words everywhere:

- ``chi2``: mean squared residual per pixel (normalised intensity^2), the paper's "per-pixel
  chi^2";
- ``chi2_red``: residual sum of squares over ``noise_sd^2 (N - p)``, with ``noise_sd`` the
  pixel noise (given, or estimated from the crop itself): about 1 for a model that explains
  the data down to the camera noise;
- ``r2``: the coefficient of determination (the paper's R^2).

Status (:mod:`holofit.status`): a converged fit is ``ok`` only if it is also close to the data
and physical (:func:`holofit.quality.judge_fit`); otherwise it is ``poor_fit``, with the reason in
``message``. ``holofit analyze`` uses ``ok`` rows only.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from holofit.conventions import r_squared
from holofit.holomodel.leastsq import Solution
from holofit.holomodel.parameters import APERTURE, ParameterSpace
from holofit.holomodel.statistics import covariance_from_jacobian
from holofit.quality import Goodness, QualityLimits, judge_fit
from holofit.status import FAILED, NOT_CONVERGED, OK

__all__ = [
    "APERTURE_CHI2",
    "GOODNESS_COLUMNS",
    "FitResult",
    "aperture_spread",
    "fit_result",
    "result_columns",
    "result_row",
]

#: a scanned NA whose misfit is within this many units of chi^2 (s^2) of the best one is
#: not told apart from it. The misfit in NA has some 30 local minima between 0.6 and 1.33, and
#: noise alone makes the best of ~30 look better than the true one by up to ~10 (the 95 %
#: point of the largest of 30 chi^2 variables of one degree of freedom)
APERTURE_CHI2 = 10.0
#: columns every fit table has after the parameters (their units: holofit.tables.fit)
GOODNESS_COLUMNS = ("chi2", "chi2_red", "noise_sd", "r2", "n_pixels", "n_eval", "fit_time_s")


@dataclass
class FitResult:
    """A fitted hologram.

    Attributes
    ----------
    values, errors : dict
        Every reported quantity (position, orientation ``theta_rad, psi_rad[, phi_rad]`` and
        axis ``ux, uy, uz``, alpha, static parameters) and its 1-sigma error (NaN if held
        fixed).
    free : tuple of str
        The optimiser's parameters.
    rss, chi2, chi2_red, noise_sd, r2 : float
        Goodness of fit (module docstring).
    n_pixels, n_eval, n_solves : int
        Pixels fitted; holograms computed (Jacobian columns included); scattering solves.
    status, message : str
        ``ok``, ``poor_fit`` or ``not_converged``/``failed``, and why.
    time_s : float
        Wall time of the fit.
    extra : dict
        Stage-specific columns (start values, runner-up, ...).
    model : ndarray or None
        The model hologram on the fitted pixels (for pictures; not written to tables).
    """

    values: dict[str, float]
    errors: dict[str, float]
    free: tuple[str, ...]
    rss: float
    chi2: float
    chi2_red: float
    noise_sd: float
    r2: float
    n_pixels: int
    n_eval: int
    n_solves: int
    status: str
    message: str
    time_s: float = 0.0
    extra: dict[str, Any] = field(default_factory=dict)
    model: NDArray[np.float64] | None = None

    @property
    def ok(self) -> bool:
        return self.status == OK


def fit_result(
    space: ParameterSpace,
    solution: Solution,
    data: NDArray[np.float64],
    noise_sd: float,
    limits: QualityLimits | None = None,
    n_solves: int = 0,
) -> FitResult:
    """Turn an optimiser solution into a :class:`FitResult` with its status.

    Uncertainties are ``s^2 (J^T J)^-1`` with ``s^2 = rss / (N - p)`` (as in the paper and
    ``scipy.optimize.curve_fit``), propagated to the reported angles. A fitted numerical
    aperture's misfit is rugged (local minima a few hundredths apart, often of nearly equal
    depth), so its local curvature understates how well the data fix it: its error is at least
    the half-width of the NAs of the fit's scan whose misfit is within
    :data:`APERTURE_CHI2` units of chi^2 of the scan's best (:func:`aperture_spread`).
    """
    limits = limits or QualityLimits()
    n = int(data.size)
    p = int(solution.vector.size)
    cov = covariance_from_jacobian(solution.jacobian, solution.rss, n)
    values, errors = space.report(solution.vector, cov)
    dof = max(n - p, 1)
    if solution.aperture_scan is not None and APERTURE.name in errors:
        spread = aperture_spread(*solution.aperture_scan, APERTURE_CHI2 * solution.rss / dof)
        local = errors[APERTURE.name]
        errors[APERTURE.name] = spread if not local >= spread else local
    model = data + solution.residuals
    chi2_red = solution.rss / (noise_sd**2 * dof) if noise_sd > 0 else math.nan
    r2 = float(r_squared(data, model))
    flat = float(np.sum((data - np.mean(data)) ** 2)) if n else 0.0
    signal = (flat - solution.rss) / noise_sd**2 if noise_sd > 0 else math.nan
    status, message = _assess(space, solution, values, Goodness(chi2_red, r2, signal, p),
                              limits)
    return FitResult(
        values=values, errors=errors, free=space.names, rss=solution.rss,
        chi2=solution.rss / n, chi2_red=float(chi2_red), noise_sd=float(noise_sd), r2=r2,
        n_pixels=n, n_eval=solution.n_eval, n_solves=n_solves, status=status, message=message,
        model=model,
    )


def aperture_spread(grid: NDArray[np.float64], rss: NDArray[np.float64],
                    variance: float) -> float:
    """Half-width of the NAs of a scan whose misfit is within ``variance`` of its best.

    Parameters
    ----------
    grid, rss : ndarray
        The NAs scanned and their residual sums of squares.
    variance : float
        How far above the best misfit an NA is still as good (``APERTURE_CHI2 s^2``).

    Returns
    -------
    float
        ``(max - min) / 2`` of the NAs with ``rss <= min(rss) + variance`` (NaN if none).
    """
    ok = np.isfinite(rss)
    if not ok.any() or not math.isfinite(variance):
        return math.nan
    near = grid[ok][rss[ok] <= rss[ok].min() + variance]
    return float(0.5 * (near.max() - near.min()))


def _assess(space: ParameterSpace, solution: Solution, values: dict[str, float],
            goodness: Goodness, limits: QualityLimits) -> tuple[str, str]:
    if not np.all(np.isfinite(solution.vector)) or not math.isfinite(solution.rss):
        return FAILED, "the fit diverged (non-finite parameters or residuals)"
    if not solution.converged:
        return NOT_CONVERGED, solution.message
    return judge_fit(space.out_of_range(space.state(solution.vector)), values, space.names,
                     goodness, limits)


def result_columns(value_columns: Iterable[str], error_columns: Iterable[str],
                   extra_columns: Iterable[str] = ()) -> tuple[str, ...]:
    """Column order of a fit table: frame, time, values, errors, goodness, extras, status."""
    return ("frame", "time_s", *value_columns, *(f"d_{c}" for c in error_columns),
            *GOODNESS_COLUMNS, *extra_columns, "status", "message")


def result_row(frame: int, time_s: float, result: FitResult) -> dict[str, Any]:
    """The table row of a fit (fit-table schema, :mod:`holofit.tables.fit`)."""
    row: dict[str, Any] = {"frame": int(frame), "time_s": float(time_s)}
    row.update(result.values)
    row.update({f"d_{k}": v for k, v in result.errors.items()})
    row.update(chi2=result.chi2, chi2_red=result.chi2_red, noise_sd=result.noise_sd,
               r2=result.r2, n_pixels=result.n_pixels, n_eval=result.n_eval,
               fit_time_s=result.time_s, status=result.status, message=result.message)
    row.update(result.extra)
    return row
