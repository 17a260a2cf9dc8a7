"""A hologram's radial profile about its centre: its fringe scale and its reach.

Every detection scale of the crop stage follows from two lengths measured on each hologram
(:func:`measure_profile`), in pixels of the frame, so that they follow the instrument's pixel
size and the particle's height without a setting:

*zone radius* ``zeta``
    The radius of the first Fresnel zone, ``zeta = sqrt(lambda_m z)`` (``lambda_m`` the
    wavelength in the medium, ``z`` the height): the hologram's fringes are
    ``cos(pi rho^2 / zeta^2 + phase)`` near the centre (paraxially), so the squared radii of
    successive zero crossings of the profile advance by ``zeta^2``. It is measured as the
    median of those steps over the first crossings (robust to one missed or spurious
    crossing; 1-5 % high, the non-paraxial growth of the steps, at 6-30 um). The central
    bright or dark spot has a radius of ~``zeta / 2`` (the first crossing: 0.45-0.51
    ``zeta`` for spheres at 6-30 um on the paper's 60x instrument), and
    the fringe spacing at radius ``rho`` is ``~zeta^2 / rho``: ``zeta`` is the hologram's
    own length scale near its centre, where two holograms must be told apart.
*reach*
    The largest radius at which the rings' fringe power envelope (their clipped mean square
    less the noise variance, the largest within one local fringe spacing) stands above the
    frame's pixel noise variance (:func:`_reach`): beyond it a
    hologram's fringes are below the noise of every single pixel, within it they are not,
    which is what decides whether a neighbour's hologram enters a crop.

The profile is the azimuthal mean of the normalised frame minus one on 1-px rings, each ring
clipped at :data:`CLIP` standard deviations (a neighbour's central fringes, which cover a
small arc of a ring, are left out of its mean), the same rings as the ring models of
:mod:`holofit.crop.peel`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["CLIP", "FringeOptics", "RingProfile", "Scales", "clipped_profile", "measure_profile"]

#: pixels farther than this many ring standard deviations from a ring's mean are left out of it
CLIP = 2.5
#: zero crossings closer to the centre than this many pixels are ignored (rings of a few
#: pixels carry more noise than signal)
INNER_PX = 2.0
#: the zone radius is the median step of this many first zero crossings' squared radii
CROSSINGS = 6
#: rings of fewer pixels than this (in the frame's corners) do not decide the reach: the
#: noise of their mean square is more than a fifth of the noise variance
MIN_RING = 50
#: the circularity is measured within this many zone radii (the central spot and the first
#: two fringes: where a hologram outweighs its neighbours)
CIRCLE_ZONES = 1.5


@dataclass(frozen=True)
class FringeOptics:
    """What the instrument says about a hologram's fringes, in frame pixels.

    Attributes
    ----------
    wavelength_px : float
        Wavelength in the medium over the pixel size, ``lambda_0 / (n_m * pixel)``: converts
        a zone radius to a height, ``z = zeta^2 / lambda_m``.
    max_sin : float
        Sine of the steepest scattering angle whose fringes reach the camera resolved: the
        objective's ``NA / n_m`` (1 without an objective) and the pixel's Nyquist limit
        ``lambda_m / (2 pixel)``, whichever is smaller. Fringes at radius ``rho`` belong to
        ``sin(theta) = rho / sqrt(z^2 + rho^2)``: none reach past ``z tan(theta_max)``.
    """

    wavelength_px: float
    max_sin: float

    def __post_init__(self) -> None:
        if not (self.wavelength_px > 0 and 0 < self.max_sin <= 1):
            raise ValueError(f"wavelength_px must be > 0 and max_sin in (0, 1], got "
                             f"{self.wavelength_px!r}, {self.max_sin!r}")

    @classmethod
    def of(cls, wavelength_um: float, medium_index: float, pixel_size_um: float,
           numerical_aperture: float | None) -> FringeOptics:
        """From the instrument's vacuum wavelength, medium index, pixel size (um) and NA."""
        lam = wavelength_um / medium_index
        sines = [1.0, lam / (2.0 * pixel_size_um)]
        if numerical_aperture is not None:
            sines.append(numerical_aperture / medium_index)
        return cls(lam / pixel_size_um, min(sines))

    def height_px(self, zone_px: float) -> float:
        """``|z|`` of a hologram of zone radius ``zone_px``, pixels (paraxial: the first
        crossings' steps grow with ``rho / z``, so this is 2-10 % high at 6-30 um on the
        paper's 60x instrument)."""
        return zone_px * zone_px / self.wavelength_px

    def farthest_px(self, zone_px: float) -> float:
        """The largest radius any resolved fringe of this hologram reaches, pixels."""
        t = self.max_sin / math.sqrt(max(1.0 - self.max_sin**2, 1e-12))
        return self.height_px(zone_px) * t


@dataclass(frozen=True)
class RingProfile:
    """What :func:`measure_profile` found (pixels; NaN: not measurable).

    Attributes
    ----------
    zone_px : float
        Radius of the first Fresnel zone, ``sqrt(lambda_m z)``.
    reach_px : float
        Largest radius at which the fringes stand above the pixel noise.
    crossings : int
        Zero crossings the zone radius was measured from.
    circularity : float
        Fraction of the signal power ``sum (I - 1)^2`` within :data:`CIRCLE_ZONES` zone radii
        that the ring means hold (1: circular rings, as a lone sphere's, minus noise; a
        tilted rod's less; the midpoint of two holograms far less).
    """

    zone_px: float
    reach_px: float
    crossings: int
    circularity: float = math.nan


def clipped_profile(image: NDArray, x: float, y: float, radius: float, *,
                    spread: bool = False) -> tuple[Any, ...]:
    """Clipped ring means of ``image - 1`` about ``(x, y)`` out to ``radius`` pixels.

    Returns
    -------
    box : tuple of slice
        Rows and columns of ``image`` within ``radius`` of the centre (clipped to the frame).
    r : ndarray of float32, shape of the box
        Distance of each pixel of the box from the centre.
    profile : ndarray of float
        Ring ``k`` (radii ``k .. k + 1``): its clipped mean (:data:`CLIP`); 0 for rings
        without pixels.
    count : ndarray of int
        Pixels of each ring inside the frame.
    mean, variance, power : ndarray of float
        With ``spread``: each ring's plain mean and variance, and its clipped mean square.
    """
    r0, r1 = max(0, int(np.floor(y - radius))), min(image.shape[0], int(np.ceil(y + radius)) + 1)
    c0, c1 = max(0, int(np.floor(x - radius))), min(image.shape[1], int(np.ceil(x + radius)) + 1)
    box = (slice(r0, r1), slice(c0, c1))
    rows = np.arange(r0, r1, dtype=np.float32)[:, None] - np.float32(y)
    cols = np.arange(c0, c1, dtype=np.float32)[None, :] - np.float32(x)
    r = np.hypot(cols, rows)  # float32: the windows can be large
    inside = r < radius
    flat_b = r[inside].astype(np.int32)
    flat_v = image[box][inside].astype(np.float64) - 1.0
    ok = np.isfinite(flat_v)
    if not ok.all():
        flat_b, flat_v = flat_b[ok], flat_v[ok]
    n_bins = int(radius) + 1
    count = np.bincount(flat_b, minlength=n_bins)[:n_bins]
    safe = np.maximum(count, 1)
    mean = np.bincount(flat_b, flat_v, n_bins)[:n_bins] / safe
    var = np.bincount(flat_b, flat_v**2, n_bins)[:n_bins] / safe - mean**2
    keep = np.abs(flat_v - mean[flat_b]) <= CLIP * np.sqrt(np.maximum(var, 0.0))[flat_b] + 1e-12
    kept_b, kept_v = flat_b[keep], flat_v[keep]
    kept = np.bincount(kept_b, minlength=n_bins)[:n_bins]
    clipped = np.bincount(kept_b, kept_v, n_bins)[:n_bins] / np.maximum(kept, 1)
    profile = np.where(kept > 0, clipped, mean)
    if spread:
        power = np.bincount(kept_b, kept_v**2, n_bins)[:n_bins] / np.maximum(kept, 1)
        return box, r, profile, count, mean, np.maximum(var, 0.0), np.where(kept > 0, power, 0.0)
    return box, r, profile, count


def _zone(profile: NDArray, count: NDArray) -> tuple[float, int]:
    """Zone radius from the first zero crossings of ``profile`` (1-px rings)."""
    radius = np.arange(len(profile)) + 0.5
    used = (count > 0) & (radius >= INNER_PX)
    p, rad = profile[used], radius[used]
    if p.size < 3:
        return math.nan, 0
    flip = np.nonzero(np.sign(p[1:]) * np.sign(p[:-1]) < 0)[0]
    if flip.size < 3:
        return math.nan, int(flip.size)
    flip = flip[:CROSSINGS + 1]
    # linear interpolation of the crossing between the two rings
    a, b = p[flip], p[flip + 1]
    at = rad[flip] + (rad[flip + 1] - rad[flip]) * a / (a - b)
    steps = np.diff(at**2)
    step = float(np.median(steps))
    if not step > 0:
        return math.nan, int(flip.size)
    return math.sqrt(step), int(flip.size)


def _reach(power: NDArray, count: NDArray, zone_px: float, noise: float) -> float:
    """Largest radius whose fringe power envelope is at least the noise variance
    ``noise^2``.

    A ring's signal power is its clipped mean square less the noise variance: circular
    fringes put it in the ring's mean (a fringe of amplitude ``A`` peaks at ``A^2``), a rod's
    fringes, which are not circular, in its spread (``A^2 / 2``): the reach ends where the
    fringes' amplitude falls to between one and 1.4 noise standard deviations. Rings of fewer
    than :data:`MIN_RING` pixels (corners of the frame) are not judged.
    """
    n = len(power)
    radius = np.arange(n) + 0.5
    signal = np.where(count >= MIN_RING, power - noise * noise, 0.0)
    # one local fringe spacing, ~zeta^2 / rho, either side (at least a ring)
    zone = zone_px if math.isfinite(zone_px) else 4.0
    half = np.maximum(1, np.ceil(zone * zone / np.maximum(radius, 1.0))).astype(int)
    lo = np.maximum(np.arange(n) - half, 0)
    hi = np.minimum(np.arange(n) + half + 1, n)
    envelope = np.array([signal[a:b].max() for a, b in zip(lo, hi, strict=True)])
    above = np.nonzero(envelope >= noise * noise)[0]
    return float(radius[above[-1]] + 0.5) if above.size else 0.0


def measure_profile(image: NDArray, x: float, y: float, noise: float, max_radius: float
                    ) -> RingProfile:
    """Zone radius and reach of the hologram centred at ``(x, y)`` (module docstring).

    Parameters
    ----------
    image : ndarray, shape (rows, cols)
        Normalised frame (background ~1; NaN pixels are left out).
    x, y : float
        Centre, full-frame pixels.
    noise : float
        Pixel noise of the frame (standard deviation, normalised units).
    max_radius : float
        Rings out to this radius are measured, pixels (the reach is at most this).

    Returns
    -------
    RingProfile
    """
    radius = max(float(max_radius), 4.0)
    _, _, profile, count, mean, var, power = clipped_profile(image, x, y, radius, spread=True)
    zone, crossings = _zone(profile, count)
    circularity = math.nan
    if math.isfinite(zone):
        inner = slice(1, max(2, int(CIRCLE_ZONES * zone) + 1))
        n = count[inner]
        total = float(np.sum(n * (var[inner] + mean[inner] ** 2)))
        if total > 0:
            circularity = 1.0 - float(np.sum(n * var[inner])) / total
    return RingProfile(zone, _reach(power, count, zone, noise), crossings, circularity)


@dataclass(frozen=True)
class Scales:
    """The centre finder's lengths for one frame, from each hologram's measured profile.

    Attributes
    ----------
    radius_px : float
        Vote radius, pixels.
    pixel_noise : float
        The frame's pixel noise (normalised units), the threshold of the reach.
    optics : FringeOptics, optional
        The instrument's fringe limits (caps the reach at the farthest resolved fringe).
    separation_px : float, optional
        A fixed merge distance instead of the measured one (``min_separation_px``).
    """

    radius_px: float
    pixel_noise: float
    optics: FringeOptics | None = None
    separation_px: float | None = None

    @property
    def profile_radius(self) -> float:
        """Rings measured out to this radius, pixels: three vote radii (the ring models of
        :mod:`holofit.crop.peel` cover as much)."""
        return 3.0 * self.radius_px

    def measure(self, image: NDArray, x: float, y: float) -> RingProfile:
        """The profile of the hologram at ``(x, y)`` (:func:`measure_profile`), its reach at
        most the farthest fringe the optics resolve."""
        prof = measure_profile(image, x, y, self.pixel_noise, self.profile_radius)
        if self.optics is not None and math.isfinite(prof.zone_px):
            prof = replace(prof, reach_px=min(prof.reach_px,
                                              self.optics.farthest_px(prof.zone_px)))
        return prof

    def zone_or_default(self, zone: float) -> float:
        """``zone``, or where it could not be measured (fewer than three fringe crossings
        in the frame) a quarter of the vote radius (a guess, which merges centres an eighth
        of the vote radius apart)."""
        return zone if math.isfinite(zone) and zone > 0 else 0.25 * self.radius_px

    def separation(self, *zones: float) -> float:
        """Two centres closer than this are one hologram: half the larger zone radius (the
        radius of the central spot: each centre would lie in the other's central fringe),
        unless a fixed distance was given."""
        if self.separation_px is not None:
            return self.separation_px
        return 0.5 * max(self.zone_or_default(z) for z in zones)
