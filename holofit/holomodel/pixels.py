"""Which pixels of a crop a fit uses, and where they are.

Shared by the Lorenz-Mie prefit and the DDA fit: NaN pixels (outside the frame, saturated:
the crop stage's mask) and pixels at or above an optional saturation level are left out, and an
optional random subset keeps a fraction of the rest. The subset is drawn from a seeded
generator, so the same frame with the same seed always uses the same pixels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["PixelSelection", "select_pixels"]


@dataclass(frozen=True)
class PixelSelection:
    """The pixels a fit uses.

    Attributes
    ----------
    valid : ndarray of bool, shape of the crop
        Pixels that are not masked or saturated (before any random subset).
    index : ndarray of int
        Flat indices into the crop of the pixels used, increasing.
    data : ndarray
        Their normalised values.
    xs_um, ys_um : ndarray
        Their full-frame sample-plane coordinates (x along columns), um.
    n_masked : int
        Pixels left out as NaN or saturated.
    """

    valid: NDArray[np.bool_]
    index: NDArray[np.intp]
    data: NDArray[np.float64]
    xs_um: NDArray[np.float64]
    ys_um: NDArray[np.float64]
    n_masked: int

    @property
    def size(self) -> int:
        """Number of pixels used."""
        return int(self.index.size)


def select_pixels(
    crop: NDArray,
    corner_rc: tuple[int, int],
    pixel_size_um: float,
    *,
    saturation: float | None = None,
    fraction: float = 1.0,
    rng: np.random.Generator | None = None,
    min_pixels: int = 1,
) -> PixelSelection:
    """Choose the pixels of a crop to fit.

    Parameters
    ----------
    crop : ndarray, shape (rows, cols)
        Normalised crop; NaN marks pixels to leave out.
    corner_rc : tuple of int
        Full-frame ``(row, column)`` of the crop's pixel ``[0, 0]``.
    pixel_size_um : float
        Pixel pitch, um.
    saturation : float, optional
        Also leave out pixels whose value is at or above this level.
    fraction : float
        Keep a random subset with this fraction of the usable pixels (at least
        ``min_pixels``).
    rng : numpy.random.Generator, optional
        Source of the subset (required if ``fraction < 1``).
    min_pixels : int
        Fewest usable pixels accepted.

    Raises
    ------
    ValueError
        If the crop is not 2-D or fewer than ``min_pixels`` pixels are usable.
    """
    data = np.asarray(crop, dtype=float)
    if data.ndim != 2:
        raise ValueError(f"crop must be 2-D, got shape {data.shape}")
    if not 0 < fraction <= 1:
        raise ValueError(f"pixel fraction must be in (0, 1], got {fraction}")
    valid = np.isfinite(data)
    if saturation is not None:
        valid &= data < saturation
    n_valid = int(valid.sum())
    if n_valid < min_pixels:
        raise ValueError(f"only {n_valid} usable pixels in a {data.shape} crop")
    idx = np.flatnonzero(valid.ravel())
    if fraction < 1:
        if rng is None:
            raise ValueError("a random pixel subset needs a random generator")
        keep = min(max(round(fraction * idx.size), min_pixels), idx.size)
        idx = np.sort(rng.choice(idx, size=keep, replace=False))
    rows, cols = np.divmod(idx, data.shape[1])
    return PixelSelection(
        valid=valid,
        index=idx,
        data=data.ravel()[idx],
        xs_um=(corner_rc[1] + cols) * pixel_size_um,
        ys_um=(corner_rc[0] + rows) * pixel_size_um,
        n_masked=data.size - n_valid,
    )
