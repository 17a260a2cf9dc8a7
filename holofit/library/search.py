"""The orientation library (the paper's steps 3-4): which orientations make a particle's
hologram look most like a frame.

Turning the particle about the optical axis by ``psi`` is the same as turning the incident
polarisation by ``-psi`` and the camera by ``-psi`` (the light travels along the axis). So a
library needs solves over the *tilt* only: for each tilt ``theta`` (and spin ``phi`` for a
particle that is not axisymmetric) the particle is solved, at ``psi = 0``, for incident light
polarised along x (scattered field ``X``) and along y (``Y``). For an instrument polarised at
angle beta, the hologram of the particle turned by ``psi`` at the polar sample ``(rho, phi)``
is that of the unturned one, lit at ``gamma = beta - psi``, at ``(rho, phi - psi)``:

    I = A0 + A1 cos 2 gamma + A2 sin 2 gamma,
    A0 = 1 + alpha Re(X_x + Y_y) + alpha^2 (|X|^2 + |Y|^2) / 2,
    A1 = alpha Re(X_x - Y_y) + alpha^2 (|X|^2 - |Y|^2) / 2,
    A2 = alpha Re(X_y + Y_x) + alpha^2 Re(X . Y*),

(the fields as the camera records them: an objective lens is linear and commutes with the
rotation about its axis) with ``E = cos(gamma) X + sin(gamma) Y`` by linearity: exact for an
incidence-independent polarisability (FCD, the default, and CM); with LDR, whose polarisability
depends on the polarisation, a small approximation that only ranks starting points. On a polar
grid the shift by ``psi`` is cyclic, so the weighted sums that make up R^2 for *every* psi on
the grid are a few FFT correlations along the azimuth: per tilt and frame, two field
evaluations and nine correlations.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from holofit.cache import LRUCache
from holofit.conventions import axis_from_angles, euler_zyz
from holofit.library.polar import PolarGrid
from holofit.optics import Optics
from holofit.particles import ParticleModel
from holofit.scattering.recorded_field import recorded_field
from holofit.scattering.theory import Orientation, ScatteredWave, ScatteringEngine

__all__ = ["HEIGHT_STEP_UM", "Candidate", "OrientationLibrary", "Tilt", "pick_candidates",
           "tilt_grid"]

#: the tilts' fields on a frame's polar grid are kept for heights rounded to this step, um
#: (:class:`OrientationLibrary`)
HEIGHT_STEP_UM = 0.05


@dataclass(frozen=True)
class Tilt:
    """A solved orientation of the library (``psi = 0``): polar angle and spin, rad."""

    theta: float
    phi: float = 0.0


@dataclass(frozen=True)
class Candidate:
    """A starting orientation for a frame: zyz angles (rad) and the library's R^2 there."""

    psi: float
    theta: float
    phi: float
    r2: float

    @property
    def orientation(self) -> Orientation:
        return Orientation(self.psi, self.theta, self.phi)


def tilt_grid(model: ParticleModel, step_rad: float) -> list[Tilt]:
    """The library's tilts for ``model`` at a grid step of about ``step_rad``.

    ``theta`` covers [0, pi/2] for a particle that is its own mirror image (u and -u are one
    orientation: with psi in [0, 2 pi) every axis is covered once) and [0, pi] otherwise; a
    particle that is not axisymmetric also gets spins ``phi`` in [0, 2 pi). Nodes are equally
    spaced and include both ends of the theta range.
    """
    if not 0 < step_rad <= math.pi / 2:
        raise ValueError(f"tilt step must be in (0, pi/2] rad, got {step_rad}")
    top = math.pi / 2 if model.head_tail_symmetric else math.pi
    n = math.ceil(top / step_rad - 1e-9) + 1
    thetas = np.linspace(0.0, top, n)
    if model.axisymmetric:
        return [Tilt(float(t)) for t in thetas]
    n_phi = math.ceil(2 * math.pi / step_rad - 1e-9)
    phis = 2 * math.pi * np.arange(n_phi) / n_phi
    return [Tilt(float(t), float(p)) for t in thetas for p in phis]


class OrientationLibrary:
    """Solved tilts of one particle and the R^2 of every (tilt, psi) for a frame.

    Parameters
    ----------
    theory : ScatteringEngine
        The engine.
    model : ParticleModel
        The particle.
    optics : Optics
        The instrument's illumination (its polarisation angle is beta above).
    tilts : list of Tilt
        The solved orientations (:func:`tilt_grid`).
    z_step_um : float, optional
        The tilts' fields on a polar grid depend on the particle's height only (the grid is
        centred on the particle), so they are kept for heights rounded to this step and reused
        by every frame within half a step (0.05 um: a fringe phase error of ~0.2 rad at the
        edge of a 140-pixel crop 12 um from focus, immaterial to which orientation ranks
        first); None computes them at every frame's own height.
    """

    def __init__(self, theory: ScatteringEngine, model: ParticleModel, optics: Optics,
                 tilts: list[Tilt], z_step_um: float | None = HEIGHT_STEP_UM) -> None:
        if not tilts:
            raise ValueError("the library needs at least one tilt")
        self.theory = theory
        self.model = model
        self.optics = optics
        self.tilts = list(tilts)
        self._x = replace(optics, polarization_rad=0.0)
        self._y = replace(optics, polarization_rad=math.pi / 2)
        self._waves: dict[int, tuple[ScatteredWave, ScatteredWave]] = {}
        self.n_solves = 0
        self.z_step_um = z_step_um
        self._fields: LRUCache[tuple, tuple[NDArray, ...]] = LRUCache(8 * len(self.tilts))

    @property
    def optics_x(self) -> Optics:
        """The optics of the x-polarised solves."""
        return self._x

    @property
    def optics_y(self) -> Optics:
        """The optics of the y-polarised solves."""
        return self._y

    def set_waves(self, i: int, pair: tuple[ScatteredWave, ScatteredWave]) -> None:
        """Tilt ``i``'s x- and y-polarised waves, solved elsewhere
        (:mod:`holofit.library.tilts`)."""
        self._waves[i] = pair

    def waves(self, i: int) -> tuple[ScatteredWave, ScatteredWave]:
        """The x- and y-polarised solutions of tilt ``i`` (solved on first use)."""
        pair = self._waves.get(i)
        if pair is None:
            t = self.tilts[i]
            o = Orientation(0.0, t.theta, t.phi)
            pair = (self.theory.solve(self.model, self._x, o),
                    self.theory.solve(self.model, self._y, o))
            self.n_solves += 2
            self._waves[i] = pair
        return pair

    def solve_all(self) -> None:
        """Solve every tilt now (otherwise they are solved as frames need them)."""
        for i in range(len(self.tilts)):
            self.waves(i)

    def polar_fields(self, i: int, grid: PolarGrid, position_um: tuple[float, float, float]
                     ) -> tuple[NDArray, ...]:
        """The recorded fields of tilt ``i``'s x- and y-polarised solutions on ``grid``
        (``X_x, X_y, Y_x, Y_y``), at the particle's height rounded to :attr:`z_step_um`."""
        z = float(position_um[2])
        if self.z_step_um is not None:
            z = round(z / self.z_step_um) * self.z_step_um
        key = (i, round(z, 9), _grid_key(grid))
        cached = self._fields.get(key)
        if cached is not None:
            return cached
        # offsets from the grid's centre: the fields depend on them and on the height only
        cx, cy = float(grid.xs_um[0].mean()), float(grid.ys_um[0].mean())
        xs = (grid.xs_um - cx).ravel()
        ys = (grid.ys_um - cy).ravel()
        wx, wy = self.waves(i)
        here = (0.0, 0.0, z)
        fields = tuple(v.reshape(grid.shape) for w in (wx, wy)
                       for v in recorded_field(w, here, xs, ys))
        return self._fields.put(key, fields)

    def scores(self, grid: PolarGrid, data: NDArray, weights: NDArray,
               position_um: tuple[float, float, float], alpha: float) -> NDArray[np.float64]:
        """R^2 of every (tilt, psi) against a frame sampled on ``grid``.

        Parameters
        ----------
        grid : PolarGrid
            Polar samples about the frame's particle position (x, y).
        data, weights : ndarray, shape ``grid.shape``
            The frame's samples and their weights (:func:`holofit.library.polar.sample_crop`).
        position_um : tuple of float
            ``(x, y, z)`` of the particle, um (x, y = the grid's centre).
        alpha : float
            Scattered-field scaling.

        Returns
        -------
        ndarray, shape (n_tilts, n_phi)
            ``R^2`` for psi = ``grid.phi``.
        """
        n_phi = grid.phi.size
        w = np.asarray(weights, dtype=float)
        d = np.asarray(data, dtype=float)
        s_w = w.sum()
        s_d = (w * d).sum()
        s_dd = (w * d * d).sum()
        ss_tot = s_dd - s_d * s_d / s_w
        wd_f = np.fft.rfft(w * d, axis=1)
        w_f = np.fft.rfft(w, axis=1)
        gamma = self.optics.polarization_rad - grid.phi
        coef = np.stack([np.ones(n_phi), np.cos(2 * gamma), np.sin(2 * gamma)])  # (3, n_phi)
        out = np.empty((len(self.tilts), n_phi))

        def corr(f_hat: NDArray, g: NDArray) -> NDArray:
            # sum over rho and phi of f(rho, phi) g(rho, phi - psi_j), for every j
            return np.fft.irfft((f_hat * np.conj(np.fft.rfft(g, axis=1))).sum(axis=0), n=n_phi)

        for i in range(len(self.tilts)):
            xx, xy, yx, yy = self.polar_fields(i, grid, position_um)
            mag_x = xx.real**2 + xx.imag**2 + xy.real**2 + xy.imag**2
            mag_y = yx.real**2 + yx.imag**2 + yy.real**2 + yy.imag**2
            cross = (xx * np.conj(yx) + xy * np.conj(yy)).real
            a = [
                1.0 + alpha * (xx.real + yy.real) + 0.5 * alpha**2 * (mag_x + mag_y),
                alpha * (xx.real - yy.real) + 0.5 * alpha**2 * (mag_x - mag_y),
                alpha * (xy.real + yx.real) + alpha**2 * cross,
            ]
            s_dm = sum(coef[k] * corr(wd_f, a[k]) for k in range(3))
            s_mm = sum(coef[k] * coef[m] * corr(w_f, a[k] * a[m]) * (1 if k == m else 2)
                       for k in range(3) for m in range(k, 3))
            out[i] = 1.0 - (s_dd - 2.0 * s_dm + s_mm) / ss_tot
        return out


def _grid_key(grid: PolarGrid) -> tuple:
    return (grid.rho_um.size, float(grid.rho_um[0]), float(grid.rho_um[-1]), grid.phi.size)


def _axis_distance(a: Candidate, b: Candidate, head_tail: bool, axisymmetric: bool) -> float:
    """Angle between two orientations, rad (between axes for axisymmetric particles)."""
    if axisymmetric:
        ua = axis_from_angles(a.theta, a.psi)
        ub = axis_from_angles(b.theta, b.psi)
        c = float(np.dot(ua, ub))
        if head_tail:
            c = abs(c)
        return math.acos(max(-1.0, min(1.0, c)))
    ra = euler_zyz(a.psi, a.theta, a.phi)
    rb = euler_zyz(b.psi, b.theta, b.phi)
    c = (np.trace(ra.T @ rb) - 1.0) / 2.0
    return math.acos(max(-1.0, min(1.0, float(c))))


def pick_candidates(scores: NDArray[np.float64], tilts: list[Tilt], psi: NDArray[np.float64],
                    model: ParticleModel, n: int, min_separation_rad: float) -> list[Candidate]:
    """The best ``n`` local maxima of a score table, at least ``min_separation_rad`` apart.

    Local maxima are taken over neighbouring tilts (in list order) and neighbouring psi
    (cyclic); a maximum closer than the separation to a better one is skipped.
    """
    s = np.asarray(scores, dtype=float)
    padded = np.pad(s, ((1, 1), (0, 0)), constant_values=-np.inf)
    is_max = np.ones_like(s, dtype=bool)
    for di in (-1, 0, 1):
        for dj in (-1, 0, 1):
            if di == 0 and dj == 0:
                continue
            shifted = np.roll(padded, -dj, axis=1)[1 + di: 1 + di + s.shape[0]]
            is_max &= s >= shifted
    order = np.argsort(s[is_max])[::-1]
    ii, jj = np.nonzero(is_max)
    picked: list[Candidate] = []
    for k in order:
        i, j = int(ii[k]), int(jj[k])
        if not np.isfinite(s[i, j]):
            continue
        cand = Candidate(float(psi[j]), tilts[i].theta, tilts[i].phi, float(s[i, j]))
        if all(_axis_distance(cand, c, model.head_tail_symmetric, model.axisymmetric)
               >= min_separation_rad for c in picked):
            picked.append(cand)
        if len(picked) >= n:
            break
    return picked
