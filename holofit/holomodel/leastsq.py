"""The one least-squares entry point of holofit's fits.

Levenberg-Marquardt (``scipy.optimize.least_squares``, MINPACK's ``lmder``) of a
:class:`~holofit.holomodel.forward.HologramModel` to the data on its pixels, with the model's own
Jacobian and ``x_scale="jac"`` (the parameters differ in scale by orders of magnitude: um,
rad, refractive index). A step that leaves the physical domain (negative size, detector inside
the particle) gets a large constant residual, so the trust region rejects it instead of the fit
aborting.

A fit may also stop early, at the first point where the Gauss-Newton step's predicted decrease
of the sum of squares, ``|P r|^2`` (``P`` the projection onto the Jacobian's columns, ``r``
the residuals), is at most ``stop_rss``: in the quadratic model the fit is then within
``stop_rss`` of its minimum, and the step and the Jacobian after it (MINPACK's confirming
iteration, which its ``ftol`` test needs) are saved. The Jacobian returned is the one computed
there, so the covariance is that of the point reported.

A fit of the objective's numerical aperture goes in three steps, because the misfit is rugged
in NA alone (:mod:`holofit.holomodel.aperture`) and a scan over NA is only as good as the other
parameters it holds: every other parameter is fitted at the start NA, the NA of least misfit
on a grid is found with those held (:func:`holofit.holomodel.aperture.scan_aperture`), and
everything is fitted from each of the scan's three deepest minima
(:func:`holofit.holomodel.aperture.aperture_minima`), the best fit kept.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from holofit.holomodel.aperture import aperture_minima, scan_aperture
from holofit.holomodel.forward import HologramModel, InvalidParameters
from holofit.holomodel.parameters import APERTURE

__all__ = ["CONVERGED_CODES", "Solution", "predicted_decrease", "solve_least_squares"]

#: least_squares status codes that mean convergence (1: gtol, 2: ftol, 3: xtol, 4: both)
CONVERGED_CODES = (1, 2, 3, 4)
#: residual given to a step outside the physical domain
INVALID_RESIDUAL = 1e3


@dataclass
class Solution:
    """What the optimiser returned.

    Attributes
    ----------
    vector : ndarray
        Best parameter vector.
    residuals : ndarray
        ``model - data`` there.
    jacobian : ndarray
        Jacobian there, (N, n).
    rss : float
        Residual sum of squares.
    n_eval : int
        Holograms computed (residuals and Jacobian columns).
    converged : bool
        The tolerances were met.
    message : str
        The optimiser's message.
    aperture_scan : tuple of ndarray, optional
        ``(grid, rss)`` of the numerical-aperture scan the fit started from (a fitted NA
        only; :func:`holofit.holomodel.aperture.scan_aperture`).
    """

    vector: NDArray[np.float64]
    residuals: NDArray[np.float64]
    jacobian: NDArray[np.float64]
    rss: float
    n_eval: int
    converged: bool
    message: str
    aperture_scan: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None


def solve_least_squares(
    model: HologramModel,
    data: NDArray[np.float64],
    start: NDArray[np.float64],
    *,
    max_nfev: int = 200,
    ftol: float = 1e-8,
    xtol: float = 1e-8,
    stop_rss: float | None = None,
) -> Solution:
    """Fit ``model`` to ``data`` from ``start``.

    Parameters
    ----------
    model : HologramModel
        The forward model on the pixels of ``data``.
    data : ndarray, shape (N,)
        Normalised intensities.
    start : ndarray
        Start vector (``model.space.initial_vector()`` or a screened one); with a fitted NA,
        the start of the three steps of the module docstring.
    max_nfev : int
        Most residual evaluations.
    ftol, xtol : float
        Convergence tolerances (relative change of the cost and of the parameters).
    stop_rss : float, optional
        Also stop where the Gauss-Newton step predicts a decrease of the sum of squares of at
        most this (the module docstring); in the units of ``data`` squared.

    Returns
    -------
    Solution
    """
    data = np.asarray(data, dtype=float)
    before = model.n_holograms
    start = np.asarray(start, dtype=float)
    grid = np.empty(0)
    grid_rss = np.empty(0)
    starts = [start]
    if APERTURE.name in model.space.names:
        start = _others_at_start_aperture(model, data, start, max_nfev, ftol, xtol)
        _, grid, grid_rss = scan_aperture(model, data, start)
        i = model.space.names.index(APERTURE.name)
        starts = []
        for na in aperture_minima(grid, grid_rss) or [start[i]]:
            v = start.copy()
            v[i] = na
            starts.append(v)
    sol: Solution | None = None
    for v in starts:  # each of the scan's deepest minima, fitted; the best kept
        s = _levenberg_marquardt(model, data, v, max_nfev, ftol, xtol, stop_rss)
        if sol is None or (np.isfinite(s.rss) and not s.rss >= sol.rss):
            sol = s
    assert sol is not None
    sol.n_eval = model.n_holograms - before
    sol.aperture_scan = (grid, grid_rss) if grid.size else None
    return sol


def _others_at_start_aperture(model: HologramModel, data: NDArray[np.float64],
                              start: NDArray[np.float64], max_nfev: int, ftol: float,
                              xtol: float) -> NDArray[np.float64]:
    """``start`` with every parameter but the NA fitted at the start's NA."""
    if len(model.space.names) == 1:
        return start
    held, index = model.space.holding(APERTURE.name, start)
    sub = HologramModel(model.theory, held, model.optics, model.xs, model.ys,
                        far_field=model.far_field, waves=model.waves)
    sol = _levenberg_marquardt(sub, data, start[index], max_nfev, ftol, xtol)
    model.n_holograms += sub.n_holograms
    model.n_solves += sub.n_solves
    out = start.copy()
    out[index] = sol.vector
    return out


class _Settled(Exception):
    """Raised from the Jacobian callback where the predicted decrease is below the bar."""

    def __init__(self, vector: NDArray[np.float64], residuals: NDArray[np.float64],
                 jacobian: NDArray[np.float64]) -> None:
        super().__init__("settled")
        self.vector, self.residuals, self.jacobian = vector, residuals, jacobian


def predicted_decrease(jacobian: NDArray[np.float64], residuals: NDArray[np.float64]) -> float:
    """``|P r|^2``: the decrease of ``|r|^2`` the (undamped) Gauss-Newton step predicts, ``P``
    the projection onto the span of the Jacobian's columns (scaled to unit norm first; a
    rank-deficient Jacobian gives an upper bound)."""
    norms = np.linalg.norm(jacobian, axis=0)
    keep = norms > 0
    if not keep.any() or not np.all(np.isfinite(jacobian)):
        return 0.0 if not keep.any() else np.inf
    q, _ = np.linalg.qr(jacobian[:, keep] / norms[keep])
    proj = q.T @ residuals
    return float(proj @ proj)


def _levenberg_marquardt(model: HologramModel, data: NDArray[np.float64],
                         start: NDArray[np.float64], max_nfev: int, ftol: float,
                         xtol: float, stop_rss: float | None = None) -> Solution:
    """One Levenberg-Marquardt run (the module docstring)."""
    before = model.n_holograms

    def residuals(v: NDArray[np.float64]) -> NDArray[np.float64]:
        try:
            return model.hologram(v) - data
        except InvalidParameters:
            return np.full(data.shape, INVALID_RESIDUAL)

    def jacobian(v: NDArray[np.float64]) -> NDArray[np.float64]:
        try:
            jac = model.jacobian(v)
        except InvalidParameters:
            return np.zeros((data.size, v.size))
        if stop_rss is not None:
            res = residuals(v)  # the model's last evaluation: no new hologram
            if predicted_decrease(jac, res) <= stop_rss:
                raise _Settled(np.array(v, dtype=float), res, jac)
        return jac

    try:
        sol = least_squares(residuals, np.asarray(start, dtype=float), jac=jacobian,
                            method="lm", x_scale="jac", max_nfev=max_nfev, ftol=ftol,
                            xtol=xtol)
    except _Settled as settled:
        return Solution(
            vector=settled.vector,
            residuals=settled.residuals,
            jacobian=settled.jacobian,
            rss=float(settled.residuals @ settled.residuals),
            n_eval=model.n_holograms - before,
            converged=True,
            message=f"Gauss-Newton step predicts a decrease of at most {stop_rss:.3g}",
        )
    res = np.asarray(sol.fun, dtype=float)
    return Solution(
        vector=np.asarray(sol.x, dtype=float),
        residuals=res,
        jacobian=np.asarray(sol.jac, dtype=float),
        rss=float(res @ res),
        n_eval=model.n_holograms - before,
        converged=bool(sol.status in CONVERGED_CODES),
        message=str(sol.message),
    )
