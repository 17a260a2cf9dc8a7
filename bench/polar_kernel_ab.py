"""The lens image's polar grid and pixel interpolation against their previous implementation,
in one process (``python bench/polar_kernel_ab.py [rod|janus] [--repeat N]``): prints JSON.

The grids are the final pass's particle's (:mod:`track_cases`: its T-matrix, cached in
``bench/.cache/``) at the track's heights, at the pixels of a 140 x 140 crop centred on the
particle: one field (a new height, :meth:`LensImage.field_on_pixels`) and three (a wave with
two derivative waves, :func:`lens_fields_on_pixels`).

* ``polar_pixels``: the interleaved single-precision grid ``(rows, columns, 4)`` of
  :func:`holofit.scattering.lens_transform.polar_grids` against the previous loop over four
  separate double-precision planes ``(4, rows, columns)`` holding the same values
  (:func:`_planar_pixels` below). Reported: the mean CPU time per call of each (the process's,
  less sensitive to other jobs than wall time), called alternately, their ratio, and the
  largest difference of the images relative to their largest value.
* ``polar_grids``: the current function against the previous assembly (a zeroed spectrum
  array filled by transposed copies, an FFT, a copy into four padded double planes,
  :func:`_planar_grids` below); the grids must be equal value for value.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numba
import numpy as np
import scipy.fft as sfft

sys.path.insert(0, str(Path(__file__).resolve().parent))

from fit_cases import make_case, use_tmatrix

from holofit.scattering import lens_transform as lt
from holofit.scattering.lens import lens_image
from holofit.scattering.lens_kernels import (
    FASTMATH,
    POLAR_STENCIL,
    _node_factors,
    _weights,
    polar_pixels,
)
from holofit.scattering.theory import Orientation

CACHE = Path(__file__).resolve().parent / ".cache"
CROP = 140


@numba.njit(nogil=True, fastmath=FASTMATH, inline="always")
def _planar_stencil(plane, i0, j0, wr, wp):  # pragma: no cover - compiled
    s = 0.0
    for a in range(8):
        r = 0.0
        for b in range(8):
            r += wp[b] * plane[i0 + a, j0 + b]
        s += wr[a] * r
    return s


@numba.njit(nogil=True, fastmath=FASTMATH)
def _planar_pixels(t, u, g, ex, ey):  # pragma: no cover - compiled
    """The previous kernel: four separate planes ``g[p, row, column]``."""
    half = POLAR_STENCIL // 2 - 1
    c = _node_factors(POLAR_STENCIL)
    wr = np.empty(POLAR_STENCIL)
    wp = np.empty(POLAR_STENCIL)
    g0, g1, g2, g3 = g[0], g[1], g[2], g[3]
    for q in range(t.shape[0]):
        i0 = int(t[q]) - half
        _weights(t[q] - i0, POLAR_STENCIL, c, wr)
        j0 = int(u[q]) - half
        _weights(u[q] - j0, POLAR_STENCIL, c, wp)
        ex[q] = complex(_planar_stencil(g0, i0, j0, wr, wp), _planar_stencil(g1, i0, j0, wr, wp))
        ey[q] = complex(_planar_stencil(g2, i0, j0, wr, wp), _planar_stencil(g3, i0, j0, wr, wp))


def _planar_grids(fields, x_step, n_rho, key, max_order):
    """The previous assembly of :func:`lens_transform.polar_grids`, shape (F, 4, rows, cols)."""
    mmax = max((tp.shape[1] - 1) // 2 for tp, _, _ in fields)
    m = np.arange(mmax + 1)
    sign = ((-1.0) ** m)[:, None]
    n_f = len(fields)
    h = np.zeros((mmax + 1, x_step.size, 4 * n_f), dtype=complex)
    for f, (t_plus, t_minus, base) in enumerate(fields):
        mf = (t_plus.shape[1] - 1) // 2
        tx = (-0.5 * base)[:, None] * (t_plus + t_minus)
        ty = (0.5j * base)[:, None] * (t_plus - t_minus)
        for c, t in enumerate((tx, ty)):
            h[: mf + 1, :, 4 * f + 2 * c] = t[:, mf:].T
            h[: mf + 1, :, 4 * f + 2 * c + 1] = t[:, mf::-1].T * sign[: mf + 1]
    g = lt.radial_transform(x_step, h, n_rho, mmax, key, max_order)
    n_phi = 2 * sfft.next_fast_len(max(int(np.ceil(np.pi * (mmax + 1) / lt.PHI_STEP)),
                                       mmax + 1), real=False)
    spec = np.zeros((2 * n_f, n_rho, n_phi), dtype=g.dtype)
    up = (1j**m).astype(g.dtype)[:, None, None] * g[:, :, 0::2]
    down = (1j ** (-m[1:])).astype(g.dtype)[:, None, None] * g[1:, :, 1::2]
    spec[:, :, : mmax + 1] = np.transpose(up, (2, 1, 0))
    spec[:, :, n_phi - mmax :] = np.transpose(down[::-1], (2, 1, 0))
    fld = sfft.ifft(spec, axis=2, norm="forward", overwrite_x=True)
    s = lt.STENCIL
    out = np.empty((n_f, 4, n_rho + s, n_phi + 2 * s))
    for f in range(n_f):
        core = out[f][:, s:, s : s + n_phi]
        core[0::2] = fld[2 * f : 2 * f + 2].real
        core[1::2] = fld[2 * f : 2 * f + 2].imag
        half = n_phi // 2
        mirror = core[:, 1 : s + 1][:, ::-1]
        out[f][:, :s, s : s + half] = mirror[:, :, half:]
        out[f][:, :s, s + half : s + n_phi] = mirror[:, :, :half]
        out[f][:, :, :s] = out[f][:, :, n_phi : n_phi + s]
        out[f][:, :, s + n_phi :] = out[f][:, :, s : 2 * s]
    return out


def _grid_inputs(name: str):
    """The polar_grids calls of the track's heights: (fields, x_step, n_rho, key, max_order)
    and the crop's pixel coordinates (t, u) for each."""
    case = make_case(name)
    model, theory = case.fit_model()
    CACHE.mkdir(exist_ok=True)
    use_tmatrix(theory, model, case.inst, CACHE / f"{name}_final_tmatrix.npz")
    o = case.orientation
    waves = [theory.solve(model, case.inst.optics, Orientation(o.psi + d, o.theta - d))
             for d in (0.0, 0.01, 0.02)]
    images = [lens_image(w) for w in waves]
    k = case.inst.optics.k
    px = case.inst.pixel_size_um
    theta_max = images[0].aperture_angle()
    xs = (np.arange(CROP) - CROP / 2 + 0.37) * px
    dx, dy = np.meshgrid(xs, xs + 0.11 * px)
    rho = np.hypot(dx, dy).ravel()
    calls = []
    for z in (12.0, 11.5, 12.7):
        n_nodes = lt.node_count(k, z, float(rho.max()), theta_max, images[0].source.order)
        step = lt.STEP / (k * np.sin(theta_max))
        n_rho = int(np.ceil(float(rho.max()) / step)) + lt.STENCIL // 2 + 2
        pupils = [im._pupil(theta_max, n_nodes) for im in images]
        p = pupils[0]
        x_step = k * step * np.sin(p.theta)
        base = p.weights * np.sin(p.theta) * np.exp(1j * k * z * (np.cos(p.theta) - 1.0))
        key = (round(k * step, 12), *p.key)
        order = images[0].source.order + 1
        for n_f in (1, 3):
            calls.append(([(*q.modes, base) for q in pupils[:n_f]], x_step, n_rho, key, order))
    t = rho / step + lt.STENCIL
    return calls, t, np.arctan2(dy, dx).ravel()


def run(name: str, repeat: int) -> dict[str, float]:
    calls, t, phi = _grid_inputs(name)
    # grids: equal value for value, and timed alternately
    new_grids = [lt.polar_grids(*c) for c in calls]  # (also compiles, fills the table cache)
    old_grids = [_planar_grids(*c) for c in calls]
    tg_old, tg_new = [], []
    for _ in range(repeat):
        for c in calls:
            t0 = time.process_time()
            _planar_grids(*c)
            t1 = time.process_time()
            lt.polar_grids(*c)
            t2 = time.process_time()
            tg_old.append(t1 - t0)
            tg_new.append(t2 - t1)
    equal = all(np.array_equal(np.moveaxis(o, 1, 3), n)
                for o, n in zip(old_grids, new_grids, strict=True))
    # pixels: every grid of the one-field calls, old and new alternately
    tp_old, tp_new, diff = [], [], 0.0
    ex = np.empty(t.size, dtype=complex)
    ey = np.empty(t.size, dtype=complex)
    ex0 = np.empty(t.size, dtype=complex)
    ey0 = np.empty(t.size, dtype=complex)
    u = np.zeros_like(t)
    _planar_pixels(t, u + 8.0, old_grids[0][0], ex0, ey0)  # compile before timing
    polar_pixels(t, u + 8.0, new_grids[0][0], ex, ey)
    for _ in range(3 * repeat):
        for o, n in zip(old_grids, new_grids, strict=True):
            n_phi = n.shape[2] - 2 * lt.STENCIL
            u = phi * (n_phi / (2.0 * np.pi))
            u[u < 0] += n_phi
            u += lt.STENCIL
            t0 = time.process_time()
            _planar_pixels(t, u, o[0], ex0, ey0)
            t1 = time.process_time()
            polar_pixels(t, u, n[0], ex, ey)
            t2 = time.process_time()
            tp_old.append(t1 - t0)
            tp_new.append(t2 - t1)
            scale = max(np.abs(ex0).max(), np.abs(ey0).max())
            diff = max(diff, np.abs(ex - ex0).max() / scale, np.abs(ey - ey0).max() / scale)
    return {
        f"polar_pixels_{name}_old_s": float(np.mean(tp_old)),
        f"polar_pixels_{name}_new_s": float(np.mean(tp_new)),
        f"polar_pixels_{name}_ratio": float(np.sum(tp_new) / np.sum(tp_old)),
        f"polar_pixels_{name}_max_rel_diff": float(diff),
        f"polar_grids_{name}_old_s": float(np.mean(tg_old)),
        f"polar_grids_{name}_new_s": float(np.mean(tg_new)),
        f"polar_grids_{name}_ratio": float(np.sum(tg_new) / np.sum(tg_old)),
        f"polar_grids_{name}_equal": float(equal),
        f"polar_{name}_pixels": float(t.size),
    }


if __name__ == "__main__":
    parser = argparse.ArgumentParser()
    parser.add_argument("case", choices=("rod", "janus"), nargs="?", default="rod")
    parser.add_argument("--repeat", type=int, default=20)
    args = parser.parse_args()
    print(json.dumps(run(args.case, args.repeat)))
