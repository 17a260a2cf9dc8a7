"""The forward model of every fit: parameters -> hologram on a set of pixels, and its Jacobian.

One object serves the Lorenz-Mie prefit and the DDA fits alike: it works for any
:class:`~holofit.scattering.theory.ScatteringEngine` through ``theory.solve`` and the field the
camera records (:func:`holofit.scattering.recorded_field.recorded_field`: the objective lens's image
when the optics have a numerical aperture), and keeps a small cache of solved waves keyed by
what a solve depends on (the static parameters and the orientation), so that

- a position change reuses the solved wave (a new field evaluation, no new solve);
- the alpha column of the Jacobian is exact, ``dI/dalpha = 2 Re[(e_pol + alpha E) . E*]``;
- the numerical-aperture column (an optics parameter) is a one-sided finite difference that
  re-images the same solved wave through the new aperture (no new solve), stepping toward
  smaller apertures where a larger one would collect nothing more (``NA >= n_medium``);
- the spherical-aberration columns (optics parameters too) are exact: the image's derivative
  with respect to a pupil-phase coefficient is one more transform of the same solved wave, all
  of them in one pass (:meth:`holofit.scattering.lens.LensImage.field_derivatives`);
- orientation and static columns are one-sided finite differences on the smooth
  discretisation, each one new solve, warm-started by the engine from its previous solutions
  (the built-in DDA keeps them per lattice); a wave that can differentiate itself with respect
  to a rotation about a lab axis (``wave.rotation_derivative(axis)`` returning a wave-like
  object with ``field_on_pixels``, e.g. served from a T-matrix) gives the orientation columns
  analytically instead. (For an axisymmetric particle the fit keeps the spin at zero; the
  analytic column then includes the spin-about-the-axis part of the lab rotation, which changes
  such a particle's hologram only through lattice artefacts: it steers the optimiser, while
  the residuals it minimises stay exact.) Through the lens, those derivative waves and the
  height derivative of the image (the exact ``z_um`` column) are imaged in one pass
  (:func:`holofit.scattering.lens.lens_fields_on_pixels`).

A fixed extra field on the pixels (``extra_field``: a neighbouring particle's scattered field,
already scaled by its alpha, from its own fit) is added to the particle's scattered field
before the intensity is formed, ``|e_pol + E_extra + alpha E|^2`` (superposition at the camera;
multiple scattering between the two is neglected), through the one intensity function; the
alpha and analytic orientation columns then use ``e_pol + E_extra`` as the reference wave.

Parameters that describe no physical particle (a negative size, a detector plane inside the
particle in the ideal model, a non-positive aperture) raise :class:`InvalidParameters`; the
optimiser wrapper turns that into a rejected step. With an objective in the model (an NA in the
optics or in the state) the hologram is the lens image, defined at every height: a particle
in, near or below the focal plane is valid.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from holofit.aberration import Aberration
from holofit.cache import LRUCache
from holofit.conventions import hologram_intensity
from holofit.holomodel.parameters import ParameterSpace, State
from holofit.optics import Optics
from holofit.scattering.lens import lens_fields_on_pixels, lens_image
from holofit.scattering.recorded_field import recorded_field
from holofit.scattering.theory import Orientation, ScatteredWave, ScatteringEngine

__all__ = ["Evaluation", "HologramModel", "InvalidParameters"]


class InvalidParameters(ValueError):
    """The parameters describe no valid hologram (negative size, detector inside particle)."""


@dataclass
class Evaluation:
    """Fields and hologram at one parameter vector."""

    key: bytes
    state: State
    ex: NDArray[np.complex128]
    ey: NDArray[np.complex128]
    hologram: NDArray[np.float64]


class HologramModel:
    """The hologram of a particle on chosen pixels as a function of a parameter vector.

    Parameters
    ----------
    theory : ScatteringEngine
        Any engine (Lorenz-Mie, the built-in DDA, ADDA).
    space : ParameterSpace
        Which parameters vary and how the optimiser's vector maps to a particle state.
    optics : Optics
        Illumination.
    xs_um, ys_um : array_like, shape (N,)
        Full-frame sample-plane coordinates of the pixels, um (x along columns).
    far_field : bool
        Use the asymptotic far-field form of the scattered field (as ADDA and the paper did).
    wave_cache : int
        Solved waves kept.
    waves : LRUCache, optional
        Share another model's cache of solved waves (e.g. a model on a subset of the same
        crop's pixels).
    """

    def __init__(
        self,
        theory: ScatteringEngine,
        space: ParameterSpace,
        optics: Optics,
        xs_um: ArrayLike,
        ys_um: ArrayLike,
        *,
        far_field: bool = False,
        wave_cache: int = 8,
        waves: LRUCache[tuple, ScatteredWave] | None = None,
        extra_field: tuple[ArrayLike, ArrayLike] | None = None,
    ) -> None:
        self.theory = theory
        self.space = space
        self.optics = optics
        self.xs = np.ascontiguousarray(xs_um, dtype=float).ravel()
        self.ys = np.ascontiguousarray(ys_um, dtype=float).ravel()
        if self.xs.shape != self.ys.shape:
            raise ValueError("xs_um and ys_um must have the same length")
        self.far_field = far_field
        self.n_holograms = 0
        self.n_solves = 0
        self.waves: LRUCache[tuple, ScatteredWave] = waves or LRUCache(wave_cache)
        self._last: Evaluation | None = None
        self._pol = (float(np.cos(optics.polarization_rad)),
                     float(np.sin(optics.polarization_rad)))
        self._radius_um = space.model.bounding_radius_um
        self.extra_field: tuple[NDArray[np.complex128], NDArray[np.complex128]] | None = None
        if extra_field is not None:
            fx, fy = (np.ascontiguousarray(f, dtype=complex).ravel() for f in extra_field)
            if fx.shape != self.xs.shape or fy.shape != self.xs.shape:
                raise ValueError("extra_field must hold one (Ex, Ey) value per pixel")
            self.extra_field = (fx, fy)

    @property
    def n_pixels(self) -> int:
        return int(self.xs.size)

    def restricted(self, index: NDArray[np.intp]) -> HologramModel:
        """The same model on a subset of its pixels, sharing the solved waves."""
        extra = (None if self.extra_field is None
                 else (self.extra_field[0][index], self.extra_field[1][index]))
        return HologramModel(self.theory, self.space, self.optics, self.xs[index],
                             self.ys[index], far_field=self.far_field, waves=self.waves,
                             extra_field=extra)

    # -- solves -------------------------------------------------------------------------
    def wave(self, state: State) -> ScatteredWave:
        """The solved particle of ``state`` (cached by static parameters and orientation)."""
        rot = state.rotation
        key = (state.statics, None if rot is None else np.round(rot, 13).tobytes())
        wave = self.waves.get(key)
        if wave is None:
            try:
                particle = self.space.particle(state)
            except (TypeError, ValueError) as exc:
                raise InvalidParameters(str(exc)) from None
            psi, theta, phi = state.angles()
            wave = self.theory.solve(particle, self.optics, Orientation(psi, theta, phi))
            self.n_solves += 1
            self.waves.put(key, wave)
        return wave

    def aperture(self, state: State) -> float | None:
        """The objective's NA for ``state``: its own (a fitted one), else the optics'."""
        na = state.numerical_aperture
        return self.optics.numerical_aperture if na is None else na

    def aberration(self, state: State) -> Aberration:
        """The objective's pupil phase for ``state``: its own (a fitted one), else the
        optics'."""
        return self.optics.aberration if state.aberration is None else state.aberration

    def fields(self, state: State) -> tuple[NDArray[np.complex128], NDArray[np.complex128]]:
        """Transverse scattered field at the pixels."""
        z = state.position[2]
        na = self.aperture(state)
        if na is not None and not (na > 0 and np.isfinite(na)):
            raise InvalidParameters(f"numerical aperture {na:.4g} is not positive")
        if na is None and not self.aberration(state).is_zero:
            raise InvalidParameters("an aberrated pupil needs an objective (a numerical "
                                    "aperture)")
        if na is None and not abs(z) > 1.0001 * self._radius_for(state):
            raise InvalidParameters(
                f"|z| = {abs(z):.4g} um: the detector plane cuts the particle "
                f"({self._radius_for(state):.4g} um)")
        wave = self.wave(state)
        try:
            ex, ey = recorded_field(wave, state.position, self.xs, self.ys, self.far_field,
                                    state.numerical_aperture, state.aberration)
        except ValueError as exc:  # e.g. pixels too close to grazing for the plane grid
            raise InvalidParameters(str(exc)) from None
        self.n_holograms += 1
        return ex, ey

    def _radius_for(self, state: State) -> float:
        if not self.space.parameters or all(p.kind != "static" for p in self.space.parameters):
            return self._radius_um
        try:
            return self.space.particle(state).bounding_radius_um
        except (TypeError, ValueError) as exc:
            raise InvalidParameters(str(exc)) from None

    # -- holograms ----------------------------------------------------------------------
    def intensity(self, ex: NDArray, ey: NDArray, alpha: float) -> NDArray[np.float64]:
        """``|e_pol + alpha E_perp|^2`` (``+ E_extra`` inside with an extra field):
        :func:`holofit.conventions.hologram_intensity`."""
        if self.extra_field is None:
            return hologram_intensity(ex, ey, self.optics.polarization_rad, alpha)
        fx, fy = self.extra_field
        return hologram_intensity(alpha * ex + fx, alpha * ey + fy,
                                  self.optics.polarization_rad, 1.0)

    def _reference(self) -> tuple[NDArray | float, NDArray | float]:
        """The wave the particle's field interferes with: ``e_pol`` (+ the extra field)."""
        cp, sp = self._pol
        if self.extra_field is None:
            return cp, sp
        return cp + self.extra_field[0], sp + self.extra_field[1]

    @staticmethod
    def _interference(rx: NDArray | float, ry: NDArray | float, a: float, ex: NDArray,
                      ey: NDArray, dx: NDArray, dy: NDArray) -> NDArray[np.float64]:
        """``2 Re[(r + a E) . conj(D)]``: the derivative of the intensity along a field
        derivative ``D`` with a complex reference ``r``."""
        return 2.0 * (np.real((rx + a * ex) * np.conj(dx))
                      + np.real((ry + a * ey) * np.conj(dy)))

    def evaluate(self, vector: ArrayLike) -> Evaluation:
        """Fields and hologram at an optimiser vector (the last one is cached)."""
        v = np.asarray(vector, dtype=float)
        key = v.tobytes()
        if self._last is not None and self._last.key == key:
            return self._last
        state = self.space.state(v)
        ex, ey = self.fields(state)
        ev = Evaluation(key, state, ex, ey, self.intensity(ex, ey, state.alpha))
        self._last = ev
        return ev

    def hologram(self, vector: ArrayLike) -> NDArray[np.float64]:
        """Normalised hologram at the pixels for an optimiser vector."""
        return self.evaluate(vector).hologram

    def hologram_of(self, state: State) -> NDArray[np.float64]:
        """Normalised hologram at the pixels for a state."""
        ex, ey = self.fields(state)
        return self.intensity(ex, ey, state.alpha)

    # -- Jacobian -----------------------------------------------------------------------
    def jacobian(self, vector: ArrayLike) -> NDArray[np.float64]:
        """``d(hologram)/d(vector)``, shape (N, n_parameters); see the module docstring."""
        v = np.asarray(vector, dtype=float)
        base = self.evaluate(v)
        params = self.space.parameters
        cols = np.empty((self.n_pixels, len(params)))
        cp, sp = self._pol
        a = base.state.alpha
        analytic = self._rotation_columns(base)
        pupil = self._aberration_columns(base)
        for i, p in enumerate(params):
            if p.kind == "aberration":
                cols[:, i] = pupil[p.name]
                continue
            if p.kind == "scale":
                ex, ey = base.ex, base.ey
                if self.extra_field is not None:
                    cols[:, i] = self._interference(*self._reference(), a, ex, ey, ex, ey)
                    continue
                cols[:, i] = 2.0 * ((cp + a * ex.real) * ex.real + a * ex.imag * ex.imag
                                    + (sp + a * ey.real) * ey.real + a * ey.imag * ey.imag)
                continue
            if analytic is not None and p.name in analytic:  # orientation (and z, lens)
                cols[:, i] = analytic[p.name]
                continue
            h = p.step
            if p.kind == "optics" and v[i] + h > self.optics.n_medium:
                h = -h  # a larger aperture collects nothing more: look toward smaller ones
            cols[:, i] = self._difference(v, i, h, base)
        return cols

    def _difference(self, v: NDArray, i: int, step: float, base: Evaluation) -> NDArray:
        """One-sided difference along component ``i``, stepping away from invalid values
        (a positive ``step`` goes toward zero for negative values; a negative one is kept)."""
        h = step if (v[i] >= 0 or step < 0) else -step
        for attempt in (h, -h):
            q = v.copy()
            q[i] += attempt
            try:
                state = self.space.state(q)
                return (self.hologram_of(state) - base.hologram) / attempt
            except InvalidParameters:
                continue
        return np.zeros(self.n_pixels)

    def _intensity_derivative(self, base: Evaluation, dx: NDArray, dy: NDArray
                              ) -> NDArray[np.float64]:
        """``dI`` along a derivative ``(dx, dy)`` of the particle's field (before alpha)."""
        a = base.state.alpha
        ex, ey = base.ex, base.ey
        if self.extra_field is not None:
            return a * self._interference(*self._reference(), a, ex, ey, dx, dy)
        cp, sp = self._pol
        return 2.0 * a * (((cp + a * ex.real) * dx.real + a * ex.imag * dx.imag)
                          + ((sp + a * ey.real) * dy.real + a * ey.imag * dy.imag))

    def _aberration_columns(self, base: Evaluation) -> dict[str, NDArray]:
        """The exact columns of the fitted spherical-aberration coefficients (one pass of the
        lens over the solved wave for all of them)."""
        names = [p.name for p in self.space.parameters if p.kind == "aberration"]
        if not names:
            return {}
        state = base.state
        na = self.aperture(state)
        if na is None:
            raise InvalidParameters("fitting an aberration needs an objective (a numerical "
                                    "aperture)")
        fields = lens_image(self.wave(state)).field_derivatives(
            state.position, self.xs, self.ys, names, na, self.aberration(state))
        self.n_holograms += 1
        return {n: self._intensity_derivative(base, dx, dy)
                for n, (dx, dy) in zip(names, fields, strict=True)}

    def _rotation_columns(self, base: Evaluation) -> dict[str, NDArray] | None:
        """Analytic orientation columns, if the solved wave can differentiate itself (through
        the lens, with the exact height column ``z_um`` from the same pass, also when no
        orientation is fitted)."""
        names = [p.name for p in self.space.parameters if p.kind == "orientation"]
        lens = self.aperture(base.state) is not None
        height = lens and "z_um" in self.space.names
        if not names and not height:
            return None
        wave = self.wave(base.state)
        derivative = getattr(wave, "rotation_derivative", None)
        if derivative is None:
            return None
        cp, sp = self._pol
        a = base.state.alpha
        axes = self.space.rotation_axes()
        joint = getattr(wave, "field_and_rotation_derivatives", None)
        na = base.state.numerical_aperture
        if joint is not None and not lens:
            # field and derivatives share the pixels' geometry: one pass over the pixels
            _, fields = joint(base.state.position, self.xs, self.ys, axes, self.far_field)
        elif lens:
            # through the lens: the derivative waves, and the height derivative of the image
            # (exact, no new table: the z column, also when no orientation is fitted), share
            # one pass over the Bessel table
            fields = lens_fields_on_pixels(
                [derivative(axis) for axis in axes] + [wave] * height, base.state.position,
                self.xs, self.ys, na, height_derivative=[False] * len(axes) + [True] * height,
                aberration=base.state.aberration)
            if height:
                names = [*names, "z_um"]
        else:
            fields = [recorded_field(derivative(axis), base.state.position, self.xs, self.ys,
                                     self.far_field, na, base.state.aberration) for axis in axes]
        ex, ey = base.ex, base.ey
        out = {}
        for name, (dx, dy) in zip(names, fields, strict=True):
            if self.extra_field is not None:
                out[name] = a * self._interference(*self._reference(), a, ex, ey, dx, dy)
                continue
            out[name] = 2.0 * a * (((cp + a * ex.real) * dx.real + a * ex.imag * dx.imag)
                                   + ((sp + a * ey.real) * dy.real + a * ey.imag * dy.imag))
        return out

