"""Camera model for synthetic data: illumination level, shot noise, read noise, quantisation."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["Camera"]


@dataclass(frozen=True)
class Camera:
    """A camera that turns a normalised hologram into raw counts.

    Parameters
    ----------
    bit_depth : int
        Counts are integers in ``[0, 2**bit_depth - 1]``.
    background_counts : float
        Mean count of the background (hologram value 1).
    electrons_per_count : float
        Conversion gain; Poisson noise acts on ``counts * electrons_per_count`` photoelectrons.
        ``0`` switches shot noise off.
    read_noise_counts : float
        Gaussian read noise, rms counts.
    dark_counts : float
        Offset added to every pixel (dark level), counts.
    """

    bit_depth: int = 8
    background_counts: float = 120.0
    electrons_per_count: float = 40.0
    read_noise_counts: float = 0.8
    dark_counts: float = 0.0

    def __post_init__(self) -> None:
        full = 2**self.bit_depth - 1
        if not 0 < self.background_counts < full:
            raise ValueError(
                f"background_counts must lie in (0, {full}) for a {self.bit_depth}-bit camera, "
                f"got {self.background_counts}"
            )
        if self.electrons_per_count < 0 or self.read_noise_counts < 0:
            raise ValueError("noise parameters must be >= 0")

    @property
    def dtype(self) -> np.dtype:
        return np.dtype(np.uint8 if self.bit_depth <= 8 else np.uint16)

    def expose(
        self,
        intensity: NDArray[np.float64],
        rng: np.random.Generator | None = None,
        illumination: NDArray[np.float64] | None = None,
        noise: bool = True,
    ) -> NDArray:
        """Raw frame for a normalised hologram.

        Parameters
        ----------
        intensity : ndarray
            Hologram relative to the background (background = 1).
        rng : numpy.random.Generator, optional
            Source of noise.
        illumination : ndarray, optional
            Relative illumination pattern of the optical train (multiplies the counts; the
            background frame records it).
        noise : bool
            If False, only scale and quantise.

        Returns
        -------
        ndarray of uint8 or uint16
        """
        rng = rng or np.random.default_rng()
        counts = np.asarray(intensity, dtype=float) * self.background_counts
        if illumination is not None:
            counts = counts * illumination
        if noise and self.electrons_per_count > 0:
            counts = rng.poisson(np.maximum(counts, 0) * self.electrons_per_count) / (
                self.electrons_per_count
            )
        counts = counts + self.dark_counts
        if noise and self.read_noise_counts > 0:
            counts = counts + rng.normal(0.0, self.read_noise_counts, counts.shape)
        full = 2**self.bit_depth - 1
        return np.clip(np.rint(counts), 0, full).astype(self.dtype)
