"""The dipole-dipole interaction as a block-Toeplitz convolution, applied through 3D FFTs.

Point-dipole Green's tensor (Gaussian units, ADDA ``-int poi``):

    G(R) = exp(ikR)/R [k^2 (I - R^ R^) - (1 - ikR)/R^2 (I - 3 R^ R^)],   G(0) = 0.

Filtered coupled dipoles (``kind="fcd"``, ADDA ``-int fcd``; Piller 1998, Gay-Balmaz & Martin
2002, Yurkin, Min & Hoekstra 2010): the point-dipole tensor plus a real correction that removes
the spatial frequencies above ``k_F = pi / d`` (the lattice cannot represent them),

    G_F = G + [(-g0 (kR)^2 - g2) I + (g0 (kR)^2 + 3 g2) R^ R^],
    g0 = [Im(e) C + Re(e) S] / pi,
    g2 = [kR (Re(e) C - Im(e) S) + (2/3)(k_F R cos(k_F R) - 4 sin(k_F R)) / R^3] / pi - g0,

with ``e = exp(ikR)/R^3``, ``C = Ci((k_F + k)R) - Ci((k_F - k)R)`` and
``S = pi - Si((k_F + k)R) - Si((k_F - k)R)`` (sine and cosine integrals).

Circulant embedding
    Its values at the lattice offsets are embedded in a circulant grid of ``M >= 2n`` points per
    axis (``M`` even and FFT-friendly). Every component is even or odd in each axis (``G_xy`` is
    odd in x and y, ``G_xx`` even in all), and so is its DFT: only one octant of the transform
    is stored (1/8 of the memory), computed directly with DCT-I/DST-I transforms of the octant
    of ``G``, and unfolded with the right signs on the fly. It is cached per
    ``(grid, d, k, precision)``; every box that fits the grid (any size, any orientation with the
    same d and k) reuses it.

Grid sizes
    ``M`` is the smallest even number ``>= 2 n`` whose prime factors are 2, 3, 5 and 7, with at
    most one factor 11 or 13 (sizes FFTW transforms at full speed; ADDA's rule).

The matrix-vector product that uses the tensor lives in :mod:`holofit.dda.convolution`; it
asks the interaction for the tensor in its slab layout (:meth:`Interaction.slab_tensor`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.fft as sfft
import scipy.special as ssp
from numpy.typing import NDArray

from holofit.cache import LRUCache

__all__ = ["Interaction", "clear_cache", "fft_size", "get_interaction", "green_tensor",
           "grid_for_box"]

CACHE_SIZE = 3
_CACHE: LRUCache[tuple, Interaction] = LRUCache(CACHE_SIZE)
#: interaction tensors: point dipoles (ADDA's default) and filtered coupled dipoles
INTERACTIONS = ("poi", "fcd")
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


def fft_size(m: int) -> int:
    """Smallest even integer ``>= m`` with prime factors 2, 3, 5, 7 and at most one 11 or 13."""
    m = max(m + (m % 2), 2)
    while True:
        r = m
        for f in (2, 3, 5, 7):
            while r % f == 0:
                r //= f
        if r in (1, 11, 13):
            return m
        m += 2


def grid_for_box(shape: tuple[int, int, int]) -> tuple[int, int, int]:
    """Circulant grid ``(Mx, My, Mz)`` for a box ``(nx, ny, nz)``: :func:`fft_size` of ``2n``."""
    return tuple(fft_size(2 * n) for n in shape)  # type: ignore[return-value]


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
    kind: str = "poi"
    _slab_cache: dict = field(default_factory=dict, repr=False)

    @classmethod
    def build(cls, grid: tuple[int, int, int], d: float, k: float,
              dtype: type = np.complex128, kind: str = "poi") -> Interaction:
        """Transform the tensor of ``kind`` ("poi" point dipoles, "fcd" filtered) on ``grid``."""
        if kind not in INTERACTIONS:
            raise ValueError(f"interaction kind must be one of {INTERACTIONS}, got {kind!r}")
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
        if kind == "fcd":
            # filtered correction: a += -g0 (kR)^2 - g2 (isotropic), b += g0 (kR)^2 + 3 g2
            kf = np.pi / d
            if k >= kf:
                raise ValueError(f"filtered coupled dipoles need k d < pi (k d = {k * d:.3g})")
            kr = k * dist
            ev = e * inv**2  # exp(ikR)/R^3
            with np.errstate(invalid="ignore"):  # Ci(0) = -inf at R = 0 (masked below)
                si1, ci1 = ssp.sici((kf + k) * dist)
                si2, ci2 = ssp.sici((kf - k) * dist)
                c_int = ci1 - ci2
            s_int = np.pi - si1 - si2
            g0 = (ev.imag * c_int + ev.real * s_int) / np.pi
            g2 = (kr * (ev.real * c_int - ev.imag * s_int)
                  + 2.0 / 3.0 * inv**3 * (kf * dist * np.cos(kf * dist)
                                          - 4.0 * np.sin(kf * dist))) / np.pi - g0
            a = a + np.where(dist > 0, np.nan_to_num(-g0 * kr**2 - g2), 0.0)
            b = b + np.where(dist > 0, np.nan_to_num(g0 * kr**2 + 3.0 * g2), 0.0)
        del e
        # offsets M/2 are never used by a box that fits (n <= M/2): zero them so that the
        # embedded array has exact parity
        outer = np.zeros(dist.shape, dtype=bool)
        outer[-1, :, :] = outer[:, -1, :] = outer[:, :, -1] = True
        coords = (x, y, z)
        g_oct: NDArray[np.complexfloating] = np.empty(
            (6, mz // 2 + 1, my // 2 + 1, mx // 2 + 1), dtype=dtype)
        for c, (p, q) in enumerate(COMPONENTS):
            g = b * (coords[p] * inv) * (coords[q] * inv)
            if p == q:
                g = g + a
            g = np.where((dist > 0) & ~outer, g, 0.0)
            g_oct[c] = _octant_transform(g, PARITY[(p, q)])
        return cls(grid=tuple(int(v) for v in grid), d=d, k=k, g_oct=g_oct,  # type: ignore[arg-type]
                   kind=kind)

    @property
    def dtype(self) -> np.dtype:
        return self.g_oct.dtype

    def slab_tensor(self, order: tuple[int, int, int]) -> tuple[NDArray, NDArray]:
        """The tensor in the layout of the slab convolution (cached per axis order).

        Parameters
        ----------
        order : tuple of int
            Lattice axes ``(s, a, b)`` (0 = x, 1 = y, 2 = z): slab axis, then the two in-slab
            axes, ``b`` contiguous.

        Returns
        -------
        tensor : ndarray, shape (M_s/2+1, M_a/2+1, 6, M_b)
            Folded along ``s`` and ``a``, unfolded along ``b`` (the odd components' signs along
            ``b`` applied), divided by ``M_s M_a M_b`` (the inverse transform's normalisation).
        signs : ndarray, shape (2, 2, 3)
            Signs of the xy, xz, yz components in the upper (1) or lower (0) half of the slab
            axis (first index) and of the ``a`` axis (second index).
        """
        key = tuple(int(i) for i in order)
        if key in self._slab_cache:
            return self._slab_cache[key]
        s, a, b = key
        goct_axis = {0: 3, 1: 2, 2: 1}  # lattice axis -> axis of g_oct (c, z, y, x)
        g = np.transpose(self.g_oct, (goct_axis[s], goct_axis[a], 0, goct_axis[b]))
        mb = self.grid[b]
        idx = np.arange(mb)
        upper = idx > mb // 2
        g = g[..., np.where(upper, mb - idx, idx)]
        odd_b = np.array([PARITY[c][b] < 0 for c in COMPONENTS])
        g = g * np.where(odd_b[:, None] & upper[None, :], -1.0, 1.0)
        tensor = np.ascontiguousarray(g / float(np.prod(self.grid)), dtype=self.dtype)
        signs = np.empty((2, 2, 3), dtype=tensor.real.dtype)
        for hs in range(2):
            for ha in range(2):
                sg = np.ones(3)
                sg[s] = -1.0 if hs else 1.0
                sg[a] = -1.0 if ha else 1.0
                signs[hs, ha] = (sg[0] * sg[1], sg[0] * sg[2], sg[1] * sg[2])
        self._slab_cache[key] = (tensor, signs)
        return tensor, signs


def get_interaction(shape: tuple[int, int, int], d: float, k: float,
                    dtype: type = np.complex128, kind: str = "poi") -> Interaction:
    """The cached interaction for a box (built on first use, LRU cache of a few grids)."""
    grid = grid_for_box(shape)
    for key, inter in _CACHE.items():
        g, dd, kk, dt, kd = key
        fits = all(2 * n <= m for n, m in zip(shape, g, strict=True))
        not_wasteful = all(m <= 1.3 * mi for m, mi in zip(g, grid, strict=True))
        if (dd == d and kk == k and dt == np.dtype(dtype) and kd == kind and fits
                and not_wasteful):
            _CACHE.get(key)  # marks it most recently used
            return inter
    return _CACHE.put((grid, d, k, np.dtype(dtype), kind),
                      Interaction.build(grid, d, k, dtype, kind))


def clear_cache() -> None:
    """Forget all cached interactions (benchmarks of 'empty caches')."""
    _CACHE.clear()
