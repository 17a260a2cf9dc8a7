"""Background division and normalisation of raw hologram frames (the paper's I_measured).

    I = (I_data - dark) / (I_bg - dark) * mean(I_bg - dark) / mean(I_data - dark)

(Wang, Dimiduk et al. 2014, with the dark level of the camera subtracted first), so that the
background is 1 and slow changes of the illumination between the background and the frame
cancel. Pixels where the background is (close to) the dark level carry no light and are never
divided by: they are *masked*, set to NaN in the result and reported. Saturated pixels of the
frame (at the camera's full-scale count) can be masked the same way.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["DEFAULT_MIN_BACKGROUND", "Normalizer", "normalize"]

#: Background pixels at or below this fraction of the median background (above dark) are
#: masked.
DEFAULT_MIN_BACKGROUND = 0.02


def _first_bad(bad: NDArray[np.bool_]) -> str:
    row, col = np.unravel_index(int(np.argmax(bad)), bad.shape)
    return f"{int(bad.sum())} pixel(s), first at row {row}, column {col}"


@dataclass(frozen=True)
class _Prepared:
    inverse: NDArray[np.float32]  # 1 / (bg - dark), 0 where masked
    dark: NDArray[np.float32] | np.float32
    masked: NDArray[np.bool_]
    valid: NDArray[np.bool_]
    background_mean: float
    n_valid: int


class Normalizer:
    """Normalise frames against one background (and dark level), prepared once.

    Parameters
    ----------
    background : array_like, shape (rows, cols)
        Background intensity (a single frame, or the median of a stack), raw counts.
    dark : float or array_like, optional
        Dark level: a number (counts) or a dark frame of the background's shape. Default 0.
    min_background : float
        Pixels whose ``background - dark`` is at or below this fraction of its median are
        masked (dead or unlit pixels).
    saturation : float, optional
        Raw frame count at or above which a pixel is clipped and masked (e.g. 255 for an 8-bit
        camera). None keeps every frame pixel.
    full_scale : float, optional
        The instrument's full-scale count (``2**bit_depth - 1``), which no frame may exceed
        (:func:`holofit.crop.detect.read_normalised`); default ``saturation`` (lower where
        the data show the camera saturating below it: :mod:`holofit.crop.saturation`).

    Raises
    ------
    ValueError
        Non-finite background or dark values, a dark frame of another shape, a background that
        is at the dark level everywhere or in more than half of the frame.

    Attributes
    ----------
    shape : tuple of int
        Frame shape expected.
    background_masked : ndarray of bool
        True where the background is ~0 (masked in every frame).
    """

    def __init__(
        self,
        background: ArrayLike,
        dark: float | ArrayLike | None = None,
        *,
        min_background: float = DEFAULT_MIN_BACKGROUND,
        saturation: float | None = None,
        full_scale: float | None = None,
    ) -> None:
        bg = np.asarray(background, dtype=np.float64)
        if bg.ndim != 2:
            raise ValueError(f"background must be a 2-D frame, got shape {bg.shape}")
        bad = ~np.isfinite(bg)
        if bad.any():
            raise ValueError(f"background has non-finite values (NaN/inf): {_first_bad(bad)}")
        if dark is None:
            dk: NDArray[np.float64] | float = 0.0
        elif np.ndim(dark) == 0:
            dk = float(dark)  # type: ignore[arg-type]
            if not np.isfinite(dk):
                raise ValueError(f"dark level must be a finite number, got {dark!r}")
        else:
            dk = np.asarray(dark, dtype=np.float64)
            if dk.shape != bg.shape:
                raise ValueError(f"dark frame has shape {dk.shape}, the background has {bg.shape}")
            bad = ~np.isfinite(dk)
            if bad.any():
                raise ValueError(f"dark frame has non-finite values: {_first_bad(bad)}")
        if not 0 <= min_background < 1:
            raise ValueError(f"min_background must lie in [0, 1), got {min_background}")
        light = bg - dk
        lit = light > 0
        if not lit.any():
            raise ValueError(
                "background is zero everywhere (at or below the dark level): nothing to divide by"
            )
        floor = min_background * float(np.median(light[lit]))
        masked = ~(light > floor)
        if masked.mean() > 0.5:
            raise ValueError(
                f"background is at or below the dark level in {masked.mean():.0%} of the pixels: "
                "wrong background or dark frame?"
            )
        valid = ~masked
        inverse = np.zeros(bg.shape, dtype=np.float32)
        inverse[valid] = 1.0 / light[valid]
        self.shape: tuple[int, int] = (int(bg.shape[0]), int(bg.shape[1]))
        self.background_masked = masked
        self.saturation = saturation
        self.full_scale = full_scale if full_scale is not None else saturation
        self._p = _Prepared(
            inverse=inverse,
            dark=np.asarray(dk, dtype=np.float32) if np.ndim(dk) else np.float32(dk),
            masked=masked,
            valid=valid,
            background_mean=float(light[valid].mean()),
            n_valid=int(valid.sum()),
        )

    @property
    def n_masked_background(self) -> int:
        """Pixels masked because the background is ~0."""
        return int(self._p.masked.sum())

    @property
    def background_mean(self) -> float:
        """Mean of ``background - dark`` over the unmasked pixels, counts."""
        return self._p.background_mean

    def __call__(self, frame: ArrayLike) -> tuple[NDArray[np.float32], NDArray[np.bool_]]:
        """Normalise one raw frame.

        Parameters
        ----------
        frame : array_like, shape ``self.shape``
            Raw counts (any integer or float type).

        Returns
        -------
        image : ndarray of float32
            Normalised hologram (background ~1); NaN where masked.
        mask : ndarray of bool
            True where the pixel is masked (background ~0, or saturated in this frame).

        Raises
        ------
        ValueError
            Wrong shape, non-finite pixels, or a frame at or below the dark level on average.
        """
        raw = np.asarray(frame)
        if raw.shape != self.shape:
            raise ValueError(f"frame has shape {raw.shape}, the background has {self.shape}")
        if raw.dtype.kind not in "uif":
            raise ValueError(f"frame has unsupported pixel type {raw.dtype}")
        if raw.dtype.kind == "f":
            bad = ~np.isfinite(raw)
            if bad.any():
                raise ValueError(f"frame has non-finite values (NaN/inf): {_first_bad(bad)}")
        p = self._p
        data = raw.astype(np.float32)
        data -= p.dark
        mean = float(np.sum(data, where=p.valid, dtype=np.float64)) / p.n_valid
        if not mean > 0:
            raise ValueError(
                f"frame is at or below the dark level on average (mean - dark = {mean:.4g} "
                "counts): an empty or dropped frame?"
            )
        data *= p.inverse
        data *= np.float32(p.background_mean / mean)
        mask = p.masked
        if self.saturation is not None and raw.dtype.kind in "ui":
            saturated = raw >= self.saturation
            if saturated.any():
                mask = mask | saturated
        data[mask] = np.nan
        return data, mask


def normalize(
    frame: ArrayLike,
    background: ArrayLike,
    dark: float | ArrayLike | None = None,
    *,
    min_background: float = DEFAULT_MIN_BACKGROUND,
    saturation: float | None = None,
) -> tuple[NDArray[np.float32], NDArray[np.bool_]]:
    """Background-divide and normalise one raw frame (see :class:`Normalizer`).

    Parameters
    ----------
    frame : array_like, shape (rows, cols)
        Raw counts.
    background : array_like, shape (rows, cols)
        Background counts (one frame or a stack's median).
    dark : float or array_like, optional
        Dark level (number of counts, or a frame).
    min_background : float
        Fraction of the median background below which pixels are masked.
    saturation : float, optional
        Raw count at or above which a frame pixel is masked.

    Returns
    -------
    image : ndarray of float32
        ``(frame - dark) / (background - dark) * mean(background - dark) / mean(frame - dark)``,
        means over unmasked pixels; NaN where masked.
    mask : ndarray of bool
        True where masked.
    """
    normalizer = Normalizer(background, dark, min_background=min_background, saturation=saturation)
    return normalizer(frame)
