"""Covariance of time-averaged squared displacements at several lags (diffusion + noise).

A time-averaged MSD at lag ``k`` averages ``x_t(k)^2`` over overlapping pairs ``(t, t + k)``,
and the averages at different lags share the same steps, so they are strongly correlated;
treating them as independent understates the error of a line fitted through them. For a
coordinate that diffuses (``<step^2> = 2 D dt`` per frame) and is measured with white
Gaussian noise of variance ``s^2`` per frame, displacements are jointly Gaussian with

    c(t, k; t + d, l) = Cov(x_{t+k} - x_t, x_{t+d+l} - x_{t+d})
                      = 2 D dt |[0, k] & [d, d + l]|
                        + s^2 (delta_{d, k-l} - delta_{d, k} - delta_{d, -l} + delta_{d, 0}),

(the overlap of the two lag intervals, in frames, and the frames the two pairs share), and for
zero-mean Gaussians ``Cov(a^2, b^2) = 2 Cov(a, b)^2``. The covariance of the averages is the sum
over the pairs each average uses,

    Cov(m_k, m_l) = 2 / (n_k n_l) sum_d c(d)^2 #{t : pair (t, k) and pair (t + d, l) used},

which is exact for any pattern of gaps (Qian, Sheetz & Elson, Biophys. J. 60, 910, 1991, give
it for a gap-free trajectory without noise; Michalet, Phys. Rev. E 82, 041914, 2010, with
localisation noise). An observable summing ``n_c`` independent such coordinates (the MSD
across a rod's axis: 2; the 3D MSD: 3) has ``n_c`` times this covariance.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

__all__ = ["msd_covariance", "pair_overlap_counts"]

#: above this many offsets per pair of lags the pair counts are computed by FFT
_DIRECT_OFFSETS = 256


def pair_overlap_counts(
    mask_k: NDArray[np.bool_], mask_l: NDArray[np.bool_], offsets: NDArray[np.int64]
) -> NDArray[np.float64]:
    """``#{t : mask_k[t] and mask_l[t + d]}`` for each offset ``d``.

    Parameters
    ----------
    mask_k, mask_l : ndarray of bool
        Pairs used at lags ``k`` and ``l`` (indexed by their first frame).
    offsets : ndarray of int
        Offsets ``d`` (frames).
    """
    a = mask_k.astype(float)
    b = mask_l.astype(float)
    if a.all() and b.all():
        lo = np.maximum(0, -offsets)
        hi = np.minimum(a.size, b.size - offsets)
        return np.maximum(hi - lo, 0).astype(float)
    if offsets.size > _DIRECT_OFFSETS:
        size = 1 << int(np.ceil(np.log2(a.size + b.size)))
        corr = np.fft.irfft(np.conj(np.fft.rfft(a, size)) * np.fft.rfft(b, size), size)
        return np.round(corr[offsets % size])
    out = np.empty(offsets.size)
    for i, d in enumerate(offsets):
        if d >= 0:
            n = min(a.size, b.size - d)
            out[i] = a[:n] @ b[d:d + n] if n > 0 else 0.0
        else:
            n = min(a.size + d, b.size)
            out[i] = a[-d:-d + n] @ b[:n] if n > 0 else 0.0
    return out


def msd_covariance(
    lags: Sequence[int] | NDArray[np.int64],
    masks: Sequence[NDArray[np.bool_]],
    step_var: float,
    noise_var: float,
    components: float = 1.0,
) -> NDArray[np.float64]:
    """Covariance matrix of the time-averaged squared displacements at ``lags``.

    Parameters
    ----------
    lags : sequence of int
        Lags, frames.
    masks : sequence of ndarray of bool
        For each lag ``k``, the pairs ``(t, t + k)`` used (length ``N - k``).
    step_var : float
        ``2 D dt``: variance of one frame's step of one coordinate, um^2 (or rad^2).
    noise_var : float
        Variance of the measurement noise of one coordinate in one frame.
    components : float
        Number of independent, identically distributed coordinates summed by the observable.

    Returns
    -------
    ndarray, shape (L, L)
    """
    lags = np.asarray(lags, dtype=np.int64)
    counts = np.array([float(np.count_nonzero(m)) for m in masks])
    m = lags.size
    cov = np.zeros((m, m))
    for i in range(m):
        k = int(lags[i])
        for j in range(i, m):
            l = int(lags[j])
            d = np.arange(-l, k + 1)
            overlap = np.maximum(np.minimum(k, d + l) - np.maximum(0, d), 0).astype(float)
            c = step_var * overlap
            c[d == k - l] += noise_var
            c[d == k] -= noise_var
            c[d == -l] -= noise_var
            c[d == 0] += noise_var
            n = pair_overlap_counts(masks[i], masks[j], d)
            denom = counts[i] * counts[j]
            cov[i, j] = cov[j, i] = 2.0 * components * float(c**2 @ n) / denom if denom else 0.0
    return cov
