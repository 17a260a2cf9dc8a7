"""The dipole-dipole interaction as a block-Toeplitz convolution, applied through 3D FFTs.

Point-dipole Green's tensor (Gaussian units, ADDA ``-int poi``):

    G(R) = exp(ikR)/R [k^2 (I - R^ R^) - (1 - ikR)/R^2 (I - 3 R^ R^)],   G(0) = 0.

Its values at the lattice offsets are embedded in a circulant grid of ``M >= 2n - 1`` points
per axis (``M`` an FFT-friendly size), Fourier transformed once and cached per
``(grid, d, k, precision)``, so the interaction of every box that fits in the grid (any particle
size and orientation with the same d and k) reuses it. The convolution skips the FFTs of
all-zero blocks ("pruned" transforms, as ADDA does): the forward transform runs along z on
the ``nx * ny`` occupied lines only, then y on ``nx * Mz`` lines, then x on all; the inverse in
the opposite order, keeping only the box. That is 7/12 of the work of full 3D transforms.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass

import numba
import numpy as np
import scipy.fft as sfft
from numpy.typing import NDArray

__all__ = ["Interaction", "get_interaction", "green_tensor"]

_CACHE: OrderedDict[tuple, Interaction] = OrderedDict()
CACHE_SIZE = 3


def green_tensor(r: NDArray[np.float64], k: float) -> NDArray[np.complex128]:
    """Green's tensor ``G(r)`` for separation vectors ``r`` (..., 3), um; shape (..., 3, 3)."""
    r = np.asarray(r, dtype=float)
    dist = np.sqrt((r**2).sum(axis=-1))
    with np.errstate(divide="ignore", invalid="ignore"):
        rh = r / dist[..., None]
        e = np.exp(1j * k * dist) / dist
        a = e * (k**2 - (1 - 1j * k * dist) / dist**2)
        b = e * (3 * (1 - 1j * k * dist) / dist**2 - k**2)
    g = a[..., None, None] * np.eye(3) + b[..., None, None] * rh[..., :, None] * rh[..., None, :]
    return np.where((dist > 0)[..., None, None], g, 0.0)


def _signed_offsets(m: int) -> NDArray[np.float64]:
    i = np.arange(m)
    return np.where(i <= m // 2, i, i - m).astype(float)


@numba.njit(cache=True, nogil=True)
def _tensor_apply(g, y):  # pragma: no cover - compiled
    """In place ``y[:, p] = G[:, p] . y[:, p]`` with G stored as xx, xy, xz, yy, yz, zz."""
    for p in range(y.shape[1]):
        y0 = y[0, p]
        y1 = y[1, p]
        y2 = y[2, p]
        y[0, p] = g[0, p] * y0 + g[1, p] * y1 + g[2, p] * y2
        y[1, p] = g[1, p] * y0 + g[3, p] * y1 + g[4, p] * y2
        y[2, p] = g[2, p] * y0 + g[4, p] * y1 + g[5, p] * y2


@dataclass(eq=False)
class Interaction:
    """Fourier-transformed interaction tensor on a circulant grid.

    Attributes
    ----------
    grid : tuple of int
        FFT grid ``(Mx, My, Mz)``.
    d : float
        Dipole size, um.
    k : float
        Wavenumber in the medium, rad/um.
    g_hat : ndarray, shape (6, Mx*My*Mz)
        FFT of the xx, xy, xz, yy, yz, zz components.
    """

    grid: tuple[int, int, int]
    d: float
    k: float
    g_hat: NDArray[np.complexfloating]

    @classmethod
    def build(cls, grid: tuple[int, int, int], d: float, k: float,
              dtype: type = np.complex128) -> Interaction:
        ox, oy, oz = (_signed_offsets(m) * d for m in grid)
        x = ox[:, None, None]
        y = oy[None, :, None]
        z = oz[None, None, :]
        dist = np.sqrt(x * x + y * y + z * z)
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = np.where(dist > 0, 1.0 / dist, 0.0)
            e = np.exp(1j * k * dist) * inv
            a = e * (k**2 - (1 - 1j * k * dist) * inv**2)
            b = e * (3 * (1 - 1j * k * dist) * inv**2 - k**2)
        comps = []
        for p, q in ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)):
            rp = (x, y, z)[p] * inv
            rq = (x, y, z)[q] * inv
            g = b * rp * rq
            if p == q:
                g = g + a
            g = np.where(dist > 0, g, 0.0)
            comps.append(sfft.fftn(g, workers=1).ravel())
        g_hat = np.ascontiguousarray(np.array(comps), dtype=dtype)
        return cls(grid=tuple(int(v) for v in grid), d=d, k=k, g_hat=g_hat)  # type: ignore[arg-type]

    @property
    def dtype(self) -> np.dtype:
        return self.g_hat.dtype

    def convolve(self, y: NDArray[np.complexfloating]) -> NDArray[np.complexfloating]:
        """``z_i = sum_j G(r_i - r_j) y_j`` for a box field ``y`` of shape (3, nx, ny, nz)."""
        _, nx, ny, nz = y.shape
        mx, my, mz = self.grid
        if nx > (mx + 1) // 2 or ny > (my + 1) // 2 or nz > (mz + 1) // 2:
            raise ValueError(f"box {y.shape[1:]} does not fit the interaction grid {self.grid}")
        t = sfft.fft(y, n=mz, axis=3, workers=1)
        t = sfft.fft(t, n=my, axis=2, workers=1, overwrite_x=True)
        t = sfft.fft(t, n=mx, axis=1, workers=1, overwrite_x=True)
        flat = t.reshape(3, -1)
        _tensor_apply(self.g_hat, flat)
        t = sfft.ifft(t, axis=1, workers=1, overwrite_x=True)[:, :nx]
        t = sfft.ifft(t, axis=2, workers=1)[:, :, :ny]
        t = sfft.ifft(t, axis=3, workers=1)[:, :, :, :nz]
        return t


def grid_for_box(shape: tuple[int, int, int]) -> tuple[int, int, int]:
    """FFT-friendly circulant grid for a box: ``M >= 2n - 1`` per axis, 5-smooth."""
    out = []
    for n in shape:
        m = max(2 * n - 1, 2)
        while True:
            m = sfft.next_fast_len(m)
            r = m
            for f in (2, 3, 5):
                while r % f == 0:
                    r //= f
            if r == 1:
                break
            m += 1
        out.append(m)
    return tuple(out)  # type: ignore[return-value]


def get_interaction(shape: tuple[int, int, int], d: float, k: float,
                    dtype: type = np.complex128) -> Interaction:
    """The cached interaction for a box (built on first use, LRU cache of a few grids)."""
    grid = grid_for_box(shape)
    for key, inter in _CACHE.items():
        g, dd, kk, dt = key
        fits = all(n <= (m + 1) // 2 for n, m in zip(shape, g, strict=True))
        not_wasteful = all(m <= 1.3 * mi for m, mi in zip(g, grid, strict=True))
        if dd == d and kk == k and dt == np.dtype(dtype) and fits and not_wasteful:
            _CACHE.move_to_end(key)
            return inter
    inter = Interaction.build(grid, d, k, dtype)
    _CACHE[(grid, d, k, np.dtype(dtype))] = inter
    while len(_CACHE) > CACHE_SIZE:
        _CACHE.popitem(last=False)
    return inter


def clear_cache() -> None:
    """Forget all cached interactions (benchmarks of 'empty caches')."""
    _CACHE.clear()
