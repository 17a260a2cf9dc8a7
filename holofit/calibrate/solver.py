"""Levenberg-Marquardt on the normal equations of a joint fit (:mod:`holofit.calibrate.joint`).

Rule: every iteration solves ``(A + lambda diag(d^2)) step = -g`` with ``A = J^T J`` and
``g = J^T r`` accumulated frame by frame (:meth:`holofit.calibrate.model.JointModel.normal`),
``d`` the largest column norms of ``J`` met so far (MINPACK's ``x_scale="jac"``); a step is kept
when it lowers the sum of squares, and ``lambda`` follows the ratio of the actual to the
predicted decrease (Nielsen's update, Madsen, Nielsen & Tingleff 2004, sec. 3.2).

Why not MINPACK (:func:`holofit.holomodel.leastsq.solve_least_squares`): the stacked Jacobian
of F frames is block-sparse (each frame's rows touch its own few columns and the shared ones),
but MINPACK factorises it densely, ``O(N p^2)`` per iteration with ``N`` and ``p`` both growing
as F: a 12-frame calibration of 64-pixel crops spent 60 % of its time there, 20 frames of
100-pixel crops would take minutes per iteration and gigabytes. ``A`` is ``p x p`` and its
blocks cost ``O(N_f p_f^2)`` per frame, so an iteration costs what the frames' holograms cost.

The convergence tests are MINPACK's: ``ftol`` on the actual and predicted relative decrease of
the sum of squares, ``xtol`` on the scaled step relative to the scaled vector, and a vanishing
scaled gradient.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from holofit.holomodel.forward import InvalidParameters

__all__ = ["NormalSolution", "covariance_from_normal", "solve_normal_lm"]

#: a scaled normal matrix whose smallest eigenvalue is below this times its largest is
#: singular (the covariance is NaN): ``J``'s singular values 3e-8 apart, beyond which the
#: normal equations (their condition squared) have no digits left
SINGULAR = 1e-15
#: the first damping, relative to the scaled normal matrix's unit diagonal (nearly Gauss-Newton,
#: as MINPACK's initial step bound of 100 times the scaled vector is)
LAMBDA_START = 1e-3


class NormalModel(Protocol):
    """What :func:`solve_normal_lm` needs of a model
    (:class:`~holofit.calibrate.model.JointModel`)."""

    def hologram(self, vector: NDArray) -> NDArray[np.float64]: ...

    def normal(self, vector: NDArray, residuals: NDArray
               ) -> tuple[NDArray[np.float64], NDArray[np.float64]]: ...


@dataclass
class NormalSolution:
    """What :func:`solve_normal_lm` found.

    Attributes
    ----------
    vector : ndarray
        The best vector.
    residuals : ndarray
        ``model - data`` there (weighted, as the model gives them).
    normal : ndarray
        ``J^T J`` there, ``(p, p)``.
    rss : float
        Sum of squared residuals.
    n_eval : int
        Residual evaluations (Jacobians not counted, as MINPACK's ``nfev``).
    converged : bool
        A tolerance was met.
    message : str
        Which one, or why not.
    """

    vector: NDArray[np.float64]
    residuals: NDArray[np.float64]
    normal: NDArray[np.float64]
    rss: float
    n_eval: int
    converged: bool
    message: str


def covariance_from_normal(normal: NDArray[np.float64], rss: float, n_points: int
                           ) -> NDArray[np.float64]:
    """``s^2 A^-1`` with ``s^2 = rss / (N - p)`` (the convention of
    :func:`holofit.holomodel.statistics.covariance_from_jacobian`, from ``A = J^T J``).

    Parameters
    ----------
    normal : ndarray, shape (p, p)
        ``J^T J`` at the solution.
    rss : float
        Sum of squared residuals.
    n_points : int
        Residuals ``N``.

    Returns
    -------
    ndarray, shape (p, p)
        NaN where there are no degrees of freedom or ``A`` is singular (:data:`SINGULAR`).
    """
    p = normal.shape[0]
    dof = n_points - p
    if dof <= 0 or p == 0 or not np.all(np.isfinite(normal)):
        return np.full((p, p), np.nan)
    d = np.sqrt(np.diag(normal))
    if not np.all(d > 0):
        return np.full((p, p), np.nan)
    w, v = np.linalg.eigh(normal / np.outer(d, d))
    if w[0] <= w[-1] * SINGULAR:
        return np.full((p, p), np.nan)
    inv = (v / w) @ v.T
    return inv / np.outer(d, d) * (rss / dof)


def _residuals(model: NormalModel, data: NDArray, vector: NDArray) -> NDArray[np.float64] | None:
    try:
        r = model.hologram(vector) - data
    except InvalidParameters:
        return None
    return r if np.all(np.isfinite(r)) else None


def solve_normal_lm(model: NormalModel, data: NDArray[np.float64], start: NDArray[np.float64],
                    *, max_nfev: int = 100, ftol: float = 1e-8, xtol: float = 1e-8,
                    gtol: float = 1e-10) -> NormalSolution:
    """Fit ``model`` to ``data`` from ``start`` (the module docstring).

    Parameters
    ----------
    model : NormalModel
        ``hologram(vector)`` (raising :class:`~holofit.holomodel.forward.InvalidParameters`
        outside the physical domain) and ``normal(vector, residuals) -> (J^T J, J^T r)``.
    data : ndarray, shape (N,)
        What the model is fitted to.
    start : ndarray, shape (p,)
        Start vector (must be valid).
    max_nfev : int
        Most residual evaluations.
    ftol, xtol, gtol : float
        Tolerances: relative decrease of the sum of squares, relative scaled step, largest
        cosine between the residuals and a column of ``J``.

    Returns
    -------
    NormalSolution

    Raises
    ------
    ValueError
        If the start is outside the model's domain.
    """
    x = np.array(start, dtype=float)
    r = _residuals(model, data, x)
    if r is None:
        raise ValueError("the joint fit's start vector describes no valid hologram")
    n_eval = 1
    cost = float(r @ r)
    a, g = model.normal(x, r)
    scale = np.sqrt(np.maximum(np.diag(a), 0.0))
    scale[scale == 0] = 1.0
    lam = LAMBDA_START
    nu = 2.0
    message = f"reached the limit of {max_nfev} evaluations"
    converged = False
    while n_eval < max_nfev:
        if cost == 0.0 or np.max(np.abs(g) / scale) <= gtol * math.sqrt(cost):
            converged, message = True, "the gradient vanishes (gtol)"
            break
        ahat = a / np.outer(scale, scale)
        ghat = g / scale
        try:
            step_hat = -np.linalg.solve(ahat + lam * np.eye(x.size), ghat)
        except np.linalg.LinAlgError:
            lam *= nu
            nu *= 2.0
            continue
        step = step_hat / scale
        predicted = -(2.0 * ghat @ step_hat + step_hat @ ahat @ step_hat)
        trial = x + step
        r_new = _residuals(model, data, trial)
        n_eval += 1
        new_cost = float(r_new @ r_new) if r_new is not None else math.inf
        actual = cost - new_cost
        rho = actual / predicted if predicted > 0 else -1.0
        small_x = float(np.linalg.norm(step_hat)) <= xtol * float(np.linalg.norm(scale * x))
        if r_new is not None and actual > 0:
            small_f = (abs(actual) <= ftol * cost and predicted <= ftol * cost
                       and rho <= 2.0)
            x, r, cost = trial, r_new, new_cost
            a, g = model.normal(x, r)
            scale = np.maximum(scale, np.sqrt(np.maximum(np.diag(a), 0.0)))
            lam *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
            nu = 2.0
            if small_f or small_x:
                converged = True
                message = ("the sum of squares changes by less than ftol" if small_f
                           else "the step is below xtol")
                break
        else:
            if small_x and predicted <= ftol * cost:
                converged, message = True, "no smaller sum of squares within xtol"
                break
            lam *= nu
            nu *= 2.0
    return NormalSolution(vector=x, residuals=r, normal=a, rss=cost, n_eval=n_eval,
                          converged=converged, message=message)
