"""Standard errors of time averages of correlated series: Flyvbjerg-Petersen block decorrelation.

A time average over a correlated series has a larger error than ``std / sqrt(n)``. Flyvbjerg and
Petersen (J. Chem. Phys. 91, 461, 1989) replace the series by averages of neighbouring pairs,
again and again; the naive error estimate ``var / (n - 1)`` grows with every transformation
until the blocks are longer than the correlation time, and then stays on a plateau, which is the
true error. We pick the plateau with the criterion of Lee, Morales and Wagner (Phys. Rev. E 83,
066706, 2011): the smallest block size ``B = 2**k`` with ``B**3 > 2 n (se_k / se_0)**4``, where
``n`` is the length of the series and ``se_k`` the estimate at level ``k``. If no level with at
least :data:`MIN_BLOCKS` blocks satisfies it, the largest estimate among those levels is taken
and the result is marked as not converged.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["MIN_BLOCKS", "BlockingResult", "block_levels", "block_standard_error",
           "block_standard_errors"]

#: fewest blocks a level may have and still be chosen
MIN_BLOCKS = 4


@dataclass(frozen=True)
class BlockingResult:
    """Mean of a series and the block-decorrelated standard error of that mean."""

    mean: float
    sem: float
    block_size: int
    converged: bool
    n: int


def block_levels(x: ArrayLike) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.int64]]:
    """Naive standard error of the mean at every blocking level.

    Parameters
    ----------
    x : array_like, shape (m, n) or (n,)
        One series per row.

    Returns
    -------
    block_sizes : ndarray of int, shape (L,)
        ``2**k`` for level ``k``.
    sem : ndarray, shape (m, L) or (L,)
        ``sqrt(var_k / (n_k - 1))`` at each level (``var_k`` with denominator ``n_k``).
    n_blocks : ndarray of int, shape (L,)
        Number of blocks at each level.
    """
    a = np.asarray(x, dtype=float)
    one = a.ndim == 1
    a = np.atleast_2d(a)
    sizes, sems, counts = [], [], []
    size = 1
    while a.shape[1] >= 2:
        n = a.shape[1]
        var = np.mean((a - a.mean(axis=1, keepdims=True)) ** 2, axis=1)
        sems.append(np.sqrt(var / (n - 1)))
        sizes.append(size)
        counts.append(n)
        half = n // 2
        a = 0.5 * (a[:, 0 : 2 * half : 2] + a[:, 1 : 2 * half : 2])
        size *= 2
    sem = np.array(sems).T if sems else np.zeros((a.shape[0], 0))
    out_sizes = np.array(sizes, dtype=np.int64)
    out_counts = np.array(counts, dtype=np.int64)
    return out_sizes, (sem[0] if one else sem), out_counts


def block_standard_errors(
    x: ArrayLike,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.int64], NDArray[np.bool_]]:
    """Block-decorrelated standard errors of the means of several equal-length series.

    Parameters
    ----------
    x : array_like, shape (m, n)
        One series per row (finite values).

    Returns
    -------
    mean, sem : ndarray, shape (m,)
        Mean of each row and its standard error (NaN for fewer than 2 values).
    block_size : ndarray of int, shape (m,)
        Block size of the chosen level.
    converged : ndarray of bool, shape (m,)
        Whether the plateau criterion was met.
    """
    a = np.atleast_2d(np.asarray(x, dtype=float))
    m, n = a.shape
    mean = a.mean(axis=1) if n else np.full(m, np.nan)
    if n < 2:
        return mean, np.full(m, np.nan), np.ones(m, np.int64), np.zeros(m, bool)
    sizes, sem, counts = block_levels(a)
    usable = counts >= MIN_BLOCKS
    if not usable.any():
        usable[0] = True
    se0 = sem[:, :1]
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio4 = np.where(se0 > 0, (sem / se0) ** 4, 1.0)
    crit = (sizes.astype(float) ** 3)[None, :] > 2.0 * n * ratio4
    crit &= usable[None, :]
    found = crit.any(axis=1)
    first = np.argmax(crit, axis=1)
    masked = np.where(usable[None, :], sem, -np.inf)
    fallback = np.argmax(masked, axis=1)
    level = np.where(found, first, fallback)
    rows = np.arange(m)
    chosen = sem[rows, level]
    # a constant series has zero error at every level
    chosen = np.where(se0[:, 0] > 0, chosen, 0.0)
    return mean, chosen, sizes[level], found | (se0[:, 0] == 0)


def block_standard_error(x: ArrayLike) -> BlockingResult:
    """Block-decorrelated standard error of the mean of one series (NaNs are dropped)."""
    a = np.asarray(x, dtype=float).ravel()
    a = a[np.isfinite(a)]
    mean, sem, size, conv = block_standard_errors(a[None, :])
    return BlockingResult(float(mean[0]), float(sem[0]), int(size[0]), bool(conv[0]), a.size)
