"""The DDA matrix-vector product: dipoles -> box -> slab-by-slab FFT convolution -> dipoles.

For the occupied voxels of a box it computes

    out_i = c0 v_i + c1 w_i sum_{j != i} G(r_i - r_j) (w_j v_j),

with ``w`` the square roots of the polarisabilities (``c0 = 1, c1 = -1`` is the Jacobi-scaled
DDA operator of :mod:`holofit.dda.dipoles`; ``c0 = 0, c1 = 1, w = 1`` a plain convolution).

Slab algorithm (FFTW; one compiled kernel per product)
    Axes are relabelled ``(s, a, b)``: ``s`` the slab axis (the longest grid axis), ``b`` the
    contiguous one. Box fields are stored as ``(s, component, a, b)``.

    1. scatter ``w v`` into the box (its padding and empty voxels stay zero);
    2. transform along ``s`` on the box's ``3 n_a n_b`` lines only (out of place, the
       zero-padded half of the grid is never stored);
    3. for each of the ``M_s`` slabs, in cache: copy it into a ``(3, M_a, M_b)`` buffer,
       transform along ``a`` on the ``n_b`` occupied columns, along ``b`` on all rows, multiply
       by the 3x3 symmetric tensor (6 components) of that slab, transform back along ``b``
       and along ``a`` (occupied columns only), and copy the box part back;
    4. transform back along ``s`` and gather the dipoles.

    The transforms are the same pruned set as a textbook implementation (7/12 of full 3-D
    FFTs) but the tensor product and half the transforms happen while the slab is in cache,
    and nothing the size of the full doubled grid is ever stored (this is ADDA's scheme).
    The tensor is stored folded along ``s`` and ``a`` (its components are even or odd along
    every axis) and unfolded along ``b`` so that the product loop runs forward over contiguous
    memory (vectorised); slabs ``f`` and ``M_s - f``, and rows ``a`` and ``M_a - a``, are
    processed one after the other to reuse the same tensor values from cache.

Fallback (no FFTW, or ``HOLOFIT_FFT=numpy``)
    Full-grid pruned transforms with numpy's pocketfft and the tensor applied from its
    octant: the same numbers, about twice as slow.

Single precision
    ``complex64`` interactions run the convolution in single precision; the vectors ``v``,
    ``w`` and ``out`` stay double (the Krylov solver works in double).
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray

from holofit.dda import fftw
from holofit.dda.interaction import Interaction

__all__ = ["Convolver"]

_FAST = {"contract", "reassoc", "nsz", "arcp"}


# -- compiled kernels -----------------------------------------------------------------------


@numba.njit(cache=True, nogil=True, fastmath=_FAST, inline="always")
def _row_product(s0, s1, s2, g, gs, fa, a, pxy, pxz, pyz):  # pragma: no cover - compiled
    """Row ``a`` of a slab times the tensor row ``g[gs, fa]`` (odd components signed)."""
    for b in range(s0.shape[1]):
        y0 = s0[a, b]
        y1 = s1[a, b]
        y2 = s2[a, b]
        gxy = g[gs, fa, 1, b] * pxy
        gxz = g[gs, fa, 2, b] * pxz
        gyz = g[gs, fa, 4, b] * pyz
        s0[a, b] = g[gs, fa, 0, b] * y0 + gxy * y1 + gxz * y2
        s1[a, b] = gxy * y0 + g[gs, fa, 3, b] * y1 + gyz * y2
        s2[a, b] = gxz * y0 + gyz * y1 + g[gs, fa, 5, b] * y2


@numba.njit(cache=True, nogil=True, fastmath=_FAST)
def _slab_product(s0, s1, s2, g, f, ms, signs):  # pragma: no cover - compiled
    """In place ``y = G y`` on slab ``f`` (components in ``s0, s1, s2``, shape (M_a, M_b))."""
    ma = s0.shape[0]
    ha = ma // 2
    hs = 0 if f <= ms // 2 else 1
    gs = f if f <= ms // 2 else ms - f
    for fa in range(ha + 1):
        _row_product(s0, s1, s2, g, gs, fa, fa, signs[hs, 0, 0], signs[hs, 0, 1],
                     signs[hs, 0, 2])
        if 0 < fa < ha:
            _row_product(s0, s1, s2, g, gs, fa, ma - fa, signs[hs, 1, 0], signs[hs, 1, 1],
                         signs[hs, 1, 2])


@numba.njit(cache=True, nogil=True)
def _slab_kernel(execute_fn, plans, v, w, layout, buffers, g, signs, c0, c1,
                 out):  # pragma: no cover - compiled
    """One FFT convolution product slab by slab (the class docstring); ``layout`` is
    ``(offsets, comp_stride)`` of the dipoles in the box, ``buffers`` ``(box_in, xmat,
    slab)``, the work arrays."""
    offsets, comp_stride = layout
    box_in, xmat, slab = buffers
    ms = xmat.shape[0]
    na = xmat.shape[2]
    nb = xmat.shape[3]
    ma = slab.shape[1]
    mb = slab.shape[2]
    n = offsets.shape[0]
    flat_in = box_in.reshape(-1)
    for d in range(n):
        o = offsets[d]
        for c in range(3):
            flat_in[o + c * comp_stride] = w[d, c] * v[3 * d + c]
    fftw.execute(execute_fn, plans[0])  # along s, box lines only, box_in -> xmat
    s0 = slab[0]
    s1 = slab[1]
    s2 = slab[2]
    for k in range(ms):
        # slabs 0, 1, M-1, 2, M-2, ...: f and M-f share their tensor
        f = (k + 1) // 2 if k % 2 == 1 else (ms - k // 2) % ms
        for c in range(3):
            for a in range(na):
                for b in range(nb):
                    slab[c, a, b] = xmat[f, c, a, b]
            for a in range(na, ma):
                for b in range(nb):
                    slab[c, a, b] = 0
        fftw.execute(execute_fn, plans[1])  # along a, occupied columns
        fftw.execute(execute_fn, plans[2])  # along b, all rows
        _slab_product(s0, s1, s2, g, f, ms, signs)
        fftw.execute(execute_fn, plans[3])  # back along b
        fftw.execute(execute_fn, plans[4])  # back along a, occupied columns
        for c in range(3):
            for a in range(na):
                for b in range(nb):
                    xmat[f, c, a, b] = slab[c, a, b]
            for a in range(ma):
                for b in range(nb, mb):
                    slab[c, a, b] = 0
    fftw.execute(execute_fn, plans[5])  # back along s, in place
    flat = xmat.reshape(-1)
    for d in range(n):
        o = offsets[d]
        for c in range(3):
            out[3 * d + c] = c0 * v[3 * d + c] + c1 * w[d, c] * flat[o + c * comp_stride]


@numba.njit(cache=True, nogil=True)
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


@numba.njit(cache=True, nogil=True)
def _scatter_box(field, v, w, ijk):  # pragma: no cover - compiled
    """``field[c, z, y, x] = w v`` at the dipoles (the rest zero)."""
    field[...] = 0
    for d in range(ijk.shape[0]):
        for c in range(3):
            field[c, ijk[d, 2], ijk[d, 1], ijk[d, 0]] = w[d, c] * v[3 * d + c]


@numba.njit(cache=True, nogil=True)
def _gather_box(field, v, w, ijk, c0, c1, out):  # pragma: no cover - compiled
    for d in range(ijk.shape[0]):
        for c in range(3):
            out[3 * d + c] = (c0 * v[3 * d + c]
                              + c1 * w[d, c] * field[c, ijk[d, 2], ijk[d, 1], ijk[d, 0]])


# -- the convolver --------------------------------------------------------------------------


class Convolver:
    """The interaction of the occupied voxels of one box, as a matrix-vector product.

    Parameters
    ----------
    interaction : Interaction
        The transformed tensor (its grid must hold the box: ``M >= 2 n`` on every axis).
    box : tuple of int
        ``(nx, ny, nz)``.
    ijk : ndarray of int, shape (N, 3)
        Box indices of the dipoles (all voxels of the box if None, in C order of ``(x, y, z)``).
    """

    def __init__(self, interaction: Interaction, box: tuple[int, int, int],
                 ijk: NDArray[np.integer] | None = None) -> None:
        grid = interaction.grid
        if any(2 * n > m for n, m in zip(box, grid, strict=True)):
            raise ValueError(f"box {box} does not fit the interaction grid {grid}")
        if ijk is None:
            ijk = np.stack(np.meshgrid(*(np.arange(n) for n in box), indexing="ij"),
                           axis=-1).reshape(-1, 3)
        ijk = np.ascontiguousarray(ijk, dtype=np.int64)
        if ijk.size and (ijk.min() < 0 or np.any(ijk.max(axis=0) >= np.asarray(box))):
            raise ValueError(f"dipole indices outside the box {box}")
        self.interaction = interaction
        self.box = tuple(int(n) for n in box)
        self.ijk = ijk
        self.n_dipoles = ijk.shape[0]
        self.dtype = interaction.dtype
        self.backend = "fftw" if fftw.available(self.dtype) else "numpy"
        if self.backend == "fftw":
            self._setup_slabs()
        else:
            nx, ny, nz = self.box
            self._field = np.zeros((3, nz, ny, nx), dtype=self.dtype)

    # -- FFTW slab algorithm ------------------------------------------------------------
    def _setup_slabs(self) -> None:
        grid = self.interaction.grid
        s = int(np.argmax(grid))
        a, b = (i for i in range(3) if i != s)
        if grid[a] > grid[b]:
            a, b = b, a
        order = (s, a, b)
        ms, ma, mb = (grid[i] for i in order)
        _, na, nb = (self.box[i] for i in order)
        dt = self.dtype
        self._box_in = fftw.aligned_zeros((ms, 3, na, nb), dt)
        self._xmat = fftw.aligned_zeros((ms, 3, na, nb), dt)
        self._slab = fftw.aligned_zeros((3, ma, mb), dt)
        lines = 3 * na * nb
        F, B = fftw.FORWARD, fftw.BACKWARD
        along_s = (ms, lines, lines, [(lines, 1, 1)])
        along_a = (ma, mb, mb, [(3, ma * mb, ma * mb), (nb, 1, 1)])
        along_b = (mb, 1, 1, [(3 * ma, mb, mb)])
        # the per-slab transforms run M_s times per product: worth FFTW's patient planner
        self._plans = [
            fftw.plan_dft(dt, *along_s, self._box_in, self._xmat, F),
            fftw.plan_dft(dt, *along_a, self._slab, self._slab, F, patient=True),
            fftw.plan_dft(dt, *along_b, self._slab, self._slab, F, patient=True),
            fftw.plan_dft(dt, *along_b, self._slab, self._slab, B, patient=True),
            fftw.plan_dft(dt, *along_a, self._slab, self._slab, B, patient=True),
            fftw.plan_dft(dt, *along_s, self._xmat, self._xmat, B),
        ]
        self._plan_ptrs = np.array([p.pointer for p in self._plans], dtype=np.int64)
        self._execute = fftw.execute_address(dt)
        # planning (FFTW_MEASURE) overwrote the buffers
        for buf in (self._box_in, self._xmat, self._slab):
            buf[...] = 0
        self._tensor, self._signs = self.interaction.slab_tensor(order)
        ijk = self.ijk
        self._comp_stride = na * nb
        self._offsets = np.ascontiguousarray(
            (ijk[:, s] * 3 * na + ijk[:, a]) * nb + ijk[:, b], dtype=np.int64)

    # -- public -------------------------------------------------------------------------
    def product(self, v: NDArray, w: NDArray, c0: float = 1.0, c1: float = -1.0,
                out: NDArray | None = None) -> NDArray[np.complex128]:
        """``out_i = c0 v_i + c1 w_i sum_j G_ij (w_j v_j)`` over the dipoles.

        Parameters
        ----------
        v : ndarray of complex, shape (3 N,)
            Vector, dipole-major (``v[3 i + c]``).
        w : ndarray of complex, shape (N,) or (N, 3)
            Diagonal weights (square roots of the polarisabilities).
        c0, c1 : float
            Coefficients.
        out : ndarray of complex128, shape (3 N,), optional
            Output buffer.
        """
        v = np.ascontiguousarray(v, dtype=np.complex128).reshape(-1)
        w = np.asarray(w, dtype=np.complex128)
        if w.ndim == 1:
            w = np.repeat(w[:, None], 3, axis=1)
        w = np.ascontiguousarray(w)
        if v.shape[0] != 3 * self.n_dipoles or w.shape != (self.n_dipoles, 3):
            raise ValueError(
                f"expected vectors for {self.n_dipoles} dipoles, got {v.shape} and {w.shape}")
        if out is None:
            out = np.empty(3 * self.n_dipoles, dtype=np.complex128)
        if self.backend == "fftw":
            _slab_kernel(self._execute, self._plan_ptrs, v, w,
                         (self._offsets, self._comp_stride),
                         (self._box_in, self._xmat, self._slab), self._tensor, self._signs,
                         float(c0), float(c1), out)
            return out
        _scatter_box(self._field, v, w, self.ijk)
        self._convolve_numpy(self._field)
        _gather_box(self._field, v, w, self.ijk, float(c0), float(c1), out)
        return out

    def convolve(self, v: NDArray) -> NDArray[np.complex128]:
        """``sum_j G_ij v_j`` (shape (3 N,)), the plain convolution."""
        ones = np.ones((self.n_dipoles, 3), dtype=np.complex128)
        return self.product(v, ones, 0.0, 1.0)

    def _convolve_numpy(self, field: NDArray) -> None:
        mx, my, mz = self.interaction.grid
        nx, ny, nz = self.box
        b = np.fft.fft(field, n=mz, axis=1)
        b = np.fft.fft(b, n=my, axis=2)
        b = np.fft.fft(b, n=mx, axis=3)
        _tensor_apply(self.interaction.g_oct, b, mz, my, mx)
        b = np.fft.ifft(b, axis=3)[..., :nx]
        b = np.fft.ifft(b, axis=2)[:, :, :ny]
        field[...] = np.fft.ifft(b, axis=1)[:, :nz]
