"""Resolving holograms whose ring systems overlap: peel the found ones off and search again.

The orientation-alignment vote (:mod:`holofit.crop.transform`) of a strong hologram swamps a
weaker one within ~1.5 vote radii: the pair gives one peak, at the stronger centre. Peeling
takes each found centre's ring system away and votes again on what is left:

1. the *ring model* of a centre is the azimuthal (clipped) mean of the normalised frame minus
   one on 1-px rings about it (:func:`ring_model`): for a sphere its whole hologram, for a rod
   most of it; the clipping keeps a neighbour's central fringes out of the rings' means;
2. the residual frame near each found centre, with the ring models of every found centre
   nearby subtracted, is voted on again (same vote radius, block size, noise level and
   thresholds as the main search); a peak within :data:`PEEL_REACH` vote radii of the centre,
   farther than the minimum separation from every found centre, whose refined centre on the
   residual is point-symmetric, is a new hologram;
3. every centre with a neighbour within reach is refined again by point symmetry with the
   neighbours' ring models subtracted (twice, alternating), which takes the neighbour's bias
   off both centres.

A lone hologram leaves only noise (and, for a non-circular one, a weak non-symmetric residual)
once its ring model is subtracted, so its result does not change.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from holofit.crop.radial import radial_variance, refine_center_radial
from holofit.crop.symmetry import quadratic_peak, refine_center
from holofit.crop.transform import block_mean, orientation_alignment

__all__ = ["PEEL_REACH", "PROFILE_REACH", "MainSearch", "Peak", "peel", "ring_model"]

#: new holograms are sought within this many vote radii of a found one (farther ones are not
#: swamped by it: the main search finds them)
PEEL_REACH = 2.0
#: a ring model covers this many vote radii about its centre
PROFILE_REACH = 3.0
#: pixels farther than this many ring standard deviations from a ring's mean are left out of it
CLIP = 2.5
#: a new hologram in the residual must score this many times the main search's smallest
#: score, and its point symmetry must lie halfway from the main search's smallest to 1: what
#: subtraction leaves behind (a fringe cut by the frame's edge) can pass the main search's
#: thresholds by a hair, while real neighbours pass these by far (docs: validation, "field of
#: view")
PEEL_SCORE = 3.0
#: ... and not be within ~10 px of the frame's edge (fewer than this fraction of its point
#: pairs inside: the main search finds such holograms, with the radial refinement)
EDGE_PAIRS = 0.5
#: refinement rounds of neighbouring centres with each other's ring models subtracted
ROUNDS = 3
#: how far one round may move a centre, pixels
MOVE = 4.0
#: a centre whose point symmetry is below this is peeled again about its most circular rings'
#: centre if the first peel finds nothing: a lone sphere scores above it, and a close
#: neighbour, which can hide from the first peel, pulls a sphere's score below it
RING_CHECK = 0.95
#: largest radius of the rings whose circularity places a ring model, pixels (the central
#: rings place it as well as all of them, at a fraction of the cost)
RING_RADIUS = 32.0


@dataclass
class Peak:
    """A found hologram centre (full-frame pixels) and its ranking values."""

    x: float
    y: float
    score: float
    alignment: float
    symmetry: float
    refinement: str
    #: centre of its ring model: that of the most circular rings (None: not yet sought)
    ring_xy: tuple[float, float] | None = None


def _box(shape: tuple[int, int], x: float, y: float, half: float) -> tuple[slice, slice]:
    r0, r1 = max(0, int(np.floor(y - half))), min(shape[0], int(np.ceil(y + half)) + 1)
    c0, c1 = max(0, int(np.floor(x - half))), min(shape[1], int(np.ceil(x + half)) + 1)
    return slice(r0, r1), slice(c0, c1)


def ring_model(image: NDArray, x: float, y: float, reach: float
               ) -> tuple[tuple[slice, slice], NDArray[np.float32]]:
    """The circular part of the hologram about ``(x, y)``: clipped ring means minus one.

    Parameters
    ----------
    image : ndarray, shape (rows, cols)
        Normalised frame (background ~1, finite).
    x, y : float
        Centre, full-frame pixels.
    reach : float
        Radius of the model, pixels; it tapers to zero over its outer fifth.

    Returns
    -------
    box : tuple of slice
        The frame's rows and columns the model covers.
    model : ndarray of float32
        The model on ``box`` (zero beyond ``reach``).
    """
    box = _box(image.shape, x, y, reach)
    rows = np.arange(box[0].start, box[0].stop, dtype=np.float32)[:, None] - np.float32(y)
    cols = np.arange(box[1].start, box[1].stop, dtype=np.float32)[None, :] - np.float32(x)
    r = np.hypot(cols, rows)  # float32: the windows are large (a 70-px vote radius: 421 px)
    inside = r < reach
    flat_r = r[inside]
    flat_b = flat_r.astype(np.int32)
    flat_v = image[box][inside].astype(np.float64) - 1.0
    n_bins = int(reach) + 1
    count = np.maximum(np.bincount(flat_b, minlength=n_bins), 1)
    mean = np.bincount(flat_b, flat_v, n_bins) / count
    var = np.bincount(flat_b, flat_v**2, n_bins) / count - mean**2
    keep = np.abs(flat_v - mean[flat_b]) <= CLIP * np.sqrt(np.maximum(var, 0.0))[flat_b] + 1e-12
    kept = np.bincount(flat_b[keep], minlength=n_bins)
    clipped = np.bincount(flat_b[keep], flat_v[keep], n_bins) / np.maximum(kept, 1)
    profile = np.where(kept > 0, clipped, mean)
    # linear interpolation between ring centres (ring k holds radii k..k+1), tapered to zero
    # over the outer fifth
    radius = np.arange(n_bins) + 0.5
    taper = np.clip((reach - flat_r) / (0.2 * reach), 0.0, 1.0)
    model = np.zeros(r.shape, dtype=np.float32)
    model[inside] = np.interp(flat_r, radius, profile) * 0.5 * (1 - np.cos(np.pi * taper))
    return box, model


def _without(image: NDArray, peaks: list[Peak], keep_out: int | None, reach: float,
             box: tuple[slice, slice], factor: int = 1) -> NDArray[np.float32]:
    """``image[box]`` less the ring models of the peaks (other than ``keep_out``) that reach
    into it (a copy of the window only: a frame's worth of memory per call would add up).
    With ``factor`` > 1, ``image`` is the frame block-averaged by ``factor`` (and ``reach``
    and ``box`` are in its pixels)."""
    out = np.array(image[box], dtype=np.float32, copy=True)
    r0, c0 = box[0].start, box[1].start
    shift = (factor - 1) / 2.0
    for k, p in enumerate(peaks):
        if k == keep_out:
            continue
        x, y = ((v - shift) / factor for v in (p.ring_xy or (p.x, p.y)))
        if not (c0 - reach < x < box[1].stop + reach and r0 - reach < y < box[0].stop + reach):
            continue
        (rows, cols), model = ring_model(image, x, y, reach)
        a0, a1 = max(rows.start, r0), min(rows.stop, box[0].stop)
        b0, b1 = max(cols.start, c0), min(cols.stop, box[1].stop)
        if a1 > a0 and b1 > b0:
            out[a0 - r0:a1 - r0, b0 - c0:b1 - c0] -= model[a0 - rows.start:a1 - rows.start,
                                                           b0 - cols.start:b1 - cols.start]
    return out


def _refine_in(window: NDArray, box: tuple[slice, slice], x: float, y: float,
               half_width: int, search_px: float) -> tuple[float, float, float, bool, float]:
    """Point-symmetry refinement (:func:`holofit.crop.symmetry.refine_center`) on a window of
    the frame; full-frame ``(x, y, symmetry, converged, pair fraction)``."""
    r0, c0 = box[0].start, box[1].start
    fit = refine_center(window, x - c0, y - r0, half_width=half_width, search_px=search_px)
    return (fit.x_px + c0, fit.y_px + r0, fit.symmetry, bool(fit.converged),
            float(fit.pair_fraction))


def _rings_at(small: NDArray, factor: int, x0: float, y0: float, radius_px: float,
              span_px: float = 0.0) -> tuple[float, float]:
    """The centre of the most circular rings near ``(x0, y0)`` (full-frame pixels), on the
    block-averaged frame ``small`` (a quarter block is precise enough to place a ring model).

    A neighbour pulls the point-symmetry centre off, by pixels at a few um, and onto the
    midpoint when the two holograms are alike (a pair is nearly point-symmetric about its
    midpoint). The most circular rings' centre is sought first on a grid of trial centres
    ``span_px`` about the start (if ``span_px`` > 0; the radial variance,
    :func:`holofit.crop.radial.radial_variance`, is lowest on a true centre, where one
    hologram's rings are all circular), then refined
    (:func:`holofit.crop.radial.refine_center_radial`)."""
    shift = (factor - 1) / 2.0
    x, y = (x0 - shift) / factor, (y0 - shift) / factor
    radius = min(radius_px, RING_RADIUS) / factor
    span = span_px / factor
    if span > 0:
        box = _box(small.shape, x, y, radius + span + 1)
        rows, cols = np.mgrid[box]
        values = small[box].astype(np.float64).ravel()
        rows, cols = rows.ravel().astype(np.float64), cols.ravel().astype(np.float64)
        steps = np.arange(-span, span + 1e-9, max(span / 4.0, 1.0))
        trials = [(radial_variance(values, cols, rows, x + dx, y + dy, radius), x + dx, y + dy)
                  for dy in steps for dx in steps if dx * dx + dy * dy <= span * span]
        _, x, y = min(trials)
    fit = refine_center_radial(small, x, y, radius=radius, reach=max(MOVE / factor, 2.0))
    if fit.converged:
        return fit.x_px * factor + shift, fit.y_px * factor + shift
    return x * factor + shift, y * factor + shift


@dataclass(frozen=True)
class MainSearch:
    """The main search's settings, which the residual search repeats (full-frame pixels).

    Attributes
    ----------
    radius_px : float
        Vote radius.
    factor : int
        Block size of the coarse vote.
    noise : float
        Noise transform strength of the block-averaged frame.
    min_score, min_alignment, min_symmetry : float
        Thresholds of a candidate (:class:`holofit.crop.centerfind.CenterFinder`).
    separation : float
        Minimum separation of two centres.
    half_width : int
        Half-size of the point-symmetry refinement window.
    search_px : float
        How far one refinement window may move a centre.
    max_centers : int
        Most centres returned.
    """

    radius_px: float
    factor: int
    noise: float
    min_score: float
    min_alignment: float
    min_symmetry: float
    separation: float
    half_width: int
    search_px: float
    max_centers: int


def peel(image: NDArray, peaks: list[Peak], main: MainSearch,
         small: NDArray | None = None) -> list[Peak]:
    """Add the holograms hidden by the rings of the found ones, and refine close pairs.

    Parameters
    ----------
    image : ndarray
        Normalised frame (masked pixels filled).
    peaks : list of Peak
        The main search's centres, strongest first.
    main : MainSearch
        The main search's vote radius, block size, noise, thresholds, minimum separation and
        refinement window: the residual is searched as the frame was, so a peeled hologram
        is one the main search would have found alone.
    small : ndarray, optional
        ``image`` block-averaged by ``main.factor``, if the caller has it.

    Returns
    -------
    list of Peak
        ``peaks`` (close ones refined again) and the new ones after them, at most
        ``main.max_centers``.
    """
    img = np.asarray(image, dtype=np.float32)
    radius_px, factor = main.radius_px, main.factor
    reach = PROFILE_REACH * radius_px
    if small is None:
        small = block_mean(img, factor) if factor > 1 else img
    search = _Search(img, small, reach, PEEL_REACH * radius_px,
                     max(2, round(radius_px / factor)),
                     max(1, round(main.separation / factor)), main)
    peaks = list(peaks)
    original = [replace(q) for q in peaks]
    new = False
    k = 0
    while k < len(peaks) and len(peaks) < main.max_centers:
        centre = peaks[k]
        k += 1
        found = search.next_to(centre, peaks)
        alone = not any(q is not centre and np.hypot(q.x - centre.x, q.y - centre.y)
                        < search.peel_reach for q in peaks)
        if found is None and alone and centre.ring_xy is None and centre.symmetry < RING_CHECK:
            # a neighbour may have pulled the point-symmetry centre off: peel again about
            # the most circular rings' centre (costly, so only for a centre that is not
            # clean and has no neighbour yet)
            centre.ring_xy = _rings_at(search.small, factor, centre.x, centre.y, radius_px)
            found = search.next_to(centre, peaks)
            if found is None:
                # or onto a pair's midpoint (two alike holograms): search from the most
                # circular rings within the minimum separation, keep it if that finds the
                # neighbour
                x, y = _rings_at(search.small, factor, centre.x, centre.y, radius_px,
                                 main.separation)
                if np.hypot(x - centre.x, y - centre.y) > MOVE:
                    moved = replace(centre, x=x, y=y, ring_xy=(x, y))
                    peaks[k - 1] = moved
                    found = search.next_to(moved, peaks)
                    if found is None:
                        peaks[k - 1] = centre
        if found is not None:
            peaks.append(found)
            new = True
            k -= 1  # peel this centre again with the new one subtracted too
    if not new:
        return peaks
    refined = _refine_pairs(img, peaks, reach, main.half_width)
    # a new hologram is judged once both are refined with the other's rings subtracted:
    # what a biased first subtraction left behind is not point-symmetric then
    strict = 0.5 * (1.0 + main.min_symmetry)
    junk = [q.refinement == "peeled" and not q.symmetry >= strict for q in refined]
    if not any(junk):
        return refined
    kept = [q for q, bad in zip(refined, junk, strict=True) if not bad]
    if not any(q.refinement == "peeled" for q in kept):
        return [q for q, bad in zip(original, junk[:len(original)], strict=True)]
    return _refine_pairs(img, [original[i] if i < len(original) else q
                               for i, (q, bad) in enumerate(zip(refined, junk, strict=True))
                               if not bad], reach, main.half_width)


@dataclass
class _Search:
    """The residual search of :func:`peel` (pixels of the frame, or of the block-averaged
    frame: ``*_ds``)."""

    img: NDArray
    small: NDArray
    reach: float
    peel_reach: float
    radius_ds: int
    sep_ds: int
    main: MainSearch

    def next_to(self, centre: Peak, peaks: list[Peak]) -> Peak | None:
        """The strongest accepted new hologram near ``centre`` with every found one's rings
        subtracted, or None."""
        img, f, small, main = self.img, self.main.factor, self.small, self.main
        # the search runs on the block-averaged frame, as the main one does (ring models
        # there cost 1/factor^2 of full-resolution ones); only the refinement needs these
        shift = (f - 1) / 2.0
        box = _box(small.shape, (centre.x - shift) / f, (centre.y - shift) / f,
                   self.peel_reach / f + self.radius_ds)
        window = _without(small, peaks, None, self.reach / f, box, f)
        if min(window.shape) < 6:
            return None
        strength, alignment = orientation_alignment(window, self.radius_ds)
        local_max = ndimage.maximum_filter(strength, size=2 * self.sep_ds + 1, mode="nearest")
        hits = (strength == local_max) & (
            strength >= PEEL_SCORE * main.min_score * main.noise) & (
            alignment >= main.min_alignment)
        rows, cols = np.nonzero(hits)
        order = np.argsort(-strength[rows, cols], kind="stable")
        # the refinement of a peak near the vote window's rim needs its own margin
        wide = _box(img.shape, centre.x, centre.y,
                    self.peel_reach + main.half_width + 2 * main.search_px + 2)
        residual = None
        for i, j in zip(rows[order], cols[order], strict=True):
            di, dj = quadratic_peak(strength, int(i), int(j))
            x0 = box[1].start + (j + dj) * f + (f - 1) / 2.0
            y0 = box[0].start + (i + di) * f + (f - 1) / 2.0
            if np.hypot(x0 - centre.x, y0 - centre.y) > self.peel_reach:
                continue
            if any(np.hypot(x0 - p.x, y0 - p.y) < main.separation for p in peaks):
                continue
            if residual is None:
                residual = _without(img, peaks, None, self.reach, wide)
            x, y, symmetry, converged, pairs = _refine_in(residual, wide, x0, y0,
                                                          main.half_width, main.search_px)
            # stricter than the main search (and judged again once refined, :func:`peel`):
            # the residual holds what subtraction left
            if not (converged and pairs >= EDGE_PAIRS and symmetry >= main.min_symmetry):
                continue
            if any(np.hypot(x - p.x, y - p.y) < main.separation for p in peaks):
                continue
            return Peak(x, y, float(strength[i, j]) / main.noise, float(alignment[i, j]),
                        symmetry, "peeled")
        return None


def _refine_pairs(img: NDArray, peaks: list[Peak], reach: float, half_width: int
                  ) -> list[Peak]:
    """Refine every centre that has a neighbour within reach with the neighbours' ring models
    subtracted (:data:`ROUNDS` rounds)."""
    close = [any(np.hypot(p.x - q.x, p.y - q.y) < reach for q in peaks if q is not p)
             for p in peaks]
    if not any(close):
        return peaks
    for _ in range(ROUNDS):
        moved = []
        for k, p in enumerate(peaks):
            if not close[k] or p.refinement == "radial":
                moved.append(p)
                continue
            start = p.ring_xy or (p.x, p.y)
            box = _box(img.shape, *start, half_width + 2 * MOVE + 2)
            residual = _without(img, peaks, k, reach, box)
            x, y, symmetry, converged, _ = _refine_in(residual, box, *start, half_width, MOVE)
            if converged and np.hypot(x - start[0], y - start[1]) < MOVE:
                p = Peak(x, y, p.score, p.alignment, symmetry, p.refinement, (x, y))
            moved.append(p)
        peaks = moved
    return peaks
