"""The built-in DDA engine: a :class:`~holofit.scattering.theory.ScatteringEngine`.

Solving a particle (``BuiltinDDA.solve``):

1. discretise the model on its lattice (cached per model and dipole size);
2. rotate the incident wave into the particle frame (no re-voxelisation on rotation) and solve
   only the instrument's polarisation, warm-started from the nearest earlier solution of the
   same lattice; the interaction's FFT is cached per (grid, d, k);
3. the returned :class:`DDAWave` knows the exact scattered field everywhere outside the
   particle: a multipole expansion (built lazily from the far-field pattern) serves points
   outside twice the circumscribing sphere, direct dipole summation the points closer in; on a
   camera plane the expansion is evaluated through :mod:`holofit.scattering.multipole`'s
   interpolated grid, so a new particle position costs milliseconds, not a new solve.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from holofit.cache import LRUCache
from holofit.conventions import PROPAGATION_DIRECTION, euler_zyz
from holofit.dda.adda.frames import adda_amplitude_matrix, lab_map
from holofit.dda.dipoles import DipoleSolution, DipoleSystem, incident_field
from holofit.dda.farfield import far_field, far_field_on_grid
from holofit.dda.lattice import Lattice
from holofit.dda.nearfield import direct_field
from holofit.dda.settings import DDASettings
from holofit.dda.voxelize import voxelize
from holofit.optics import Optics
from holofit.particles import ParticleModel
from holofit.scattering.expansion_wave import NEAR_ZONE, ExpansionWave
from holofit.scattering.mie import CrossSections
from holofit.scattering.multipole import (
    MultipoleExpansion,
    default_order,
    project_far_field,
    quadrature,
)
from holofit.scattering.theory import Orientation, ScatteringEngine
from holofit.scattering.tmatrix import TMatrix
from holofit.scattering.tmatrix_wave import TMatrixWave
from holofit.scattering.wigner import rotate_coefficients

__all__ = ["NEAR_ZONE", "BuiltinDDA", "DDAWave"]

#: warm-start from an earlier solution only if its incident wave is this close (rad-ish)
WARM_START_RADIUS = 0.3
#: earlier solutions kept per lattice, and used at most in one least-squares warm start
MAX_STORED_SOLUTIONS = 6
MAX_WARM_BASIS = 4
#: relative size below which trailing multipole orders are dropped (numerical noise)
COEFF_FLOOR = 1e-13


def _trim(expansion: MultipoleExpansion) -> MultipoleExpansion:
    mag = np.maximum(np.abs(expansion.p).max(axis=1), np.abs(expansion.q).max(axis=1))
    keep = np.nonzero(mag > COEFF_FLOOR * mag.max())[0]
    L = max(int(keep.max()) if keep.size else 1, 1)
    old = expansion.order
    sl = (slice(0, L + 1), slice(old - L, old + L + 1))
    return MultipoleExpansion(expansion.k, expansion.p[sl].copy(), expansion.q[sl].copy(),
                              expansion.radius_um)


class DDAWave(ExpansionWave):
    """A solved DDA problem: particle, orientation and illumination fixed.

    An :class:`~holofit.scattering.expansion_wave.ExpansionWave` whose expansion is built on
    first use from the far-field pattern and whose near field is the direct dipole sum.

    Attributes
    ----------
    solution : DipoleSolution
        Dipole moments in the particle frame.
    rotation : ndarray (3, 3)
        Particle-to-lab rotation.
    radius_um : float
        Radius of the sphere about the particle centre containing all dipole cells.
    """

    exact_near_field = True

    def __init__(self, model: ParticleModel, optics: Optics, orientation: Orientation,
                 solution: DipoleSolution, rotation: NDArray[np.float64],
                 system: DipoleSystem | None = None, tolerance: float = 1e-5) -> None:
        lat = solution.lattice
        radius = float(np.sqrt((lat.positions**2).sum(axis=1)).max() + lat.d * np.sqrt(3) / 2)
        super().__init__(optics, None, radius_um=radius)  # expansion: built on first use
        self.model = model
        self.orientation = orientation
        self.solution = solution
        self.rotation = rotation
        self._system = system
        self._tolerance = tolerance
        self._cross_solution: DipoleSolution | None = None

    # -- far field ----------------------------------------------------------------------
    @property
    def lattice(self) -> Lattice:
        return self.solution.lattice

    def far_field_amplitude(self, directions: ArrayLike) -> NDArray[np.complex128]:
        """``F(n)`` (lab frame) at lab unit directions, by direct dipole summation:
        ``E_sca = exp(ikr)/(-ikr) F``, phase origin at the particle centre."""
        d = np.atleast_2d(np.asarray(directions, dtype=float))
        f_p = far_field(self.lattice, self.solution.P, self.optics.k, d @ self.rotation)
        return f_p @ self.rotation.T

    def _adda_lab(self) -> NDArray[np.float64]:
        """holofit lab -> ADDA's lab for this instrument: light along +z, the instrument's
        polarisation along x (:func:`holofit.dda.adda.frames.lab_map`)."""
        return lab_map(self.optics.polarization_rad)

    def _cross_polarised(self) -> DipoleSolution:
        """The solution for the orthogonal polarisation (ADDA's "Y"), solved on first use."""
        if self._cross_solution is None:
            if self._system is None:
                raise RuntimeError("this wave has no dipole system to solve the orthogonal "
                                   "polarisation (build it with BuiltinDDA.solve)")
            e_y = self._adda_lab().T @ np.array([0.0, 1.0, 0.0])  # ADDA's y in holofit's lab
            sol = self.solution
            self._cross_solution = self._system.solve(sol.propagation, self.rotation.T @ e_y,
                                                      tol=self._tolerance)
        return self._cross_solution

    def amplitude_matrix(self, directions: ArrayLike,
                         phase_origin: str = "particle") -> NDArray[np.complex128]:
        """Amplitude matrix ``[S1, S2, S3, S4]`` (M, 4) at holofit-lab unit directions.

        ADDA's (Bohren & Huffman) convention, in ADDA's lab (light along +z, the instrument's
        polarisation along x: ``n_adda = Rx(pi) Rz(-beta) n``), at the scattering angles
        ``theta, phi`` of ``n_adda``: with ``e_par_i = (cos phi, sin phi, 0)``,
        ``e_per_i = (sin phi, -cos phi, 0)``, ``e_par_s = e_theta`` and ``e_per_s = -e_phi``,

            [E_par_s, E_per_s] = exp(ikr)/(-ikr) [[S2, S3], [S4, S1]] [E_par_i, E_per_i].

        This is what ADDA writes to ``ampl_scatgrid`` for the same dipoles and orientation
        (:class:`~holofit.dda.adda.engine.AddaWave.amplitude_matrix`). The second incident
        polarisation is solved on first use.

        Parameters
        ----------
        directions : array_like, shape (M, 3)
            Scattering directions in holofit's lab.
        phase_origin : {"particle", "box"}
            Refer the phases to the particle centre (holofit's convention) or to the centre of
            the dipole box (ADDA's; the same point for centred lattices).
        """
        n = np.atleast_2d(np.asarray(directions, dtype=float))
        n = n / np.linalg.norm(n, axis=1, keepdims=True)
        lab = self._adda_lab()
        n_a = n @ lab.T
        theta = np.arccos(np.clip(n_a[:, 2], -1.0, 1.0))
        phi = np.arctan2(n_a[:, 1], n_a[:, 0])
        k = self.optics.k
        rot = self.rotation
        f_x = far_field(self.lattice, self.solution.P, k, n @ rot) @ rot.T
        f_y = far_field(self.lattice, self._cross_polarised().P, k, n @ rot) @ rot.T
        s = adda_amplitude_matrix(f_x @ lab.T, f_y @ lab.T, theta, phi)
        if phase_origin == "box":
            # S_box(n) = S_particle(n) exp(i k (a - n).s), s = particle centre - box centre
            centre = lab @ (rot @ (-self.lattice.box_centre))
            s = s * np.exp(1j * k * ((np.array([0.0, 0.0, 1.0]) - n_a) @ centre))[:, None]
        elif phase_origin != "particle":
            raise ValueError(f"phase_origin must be 'particle' or 'box', got {phase_origin!r}")
        return s

    def cross_sections(self) -> CrossSections:
        """Extinction, scattering and absorption cross sections (um^2) for the instrument's
        polarisation; efficiencies per ``pi r_eq^2`` (volume-equivalent radius of the filling).

        ``C_ext = 4 pi k sum_j Im(E_inc,j^* . P_j)`` and
        ``C_abs = 4 pi k sum_j [Im(P_j . (alpha_j^-1)^* P_j^*) - (2/3) k^3 |P_j|^2]``
        (Draine 1988; ADDA's formulas), ``C_sca = C_ext - C_abs``, unit incident amplitude.
        """
        sol = self.solution
        k = self.optics.k
        e_inc = incident_field(self.lattice.positions, k, sol.propagation, sol.polarization)
        cext = 4 * np.pi * k * float(np.sum(np.imag(np.sum(np.conj(e_inc) * sol.P, axis=1))))
        inv_alpha = 1.0 / (sol.alpha if sol.alpha.ndim == 2 else sol.alpha[:, None])
        cabs = 4 * np.pi * k * float(np.sum((-np.imag(inv_alpha) - 2.0 / 3.0 * k**3)
                                            * np.abs(sol.P) ** 2))
        volume = float(self.lattice.occupied_volume_um3().sum())
        geo = np.pi * (3.0 * volume / (4.0 * np.pi)) ** (2.0 / 3.0)
        return CrossSections(cext, cext - cabs, cabs, cext / geo, (cext - cabs) / geo,
                             cabs / geo)

    @property
    def expansion(self) -> MultipoleExpansion:
        """Multipole expansion of the scattered field about the particle centre (lab frame)."""
        if self._expansion is None:
            # far field on a particle-frame quadrature grid (separable lattice sums), projected
            # onto vector spherical harmonics there, then rotated to the lab (Wigner D)
            k = self.optics.k
            order = default_order(k, self.radius_um)
            mu, w, phi = quadrature(order)
            a = 1j * far_field_on_grid(self.lattice, self.solution.P, k, mu, phi)
            p, q = project_far_field(a, mu, w, phi, order)
            p = rotate_coefficients(p, self.rotation)
            q = rotate_coefficients(q, self.rotation)
            self._expansion = _trim(MultipoleExpansion(k, p, q, self.radius_um))
        return self._expansion

    # -- fields: the expansion beyond NEAR_ZONE radii (ExpansionWave), dipole sums within ---
    def _near_field(self, points_lab: NDArray) -> NDArray[np.complex128]:
        return self._direct_lab(points_lab)

    def _direct_lab(self, points_lab: NDArray) -> NDArray[np.complex128]:
        """Scattered field (N, 3) at lab points by direct dipole sums (any distance)."""
        pts_p = points_lab @ self.rotation
        e_p = direct_field(pts_p, self.lattice.positions, self.solution.P, self.optics.k)
        return e_p @ self.rotation.T


class BuiltinDDA(ScatteringEngine):
    """holofit's own discrete-dipole engine.

    Parameters
    ----------
    settings : DDASettings, optional
        Discretisation and solver settings.
    """

    name = "builtin"

    def __init__(self, settings: DDASettings | None = None, **options: Any) -> None:
        self.settings = (settings or DDASettings()).replace(**options) if options else (
            settings or DDASettings())
        self._lattices: LRUCache[tuple, Lattice] = LRUCache(16)
        self._solutions: dict[tuple, list[DipoleSolution]] = {}
        #: recent solutions by lattice spacing and wavenumber, whatever the particle's sizes:
        #: another size of a smoothly filled particle keeps its dipoles where they were (a few
        #: appear or vanish at the surface with fractions near zero), so an earlier solution,
        #: carried over dipole by dipole, is a good start for it too
        self._by_spacing: LRUCache[tuple, list[DipoleSolution]] = LRUCache(8)
        self._systems: LRUCache[tuple, DipoleSystem] = LRUCache(
            8, on_evict=lambda key, _: self._solutions.pop(key, None))
        self._tmatrices: dict[tuple, TMatrix] = {}
        self.last_iterations = 0

    def forget_history(self) -> None:
        """Forget the earlier solutions the solves warm-start from (the lattices, systems and
        T-matrices stay)."""
        self._solutions.clear()
        self._by_spacing.clear()

    def dipole_size(self, model: ParticleModel, optics: Optics) -> float:
        """The lattice spacing this engine uses for ``model``, um."""
        return self.settings.dipole_size_for(model, optics)

    def lattice(self, model: ParticleModel, optics: Optics) -> Lattice:
        """The (cached) discretisation of ``model``."""
        d = self.dipole_size(model, optics)
        key = (model, d, self.settings.filling)
        return self._lattices.get_or_create(key, lambda: voxelize(model, d, self.settings.filling))

    def _system(self, lat: Lattice, optics: Optics) -> tuple[tuple, DipoleSystem]:
        dtype = np.complex64 if self.settings.precision == "single" else np.complex128
        key = (lat.cache_key(), optics.k, optics.n_medium, self.settings.polarizability, dtype)
        system = self._systems.get_or_create(
            key, lambda: DipoleSystem(lat, optics.k, optics.n_medium,
                                      self.settings.polarizability, dtype))
        return key, system

    # -- T-matrix (holofit.scattering.tmatrix): every orientation without a solve ---------------
    def _tmatrix_key(self, model: ParticleModel, optics: Optics) -> tuple:
        return (model, self.dipole_size(model, optics), optics.wavelength_um, optics.n_medium)

    def use_tmatrix(self, model: ParticleModel, optics: Optics, tmatrix: TMatrix,
                    source: str = "T-matrix") -> None:
        """Serve :meth:`solve` for ``(model, optics)`` (any orientation and polarisation) from
        ``tmatrix``, after checking that it was made for this model, lattice, optics and
        settings (:func:`holofit.dda.tmatrix_io.check_compatible`, errors name ``source``)."""
        from holofit.dda.tmatrix_io import check_compatible, describe

        d = self.dipole_size(model, optics)
        expected = describe(model, d, optics, self.settings, self.lattice(model, optics))
        check_compatible(tmatrix.provenance, expected, source, self.settings.tolerance)
        self._tmatrices[self._tmatrix_key(model, optics)] = tmatrix

    def tmatrix(self, model: ParticleModel, optics: Optics, path: str | None = None,
                **build_options: Any) -> TMatrix:
        """The T-matrix of ``(model, optics)``, used from now on by :meth:`solve`.

        Already in use: returned. Else, if ``path`` names an existing file, it is loaded
        (refused with :class:`~holofit.dda.tmatrix_io.TMatrixMismatch` if made for anything
        else); otherwise it is built (:func:`holofit.dda.tmatrix_build.build_tmatrix`, options
        passed on) and, with ``path``, saved there.
        """
        from pathlib import Path

        from holofit.dda.tmatrix_build import build_tmatrix
        from holofit.dda.tmatrix_io import load_tmatrix, save_tmatrix

        tm = self._tmatrices.get(self._tmatrix_key(model, optics))
        if tm is not None:
            return tm
        if path is not None and Path(path).exists():
            tm = load_tmatrix(path)
            self.use_tmatrix(model, optics, tm, source=str(path))
            return tm
        tm = build_tmatrix(model, optics, self.settings, **build_options)
        if path is not None:
            save_tmatrix(tm, path)
        self.use_tmatrix(model, optics, tm)
        return tm

    def solve(self, model: ParticleModel, optics: Optics,
              orientation: Orientation | None = None) -> DDAWave | TMatrixWave:
        """The scattered wave: from the particle's T-matrix if one is in use for
        ``(model, optics)`` (:meth:`tmatrix`), else by a DDA solve (:meth:`solve_direct`)."""
        orientation = orientation or Orientation()
        if self._tmatrices:
            tm = self._tmatrices.get(self._tmatrix_key(model, optics))
            if tm is not None:
                return TMatrixWave(model, optics, orientation, tm,
                                   direct=lambda o: self.solve_direct(model, optics, o))
        return self.solve_direct(model, optics, orientation)

    def solve_direct(self, model: ParticleModel, optics: Optics,
                     orientation: Orientation | None = None) -> DDAWave:
        """The scattered wave by a DDA solve (warm-started), never from a T-matrix."""
        orientation = orientation or Orientation()
        rot = euler_zyz(*orientation.as_tuple())
        a_p = rot.T @ PROPAGATION_DIRECTION
        e_p = rot.T @ optics.polarization
        lat = self.lattice(model, optics)
        key, system = self._system(lat, optics)
        previous = self._solutions.setdefault(key, [])
        siblings = self._by_spacing.get_or_create((lat.d, optics.k, optics.n_medium), list)
        x0 = self._warm_start(lat, optics.k, previous, a_p, e_p, system)
        if x0 is None:
            carried = [carry_over(s, lat) for s in siblings if s.lattice is not lat]
            x0 = self._warm_start(lat, optics.k, [c for c in carried if c is not None], a_p,
                                  e_p, system)
        sol = system.solve(a_p, e_p, tol=self.settings.tolerance, x0=x0,
                           maxiter=self.settings.max_iterations, method=self.settings.solver)
        self.last_iterations = sol.iterations
        for store in (previous, siblings):
            store.append(sol)
            if len(store) > MAX_STORED_SOLUTIONS:
                store.pop(0)
        return DDAWave(model, optics, orientation, sol, rot, system, self.settings.tolerance)


    @staticmethod
    def _warm_start(lat: Lattice, k: float, previous: list[DipoleSolution], a_p: NDArray,
                    e_p: NDArray, system: DipoleSystem) -> NDArray[np.complex128] | None:
        """Initial guess for the new incident wave from earlier solutions of the same lattice.

        With several nearby solutions, the new incident field is fitted (least squares) by
        theirs and the same combination of their dipole moments is the guess (the system is
        linear); with one, its moments are rotated and re-phased to the new wave (a rotation of
        the particle rotates the field it feels and shifts its phase by ``exp(ik da.r)``).
        """
        def distance(s: DipoleSolution) -> float:
            return float(np.sum((s.propagation - a_p) ** 2) + np.sum((s.polarization - e_p) ** 2))

        near = sorted((s for s in previous if distance(s) < WARM_START_RADIUS**2), key=distance)
        if not near:
            return None
        pos = lat.positions
        if len(near) >= 2:
            near = near[:MAX_WARM_BASIS]
            basis = np.array([incident_field(pos, k, s.propagation, s.polarization).ravel()
                              for s in near]).T
            target = incident_field(pos, k, a_p, e_p).ravel()
            coef, *_ = np.linalg.lstsq(basis, target, rcond=None)
            p0 = np.einsum("i,inc->nc", coef, np.array([s.P for s in near]))
        else:
            s = near[0]
            q = _rotation_between((s.propagation, s.polarization), (a_p, e_p))
            phase = np.exp(1j * k * (pos @ (a_p - s.propagation)))
            p0 = (s.P @ q.T) * phase[:, None]
        alpha = system.alpha(a_p, e_p)
        w = np.sqrt(alpha if alpha.ndim == 2 else alpha[:, None])
        # the solver's unknown is alpha^(-1/2) P; a voxel that is all medium (alpha = 0, e.g.
        # a new boundary voxel of a smaller particle) has no moment to carry over
        with np.errstate(divide="ignore", invalid="ignore"):
            x0 = np.where(w != 0, p0 / np.where(w != 0, w, 1.0), 0.0).ravel()
        return x0 if np.all(np.isfinite(x0)) else None


def carry_over(solution: DipoleSolution, lattice: Lattice) -> DipoleSolution | None:
    """``solution`` moved onto another lattice of the same spacing, dipole by dipole.

    Dipoles at the same particle-frame position keep their moments; new ones start at zero.
    None if the lattices do not share the same grid (another spacing or offset).
    """
    old = solution.lattice
    d = lattice.d
    if old.d != d:
        return None
    shift = (old.origin - lattice.origin) / d
    if np.max(np.abs(shift - np.round(shift))) > 1e-6:
        return None
    old_ijk = old.ijk + np.round(shift).astype(np.int64)
    lo = np.minimum(old_ijk.min(axis=0), lattice.ijk.min(axis=0))
    hi = np.maximum(old_ijk.max(axis=0), lattice.ijk.max(axis=0))
    dims = tuple(int(v) for v in hi - lo + 1)
    old_flat = np.ravel_multi_index((old_ijk - lo).T, dims)
    new_flat = np.ravel_multi_index((lattice.ijk - lo).T, dims)
    order = np.argsort(old_flat)
    pos = np.searchsorted(old_flat[order], new_flat)
    pos = np.clip(pos, 0, old_flat.size - 1)
    match = old_flat[order][pos] == new_flat
    moments = np.zeros((lattice.n_dipoles, 3), dtype=solution.P.dtype)
    moments[match] = solution.P[order[pos[match]]]
    return dataclasses.replace(solution, lattice=lattice, P=moments)


def _rotation_between(old: tuple[NDArray, NDArray], new: tuple[NDArray, NDArray]) -> NDArray:
    """Rotation taking the orthonormal pair (a, e) of ``old`` to that of ``new``."""
    def frame(a: NDArray, e: NDArray) -> NDArray:
        return np.column_stack([a, e, np.cross(a, e)])

    return frame(*new) @ frame(*old).T

