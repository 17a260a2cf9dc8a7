"""Orientation-alignment transform: a Hough-type vote for the centres of ring patterns.

Every pixel of a hologram lies on a fringe, and the intensity gradient across a fringe points
toward (or away from) the hologram's centre. Each pixel therefore votes for every point on the
line through it along its gradient. Following the orientation-alignment transform of
Krishnatreya & Grier (Opt. Express 22, 12773, 2014), the votes are cast as a convolution, which
makes the transform one FFT product instead of a loop over pixels:

* the gradient ``g = (g_x, g_y)`` is turned into the orientation field
  ``psi = (g_x + i g_y)^2 = |g|^2 exp(2 i theta)``; squaring the phase makes a gradient and its
  opposite (dark-to-bright and bright-to-dark fringes) vote alike;
* each pixel's vote at a distance ``d = (d_x, d_y)`` (``r = |d| <= R``) is ``psi K(d)`` with
  ``K(d) = (d_x - i d_y)^2 / r^3 = exp(-2 i phi) / r``: it has unit phase exactly when the
  gradient is parallel to ``d``, so votes from every fringe around a centre add in phase, and
  the ``1 / r`` weight gives every ring the same say however large it is;
* ``B = psi * K`` (convolution); ``|B|`` peaks at the centres.

Two normalised quantities come with it: the *strength* ``|B| / sum_K (1/r)``, a weighted mean
of the aligned squared gradient (normalised intensity per pixel, squared), and the *alignment*
``|B| / (|psi| * (1/r))``, the fraction of the local gradient energy that points at the
candidate centre (0 for random gradients, 1 for perfect rings).

For pure white noise of standard deviation ``sigma`` the central-difference gradient has
``var(g_x) = var(g_y) = sigma^2 / 2``, so ``E|psi|^2 = 2 sigma^4`` and the transform has rms
``|B| = sigma^2 sqrt(2 sum_K 1/r^2)`` (:func:`noise_strength`); dividing a peak by it gives a
detection score that means the same in every frame, however much of it a hologram fills.

At full resolution the peak of ``|B|`` has a shallow crater (a dip of a few per cent, ~2 px
across) where the central bright or dark spot is only a few pixels wide; on the block-averaged
frames the finder uses it is gone, and the sub-pixel centre comes from the point-symmetry
refinement (:mod:`holofit.crop.symmetry`), not from this peak.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import scipy.fft as sfft
from numpy.typing import NDArray

__all__ = [
    "block_mean",
    "estimate_noise",
    "exact_median",
    "gradient",
    "noise_strength",
    "orientation_alignment",
]


def block_mean(image: NDArray, factor: int) -> NDArray[np.float32]:
    """Average non-overlapping ``factor x factor`` blocks (incomplete edge blocks are dropped).

    Parameters
    ----------
    image : ndarray, shape (rows, cols)
        Image to shrink.
    factor : int
        Block size, pixels (1 returns a float32 copy).

    Returns
    -------
    ndarray of float32, shape ``(rows // factor, cols // factor)``
        Pixel ``[i, j]`` is the mean of full-size rows ``i*factor ... i*factor + factor - 1``,
        so its centre sits at full-size coordinate ``i*factor + (factor - 1)/2``.
    """
    image = np.asarray(image, dtype=np.float32)
    if factor == 1:
        return image.copy()
    rows, cols = image.shape[0] // factor, image.shape[1] // factor
    view = image[: rows * factor, : cols * factor].reshape(rows, factor, cols, factor)
    if factor >= 8:  # numpy sums 8 or more terms pairwise
        return view.mean(axis=(1, 3), dtype=np.float32)
    # np.mean's own order (along each block row, then down the rows), as whole-array adds:
    # the same float32 values at an eighth of the time
    acc = view[:, :, :, 0].copy()
    for b in range(1, factor):
        acc += view[:, :, :, b]
    out = acc[:, 0].copy()
    for a in range(1, factor):
        out += acc[:, a]
    out /= np.float32(factor * factor)
    return out


def gradient(image: NDArray) -> tuple[NDArray, NDArray]:
    """Central-difference gradient ``(d/dx, d/dy)`` = (along columns, along rows).

    The outermost rows and columns get 0 (no one-sided differences: they would vote with a
    different noise level).
    """
    gx = np.zeros_like(image)
    gy = np.zeros_like(image)
    gx[:, 1:-1] = image[:, 2:] - image[:, :-2]
    gy[1:-1, :] = image[2:, :] - image[:-2, :]
    gx *= 0.5
    gy *= 0.5
    return gx, gy


def estimate_noise(image: NDArray) -> float:
    """Robust pixel-noise standard deviation of an image.

    From the median absolute deviation of second differences along rows (which cancel smooth
    signal and linear trends): ``sigma = 1.4826 MAD / sqrt(6)``.
    """
    image = np.asarray(image, dtype=np.float32)
    if image.shape[1] < 3:
        return 0.0
    d2 = (image[:, :-2] - 2.0 * image[:, 1:-1] + image[:, 2:]).ravel()
    return float(1.4826 * exact_median(np.abs(d2 - exact_median(d2))) / np.sqrt(6.0))


#: :func:`exact_median` looks for the middle values among the samples of every this-many-th
#: element first
MEDIAN_STRIDE = 64


def exact_median(values: NDArray) -> np.floating:
    """``np.median`` of a 1-D array, the same value, in a fraction of the time for large ones.

    The two middle order statistics are bracketed by quantiles of a strided sample, counted,
    and selected among the few values in the bracket only (a full selection where the bracket
    misses them, or with NaN): a megapixel frame's noise estimate is two medians, which
    dominated the centre finder's time.
    """
    n = values.size
    if n < 64 * MEDIAN_STRIDE:
        return np.median(values)
    sample = np.sort(values[::MEDIAN_STRIDE])
    m = sample.size
    # ranks 4.5 sample standard deviations either side of the middle (a miss: ~1e-5)
    half = int(np.ceil(4.5 * 0.5 * np.sqrt(m))) + 2
    lo, hi = sample[max(m // 2 - half, 0)], sample[min(m // 2 + half, m - 1)]
    k1, k2 = (n - 1) // 2, n // 2
    below = int(np.count_nonzero(values < lo))
    inside = values[(values >= lo) & (values <= hi)]
    above = int(np.count_nonzero(values > hi))
    if not (below <= k1 and k2 < below + inside.size) or below + inside.size + above < n:
        return np.median(values)  # the bracket missed, or NaN (in no count)
    part = np.partition(inside, [k1 - below, k2 - below])
    return np.mean(part[[k1 - below, k2 - below]])


def noise_strength(sigma: float, radius: int) -> float:
    """Rms transform strength of white noise of standard deviation ``sigma``.

    ``sigma^2 sqrt(2 sum_K 1/r^2) / sum_K 1/r`` over the vote disc of ``radius`` pixels (module
    docstring); neighbouring gradients share pixels, so this is an approximation to ~10 %.
    """
    d = np.arange(-int(radius), int(radius) + 1, dtype=np.float64)
    r = np.hypot(*np.meshgrid(d, d, indexing="ij"))
    r = r[(r > 0) & (r <= radius)]
    return float(sigma**2 * np.sqrt(2.0 * np.sum(1.0 / r**2)) / np.sum(1.0 / r))


@lru_cache(maxsize=16)
def _kernel_spectra(
    fft_shape: tuple[int, int], radius: int
) -> tuple[NDArray, NDArray, NDArray, float]:
    """Real FFTs of the vote kernels ``Re K``, ``Im K`` and ``1/r``, centred on index 0.

    Returns the three spectra and ``sum(1/r)`` over the kernel.
    """
    d = np.arange(-radius, radius + 1, dtype=np.float64)
    dy, dx = np.meshgrid(d, d, indexing="ij")
    r = np.hypot(dx, dy)
    inside = (r > 0) & (r <= radius)
    r_safe = np.where(inside, r, 1.0)
    k_re = np.where(inside, (dx * dx - dy * dy) / r_safe**3, 0.0)
    k_im = np.where(inside, -2.0 * dx * dy / r_safe**3, 0.0)
    k_abs = np.where(inside, 1.0 / r_safe, 0.0)
    rows = np.mod(dy.astype(int), fft_shape[0])
    cols = np.mod(dx.astype(int), fft_shape[1])
    spectra = []
    for kernel in (k_re, k_im, k_abs):
        full = np.zeros(fft_shape, dtype=np.float32)
        full[rows, cols] = kernel
        spectra.append(sfft.rfft2(full, workers=1))
    return spectra[0], spectra[1], spectra[2], float(k_abs.sum())


def orientation_alignment(
    image: NDArray, radius: int
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Orientation-alignment transform of an image.

    Parameters
    ----------
    image : ndarray, shape (rows, cols)
        Normalised hologram (finite values; fill masked pixels before calling).
    radius : int
        Largest distance over which a pixel votes, pixels of ``image``.

    Returns
    -------
    strength : ndarray of float32, shape of ``image``
        ``|B| / sum_K(1/r)``: (intensity / pixel)^2, large at ring centres.
    alignment : ndarray of float32, shape of ``image``
        ``|B| / (|psi| * (1/r))`` in [0, 1]: how well the surrounding gradients point at each
        pixel.
    """
    image = np.asarray(image, dtype=np.float32)
    if image.ndim != 2:
        raise ValueError(f"expected a 2-D image, got shape {image.shape}")
    radius = int(radius)
    if radius < 2:
        raise ValueError(f"vote radius must be >= 2 pixels, got {radius}")
    gx, gy = gradient(image)
    p = gx * gx - gy * gy  # Re psi
    q = 2.0 * gx * gy  # Im psi
    m = gx * gx + gy * gy  # |psi|
    # circular convolution of size >= shape + radius never wraps into the kept region
    fft_shape = (
        sfft.next_fast_len(image.shape[0] + radius, real=True),
        sfft.next_fast_len(image.shape[1] + radius, real=True),
    )
    k_re, k_im, k_abs, weight = _kernel_spectra(fft_shape, radius)
    fp = sfft.rfft2(p, fft_shape, workers=1)
    fq = sfft.rfft2(q, fft_shape, workers=1)
    fm = sfft.rfft2(m, fft_shape, workers=1)
    rows, cols = image.shape

    def back(spectrum: NDArray) -> NDArray:
        return sfft.irfft2(spectrum, fft_shape, workers=1)[:rows, :cols]

    b_re = back(fp * k_re - fq * k_im)
    b_im = back(fp * k_im + fq * k_re)
    total = back(fm * k_abs)
    magnitude = np.hypot(b_re, b_im).astype(np.float32)
    floor = np.float32(1e-12 * max(float(total.max()), 1e-30))
    alignment = magnitude / np.maximum(total, floor)
    return magnitude / np.float32(weight), np.clip(alignment, 0.0, 1.0).astype(np.float32)
