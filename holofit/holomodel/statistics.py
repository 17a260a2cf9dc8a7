"""Statistics of a least-squares fit: parameter uncertainties from the Jacobian, and the
camera noise of a hologram estimated from the image itself."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import convolve

__all__ = ["covariance_from_jacobian", "estimate_noise_sd"]


def covariance_from_jacobian(
    jac: NDArray[np.float64], rss: float, n_points: int
) -> NDArray[np.float64]:
    """Parameter covariance ``s^2 (J^T J)^-1`` with ``s^2 = rss / (N - p)``.

    The residual variance stands in for the (unknown) pixel noise, as in the paper and in
    ``scipy.optimize.curve_fit``; it is exact for a correct model with white noise.

    Parameters
    ----------
    jac : ndarray, shape (N, p)
        Jacobian of the model at the solution.
    rss : float
        Residual sum of squares.
    n_points : int
        Number of data points N.

    Returns
    -------
    ndarray, shape (p, p)
        Covariance; NaN if the problem has no degrees of freedom or J is rank-deficient.
    """
    p = jac.shape[1]
    dof = n_points - p
    if dof <= 0 or p == 0:
        return np.full((p, p), np.nan)
    _, s, vt = np.linalg.svd(jac, full_matrices=False)
    if s[-1] <= s[0] * 1e-12:
        return np.full((p, p), np.nan)
    return (vt.T / s**2) @ vt * (rss / dof)


#: discrete-Laplacian difference mask of Immerkaer (1996)
_LAPLACE_DIFF = np.array([[1.0, -2.0, 1.0], [-2.0, 4.0, -2.0], [1.0, -2.0, 1.0]])


def estimate_noise_sd(image: NDArray, valid: NDArray[np.bool_] | None = None) -> float:
    """Standard deviation of white pixel noise, estimated from one image.

    Immerkaer's estimator (Comput. Vis. Image Underst. 64, 300, 1996): the image is filtered
    with the difference of two discrete Laplacians, which cancels smooth structure up to
    second order, and ``sigma = sqrt(pi/2) / 6 * mean|filtered|``. Holograms sampled well
    above their fringe frequency (the usual case) leave little structure in the filtered
    image; finely fringed edges bias the estimate upward.

    Parameters
    ----------
    image : ndarray, shape (rows, cols)
        The image (NaN for invalid pixels).
    valid : ndarray of bool, optional
        Pixels to use; a filtered value is used only if its whole 3x3 neighbourhood is valid.

    Returns
    -------
    float
        Noise standard deviation in the image's units (NaN if too few pixels).
    """
    img = np.asarray(image, dtype=float)
    ok = np.isfinite(img) if valid is None else (np.asarray(valid, bool) & np.isfinite(img))
    filled = np.where(ok, img, 0.0)
    filt = convolve(filled, _LAPLACE_DIFF, mode="constant")
    whole = convolve(ok.astype(float), np.ones((3, 3)), mode="constant") > 8.5
    values = np.abs(filt[whole])
    if values.size < 9:
        return float("nan")
    return float(np.sqrt(np.pi / 2.0) / 6.0 * values.mean())
