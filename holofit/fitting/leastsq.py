"""The one least-squares entry point of holofit's fits.

Levenberg-Marquardt (``scipy.optimize.least_squares``, MINPACK's ``lmder``) of a
:class:`~holofit.fitting.forward.HologramModel` to the data on its pixels, with the model's own
Jacobian and ``x_scale="jac"`` (the parameters differ in scale by orders of magnitude: um,
rad, refractive index). A step that leaves the physical domain (negative size, detector inside
the particle) gets a large constant residual, so the trust region rejects it instead of the fit
aborting. A fit of the objective's numerical aperture starts from the best NA of a grid
(:func:`holofit.fitting.aperture.scan_aperture`: the misfit is rugged in NA alone).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from holofit.fitting.aperture import scan_aperture
from holofit.fitting.forward import HologramModel, InvalidParameters

__all__ = ["CONVERGED_CODES", "Solution", "solve_least_squares"]

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
        only; :func:`holofit.fitting.aperture.scan_aperture`).
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
) -> Solution:
    """Fit ``model`` to ``data`` from ``start``.

    Parameters
    ----------
    model : HologramModel
        The forward model on the pixels of ``data``.
    data : ndarray, shape (N,)
        Normalised intensities.
    start : ndarray
        Start vector (``model.space.initial_vector()`` or a screened one); a fitted NA starts
        from the best of a grid instead (:func:`holofit.fitting.aperture.scan_aperture`).
    max_nfev : int
        Most residual evaluations.
    ftol, xtol : float
        Convergence tolerances (relative change of the cost and of the parameters).

    Returns
    -------
    Solution
    """
    data = np.asarray(data, dtype=float)
    before = model.n_holograms
    start, grid, grid_rss = scan_aperture(model, data, np.asarray(start, dtype=float))

    def residuals(v: NDArray[np.float64]) -> NDArray[np.float64]:
        try:
            return model.hologram(v) - data
        except InvalidParameters:
            return np.full(data.shape, INVALID_RESIDUAL)

    def jacobian(v: NDArray[np.float64]) -> NDArray[np.float64]:
        try:
            return model.jacobian(v)
        except InvalidParameters:
            return np.zeros((data.size, v.size))

    sol = least_squares(residuals, np.asarray(start, dtype=float), jac=jacobian, method="lm",
                        x_scale="jac", max_nfev=max_nfev, ftol=ftol, xtol=xtol)
    res = np.asarray(sol.fun, dtype=float)
    return Solution(
        vector=np.asarray(sol.x, dtype=float),
        residuals=res,
        jacobian=np.asarray(sol.jac, dtype=float),
        rss=float(res @ res),
        n_eval=model.n_holograms - before,
        converged=bool(sol.status in CONVERGED_CODES),
        message=str(sol.message),
        aperture_scan=(grid, grid_rss) if grid.size else None,
    )
