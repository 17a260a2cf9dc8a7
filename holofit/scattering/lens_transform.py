"""The radial transforms of the lens image: quadrature over the pupil, Bessel tables, and the
tables or polar grid that the pixels are interpolated from.

For one height ``z_p`` and azimuthal order ``m``,

    G_m(rho_j) = sum_i w_i sin th_i t_m(th_i) exp(i k z_p cos th_i) J_m(k rho_j sin th_i),

Gauss-Legendre nodes ``th_i`` over the aperture (:func:`node_count` of them) and a uniform radial
grid ``rho_j = j h``, ``h = STEP / (k sin th_max)`` (the image is band-limited to spatial
frequencies ``k sin th_max``). With the Bessel values ``J_m(j x_i)``, ``x_i = k h sin th_i``,
tabulated once (they depend on the aperture and the node count only, not on the particle or its
height), a height costs one real matrix product per order.

Accuracy (measured against the brute-force pupil integral of tests/lens_reference.py, over NA
0.8-1.45, z from -10 to 30 um, pixel reach 4-15 um, spheres and a DDA rod): the node rule keeps
the quadrature error below 1e-9 of the field; the 8-point Lagrange interpolation sets the error,
at most 2.2e-7 of the field at ``STEP = 0.5`` (NA 0.8, z 25 um, reach 15 um; 1e-8 to 1e-7
elsewhere), 4e-8 at ``STEP = 0.4``, 1e-6 at ``STEP = 0.7``. The fits need far less (the pixel
noise is ~1e-2 of the field); ``STEP = 0.5`` and the node rule below cost 0.6 of the
``STEP = 0.4`` rule that keeps 1e-10 everywhere.

Bessel tables of many orders (any image but a sphere's) are kept in single precision
(:data:`TABLE_DTYPE`), and their products with the pupil field are single-precision matrix
products: the rounding (~6e-8 of each term) adds ~1e-7 of the image's largest value (the DDA
rod of tests/test_lens.py against the brute-force integral, double -> single precision tables,
FFT and planes: 4e-8 -> 1.7e-7 at NA 1.2, 2e-8 -> 8e-8 at NA 1.45, 1.2e-7 -> 2.0e-7 at NA 0.9;
the tests' bound is 1e-6, the pixel noise of a fit ~1e-2); the table takes half the memory and
the product, which reads the whole table once per image, runs about twice as fast. Entries too
small to change a single-precision sum are stored as zeros (:data:`FLUSH`): subnormal numbers
would slow the product several times over. The polar grid's FFT stays in single precision, and
the grid keeps its single-precision values: its four real planes interleaved per node (shape
``(rows, columns, 4)``), so that the pixel kernel's stencil rows are contiguous runs whose four
sums vectorise, converted to double precision as they are read. The spectrum is assembled and
transformed in place inside the padded grid (no copy). Measured (``bench/polar_kernel_ab.py``,
CPU time, one core, the rod's and the Janus particle's grids, 19600 pixels) against the
previous separate double-precision planes: the pixel interpolation 0.55-0.66 of the time, the
grids 0.77-0.8, the grids equal value for value and the images to 6e-16 of their largest value.
A table is built once per pupil rule and radial step with every order the source can need
(:func:`radial_transform`'s ``max_orders``), so that waves of the same particle whose small
high orders were trimmed away share it.
"""

from __future__ import annotations

import threading
from collections import OrderedDict

import numpy as np
import scipy.fft as sfft
from numpy.typing import NDArray
from scipy import special

from holofit.scattering.lens_kernels import POLAR_STENCIL, bessel_planes, polar_spectrum

__all__ = ["MAX_NODES", "STENCIL", "STEP", "node_count", "polar_grid", "polar_grids",
           "radial_transform", "sphere_table_columns", "sphere_tables"]

#: Lagrange stencil (points per axis; the compiled kernels' constant) and radial step times the
#: band limit k sin(th_max)
STENCIL = POLAR_STENCIL
STEP = 0.5
#: polar-grid step in phi times (highest azimuthal order + 1); the orders near the highest kept
#: are small, so this is coarser than the radial step at the same accuracy (tested up to 1.6)
PHI_STEP = 1.0
#: quadrature rule: NODES_PER_RAD * phase variation + NODES_EXTRA, rounded up to a multiple of
#: NODES_ROUND (so that small moves keep the nodes and their Bessel tables)
NODES_PER_RAD = 0.4
NODES_EXTRA = 16
NODES_ROUND = 16
#: the Bessel tables kept, in bytes; a single table bigger than this is computed in row blocks
BESSEL_CACHE_BYTES = 128 * 2**20
#: element type of the tables of many orders (the sphere's two orders stay double precision)
TABLE_DTYPE = np.float32
#: a new table of many orders gets this many times the rows asked for
ROW_MARGIN = 1.05
BLOCK_BYTES = 32 * 2**20
BLOCK_TABLE_BYTES = 2**19
#: single-precision table entries below this (``|J_m| <= 1``), and pupil-field entries below
#: this share of the field's largest, are set to zero: they change no sum at single
#: precision (6e-8), while the subnormal numbers that the high orders near the axis would
#: otherwise hold, and their products, run the matrix product several times slower
FLUSH = 1e-15


#: most Gauss-Legendre nodes over the pupil (~z = 2 mm at NA 1.2): beyond, a fit's trial step
#: has wandered off, and the nodes' eigenvalue problem alone would take minutes
MAX_NODES = 8192


def node_count(k: float, z_um: float, rho_max_um: float, theta_max: float, order: int,
               pupil_phase_rad: float = 0.0) -> int:
    """Gauss-Legendre nodes over the pupil for a height, a pixel reach and a far-field order.

    The integrand's phase varies by ``k |z| (1 - cos th_max) + k rho_max sin th_max`` over the
    pupil, a far field of multipole order L by about ``L th_max``, and an aberrated pupil by
    its phase's total variation ``pupil_phase_rad`` (:mod:`holofit.aberration`; 0 for the
    ideal objective, which leaves the rule as it was).
    """
    variation = (k * abs(z_um) * (1.0 - np.cos(theta_max)) + k * rho_max_um * np.sin(theta_max)
                 + order * theta_max)
    if pupil_phase_rad:
        variation += abs(float(pupil_phase_rad))
    n = NODES_PER_RAD * variation + NODES_EXTRA
    if not n <= MAX_NODES:  # also NaN
        raise ValueError(
            f"the lens image at z = {z_um:.4g} um over {rho_max_um:.4g} um of pixels would need "
            f"{n:.3g} pupil nodes (at most {MAX_NODES}): the particle is implausibly far from "
            "the focal plane or from its pixels")
    return int(np.ceil(n / NODES_ROUND) * NODES_ROUND)


# -- Bessel tables ---------------------------------------------------------------------------

#: a table is a tuple of row blocks (a grown table keeps its old rows and adds a block)
_BESSEL: OrderedDict[tuple, tuple[NDArray, ...]] = OrderedDict()
_BESSEL_LOCK = threading.Lock()


def clear_cache() -> None:
    """Forget the cached Bessel tables."""
    with _BESSEL_LOCK:
        _BESSEL.clear()


def _bessel_rows(x_step: NDArray, rows: range, orders: int | None) -> NDArray:
    """``J_m(j x_step[i])`` for j in ``rows``: shape (n_orders, len(rows), n_nodes).

    ``orders`` None: the sphere's orders 0 and 2 (double precision); an int M: every order
    0..M (:data:`TABLE_DTYPE`), in the (order, row, node) layout of the matrix products.
    """
    j = np.arange(rows.start, rows.stop, dtype=float)
    x = j[:, None] * x_step[None, :]
    if orders is None:
        j0 = special.j0(x)
        with np.errstate(divide="ignore", invalid="ignore"):
            j2 = np.where(x > 0, 2.0 * special.j1(x) / x - j0, 0.0)
        return np.stack([j0, j2])
    out = np.empty((orders + 1, j.size, x_step.size), dtype=TABLE_DTYPE)
    # a block of rows at a time, so that the block's orders stay in cache
    block = max(1, BLOCK_TABLE_BYTES // (out.itemsize * (orders + 1) * x_step.size))
    for start in range(0, j.size, block):
        stop = min(j.size, start + block)
        flat = x[start:stop].ravel()
        view = out[:, start:stop].reshape(orders + 1, flat.size)
        bessel_planes(flat, special.j0(flat), special.j1(flat), orders, view)
    out[np.abs(out) < FLUSH] = 0.0
    return out


def _table_bytes(n_orders: int, n_rho: int, n_nodes: int, sphere: bool) -> int:
    """Size of a Bessel table, bytes."""
    return n_orders * n_rho * n_nodes * (8 if sphere else np.dtype(TABLE_DTYPE).itemsize)


def _cached_table(x_step: NDArray, n_rho: int, orders: int | None,
                  key: tuple) -> tuple[NDArray, ...]:
    """A cached Bessel table with at least ``n_rho`` rows and the orders asked for, as row
    blocks (shape ``(n_orders, rows_b, n_nodes)`` each, in row order).

    Tables are shared by everything with the same nodes and radial step (``key``); a table with
    more orders or rows serves fewer. A table asked for more rows than it has (a fit's trial
    step farther from its pixels) gets the new rows as a new block: neither its old rows are
    recomputed nor the table copied (a 100 MB copy into fresh memory costs ~0.1-0.5 s under
    load). The cache is bounded by :data:`BESSEL_CACHE_BYTES`.
    """
    n_orders = 2 if orders is None else orders + 1
    with _BESSEL_LOCK:
        blocks = _BESSEL.get(key)
        if blocks is not None and blocks[0].shape[0] >= n_orders and _rows(blocks) >= n_rho:
            _BESSEL.move_to_end(key)
            return blocks
    if blocks is not None and blocks[0].shape[0] >= n_orders:
        rows = _rows(blocks)
        more = _bessel_rows(x_step, range(rows, max(n_rho, int(1.1 * rows))),
                            None if orders is None else blocks[0].shape[0] - 1)
        blocks = (*blocks, more)
    else:
        if blocks is not None:  # grow, with a little room for the next few moves
            rows = _rows(blocks)
            n_rho = max(n_rho, int(1.1 * rows)) if rows < n_rho else rows
            if orders is not None:
                orders = max(orders, blocks[0].shape[0] - 1)
        elif orders is not None:  # room for a fit's small moves of the particle
            n_rho = int(ROW_MARGIN * n_rho)
        blocks = (_bessel_rows(x_step, range(n_rho), orders),)
    with _BESSEL_LOCK:
        _BESSEL[key] = blocks
        _BESSEL.move_to_end(key)
        while len(_BESSEL) > 1 and sum(
                b.nbytes for bs in _BESSEL.values() for b in bs) > BESSEL_CACHE_BYTES:
            _BESSEL.popitem(last=False)
    return blocks


def _rows(blocks: tuple[NDArray, ...]) -> int:
    return sum(b.shape[1] for b in blocks)


def radial_transform(x_step: NDArray, h: NDArray[np.complex128], n_rho: int,
                     orders: int | None, key: tuple,
                     max_orders: int | None = None) -> NDArray[np.complex128]:
    """``G[o, j, c] = sum_i J_{m_o}(j x_step[i]) h[o, i, c]`` for ``j = 0..n_rho-1``.

    Parameters
    ----------
    x_step : ndarray, shape (n_nodes,)
        ``k h sin th_i``.
    h : ndarray of complex, shape (n_orders, n_nodes, n_cols)
        Weighted pupil field per order.
    n_rho : int
        Radial samples.
    orders : int or None
        None: orders (0, 2) (a sphere); M: orders 0..M.
    key : tuple
        Identifies ``x_step`` (the nodes and the radial step) for the Bessel cache.
    max_orders : int, optional
        The most orders the same source can ask for (its untrimmed highest order): a new
        table is built with them, when it fits the cache, so that it is built once.

    Returns
    -------
    ndarray of complex, shape (n_orders, n_rho, n_cols)
        Double precision for a sphere (``orders`` None), :data:`TABLE_DTYPE`'s complex type
        otherwise.
    """
    n_orders, n_nodes, n_cols = h.shape
    sphere = orders is None
    if _table_bytes(n_orders, n_rho, n_nodes, sphere) <= BESSEL_CACHE_BYTES:
        if orders is not None and max_orders is not None and max_orders > orders and _table_bytes(
                max_orders + 1, int(ROW_MARGIN * n_rho), n_nodes, sphere) <= BESSEL_CACHE_BYTES:
            orders = max_orders
        blocks = _cached_table(x_step, n_rho, orders, (sphere, *key))
    else:
        blocks = None
    real = np.dtype(np.float64 if sphere else TABLE_DTYPE)
    cplx = np.result_type(real, np.complex64)
    # (o, i, 2c): real and imaginary parts as columns of reals
    hr = np.ascontiguousarray(h, dtype=cplx).view(real)
    if not sphere:
        hr = np.where(np.abs(hr) < FLUSH * np.abs(hr).max(), real.type(0.0), hr)
    if blocks is not None and len(blocks) == 1:
        out = np.matmul(blocks[0][:n_orders, :n_rho], hr)
    elif blocks is not None:
        out = np.empty((n_orders, n_rho, 2 * n_cols), dtype=real)
        start = 0
        for b in blocks:
            stop = min(n_rho, start + b.shape[1])
            if stop > start:
                out[:, start:stop] = np.matmul(b[:n_orders, : stop - start], hr)
            start = stop
    else:
        out = np.empty((n_orders, n_rho, 2 * n_cols), dtype=real)
        block = max(1, BLOCK_BYTES // _table_bytes(n_orders, 1, n_nodes, sphere))
        for start in range(0, n_rho, block):
            rows = range(start, min(n_rho, start + block))
            out[:, rows.start:rows.stop] = np.matmul(_bessel_rows(x_step, rows, orders), hr)
    return out.view(cplx)


# -- what the pixels are interpolated from ---------------------------------------------------


def sphere_tables(a: NDArray, b: NDArray, base: NDArray, x_step: NDArray, n_rho: int,
                  key: tuple) -> tuple[NDArray[np.complex128], NDArray[np.complex128]]:
    """Radial tables of a sphere's image, in the frame of the polarisation.

    ``E_x' = -(G_0 - G_2 cos 2ph')`` and ``E_y' = G_2 sin 2ph'`` (``i^2 = -1``), so the tables
    are ``(-G_0, G_2)``, with ``G_0`` from ``a`` and ``J_0``, ``G_2`` from ``b`` and ``J_2``,
    ``base = w sin th exp(ik z cos th) exp(-ikz)`` at the nodes. Rows ``< STENCIL`` hold negative
    ``rho`` (both are even in ``rho``).
    """
    h = np.stack([base * a, base * b])[:, :, None]
    g = radial_transform(x_step, h, n_rho, None, key)[:, :, 0]
    return _reflect_rows(-g[0]), _reflect_rows(g[1])


def sphere_table_columns(a: NDArray, b: NDArray, bases: list[NDArray], x_step: NDArray,
                         n_rho: int, key: tuple
                         ) -> list[tuple[NDArray[np.complex128], NDArray[np.complex128]]]:
    """:func:`sphere_tables` for several nodes' factors over the same nodes (e.g. the exact
    derivatives of the image with respect to the height or an aberration coefficient, whose
    factors are ``base`` times ``d(phase)/d(parameter)``), in one pass over the Bessel table:
    the product reads the table once, whatever its number of columns."""
    h = np.stack([np.stack([f * a, f * b]) for f in bases], axis=-1)  # (2, nodes, columns)
    g = radial_transform(x_step, h, n_rho, None, key)
    return [(_reflect_rows(-g[0, :, c]), _reflect_rows(g[1, :, c])) for c in range(len(bases))]


def polar_grid(t_plus: NDArray, t_minus: NDArray, base: NDArray, x_step: NDArray, n_rho: int,
               key: tuple, max_order: int | None = None) -> NDArray[np.floating]:
    """The image ``(E_x, E_y)`` on a polar grid ``[rho row, phi column]``, as the four real
    planes ``(Re E_x, Im E_x, Re E_y, Im E_y)`` interleaved per node (the tables'
    precision) that :func:`~holofit.scattering.lens_kernels.polar_pixels` interpolates (shape
    ``(rows, columns, 4)``).

    ``E_+- = -sum_m i^m exp(i m ph) G_m^+-`` (an FFT over m per row) for the circular
    components ``T_+- = T_x +- i T_y`` of the pupil field, ``E_x = (E_+ + E_-)/2``,
    ``E_y = (E_+ - E_-)/(2i)``. Rows ``< STENCIL`` hold negative ``rho``
    (``E(-rho, ph) = E(rho, ph + pi)``); ``STENCIL`` columns on each side repeat the period.
    ``max_order``: the highest azimuthal order the source can have (see
    :func:`radial_transform`).
    """
    return polar_grids([(t_plus, t_minus, base)], x_step, n_rho, key, max_order)[0]


def polar_grids(fields: list[tuple[NDArray, NDArray, NDArray]], x_step: NDArray, n_rho: int,
                key: tuple, max_order: int | None = None) -> NDArray[np.floating]:
    """:func:`polar_grid` of several pupil fields over the same nodes (e.g. a wave's
    derivatives), shape ``(F, rows, columns, 4)``: one pass over the Bessel table for all of
    them (the product reads the table once, whatever its number of columns), one FFT call.

    ``fields``: per field ``(t_plus, t_minus, base)``, the modes of any (odd) widths
    (narrower ones, trimmed orders, are padded with zeros to the widest) and the nodes'
    factor (:func:`polar_grid`'s ``base``; its height derivative gives the image's).
    """
    mmax = max((tp.shape[1] - 1) // 2 for tp, _, _ in fields)
    m = np.arange(mmax + 1)
    sign = ((-1.0) ** m)[:, None]
    n_f = len(fields)
    # E_x = -(E_+ + E_-)/2 and E_y = i (E_+ - E_-)/2 are combined before the (linear)
    # transforms: h[|m|, node, (X at +m, X at -m, Y at +m, Y at -m) per field],
    # J_{-m} = (-1)^m J_m; stored in the tables' complex type (the product's, rounded once)
    h = np.zeros((mmax + 1, x_step.size, 4 * n_f), dtype=np.result_type(TABLE_DTYPE, np.complex64))
    for f, (t_plus, t_minus, base) in enumerate(fields):
        mf = (t_plus.shape[1] - 1) // 2
        tx = (-0.5 * base)[:, None] * (t_plus + t_minus)
        ty = (0.5j * base)[:, None] * (t_plus - t_minus)
        for c, t in enumerate((tx, ty)):
            h[: mf + 1, :, 4 * f + 2 * c] = t[:, mf:].T
            h[: mf + 1, :, 4 * f + 2 * c + 1] = t[:, mf::-1].T * sign[: mf + 1]
    g = radial_transform(x_step, h, n_rho, mmax, key, max_order)  # (|m|, rho, column)
    # even (rho -> -rho is a shift by half a period) and FFT-friendly (a large prime factor
    # costs pocketfft several times more)
    n_phi = 2 * sfft.next_fast_len(max(int(np.ceil(np.pi * (mmax + 1) / PHI_STEP)),
                                       mmax + 1), real=False)
    # in the tables' precision (single: see the module docstring). The spectrum is written
    # into the padded grid itself, [field, rho row, phi column, (X, Y)] as complex values, and
    # transformed there (in place): read as reals, it is the interleaved
    # (Re X, Im X, Re Y, Im Y) that the pixel kernel reads, with no copy
    s = STENCIL
    out = np.empty((n_f, n_rho + s, n_phi + 2 * s, 4), dtype=g.real.dtype)
    spec = out[:, s:, s : s + n_phi].view(g.dtype)  # (n_f, n_rho, n_phi, 2)
    polar_spectrum(g, mmax, spec)
    fields = sfft.ifft(spec, axis=2, norm="forward", overwrite_x=True)
    if not np.shares_memory(fields, out):  # a scipy.fft that does not transform in place
        spec[...] = fields
    for f in range(n_f):
        _pad(out[f], n_phi)
    return out


def _reflect_rows(g: NDArray) -> NDArray:
    """Prepend ``STENCIL`` rows for negative rho (an even function of rho)."""
    return np.ascontiguousarray(np.concatenate([g[1 : STENCIL + 1][::-1], g]))


def _pad(out: NDArray[np.floating], n_phi: int) -> NDArray[np.floating]:
    """Fill the padding of an interleaved polar grid ``out`` (shape
    ``(n_rho + STENCIL, n_phi + 2 STENCIL, 4)``) whose core ``out[STENCIL:, STENCIL:STENCIL +
    n_phi]`` holds ``(Re E_x, Im E_x, Re E_y, Im E_y)``: ``STENCIL`` rows for negative rho
    (``g(-rho, ph) = g(rho, ph + pi)``) and ``STENCIL`` columns on each side repeating the
    period in ``ph``."""
    s = STENCIL
    core = out[s:, s : s + n_phi]
    half = n_phi // 2
    mirror = core[1 : s + 1][::-1]
    out[:s, s : s + half] = mirror[:, half:]
    out[:s, s + half : s + n_phi] = mirror[:, :half]
    out[:, :s] = out[:, n_phi : n_phi + s]
    out[:, s + n_phi :] = out[:, s : 2 * s]
    return out
