"""Finding hologram centres in a normalised frame: detect, rank, refine.

1. *Detect* (coarse, on a block-averaged copy of the frame): the orientation-alignment
   transform (:mod:`holofit.crop.transform`) votes along intensity-gradient directions; its
   local maxima are candidate centres.
2. *Rank and accept*: a candidate's ``score`` is its transform strength in units of the rms
   strength that pure noise of the frame's measured pixel noise would give (noise maxima reach
   ~5; holograms score hundreds to thousands); its ``alignment`` is the fraction of the
   surrounding gradient energy that points at it (noise maxima <= 0.36, lone holograms
   0.7-0.98, about half that with a neighbour in the vote disc). Both must pass their
   thresholds, and after refinement so must the point symmetry. Each accepted centre's
   radial profile gives its zone radius and its reach (:mod:`holofit.crop.profile`): two
   centres closer than half a zone radius are one hologram.
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

from holofit.crop.peel import MIDPOINT_CIRCULARITY, MainSearch, Peak, peel, remeasure, taken
from holofit.crop.profile import FringeOptics, Scales
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
CENTER_COLUMNS = ("x_px", "y_px", "score", "alignment", "symmetry", "refinement", "zone_px",
                  "reach_px")
#: smallest vote radius, pixels
MIN_RADIUS_PX = 4.0

#: A local maximum of the vote within half a vote radius of a stronger one is a candidate if
#: it is at least this share of it: two rods 6 um apart at 60x vote 2661 and 2451, the junk
#: on their cones' slopes at most 760 (bench/detection_scenes.py, crossing rods)
SECONDARY_SHARE = 0.5

#: A refined candidate whose rings are not circular about it (circularity below
#: :data:`holofit.crop.peel.MIDPOINT_CIRCULARITY`) is kept only this point-symmetric: the
#: midpoint of two alike holograms (0.84-0.97 at 60x, 2-6 um apart), from which peeling finds
#: the two; junk at a frame's edge scores 0.54-0.58 (HoloPy's image0001)
MIDPOINT_SYMMETRY = 0.8

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
        Smallest accepted alignment (0-1). Noise maxima reach 0.36 but fail the score; a lone
        hologram aligns 0.84-0.98, one with an alike neighbour within its vote disc only
        0.43-0.56 (the neighbour's gradients point elsewhere: measured at 60x, 2-8 um apart),
        three such 0.3: the default lets crowded holograms through to the symmetry test,
        which rejects junk (the residual search of the peel, where found holograms are
        subtracted, asks for :data:`holofit.crop.peel.PEEL_ALIGNMENT`).
    min_symmetry : float
        Smallest accepted point-symmetry score of a refined centre (-1 to 1). Holograms of
        spheres score 0.85-0.99, fringe crossings and noise below 0.6; lower it (or set -1) for
        particles whose holograms are far from point-symmetric. Ignored without ``refine``
        and where the symmetry cannot be evaluated (centre within ~3 px of the edge).
    min_separation_px : float, optional
        Candidates closer than this merge into the stronger one. Default: half the larger of
        the two holograms' zone radii (:mod:`holofit.crop.profile`), the radius of a
        hologram's central spot, measured on each: it follows the pixel size and the
        particle's height, where a fixed distance in pixels loses close neighbours on a
        fine-pixel instrument and merges nothing on a coarse one.
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
    optics : FringeOptics, optional
        The instrument's wavelength in pixels and its steepest resolved fringe
        (:meth:`FringeOptics.of`): caps each hologram's reach at the farthest fringe the
        objective and the pixels pass. Without it the reach is measured out to three vote
        radii.
    """

    radius_px: float = 70.0
    downsample: int | None = None
    max_centers: int = 10
    min_score: float = 10.0
    min_alignment: float = 0.3
    min_symmetry: float = 0.5
    min_separation_px: float | None = None
    refine: bool = True
    refine_half_width_px: int | None = None
    search_px: float | None = None
    peel: bool = True
    optics: FringeOptics | None = None

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

    @classmethod
    def for_instrument(cls, pixel_size_um: float, wavelength_um: float, medium_index: float,
                       numerical_aperture: float | None, **settings: Any) -> CenterFinder:
        """A finder that knows the instrument's fringe limits (:class:`FringeOptics`);
        ``settings`` are the other fields."""
        optics = FringeOptics.of(wavelength_um, medium_index, pixel_size_um,
                                 numerical_aperture)
        return cls(optics=optics, **settings)

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
            "zone_px": pd.Series(dtype=float),
            "reach_px": pd.Series(dtype=float),
        }
    )


def _prepared(image: NDArray, mask: NDArray | None) -> tuple[NDArray, NDArray | None]:
    """The image as float32 with invalid pixels filled by the mean of the valid ones, and the
    valid pixels (None: all valid); an all-invalid image gives an empty image."""
    img = np.asarray(image, dtype=np.float32)
    if img.ndim != 2:
        raise ValueError(f"expected a 2-D image, got shape {img.shape}")
    invalid = ~np.isfinite(img)
    if mask is not None:
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != img.shape:
            raise ValueError(f"mask has shape {mask.shape}, the image {img.shape}")
        invalid |= mask
    if not invalid.any():
        return img, None
    if invalid.all():
        return np.empty((0, 0), np.float32), None
    fill = np.float32(np.mean(img, where=~invalid, dtype=np.float64))
    return np.where(invalid, fill, img), ~invalid


def _find(image: NDArray, mask: NDArray | None, s: CenterFinder) -> pd.DataFrame:
    img, valid = _prepared(image, mask)
    if img.size == 0:
        return _empty()
    factor = s.downsample or auto_downsample(s.radius_px, img.shape)
    small = block_mean(img, factor)
    radius_ds = max(2, round(s.radius_px / factor))
    strength, alignment = orientation_alignment(small, radius_ds)
    peak_strength = float(strength.max())
    if not peak_strength > 0:
        return _empty()
    noise = noise_strength(estimate_noise(small), radius_ds)
    noise = max(noise, 1e-9 * peak_strength)  # noise-free (synthetic) images
    # local maxima of the vote at its own resolution (a block) that are the largest within
    # half a vote radius (a hologram's cone falls off over ~a vote radius), or at least
    # SECONDARY_SHARE of that largest: a neighbour as strong as the hologram whose cone it
    # sits in is found here (a weaker one by peeling, which subtracts the stronger one's
    # rings), while junk on a cone's slope is a few tenths of its peak and not refined
    window = s.min_separation_px if s.min_separation_px is not None else s.radius_px / 2
    sep_ds = max(1, round(window / factor))
    local_max = ndimage.maximum_filter(strength, size=3, mode="nearest")
    cone_max = ndimage.maximum_filter(strength, size=2 * sep_ds + 1, mode="nearest")
    peaks = ((strength == local_max) & (strength >= SECONDARY_SHARE * cone_max)
             & (strength >= s.min_score * noise) & (alignment >= s.min_alignment))
    rows, cols = np.nonzero(peaks)
    if rows.size == 0:
        return _empty()
    order = np.argsort(-strength[rows, cols], kind="stable")
    rows, cols = rows[order], cols[order]

    half_width = int(s.refine_half_width_px or max(8, round(s.radius_px)))
    search = s.search_px if s.search_px is not None else max(3.0, 2.0 * factor)
    search = min(search, half_width - 2)
    scales = Scales(s.radius_px, estimate_noise(img), s.optics, s.min_separation_px)
    found: list[Peak] = []
    tried = 0
    # candidates that fail the symmetry test do not count: bound the work on junk-rich frames
    for i, j in zip(rows, cols, strict=True):
        if tried >= 3 * s.max_centers or len(found) >= s.max_centers:
            break
        di, dj = quadratic_peak(strength, int(i), int(j))
        x0 = float((j + dj) * factor + (factor - 1) / 2.0)
        y0 = float((i + di) * factor + (factor - 1) / 2.0)
        if taken(x0, y0, float("nan"), found, scales):
            continue  # a hologram found already, or the midpoint of two
        tried += 1
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
        if not (0 <= x <= img.shape[1] - 1 and 0 <= y <= img.shape[0] - 1):
            continue  # refined out of the frame: an edge's fringes, not a centre to crop
        prof = scales.measure(img, x, y)
        if (s.refine and not prof.circularity >= MIDPOINT_CIRCULARITY
                and not symmetry >= MIDPOINT_SYMMETRY):
            continue  # rings not circular about it, and not a pair's symmetric midpoint: junk
        if taken(x, y, prof.zone_px, found, scales):
            continue  # same hologram as a stronger candidate
        found.append(Peak(x, y, float(strength[i, j]) / noise, float(alignment[i, j]),
                          symmetry, refinement, zone=prof.zone_px, reach=prof.reach_px,
                          circularity=prof.circularity))
    if s.peel and s.refine and found:
        main = MainSearch(s.radius_px, factor, noise, s.min_score, s.min_alignment,
                          s.min_symmetry, half_width, search, s.max_centers, scales)
        found = peel(img, found, main, small=small)
    rows_n, cols_n = img.shape
    found = remeasure(img, [p for p in found if 0 <= p.x <= cols_n - 1 and 0 <= p.y <= rows_n - 1],
                      scales)
    return pd.DataFrame([(p.x, p.y, p.score, p.alignment, p.symmetry, p.refinement, p.zone,
                          p.reach) for p in found], columns=list(CENTER_COLUMNS))


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
