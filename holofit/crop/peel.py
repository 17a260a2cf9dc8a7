"""Resolving holograms whose ring systems overlap: peel the found ones off and search again.

The orientation-alignment vote (:mod:`holofit.crop.transform`) of a strong hologram swamps a
weaker one within ~1.5 vote radii: the pair gives one peak, at the stronger centre. Peeling
takes each found centre's ring system away and votes again on what is left:

1. the *ring model* of a centre is the azimuthal (clipped) mean of the normalised frame minus
   one on 1-px rings about it (:func:`ring_model`): for a sphere its whole hologram, for a rod
   most of it; the clipping keeps a neighbour's central fringes out of the rings' means. It
   covers the hologram's measured reach (:mod:`holofit.crop.profile`: its fringes above the
   pixel noise), at least one and at most :data:`PROFILE_REACH` vote radii;
2. the residual frame near each found centre, with the ring models of every found centre
   nearby subtracted, is voted on again (same vote radius, block size, noise level and
   thresholds as the main search); a peak within :data:`PEEL_REACH` vote radii of the centre
   (the distance over which a strong hologram's vote swamps a weaker one's: a property of
   the vote), farther than half a zone radius from every found centre (the separation of
   :class:`holofit.crop.profile.Scales`), whose refined centre on the residual is
   point-symmetric, is a new hologram;
3. every centre with a neighbour within reach is refined again by point symmetry with the
   neighbours' ring models subtracted (alternating), which takes the neighbour's bias off
   both centres.

Every other length is a multiple of the hologram's measured zone radius ``zeta =
sqrt(lambda_m z)`` (:mod:`holofit.crop.profile`), the scale of its central fringes, in frame
pixels: it follows the instrument's pixel size and the particle's height where fixed pixels
were right for one instrument only.

A lone hologram leaves only noise (and, for a non-circular one, a weak non-symmetric residual)
once its ring model is subtracted, so its result does not change.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from holofit.crop.profile import Scales, clipped_profile
from holofit.crop.radial import radial_variance, refine_center_radial
from holofit.crop.symmetry import quadratic_peak, refine_center
from holofit.crop.transform import block_mean, orientation_alignment

__all__ = ["PEEL_REACH", "PROFILE_REACH", "MainSearch", "Peak", "peel", "remeasure",
           "ring_model", "taken"]

#: new holograms are sought within this many vote radii of a found one (farther ones are not
#: swamped by it: the main search finds them)
PEEL_REACH = 2.0
#: a ring model covers at most this many vote radii about its centre
PROFILE_REACH = 3.0
#: a new hologram in the residual must score this many times the main search's smallest
#: score, and its point symmetry must lie halfway from the main search's smallest to 1: what
#: subtraction leaves behind (a fringe cut by the frame's edge) can pass the main search's
#: thresholds by a hair, while real neighbours pass these by far (docs: validation, "field of
#: view")
PEEL_SCORE = 3.0
#: ... and an alignment of at least this: with the found holograms subtracted a hidden one
#: points its gradients at its centre as a lone one does (0.8-0.98), where junk left by the
#: subtraction does not
PEEL_ALIGNMENT = 0.45
#: ... and not be within ~10 px of the frame's edge (fewer than this fraction of its point
#: pairs inside: the main search finds such holograms, with the radial refinement)
EDGE_PAIRS = 0.5
#: refinement rounds of neighbouring centres with each other's ring models subtracted
ROUNDS = 3
#: how far one round may move a centre, zone radii (a neighbour's bias is a fraction of the
#: central spot, half a zone radius)
MOVE = 0.2
#: a centre whose rings are less circular than this (:mod:`holofit.crop.profile`) is peeled
#: again about its most circular rings' centre if the first peel finds nothing: a lone
#: hologram scores above it, a close alike neighbour pulls a sphere's score below it
RING_CHECK = 0.9
#: a centre whose rings are less circular than this may be the midpoint of two alike
#: holograms (their point-symmetric interference term), not a particle (:func:`peel`,
#: :func:`_drop_midpoints`); a member of a close pair scores above it (docs: validation,
#: "field of view")
MIDPOINT_CIRCULARITY = 0.35
#: a new centre found in the residual must be at least this circular there (its neighbour
#: subtracted; what subtraction leaves near a centre scores well below it)
PEELED_CIRCULARITY = 0.5
#: largest radius of the rings whose circularity places a ring model, zone radii (the central
#: spot and the first two fringes place it as well as all of them, at a fraction of the cost)
RING_RADIUS = 1.5
#: the most circular rings of a pair's midpoint candidate are sought this many zone radii
#: about it (two alike holograms up to two zone radii apart give one vote peak between them)
MIDPOINT_SPAN = 1.0


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
    #: zone radius and reach, pixels (:mod:`holofit.crop.profile`; NaN: not measured)
    zone: float = float("nan")
    reach: float = float("nan")
    circularity: float = float("nan")


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
    box, r, profile, _ = clipped_profile(image, x, y, reach)
    inside = r < reach
    flat_r = r[inside]
    # linear interpolation between ring centres (ring k holds radii k..k+1), tapered to zero
    # over the outer fifth
    radius = np.arange(len(profile)) + 0.5
    taper = np.clip((reach - flat_r) / (0.2 * reach), 0.0, 1.0)
    model = np.zeros(r.shape, dtype=np.float32)
    model[inside] = np.interp(flat_r, radius, profile) * 0.5 * (1 - np.cos(np.pi * taper))
    return box, model


def model_radius(peak: Peak, radius_px: float) -> float:
    """Radius of ``peak``'s ring model, pixels: its reach, at least one vote radius (the
    central fringes, where the reach is unknown or short) and at most :data:`PROFILE_REACH`
    (the cost)."""
    reach = peak.reach if np.isfinite(peak.reach) else PROFILE_REACH * radius_px
    return float(min(max(reach, radius_px), PROFILE_REACH * radius_px))


def _without(image: NDArray, peaks: list[Peak], keep_out: int | None, radius_px: float,
             box: tuple[slice, slice], factor: int = 1) -> NDArray[np.float32]:
    """``image[box]`` less the ring models of the peaks (other than ``keep_out``) that reach
    into it (a copy of the window only: a frame's worth of memory per call would add up).
    With ``factor`` > 1, ``image`` is the frame block-averaged by ``factor`` (and ``box`` is
    in its pixels); ``radius_px`` is the vote radius in full-frame pixels."""
    out = np.array(image[box], dtype=np.float32, copy=True)
    r0, c0 = box[0].start, box[1].start
    shift = (factor - 1) / 2.0
    for k, p in enumerate(peaks):
        if k == keep_out:
            continue
        reach = model_radius(p, radius_px) / factor
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


def _rings_at(small: NDArray, factor: int, x0: float, y0: float, ring_px: float,
              move_px: float, span_px: float = 0.0) -> tuple[float, float]:
    """The centre of the most circular rings of radius up to ``ring_px`` near ``(x0, y0)``
    (full-frame pixels), on the block-averaged frame ``small`` (a quarter block is precise
    enough to place a ring model).

    A neighbour pulls the point-symmetry centre off, by pixels at a few um, and onto the
    midpoint when the two holograms are alike (a pair is nearly point-symmetric about its
    midpoint). The most circular rings' centre is sought first on a grid of trial centres
    ``span_px`` about the start (if ``span_px`` > 0; the radial variance,
    :func:`holofit.crop.radial.radial_variance`, is lowest on a true centre, where one
    hologram's rings are all circular), then refined within ``move_px``
    (:func:`holofit.crop.radial.refine_center_radial`)."""
    shift = (factor - 1) / 2.0
    x, y = (x0 - shift) / factor, (y0 - shift) / factor
    radius = max(ring_px / factor, 3.0)
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
    fit = refine_center_radial(small, x, y, radius=radius, reach=max(move_px / factor, 2.0))
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
    half_width : int
        Half-size of the point-symmetry refinement window.
    search_px : float
        How far one refinement window may move a centre.
    max_centers : int
        Most centres returned.
    scales : Scales
        The frame's pixel noise and the rules that turn a hologram's measured zone radius
        into the minimum separation of two centres (:mod:`holofit.crop.profile`).
    """

    radius_px: float
    factor: int
    noise: float
    min_score: float
    min_alignment: float
    min_symmetry: float
    half_width: int
    search_px: float
    max_centers: int
    scales: Scales

    def zone(self, peak: Peak) -> float:
        """``peak``'s zone radius, or the default where it is not known."""
        return self.scales.zone_or_default(peak.zone)

    def move(self, peak: Peak) -> float:
        """How far one refinement round may move ``peak``, pixels (:data:`MOVE`)."""
        return max(MOVE * self.zone(peak), 1.0)


def peel(image: NDArray, peaks: list[Peak], main: MainSearch,
         small: NDArray | None = None) -> list[Peak]:
    """Add the holograms hidden by the rings of the found ones, and refine close pairs.

    Parameters
    ----------
    image : ndarray
        Normalised frame (masked pixels filled).
    peaks : list of Peak
        The main search's centres, strongest first, with their zone radii and reaches.
    main : MainSearch
        The main search's vote radius, block size, noise, thresholds and refinement window,
        and the frame's scales: the residual is searched as the frame was, so a peeled
        hologram is one the main search would have found alone.
    small : ndarray, optional
        ``image`` block-averaged by ``main.factor``, if the caller has it.

    Returns
    -------
    list of Peak
        ``peaks`` (close ones refined again, whether or not a new one was found: a
        neighbour's rings pull a centre toward it by up to ~1 um at 60x) and the new ones
        after them, at most ``main.max_centers``.
    """
    img = np.asarray(image, dtype=np.float32)
    radius_px, factor = main.radius_px, main.factor
    if small is None:
        small = block_mean(img, factor) if factor > 1 else img
    search = _Search(img, small, PEEL_REACH * radius_px, max(2, round(radius_px / factor)), main)
    peaks = list(peaks)
    original = [replace(q) for q in peaks]
    new = False
    k = 0
    while k < len(peaks) and len(peaks) < main.max_centers:
        centre = peaks[k]
        k += 1
        found = None
        if centre.ring_xy is None and not centre.circularity >= MIDPOINT_CIRCULARITY:
            # the midpoint of a pair one of whose members is found: the other is its mirror
            mirrored = _mirrored(img, peaks, k - 1, main)
            if mirrored is not None:
                peaks[k - 1] = centre = mirrored
        if centre.ring_xy is None and not centre.circularity >= MIDPOINT_CIRCULARITY:
            # rings not circular about it at all (lone holograms: >= 0.83): perhaps the
            # midpoint of two alike holograms, whose interference term is point-symmetric
            # about it; search from the most circular rings within a zone radius, one of the
            # two, and keep that if it finds the other
            zone, move = main.zone(centre), main.move(centre)
            x, y = _rings_at(search.small, factor, centre.x, centre.y,
                             min(radius_px, RING_RADIUS * zone), move, MIDPOINT_SPAN * zone)
            moved = replace(centre, x=x, y=y, ring_xy=(x, y))
            peaks[k - 1] = moved
            found = search.next_to(moved, peaks)
            if found is None:
                peaks[k - 1] = centre
            else:
                centre = moved
        found = found or search.next_to(centre, peaks)
        alone = not any(q is not centre and np.hypot(q.x - centre.x, q.y - centre.y)
                        < search.peel_reach for q in peaks)
        if (found is None and alone and centre.ring_xy is None
                and not centre.circularity >= RING_CHECK):
            # a neighbour may have pulled the point-symmetry centre off: peel again about
            # the most circular rings' centre (costly, so only for a centre that is not
            # clean and has no neighbour yet)
            zone, move = main.zone(centre), main.move(centre)
            ring_px = min(radius_px, RING_RADIUS * zone)
            centre.ring_xy = _rings_at(search.small, factor, centre.x, centre.y, ring_px, move)
            found = search.next_to(centre, peaks)
            if found is None:
                # or onto a pair's midpoint (two alike holograms): search from the most
                # circular rings within a zone radius, keep it if that finds the neighbour
                x, y = _rings_at(search.small, factor, centre.x, centre.y, ring_px, move,
                                 MIDPOINT_SPAN * zone)
                if np.hypot(x - centre.x, y - centre.y) > move:
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
        return _refine_pairs(img, _drop_midpoints(peaks, main.scales), main)
    refined = _refine_pairs(img, _drop_midpoints(peaks, main.scales), main)
    # a new hologram is judged once both are refined with the other's rings subtracted:
    # what a biased first subtraction left behind is not point-symmetric then (the main
    # search's threshold: a tilted rod refined next to a neighbour scores 0.6-0.7)
    junk = [q.refinement == "peeled" and not q.symmetry >= main.min_symmetry for q in refined]
    if not any(junk):
        return refined
    kept = [q for q, bad in zip(refined, junk, strict=True) if not bad]
    if not any(q.refinement == "peeled" for q in kept):
        return original
    return _refine_pairs(img, kept, main)


@dataclass
class _Search:
    """The residual search of :func:`peel` (pixels of the frame, or of the block-averaged
    frame: ``*_ds``)."""

    img: NDArray
    small: NDArray
    peel_reach: float
    radius_ds: int
    main: MainSearch

    def next_to(self, centre: Peak, peaks: list[Peak]) -> Peak | None:
        """The strongest accepted new hologram near ``centre`` with every found one's rings
        subtracted, or None."""
        img, f, small, main = self.img, self.main.factor, self.small, self.main
        scales = main.scales
        # the search runs on the block-averaged frame, as the main one does (ring models
        # there cost 1/factor^2 of full-resolution ones); only the refinement needs these
        shift = (f - 1) / 2.0
        box = _box(small.shape, (centre.x - shift) / f, (centre.y - shift) / f,
                   self.peel_reach / f + self.radius_ds)
        window = _without(small, peaks, None, main.radius_px, box, f)
        if min(window.shape) < 6:
            return None
        strength, alignment = orientation_alignment(window, self.radius_ds)
        sep = scales.separation_px
        sep_ds = max(1, round(sep / f)) if sep else 1
        local_max = ndimage.maximum_filter(strength, size=2 * sep_ds + 1, mode="nearest")
        hits = (strength == local_max) & (
            strength >= PEEL_SCORE * main.min_score * main.noise) & (
            alignment >= max(main.min_alignment, PEEL_ALIGNMENT))
        rows, cols = np.nonzero(hits)
        order = np.argsort(-strength[rows, cols], kind="stable")
        # the refinement of a peak near the vote window's rim needs its own margin
        wide = _box(img.shape, centre.x, centre.y,
                    self.peel_reach + main.half_width + 2 * main.search_px + 2)
        residual = None
        for i, j in zip(rows[order], cols[order], strict=True):
            di, dj = quadratic_peak(strength, int(i), int(j))
            # the vote window's pixels are the block-averaged frame's, from the box's corner
            x0 = (box[1].start + j + dj) * f + (f - 1) / 2.0
            y0 = (box[0].start + i + di) * f + (f - 1) / 2.0
            if np.hypot(x0 - centre.x, y0 - centre.y) > self.peel_reach:
                continue
            if taken(x0, y0, math.nan, peaks, scales):
                continue
            if residual is None:
                residual = _without(img, peaks, None, main.radius_px, wide)
            x, y, symmetry, converged, pairs = _refine_in(residual, wide, x0, y0,
                                                          main.half_width, main.search_px)
            # stricter than the main search (and judged again once refined, :func:`peel`):
            # the residual holds what subtraction left
            if not (converged and pairs >= EDGE_PAIRS and symmetry >= main.min_symmetry):
                continue
            prof = scales.measure(residual, x - wide[1].start, y - wide[0].start)
            if not prof.circularity >= PEELED_CIRCULARITY:
                continue  # what subtraction left near a centre, or a pair's midpoint
            if taken(x, y, prof.zone_px, peaks, scales):
                continue
            return Peak(x, y, float(strength[i, j]) / main.noise, float(alignment[i, j]),
                        symmetry, "peeled", zone=prof.zone_px, reach=prof.reach_px,
                        circularity=prof.circularity)
        return None


def taken(x: float, y: float, zone: float, peaks: list[Peak], scales: Scales) -> bool:
    """``(x, y)`` is a found hologram's (closer than the separation,
    :meth:`holofit.crop.profile.Scales.separation`), or the midpoint of two found ones within
    a separation: the interference term of two holograms, ``2 Re(E_1 E_2*)``, is
    point-symmetric about their midpoint (exactly for alike particles), and it is what is
    left near the midpoint once both ring models are subtracted."""
    for k, p in enumerate(peaks):
        if np.hypot(x - p.x, y - p.y) < scales.separation(p.zone, zone):
            return True
        for q in peaks[k + 1:]:
            mx, my = 0.5 * (p.x + q.x), 0.5 * (p.y + q.y)
            if np.hypot(x - mx, y - my) < scales.separation(p.zone, q.zone, zone):
                return True
    return False


def _mirrored(img: NDArray, peaks: list[Peak], k: int, main: MainSearch) -> Peak | None:
    """Peak ``k`` moved to its mirror image through a found neighbour within two zone radii,
    ``2 c - q``, if that is a hologram centre there (point-symmetric and circular once the
    others' rings are subtracted): ``k`` is then the midpoint of ``q`` and a hologram alike
    to it, whose interference term is point-symmetric about the midpoint. None otherwise."""
    centre = peaks[k]
    zone = main.zone(centre)
    scales = main.scales
    for q in peaks:
        if q is centre or np.hypot(q.x - centre.x, q.y - centre.y) > 2 * MIDPOINT_SPAN * zone:
            continue
        x0, y0 = 2 * centre.x - q.x, 2 * centre.y - q.y
        search = scales.separation(zone)
        box = _box(img.shape, x0, y0, main.half_width + 2 * search + 2)
        if not (box[1].start <= x0 < box[1].stop and box[0].start <= y0 < box[0].stop):
            continue
        residual = _without(img, peaks, k, main.radius_px, box)
        x, y, symmetry, converged, _ = _refine_in(residual, box, x0, y0, main.half_width,
                                                  max(search, 1.0))
        if not (converged and symmetry >= main.min_symmetry):
            continue
        prof = scales.measure(residual, x - box[1].start, y - box[0].start)
        others = [p for p in peaks if p is not centre]
        if prof.circularity >= PEELED_CIRCULARITY and not taken(x, y, prof.zone_px, others,
                                                                  scales):
            return replace(centre, x=x, y=y, symmetry=symmetry, ring_xy=(x, y),
                           zone=prof.zone_px, reach=prof.reach_px,
                           circularity=prof.circularity)
    return None


def _drop_midpoints(peaks: list[Peak], scales: Scales) -> list[Peak]:
    """``peaks`` without those that are the midpoint of two others (:func:`taken`) and whose
    rings are not circular (:data:`MIDPOINT_CIRCULARITY`): the main search takes the
    interference term of two alike holograms for a centre, and once peeling has found the
    two, it is left over."""
    kept = list(peaks)
    for p in list(peaks):
        others = [q for q in kept if q is not p]
        if p.circularity < MIDPOINT_CIRCULARITY and any(
                np.hypot(p.x - 0.5 * (q.x + r.x), p.y - 0.5 * (q.y + r.y))
                < scales.separation(q.zone, r.zone, p.zone)
                for k, q in enumerate(others) for r in others[k + 1:]):
            kept = others
    return kept


def _refine_pairs(img: NDArray, peaks: list[Peak], main: MainSearch) -> list[Peak]:
    """Refine every centre whose ring model reaches a neighbour, or a neighbour's reaches it,
    with the neighbours' ring models subtracted (:data:`ROUNDS` rounds)."""
    radius_px, half_width = main.radius_px, main.half_width
    close = [any(np.hypot(p.x - q.x, p.y - q.y)
                 < max(model_radius(p, radius_px), model_radius(q, radius_px))
                 for q in peaks if q is not p) for p in peaks]
    if not any(close):
        return peaks
    for _ in range(ROUNDS):
        moved = []
        for k, p in enumerate(peaks):
            if not close[k] or p.refinement == "radial":
                moved.append(p)
                continue
            start = p.ring_xy or (p.x, p.y)
            if np.hypot(start[0] - p.x, start[1] - p.y) > main.scales.separation(p.zone):
                start = (p.x, p.y)  # rings most circular elsewhere: not this centre's
            move = main.move(p)
            box = _box(img.shape, *start, half_width + 2 * move + 2)
            residual = _without(img, peaks, k, radius_px, box)
            x, y, symmetry, converged, _ = _refine_in(residual, box, *start, half_width, move)
            if converged and np.hypot(x - start[0], y - start[1]) < move:
                p = replace(p, x=x, y=y, symmetry=symmetry, ring_xy=(x, y))
            moved.append(p)
        peaks = moved
    return peaks


def remeasure(image: NDArray, peaks: list[Peak], scales: Scales) -> list[Peak]:
    """Zone radius and reach of every centre with a neighbour within its profile's radius,
    measured again with the neighbours' ring models subtracted (a neighbour's fringes would
    lengthen the reach: their ring means do not vanish on the rings through it)."""
    radius_px = scales.radius_px
    span = scales.profile_radius
    out = []
    for k, p in enumerate(peaks):
        if not any(q is not p and np.hypot(p.x - q.x, p.y - q.y) < span + model_radius(
                q, radius_px) for q in peaks):
            out.append(p)
            continue
        box = _box(image.shape, p.x, p.y, span)
        residual = _without(image, peaks, k, radius_px, box)
        prof = scales.measure(residual, p.x - box[1].start, p.y - box[0].start)
        zone = prof.zone_px if np.isfinite(prof.zone_px) else p.zone
        out.append(replace(p, zone=zone, reach=prof.reach_px, circularity=prof.circularity))
    return out
