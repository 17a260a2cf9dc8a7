"""A particle's T-matrix: its DDA lattice's exact linear response, for every orientation.

With an incidence-independent polarisability (``"fcd"``, the engine's default, ``"ldr_avg"``
or ``"cm"``, :mod:`holofit.dda.polarizability`), the DDA is one linear map from the incident
field at the dipoles to their moments, so the lattice has a T-matrix: regular-wave
coefficients of any incident field (:mod:`holofit.scattering.vsw`) to outgoing-wave
coefficients of its scattered field (:mod:`holofit.scattering.multipole`), both about the particle
centre in the particle frame, truncated at order ``L``. It is built once from DDA solves
(:func:`holofit.dda.tmatrix_build.build_tmatrix`) and then any orientation is

    o_lab = D(R) T D(R)^H a_lab,

with ``a_lab`` the coefficients of the instrument's plane wave and ``D(R)`` the Wigner matrices
of the particle-to-lab rotation ``R = Rz(psi) Ry(theta) Rz(phi)``
(:mod:`holofit.scattering.wigner`). Because ``T`` is the lattice's own linear map, the result equals
a fresh DDA solve of that lattice to truncation and solver precision at every orientation (not
an interpolation). The derivatives with respect to the Euler angles are exact:
``d o_lab = (dD) T D^H a + D T (dD)^H a`` (one product of ``T`` with four vectors).

Storage: the lattice's rotation axis along particle z (order ``M`` = 4 for rods, Janus
particles and dimers on their lattice) makes ``T`` couple ``m`` only to ``m' = m (mod M)``, so
it is kept as ``M`` dense blocks (1/M of the memory and of the work of a product).

Use
---
Through the built-in engine (with any polarizability but ``"ldr"``)::

    engine = BuiltinDDA(settings)
    engine.tmatrix(model, optics, path="particle.npz")  # load if it fits, else build + save
    wave = engine.solve(model, optics, orientation)      # a TMatrixWave, milliseconds
    e_x, e_y = wave.field_on_pixels(position, xs, ys)
    (e_x, e_y), derivs = wave.field_and_rotation_derivatives(position, xs, ys, axes)
    d_theta = wave.orientation_derivative("theta")      # a wave: d(field)/d(theta)

``engine.solve_direct`` always solves. A worker that receives a file loads it once
(:func:`holofit.dda.tmatrix_io.load_tmatrix` caches by path and modification time) and hands
it to its engine with ``engine.use_tmatrix(model, optics, tmatrix, source=path)``; a file made
for another model, lattice, wavelength, medium or settings raises
:class:`~holofit.dda.tmatrix_io.TMatrixMismatch` naming the file and the field. The build
(:mod:`holofit.dda.tmatrix_build`) chooses the order and records its truncation estimate and
a measured validation error in :attr:`TMatrix.provenance`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from holofit.conventions import PROPAGATION_DIRECTION
from holofit.scattering.multipole import MultipoleExpansion
from holofit.scattering.vsw import n_terms, plane_wave_coefficients, term_indices, unpack
from holofit.scattering.wigner import EULER_ANGLES, wigner_d_all

__all__ = ["LabCoefficients", "TMatrix", "z_rotation_order"]


def z_rotation_order(ops: list[NDArray]) -> int:
    """Largest ``M`` in {1, 2, 4} such that the rotation by ``2 pi / M`` about particle z is
    among the lattice operations ``ops``."""
    keys = {tuple(int(v) for v in np.rint(o).ravel()) for o in ops}
    c4 = (0, -1, 0, 1, 0, 0, 0, 0, 1)
    c2 = (-1, 0, 0, 0, -1, 0, 0, 0, 1)
    if c4 in keys:
        return 4
    if c2 in keys:
        return 2
    return 1


def _angular_momentum(c: NDArray[np.complex128], axis: ArrayLike) -> NDArray[np.complex128]:
    """``(n.J) c`` for coefficients ``c`` in the padded layout ``[kind, n, m + L]``:
    ``n.J = (n_x - i n_y) J+ / 2 + (n_x + i n_y) J- / 2 + n_z J_z`` in each ``|n m>`` block."""
    ax = np.asarray(axis, dtype=float)
    L = c.shape[1] - 1
    m = np.arange(-L, L + 1)
    nn = np.arange(L + 1)[:, None] * (np.arange(L + 1)[:, None] + 1.0)
    up = np.sqrt(np.clip(nn - m[None, :] * (m[None, :] - 1.0), 0.0, None))  # (J+)_{m, m-1}
    down = np.sqrt(np.clip(nn - m[None, :] * (m[None, :] + 1.0), 0.0, None))  # (J-)_{m, m+1}
    out = ax[2] * m[None, None, :] * c
    out[:, :, 1:] += 0.5 * (ax[0] - 1j * ax[1]) * up[None, :, 1:] * c[:, :, :-1]
    out[:, :, :-1] += 0.5 * (ax[0] + 1j * ax[1]) * down[None, :, :-1] * c[:, :, 1:]
    return out


def _rotate_back(d: NDArray[np.complex128], x: NDArray[np.complex128]
                 ) -> NDArray[np.complex128]:
    """``D^H x`` in each ``n`` block: ``out[k, n, b] = sum_a conj(d[n, a, b]) x[k, n, a]`` (the
    Wigner blocks ``d`` as from :func:`wigner_d_all`; a batched matrix product, several times
    faster than the equivalent ``einsum`` at these sizes)."""
    return np.matmul(x.transpose(1, 0, 2), d.conj()).transpose(1, 0, 2)


def _rotate(d: NDArray[np.complex128], v: NDArray[np.complex128]) -> NDArray[np.complex128]:
    """``D v`` in each ``n`` block: ``out[k, n, a, ...] = sum_b d[n, a, b] v[k, n, b, ...]``
    (``v`` of shape ``(2, L + 1, 2 L + 1)`` or with one more axis of columns)."""
    kinds, blocks, width = v.shape[:3]
    cols = v.shape[3] if v.ndim == 4 else 1
    vv = np.moveaxis(v.reshape(kinds, blocks, width, cols), 0, 2).reshape(
        blocks, width, kinds * cols)
    out = np.matmul(d, vv).reshape(blocks, width, kinds, cols)
    out = np.moveaxis(out, 2, 0)
    return out if v.ndim == 4 else out[..., 0]


@dataclass
class LabCoefficients:
    """Outgoing coefficients of one orientation in the lab frame, and their derivatives.

    Attributes
    ----------
    vector : ndarray (n_terms,)
        Flat outgoing coefficients (lab frame).
    derivatives : dict
        Angle name (``"psi"``, ``"theta"``, ``"phi"``) -> derivative of ``vector``, 1/rad
        (empty unless requested).
    """

    vector: NDArray[np.complex128]
    derivatives: dict[str, NDArray[np.complex128]] = field(default_factory=dict)


@dataclass(eq=False)
class TMatrix:
    """The T-matrix of one dipole lattice (particle frame).

    Attributes
    ----------
    order : int
        Truncation order ``L``; vectors have ``2 L (L + 2)`` entries
        (:mod:`holofit.scattering.vsw` layout).
    k : float
        Wavenumber in the medium, rad/um.
    radius_um : float
        Radius about the particle centre of the sphere that contains every dipole cell; the
        outgoing expansion holds outside it.
    modulus : int
        ``M``: ``T`` couples ``m`` to ``m'`` only when ``m = m' (mod M)``.
    blocks : list of ndarray
        Dense block of each residue class ``m mod M`` (rows and columns in
        :meth:`class_indices` order).
    provenance : dict
        How it was made (model, dipole size, optics, settings, order, truncation error, ...;
        see :mod:`holofit.dda.tmatrix_io`).
    """

    order: int
    k: float
    radius_um: float
    modulus: int
    blocks: list[NDArray[np.complex128]]
    provenance: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self._incident_cache: dict[tuple, NDArray] = {}
        self._classes = self.class_indices()
        if len(self.blocks) != len(self._classes) or any(
            b.shape != (i.size, i.size) for b, i in zip(self.blocks, self._classes, strict=True)
        ):
            raise ValueError("T-matrix blocks do not match its order and modulus")

    # -- construction -------------------------------------------------------------------------
    def class_indices(self) -> list[NDArray[np.int64]]:
        """Flat indices of each residue class ``m mod M`` (M classes)."""
        _, _, m = term_indices(self.order)
        return [np.nonzero(m % self.modulus == r)[0] for r in range(self.modulus)]

    @classmethod
    def from_dense(cls, matrix: NDArray[np.complex128], order: int, k: float,
                   radius_um: float, modulus: int = 1,
                   provenance: dict[str, Any] | None = None) -> TMatrix:
        """Keep the blocks of a dense matrix (entries between residue classes must be zero by
        symmetry; they are dropped)."""
        if matrix.shape != (n_terms(order), n_terms(order)):
            raise ValueError(f"a T-matrix of order {order} is {n_terms(order)} square, got "
                             f"{matrix.shape}")
        _, _, m = term_indices(order)
        idx = [np.nonzero(m % modulus == r)[0] for r in range(modulus)]
        blocks = [np.ascontiguousarray(matrix[np.ix_(i, i)]) for i in idx]
        return cls(order, float(k), float(radius_um), int(modulus), blocks, provenance or {})

    def dense(self) -> NDArray[np.complex128]:
        """The full ``2L(L+2)``-square matrix."""
        size = n_terms(self.order)
        out = np.zeros((size, size), dtype=complex)
        for i, b in zip(self._classes, self.blocks, strict=True):
            out[np.ix_(i, i)] = b
        return out

    @property
    def n_terms(self) -> int:
        return n_terms(self.order)

    # -- application --------------------------------------------------------------------------
    def scatter(self, incident: ArrayLike) -> NDArray[np.complex128]:
        """Outgoing coefficients (particle frame) of incident regular-wave coefficients
        (particle frame); vectors along the first axis, extra columns allowed."""
        a = np.asarray(incident, dtype=complex)
        out = np.empty(a.shape, dtype=complex)
        for i, b in zip(self._classes, self.blocks, strict=True):
            out[i] = b @ a[i]
        return out

    def incident_coefficients(self, polarization: ArrayLike) -> NDArray[np.complex128]:
        """Lab-frame coefficients of the instrument's plane wave (along lab -z)."""
        e = np.asarray(polarization, dtype=float)
        key = tuple(np.round(e, 15))
        vec = self._incident_cache.get(key)
        if vec is None:
            vec = plane_wave_coefficients(PROPAGATION_DIRECTION, e, self.order)
            self._incident_cache[key] = vec
        return vec

    def lab_coefficients(
        self, euler: tuple[float, float, float], polarization: ArrayLike,
        derivatives: bool = False,
    ) -> LabCoefficients:
        """Lab-frame outgoing coefficients for the plane wave of ``polarization`` (lab frame,
        along lab -z) on the particle at zyz Euler angles ``(psi, theta, phi)``, rad; with
        ``derivatives``, also their exact derivatives with respect to each angle."""
        psi, theta, phi = (float(v) for v in euler)
        L = self.order
        kind, n, m = term_indices(L)
        a_pad = np.zeros((2, L + 1, 2 * L + 1), dtype=complex)
        a_pad[kind, n, m + L] = self.incident_coefficients(polarization)
        if not derivatives:
            d = wigner_d_all(L, psi, theta, phi)
            u = _rotate_back(d, a_pad)  # D^H a
            v = self.scatter(u[kind, n, m + L])
            v_pad = np.zeros_like(a_pad)
            v_pad[kind, n, m + L] = v
            out = _rotate(d, v_pad)
            return LabCoefficients(out[kind, n, m + L])
        d, dd = wigner_d_all(L, psi, theta, phi, derivatives=True)
        cols = [_rotate_back(x, a_pad)[kind, n, m + L] for x in (d, *dd)]
        v = self.scatter(np.stack(cols, axis=1))  # T D^H a, T (dD)^H a
        v_pad = np.zeros((2, L + 1, 2 * L + 1, 4), dtype=complex)
        v_pad[kind, n, m + L] = v
        out = _rotate(d, v_pad)  # D v_0, D v_psi, D v_theta, D v_phi
        derivs = {}
        for j, name in enumerate(EULER_ANGLES):
            dv = _rotate(dd[j], v_pad[..., 0]) + out[..., j + 1]
            derivs[name] = dv[kind, n, m + L]
        return LabCoefficients(out[..., 0][kind, n, m + L], derivs)

    def rotation_derivatives(self, euler: tuple[float, float, float],
                             polarization: ArrayLike) -> NDArray[np.complex128]:
        """Derivatives of :meth:`lab_coefficients` with respect to rotations of the particle
        about the lab x, y and z axes, ``R -> exp(eps [e_i]x) R`` (per radian), shape
        (n_terms, 3). The derivative about any unit axis ``n`` is ``sum_i n_i`` times column i.

        ``D(exp(eps [n]x) R) = exp(-i eps n.J) D(R)``, so with ``T_lab = D T D^H``:
        ``d o / d eps = -i (n.J) T_lab a + i T_lab (n.J) a`` (one product of ``T`` with four
        vectors for all three axes).
        """
        psi, theta, phi = (float(v) for v in euler)
        L = self.order
        kind, n, m = term_indices(L)
        a_pad = np.zeros((2, L + 1, 2 * L + 1), dtype=complex)
        a_pad[kind, n, m + L] = self.incident_coefficients(polarization)
        d = wigner_d_all(L, psi, theta, phi)
        axes = np.eye(3)
        sources = [a_pad] + [_angular_momentum(a_pad, ax) for ax in axes]
        cols = [_rotate_back(d, x)[kind, n, m + L] for x in sources]
        v = self.scatter(np.stack(cols, axis=1))
        v_pad = np.zeros((2, L + 1, 2 * L + 1, 4), dtype=complex)
        v_pad[kind, n, m + L] = v
        o = _rotate(d, v_pad)
        out = np.empty((self.n_terms, 3), dtype=complex)
        for i, ax in enumerate(axes):
            der = -1j * _angular_momentum(o[..., 0], ax) + 1j * o[..., i + 1]
            out[:, i] = der[kind, n, m + L]
        return out

    def rotation_derivative(self, euler: tuple[float, float, float], polarization: ArrayLike,
                            axis: ArrayLike) -> NDArray[np.complex128]:
        """Derivative of :meth:`lab_coefficients` with respect to a rotation of the particle
        about the unit lab ``axis``, ``R -> exp(eps [axis]x) R`` (per radian)."""
        return self.rotation_derivatives(euler, polarization) @ np.asarray(axis, dtype=float)

    def expansion(self, vector: NDArray[np.complex128]) -> MultipoleExpansion:
        """The multipole expansion (lab frame) of a flat outgoing coefficient vector."""
        p, q = unpack(vector, self.order)
        return MultipoleExpansion(self.k, p, q, self.radius_um)
