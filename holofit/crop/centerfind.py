"""Finding hologram centres in a normalised frame: detect, rank, refine.

1. *Detect* (coarse, on a block-averaged copy of the frame): the orientation-alignment
   transform (:mod:`holofit.crop.transform`) votes along intensity-gradient directions; its
   local maxima are candidate centres.
2. *Rank and accept*: a candidate's ``score`` is its transform strength in units of the rms
   strength that pure noise of the frame's measured pixel noise would give (noise maxima reach
   ~5; holograms score hundreds to thousands); its ``alignment`` is the fraction of the
   surrounding gradient energy that points at it (noise maxima <= 0.36, holograms 0.7-0.95).
   Both must pass their thresholds, and after refinement so must the point symmetry.
3. *Refine* (full resolution, only near accepted candidates): the centre of point symmetry
   (:mod:`holofit.crop.symmetry`), to a few hundredths of a pixel on simulated spheres; within
   ~10 px of an edge, where few symmetric pixel pairs remain, the centre of the most circular
   rings (:mod:`holofit.crop.radial`).

Everything is vectorised (FFT convolutions), so a megapixel frame is searched in milliseconds
(docs: validation, "crop and prefit").
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray
from scipy import ndimage

from holofit.crop.peel import MainSearch, Peak, peel
from holofit.crop.radial import refine_center_radial
from holofit.crop.symmetry import quadratic_peak, refine_center
from holofit.crop.transform import (
    block_mean,
    estimate_noise,
    noise_strength,
    orientation_alignment,
)

__all__ = ["CENTER_COLUMNS", "MIN_RADIUS_PX", "CenterFinder", "auto_downsample", "find_centers"]

#: Columns of the table returned by :func:`find_centers`, ranked best first.
CENTER_COLUMNS = ("x_px", "y_px", "score", "alignment", "symmetry", "refinement")
#: smallest vote radius, pixels
MIN_RADIUS_PX = 4.0

#: Below this valid pair fraction (centre within ~10 px of an edge) the radial refinement
#: takes over from the point-symmetry one.
EDGE_PAIR_FRACTION = 0.5


@dataclass(frozen=True)
class CenterFinder:
    """Settings of the centre finder (all lengths in full-frame pixels).

    Attributes
    ----------
    radius_px : float
        Largest distance over which a pixel votes for a centre: the radius of the hologram
        region that matters (default 70, half the default crop).
    downsample : int, optional
        Block size for the coarse detection; ``None`` picks one from ``radius_px`` and the frame
        size (:func:`auto_downsample`).
    max_centers : int
        Most candidates returned.
    min_score : float
        Smallest accepted detection score (transform peak / rms transform of pure noise at the
        frame's pixel-noise level).
    min_alignment : float
        Smallest accepted alignment (0-1).
    min_symmetry : float
        Smallest accepted point-symmetry score of a refined centre (-1 to 1). Holograms of
        spheres score 0.85-0.99, fringe crossings and noise below 0.6; lower it (or set -1) for
        particles whose holograms are far from point-symmetric. Ignored without ``refine``
        and where the symmetry cannot be evaluated (centre within ~3 px of the edge).
    min_separation_px : float, optional
        Candidates closer than this merge into the stronger one (default ``radius_px / 2``).
    refine : bool
        Refine accepted candidates by point symmetry at full resolution.
    refine_half_width_px : int, optional
        Half-size of the refinement window (default ``radius_px``).
    search_px : float, optional
        How far the refinement may move a centre per window (default ``max(3, 2 *
        downsample)``); up to three windows are tried.
    peel : bool
        Search again near every found centre with the found holograms' ring systems
        subtracted, and refine close centres with each other's rings subtracted
        (:mod:`holofit.crop.peel`): resolves holograms down to ~2 um (~20 px at 100x) apart,
        which the vote alone merges within ~1.5 vote radii. Needs ``refine``.
    """

    radius_px: float = 70.0
    downsample: int | None = None
    max_centers: int = 10
    min_score: float = 10.0
    min_alignment: float = 0.45
    min_symmetry: float = 0.5
    min_separation_px: float | None = None
    refine: bool = True
    refine_half_width_px: int | None = None
    search_px: float | None = None
    peel: bool = True

    def __post_init__(self) -> None:
        if not self.radius_px >= MIN_RADIUS_PX:
            raise ValueError(
                f"radius_px must be >= {MIN_RADIUS_PX:g} pixels, got {self.radius_px}"
            )
        if self.downsample is not None and not 1 <= self.downsample <= 16:
            raise ValueError(f"downsample must lie in 1..16, got {self.downsample}")
        if self.max_centers < 1:
            raise ValueError(f"max_centers must be >= 1, got {self.max_centers}")
        if not 0 <= self.min_alignment <= 1:
            raise ValueError(f"min_alignment must lie in [0, 1], got {self.min_alignment}")
        if not -1 <= self.min_symmetry <= 1:
            raise ValueError(f"min_symmetry must lie in [-1, 1], got {self.min_symmetry}")

    def as_dict(self) -> dict[str, Any]:
        """Plain dict for sidecar files."""
        return asdict(self)

    def find(self, image: NDArray, mask: NDArray | None = None) -> pd.DataFrame:
        """Candidate centres of ``image``; see :func:`find_centers`."""
        return _find(image, mask, self)


def auto_downsample(radius_px: float, shape: tuple[int, int]) -> int:
    """Block size for the coarse detection.

    About 16 downsampled pixels per vote radius (enough to resolve the central fringes), at
    most 4, and the shrunken frame keeps at least 32 pixels a side.
    """
    factor = round(radius_px / 16.0)
    factor = min(factor, 4, min(shape) // 32)
    return max(factor, 1)


def _empty() -> pd.DataFrame:
    return pd.DataFrame(
        {
            "x_px": pd.Series(dtype=float),
            "y_px": pd.Series(dtype=float),
            "score": pd.Series(dtype=float),
            "alignment": pd.Series(dtype=float),
            "symmetry": pd.Series(dtype=float),
            "refinement": pd.Series(dtype=str),
        }
    )


def _find(image: NDArray, mask: NDArray | None, s: CenterFinder) -> pd.DataFrame:
    img = np.asarray(image, dtype=np.float32)
    if img.ndim != 2:
        raise ValueError(f"expected a 2-D image, got shape {img.shape}")
    invalid = ~np.isfinite(img)
    if mask is not None:
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != img.shape:
            raise ValueError(f"mask has shape {mask.shape}, the image {img.shape}")
        invalid |= mask
    has_invalid = bool(invalid.any())
    if has_invalid:
        if invalid.all():
            return _empty()
        fill = np.float32(np.mean(img, where=~invalid, dtype=np.float64))
        img = np.where(invalid, fill, img)
    factor = s.downsample or auto_downsample(s.radius_px, img.shape)
    small = block_mean(img, factor)
    radius_ds = max(2, round(s.radius_px / factor))
    strength, alignment = orientation_alignment(small, radius_ds)
    peak_strength = float(strength.max())
    if not peak_strength > 0:
        return _empty()
    noise = noise_strength(estimate_noise(small), radius_ds)
    noise = max(noise, 1e-9 * peak_strength)  # noise-free (synthetic) images
    separation = s.min_separation_px if s.min_separation_px is not None else s.radius_px / 2
    sep_ds = max(1, round(separation / factor))
    local_max = ndimage.maximum_filter(strength, size=2 * sep_ds + 1, mode="nearest")
    peaks = (
        (strength == local_max) & (strength >= s.min_score * noise) & (alignment >= s.min_alignment)
    )
    rows, cols = np.nonzero(peaks)
    if rows.size == 0:
        return _empty()
    order = np.argsort(-strength[rows, cols], kind="stable")
    rows, cols = rows[order], cols[order]

    half_width = int(s.refine_half_width_px or max(8, round(s.radius_px)))
    search = s.search_px if s.search_px is not None else max(3.0, 2.0 * factor)
    search = min(search, half_width - 2)
    valid = ~invalid if has_invalid else None
    found: list[tuple[float, ...]] = []
    # candidates that fail the symmetry test do not count: bound the work on junk-rich frames
    for i, j in list(zip(rows, cols, strict=True))[: 3 * s.max_centers]:
        di, dj = quadratic_peak(strength, int(i), int(j))
        x0 = (j + dj) * factor + (factor - 1) / 2.0
        y0 = (i + di) * factor + (factor - 1) / 2.0
        x, y, symmetry, refinement = x0, y0, float("nan"), "none"
        if s.refine:
            fit = refine_center(img, x0, y0, valid=valid, half_width=half_width, search_px=search)
            symmetry = fit.symmetry
            if symmetry < s.min_symmetry:
                continue  # not a hologram centre: fringe crossing, dust, noise
            if fit.converged and fit.pair_fraction >= EDGE_PAIR_FRACTION:
                x, y, refinement = fit.x_px, fit.y_px, "symmetry"
            else:  # near an edge (or a mask): circular rings pin the centre across it
                start = (fit.x_px, fit.y_px) if fit.converged else (x0, y0)
                radial = refine_center_radial(
                    img, *start, valid=valid, radius=half_width, reach=min(search, 3.0)
                )
                if radial.converged:
                    x, y, refinement = radial.x_px, radial.y_px, "radial"
        if any(np.hypot(x - fx, y - fy) < separation for fx, fy, *_ in found):
            continue  # same hologram as a stronger candidate
        found.append(
            (x, y, float(strength[i, j]) / noise, float(alignment[i, j]), symmetry, refinement)
        )
        if len(found) >= s.max_centers:
            break
    if s.peel and s.refine and found:
        main = MainSearch(s.radius_px, factor, noise, s.min_score, s.min_alignment,
                          s.min_symmetry, separation, half_width, search, s.max_centers)
        peaks = peel(img, [Peak(*f) for f in found], main, small=small)
        found = [(p.x, p.y, p.score, p.alignment, p.symmetry, p.refinement) for p in peaks]
    return pd.DataFrame(found, columns=list(CENTER_COLUMNS))


def find_centers(
    image: NDArray,
    *,
    mask: NDArray | None = None,
    finder: CenterFinder | None = None,
    **settings: Any,
) -> pd.DataFrame:
    """Find, rank and refine hologram centres in one normalised 2-D image.

    Parameters
    ----------
    image : ndarray, shape (rows, cols)
        Normalised hologram (background ~1). Non-finite pixels are ignored.
    mask : ndarray of bool, optional
        True marks pixels to ignore (as returned by :func:`holofit.crop.normalize.normalize`).
    finder : CenterFinder, optional
        Settings; keyword arguments override single fields (``radius_px=50``).
    **settings
        Fields of :class:`CenterFinder`.

    Returns
    -------
    pandas.DataFrame
        One row per accepted centre, strongest first, columns

        ``x_px``, ``y_px``
            centre in full-frame pixels (x = column, y = row; pixel centres are integers);
        ``score``
            detection strength: transform peak over the rms transform of pure noise at the
            frame's measured pixel noise (noise alone reaches ~5);
        ``alignment``
            fraction of the surrounding gradient energy pointing at the centre (0-1);
        ``symmetry``
            point-symmetry score of the refined centre (1 = perfect; NaN without
            ``refine``);
        ``refinement``
            how the sub-pixel centre was found: ``"symmetry"`` (point symmetry, the usual
            case), ``"radial"`` (most circular rings; centres within ~10 px of an edge or a
            large mask) or ``"none"`` (refinement off or not converged: the coarse centre,
            good to about a block of the coarse stage).

    Examples
    --------
    >>> centers = find_centers(image)                          # doctest: +SKIP
    >>> x, y = centers.loc[0, ["x_px", "y_px"]]                # the strongest
    """
    finder = finder or CenterFinder()
    if settings:
        finder = replace(finder, **settings)
    return finder.find(image, mask)
