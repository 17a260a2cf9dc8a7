"""The dipole-dipole interaction as a block-Toeplitz convolution, applied through 3D FFTs.

Point-dipole Green's tensor (Gaussian units, ADDA ``-int poi``):

    G(R) = exp(ikR)/R [k^2 (I - R^ R^) - (1 - ikR)/R^2 (I - 3 R^ R^)],   G(0) = 0.

Circulant embedding
    Its values at the lattice offsets are embedded in a circulant grid of ``M >= 2n`` points per
    axis (``M`` even and FFT-friendly). Every component is even or odd in each axis (``G_xy`` is
    odd in x and y, ``G_xx`` even in all), and so is its DFT: only one octant of the transform
    is stored (1/8 of the memory), computed directly with DCT-I/DST-I transforms of the octant
    of ``G``, and unfolded with the right signs on the fly. It is cached per
    ``(grid, d, k, precision)``; every box that fits the grid (any size, any orientation with the
    same d and k) reuses it.

Pruned transforms
    Box fields are stored in (component, z, y, x) order. The forward transform runs along z on
    the ``ny * nx`` occupied lines only, then along y on ``Mz * nx`` lines, then along the
    contiguous x axis on all; the inverse in the opposite order, keeping only the box. That is
    7/12 of the work of full 3D transforms, and the full-size passes run along contiguous
    memory. Buffers are preallocated per box (no allocation per product).
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass

import numba
import numpy as np
import scipy.fft as sfft
from numpy.typing import NDArray

from holofit.dda import fftw

__all__ = ["Convolver", "Interaction", "clear_cache", "get_interaction", "green_tensor",
           "grid_for_box"]

_CACHE: OrderedDict[tuple, Interaction] = OrderedDict()
CACHE_SIZE = 3
#: component order of the stored tensor and, per component, its parity along (x, y, z):
#: 1 = even, -1 = odd
COMPONENTS = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))
PARITY = {
    (0, 0): (1, 1, 1), (0, 1): (-1, -1, 1), (0, 2): (-1, 1, -1),
    (1, 1): (1, 1, 1), (1, 2): (1, -1, -1), (2, 2): (1, 1, 1),
}


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


def _smooth_even(m: int) -> int:
    """Smallest even 5-smooth integer >= m."""
    m = max(m + (m % 2), 2)
    while True:
        r = m
        for f in (2, 3, 5):
            while r % f == 0:
                r //= f
        if r == 1:
            return m
        m += 2


def grid_for_box(shape: tuple[int, int, int]) -> tuple[int, int, int]:
    """Circulant grid ``(Mx, My, Mz)`` for a box ``(nx, ny, nz)``: even, 5-smooth, ``>= 2n``."""
    return tuple(_smooth_even(2 * n) for n in shape)  # type: ignore[return-value]


def _octant_transform(g: NDArray, parity: tuple[int, int, int]) -> NDArray:
    """DFT of a circulant array with the given parity, from its octant (z, y, x order).

    ``g`` holds offsets ``0..M/2`` along each axis (axes ordered z, y, x); ``parity`` is given
    as (x, y, z). Even axes use DCT-I, odd axes DST-I (with ``-i`` factors).
    """
    out = g.astype(complex)
    for axis, par in zip((2, 1, 0), parity, strict=True):  # x is axis 2, z axis 0
        if par == 1:
            out = sfft.dct(out.real, type=1, axis=axis) + 1j * sfft.dct(out.imag, type=1,
                                                                         axis=axis)
        else:
            inner = np.take(out, np.arange(1, out.shape[axis] - 1), axis=axis)
            tr = sfft.dst(inner.real, type=1, axis=axis) + 1j * sfft.dst(inner.imag, type=1,
                                                                          axis=axis)
            tr = -1j * tr
            pad = [(0, 0)] * 3
            pad[axis] = (1, 1)
            out = np.pad(tr, pad)
    return out


@dataclass(eq=False)
class Interaction:
    """Fourier-transformed interaction tensor on a circulant grid (one octant stored).

    Attributes
    ----------
    grid : tuple of int
        FFT grid ``(Mx, My, Mz)`` (all even).
    d : float
        Dipole size, um.
    k : float
        Wavenumber in the medium, rad/um.
    g_oct : ndarray, shape (6, Mz/2+1, My/2+1, Mx/2+1)
        Octant of the DFT of xx, xy, xz, yy, yz, zz.
    """

    grid: tuple[int, int, int]
    d: float
    k: float
    g_oct: NDArray[np.complexfloating]

    @classmethod
    def build(cls, grid: tuple[int, int, int], d: float, k: float,
              dtype: type = np.complex128) -> Interaction:
        if any(m % 2 for m in grid):
            raise ValueError(f"interaction grid must be even along every axis, got {grid}")
        mx, my, mz = grid
        x = (np.arange(mx // 2 + 1) * d)[None, None, :]
        y = (np.arange(my // 2 + 1) * d)[None, :, None]
        z = (np.arange(mz // 2 + 1) * d)[:, None, None]
        dist = np.sqrt(x * x + y * y + z * z)
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = np.where(dist > 0, 1.0 / dist, 0.0)
            e = np.exp(1j * k * dist) * inv
            a = e * (k**2 - (1 - 1j * k * dist) * inv**2)
            b = e * (3 * (1 - 1j * k * dist) * inv**2 - k**2)
        del e
        # offsets M/2 are never used by a box that fits (n <= M/2): zero them so that the
        # embedded array has exact parity
        outer = np.zeros(dist.shape, dtype=bool)
        outer[-1, :, :] = outer[:, -1, :] = outer[:, :, -1] = True
        coords = (x, y, z)
        g_oct = np.empty((6, mz // 2 + 1, my // 2 + 1, mx // 2 + 1), dtype=dtype)
        for c, (p, q) in enumerate(COMPONENTS):
            g = b * (coords[p] * inv) * (coords[q] * inv)
            if p == q:
                g = g + a
            g = np.where((dist > 0) & ~outer, g, 0.0)
            g_oct[c] = _octant_transform(g, PARITY[(p, q)])
        return cls(grid=tuple(int(v) for v in grid), d=d, k=k, g_oct=g_oct)  # type: ignore[arg-type]

    @property
    def dtype(self) -> np.dtype:
        return self.g_oct.dtype


@numba.njit(cache=True, nogil=True, inline="always")
def _fold(i, m):  # pragma: no cover - compiled
    """Octant index of grid index ``i`` (grid size ``m``) and the sign of an odd component."""
    if i > m // 2:
        return m - i, -1.0
    return i, 1.0


@numba.njit(cache=True, nogil=True)
def _tensor_apply(g, y, mz, my, mx):  # pragma: no cover - compiled
    """In place ``y(q) = G(q) . y(q)`` on the full grid, G unfolded from its octant."""
    for iz in range(mz):
        fz, sz = _fold(iz, mz)
        for iy in range(my):
            fy, sy = _fold(iy, my)
            for ix in range(mx):
                fx, sx = _fold(ix, mx)
                gxx = g[0, fz, fy, fx]
                gxy = g[1, fz, fy, fx] * (sx * sy)
                gxz = g[2, fz, fy, fx] * (sx * sz)
                gyy = g[3, fz, fy, fx]
                gyz = g[4, fz, fy, fx] * (sy * sz)
                gzz = g[5, fz, fy, fx]
                y0 = y[0, iz, iy, ix]
                y1 = y[1, iz, iy, ix]
                y2 = y[2, iz, iy, ix]
                y[0, iz, iy, ix] = gxx * y0 + gxy * y1 + gxz * y2
                y[1, iz, iy, ix] = gxy * y0 + gyy * y1 + gyz * y2
                y[2, iz, iy, ix] = gxz * y0 + gyz * y1 + gzz * y2


class Convolver:
    """``z_i = sum_j G(r_i - r_j) y_j`` on one box, with preallocated buffers.

    Uses FFTW (through pyFFTW, with measured plans whose wisdom is cached on disk, see
    :mod:`holofit.dda.fftw`) when it is installed, numpy's pocketfft otherwise; set
    ``HOLOFIT_FFT=numpy`` to force the latter.

    Parameters
    ----------
    interaction : Interaction
        The transformed tensor (its grid must hold the box).
    box : tuple of int
        ``(nx, ny, nz)``.
    """

    def __init__(self, interaction: Interaction, box: tuple[int, int, int]) -> None:
        mx, my, mz = interaction.grid
        nx, ny, nz = box
        if 2 * nx > mx or 2 * ny > my or 2 * nz > mz:
            raise ValueError(f"box {box} does not fit the interaction grid {interaction.grid}")
        self.interaction = interaction
        self.box = box
        dt = interaction.dtype
        self.field = np.zeros((3, nz, ny, nx), dtype=dt)  # the box, (c, z, y, x)
        self._plans = fftw.plans((3, mz, ny, nx), (3, mz, my, nx), (3, mz, my, mx), dt)
        if self._plans is not None:
            self._b1, self._b2, self._b3 = self._plans.buffers
        else:
            self._b1 = np.empty((3, mz, ny, nx), dtype=dt)
            self._b2 = np.empty((3, mz, my, nx), dtype=dt)
            self._b3 = np.empty((3, mz, my, mx), dtype=dt)

    @property
    def backend(self) -> str:
        return "fftw" if self._plans is not None else "numpy"

    def convolve(self) -> NDArray[np.complexfloating]:
        """Convolve :attr:`field` in place and return it (shape (3, nz, ny, nx))."""
        mx, my, mz = self.interaction.grid
        nx, ny, nz = self.box
        b1, b2, b3 = self._b1, self._b2, self._b3
        plans = self._plans
        if plans is None:
            np.fft.fft(self.field, n=mz, axis=1, out=b1)
            np.fft.fft(b1, n=my, axis=2, out=b2)
            np.fft.fft(b2, n=mx, axis=3, out=b3)
            _tensor_apply(self.interaction.g_oct, b3, mz, my, mx)
            np.fft.ifft(b3, axis=3, out=b3)
            np.fft.ifft(b3[..., :nx], axis=2, out=b2)
            np.fft.ifft(b2[:, :, :ny], axis=1, out=b1)
            self.field[...] = b1[:, :nz]
            return self.field
        # FFTW: zero-padding is explicit, every transform runs in place
        b1[:, :nz] = self.field
        b1[:, nz:] = 0
        plans.forward[0]()
        b2[:, :, :ny] = b1
        b2[:, :, ny:] = 0
        plans.forward[1]()
        b3[..., :nx] = b2
        b3[..., nx:] = 0
        plans.forward[2]()
        _tensor_apply(self.interaction.g_oct, b3, mz, my, mx)
        plans.backward[2]()
        b2[...] = b3[..., :nx]
        plans.backward[1]()
        b1[...] = b2[:, :, :ny]
        plans.backward[0]()
        self.field[...] = b1[:, :nz]
        self.field *= 1.0 / (mx * my * mz)
        return self.field


def get_interaction(shape: tuple[int, int, int], d: float, k: float,
                    dtype: type = np.complex128) -> Interaction:
    """The cached interaction for a box (built on first use, LRU cache of a few grids)."""
    grid = grid_for_box(shape)
    for key, inter in _CACHE.items():
        g, dd, kk, dt = key
        fits = all(2 * n <= m for n, m in zip(shape, g, strict=True))
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
