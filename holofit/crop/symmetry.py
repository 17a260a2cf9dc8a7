"""Sub-pixel hologram centres from point symmetry.

The hologram of a sphere is symmetric under inversion through its centre, ``I(c + u) =
I(c - u)`` (rotating the set-up by pi about the optical axis flips the polarisation and the
transverse field together, which leaves the intensity unchanged). With ``f`` the hologram minus
its median and ``P_m(u)`` a pair weight even in ``u`` (a Gaussian of width ``sigma`` centred on
the trial centre ``m``, times the validity of both pixels of the pair), the centre is the point
that minimises the mean squared asymmetry per unit pair weight,

    A(m) = sum_u P_m(u) (f(m + u) - f(m - u))^2 / sum_u P_m(u) = 2 (D(m) - N(m)) / W(m),

with ``N = sum P f(m+u) f(m-u)``, ``D = sum P f(m+u)^2`` and ``W = sum P``. At the true centre
the signal part of ``A`` vanishes for any set of valid pairs, and camera noise adds the same
``2 sigma_noise^2`` everywhere, so pixels outside the frame, masked pixels and the finite window
bias nothing: they drop whole pairs. The normalised *symmetry score* ``S = N / D`` (at most 1
by Cauchy-Schwarz, 1 for perfect symmetry) is reported for accepting or rejecting candidates.

With a Gaussian window ``w`` centred on the integer pixel ``c0`` the pair weight factorises,
``w(r - c0) w(s - r - c0) = exp(-(2r - s)^2 / 4 sigma^2) exp(-(s - 2 c0)^2 / 4 sigma^2)``, so
for every ``s = 2 m`` at once ``N``, ``D`` and ``W`` are the FFT convolutions
``(w M f) * (w M f)``, ``(w M f^2) * (w M)`` and ``(w M) * (w M)`` (``M`` the validity mask;
the second Gaussian factor is common to all three and cancels exactly in ``A`` and ``S``).
This gives ``A`` on the half-pixel lattice of trial centres; a quadratic fit to the 3 x 3
neighbourhood of its minimum gives the sub-pixel centre.

Near an edge only a strip of pairs along it survives, which pins the centre along the edge but
hardly across it: :func:`refine_center` reports the fraction of the pair weight still valid,
and the centre finder switches to :mod:`holofit.crop.radial` when it is small.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import scipy.fft as sfft
from numpy.typing import NDArray

from holofit.crop.transform import exact_median

__all__ = ["SymmetryFit", "quadratic_peak", "refine_center"]


@dataclass(frozen=True)
class SymmetryFit:
    """Result of :func:`refine_center`.

    Attributes
    ----------
    x_px, y_px : float
        Centre, full-frame pixels (x = column, y = row).
    symmetry : float
        Normalised symmetry score at the centre (1 = perfectly point-symmetric).
    converged : bool
        The optimum lies inside the search disc (not on its rim) after the iterations.
    iterations : int
        Windows evaluated.
    pair_fraction : float
        Valid fraction of the pair weight at the centre (1 far from edges and masks).
    """

    x_px: float
    y_px: float
    symmetry: float
    converged: bool
    iterations: int
    pair_fraction: float = float("nan")


def quadratic_peak(values: NDArray, i: int, j: int) -> tuple[float, float]:
    """Sub-pixel maximum from a quadratic fit to the 3 x 3 neighbourhood of ``[i, j]``.

    Returns
    -------
    di, dj : float
        Offsets from ``(i, j)`` in array units, each clipped to [-1, 1] (0 where the
        neighbourhood is not a proper maximum or leaves the array).
    """
    if not (1 <= i < values.shape[0] - 1 and 1 <= j < values.shape[1] - 1):
        return 0.0, 0.0
    w = values[i - 1 : i + 2, j - 1 : j + 2].astype(np.float64)
    if not np.all(np.isfinite(w)):
        return 0.0, 0.0
    gj = 0.5 * (w[1, 2] - w[1, 0])
    gi = 0.5 * (w[2, 1] - w[0, 1])
    hjj = w[1, 2] - 2 * w[1, 1] + w[1, 0]
    hii = w[2, 1] - 2 * w[1, 1] + w[0, 1]
    hij = 0.25 * (w[2, 2] - w[2, 0] - w[0, 2] + w[0, 0])
    det = hii * hjj - hij * hij
    if not (hii < 0 and det > 0):  # not negative definite: no interior maximum
        return 0.0, 0.0
    di = -(hjj * gi - hij * gj) / det
    dj = -(hii * gj - hij * gi) / det
    return float(np.clip(di, -1.0, 1.0)), float(np.clip(dj, -1.0, 1.0))


@lru_cache(maxsize=8)
def _window(size: int, sigma: float, n: int) -> tuple[NDArray, NDArray, NDArray]:
    """The Gaussian window ``w``, its spectrum on the ``n x n`` FFT grid and ``(w * w)(s)``,
    the pair weight of a window with every pixel valid (per window size, not per call: a
    window inside the frame with every pixel valid needs no other)."""
    g1 = np.exp(-0.5 * ((np.arange(size) - (size - 1) / 2) / sigma) ** 2)
    w = g1[:, None] * g1[None, :]
    spec = sfft.rfft2(w, (n, n), workers=1)
    for array in (w, spec):
        array.setflags(write=False)
    full = sfft.irfft2(spec * spec, (n, n), workers=1)
    full.setflags(write=False)
    return w, spec, full


def fft_size(half_width: int, reach: int) -> int:
    """FFT side for the lattice points ``s`` within ``reach`` of the window's centre
    ``2 half_width``: the convolutions of two windows of ``2 half_width + 1`` pixels reach
    ``s = 4 half_width``, and a circular one of period ``n`` folds ``s`` onto ``s - n``, which
    leaves the wanted points clean for ``n > 2 half_width + reach`` (not the full
    ``4 half_width + 1``: about a third of the work, the same values to rounding)."""
    return sfft.next_fast_len(2 * half_width + reach + 1, real=True)


def _inverse_near(spec: NDArray, n: int, near: slice) -> NDArray:
    """``irfft2(spec, (n, n))[near, near]``: the inverse transform along the rows for every
    column, along the columns for the rows wanted only (the same 1-D transforms, a third of
    the second pass)."""
    rows = sfft.ifft(spec, n, axis=0, workers=1)[near]
    return sfft.irfft(rows, n, axis=1, workers=1)[:, near]


def _score_map(
    image: NDArray, valid: NDArray | None, ci: int, cj: int, half_width: int, sigma: float,
    reach: int,
) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    """``N``, ``D``, ``W`` and the valid fraction of the pair weight at the lattice points
    ``s`` within ``reach`` of the window's centre (``(2 reach + 1)^2`` values each,
    :func:`fft_size`)."""
    rows, cols = image.shape
    size = 2 * half_width + 1
    i0, j0 = ci - half_width, cj - half_width
    a0, a1 = max(i0, 0), min(i0 + size, rows)
    b0, b1 = max(j0, 0), min(j0 + size, cols)
    n = fft_size(half_width, reach)
    shape = (n, n)
    near = slice(2 * half_width - reach, 2 * half_width + reach + 1)
    w, spec_w, full = _window(size, sigma, n)
    f = np.zeros((size, size), dtype=np.float64)
    inner = (slice(a0 - i0, a1 - i0), slice(b0 - j0, b1 - j0))
    rect = False  # the valid pixels are the window's part inside the frame
    if a0 < a1 and b0 < b1:
        block = np.asarray(image[a0:a1, b0:b1], dtype=np.float64)
        ok = np.isfinite(block)
        if valid is not None:
            ok &= np.asarray(valid[a0:a1, b0:b1], dtype=bool)
        rect = bool(ok.all())
    if rect:
        if block.size < 9:
            raise ValueError("no valid pixels around the candidate centre")
        f[inner] = block - exact_median(block.ravel())
    else:
        mask = np.zeros((size, size), dtype=np.float64)
        if a0 < a1 and b0 < b1:
            f[inner] = np.where(ok, block, 0.0)
            mask[inner] = ok
        if mask.sum() < 9:
            raise ValueError("no valid pixels around the candidate centre")
        f -= exact_median(f[mask > 0])
        f *= mask
    wf = w * f
    spec = sfft.rfft2(wf, shape, workers=1)
    num = _inverse_near(spec * spec, n, near)
    full_near = full[near, near]
    if rect and inner == (slice(0, size), slice(0, size)):
        spec_wm, pairs = spec_w, full_near  # the whole window valid: its own mask terms
    elif rect:  # a rectangle: the window's mask terms factorise into rows and columns
        g1 = w[half_width] / w[half_width, half_width]
        u, v = np.zeros(size), np.zeros(size)
        u[inner[0]], v[inner[1]] = g1[inner[0]], g1[inner[1]]
        fu, fv = np.fft.fft(u, n), np.fft.rfft(v, n)
        spec_wm = fu[:, None] * fv[None, :]
        pairs = np.outer(np.fft.ifft(fu * fu).real[near], np.fft.irfft(fv * fv, n)[near])
    else:
        spec_wm = sfft.rfft2(w * mask, shape, workers=1)
        pairs = _inverse_near(spec_wm * spec_wm, n, near)
    den = _inverse_near(sfft.rfft2(wf * f, shape, workers=1) * spec_wm, n, near)
    fraction = pairs / np.maximum(full_near, 1e-300)
    return num, den, pairs, fraction


def refine_center(
    image: NDArray,
    x0: float,
    y0: float,
    *,
    valid: NDArray | None = None,
    half_width: int = 70,
    sigma: float | None = None,
    search_px: float = 8.0,
    max_iterations: int = 3,
    min_pair_fraction: float = 0.1,
) -> SymmetryFit:
    """Refine a hologram centre to sub-pixel precision by point symmetry.

    Parameters
    ----------
    image : ndarray, shape (rows, cols)
        Normalised hologram (full frame; non-finite pixels are ignored).
    x0, y0 : float
        Starting centre, full-frame pixels (x = column, y = row); may lie near or beyond the
        edge.
    valid : ndarray of bool, optional
        False marks pixels to ignore (masked background, saturation).
    half_width : int
        Half-size of the square window, pixels.
    sigma : float, optional
        Width of the Gaussian pair weight, pixels (default ``half_width / 2.5``).
    search_px : float
        The centre is sought within this distance of the window centre, pixels.
    max_iterations : int
        If the best centre lies on the rim of the search disc, re-centre and search again,
        up to this many windows.
    min_pair_fraction : float
        Centres whose valid pixel pairs carry less than this fraction of the pair weight of a
        fully valid window are not considered (a centre on the frame's edge would be
        "symmetric" about a handful of pairs); with the default window this keeps centres at
        least ~3 px inside the frame.

    Returns
    -------
    SymmetryFit
    """
    if half_width < 3:
        raise ValueError(f"half_width must be >= 3 pixels, got {half_width}")
    if not 0 < search_px < half_width:
        raise ValueError(f"search_px must lie in (0, half_width), got {search_px}")
    sigma = float(sigma) if sigma is not None else half_width / 2.5
    reach = int(np.ceil(2 * search_px)) + 1  # in units of s = 2m
    yy, xx = np.mgrid[-reach : reach + 1, -reach : reach + 1]
    outside = (xx * xx + yy * yy) > (2 * search_px) ** 2
    rim = (xx * xx + yy * yy) > (2 * search_px - 2) ** 2
    x, y = float(x0), float(y0)
    best = SymmetryFit(x, y, float("nan"), False, 0)
    for it in range(1, max_iterations + 1):
        ci, cj = int(np.floor(y + 0.5)), int(np.floor(x + 0.5))
        try:
            num, den, pairs, fraction = _score_map(image, valid, ci, cj, half_width, sigma,
                                                   reach)
        except ValueError:
            return best
        # the lattice points within reach of the window centre (ci, cj), s = 2 m
        sub_n, sub_d = num, den
        tiny = 1e-12 * max(float(np.abs(sub_d).max()), 1e-300)
        usable = (sub_d > tiny) & (fraction >= min_pair_fraction) & ~outside
        score = np.where(usable, sub_n / np.where(usable, sub_d, 1.0), -np.inf)
        # minus the mean squared asymmetry A (module docstring), up to a factor 2
        closeness = np.where(usable, (sub_n - sub_d) / np.where(usable, pairs, 1.0), -np.inf)
        pi, pj = np.unravel_index(int(np.argmax(closeness)), closeness.shape)
        if not np.isfinite(score[pi, pj]):
            return best
        filled = np.where(usable, closeness, 2 * closeness[pi, pj] - 1.0)
        di, dj = quadratic_peak(filled, int(pi), int(pj))
        x = cj + (pj + dj - reach) / 2.0
        y = ci + (pi + di - reach) / 2.0
        on_rim = bool(rim[pi, pj])
        best = SymmetryFit(x, y, float(score[pi, pj]), not on_rim, it,
                           float(fraction[pi, pj]))
        if not on_rim:
            break
    return best
