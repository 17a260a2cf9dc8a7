"""The dipole lattice: a cubic grid fixed to the particle, with per-voxel material fractions."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

__all__ = ["Lattice"]


@dataclass(frozen=True, eq=False)
class Lattice:
    """Occupied voxels of a particle on a cubic lattice, in the particle frame.

    The lattice is fixed to the particle: voxel ``(i, j, l)`` of the box has its centre at
    ``origin + d * (i, j, l)`` relative to the particle centre (um). Each occupied voxel holds
    volume fractions of the particle's materials; the rest of the voxel is medium.

    Attributes
    ----------
    d : float
        Dipole size (lattice spacing), um.
    shape : tuple of int
        Box size ``(nx, ny, nz)`` in voxels (tight around the occupied voxels).
    origin : ndarray, shape (3,)
        Particle-frame position of the centre of box voxel (0, 0, 0), um.
    ijk : ndarray of int, shape (N, 3)
        Box indices of the occupied voxels, in C order of the box.
    fractions : ndarray, shape (N, n_materials)
        Volume fraction of each material in each voxel (sum <= 1).
    indices : tuple of complex
        Absolute refractive index of each material.
    normals : ndarray, shape (N, 3), optional
        Unit normal of the material interface through each partly filled voxel (zero for full
        voxels); with it, partly filled voxels are laminates
        (:meth:`component_permittivity`). None: isotropic voxels (binary lattices, voxel files).
    """

    d: float
    shape: tuple[int, int, int]
    origin: NDArray[np.float64]
    ijk: NDArray[np.int64]
    fractions: NDArray[np.float64]
    indices: tuple[complex, ...]
    normals: NDArray[np.float64] | None = None
    _cache: dict = field(default_factory=dict, repr=False, compare=False)

    @property
    def n_dipoles(self) -> int:
        return int(self.ijk.shape[0])

    @property
    def positions(self) -> NDArray[np.float64]:
        """Particle-frame dipole positions relative to the particle centre, um, shape (N, 3)."""
        if "positions" not in self._cache:
            self._cache["positions"] = self.origin + self.d * self.ijk
        return self._cache["positions"]

    @property
    def flat_index(self) -> NDArray[np.int64]:
        """C-order flat index of each occupied voxel in the box."""
        if "flat" not in self._cache:
            self._cache["flat"] = np.ravel_multi_index(self.ijk.T, self.shape)
        return self._cache["flat"]

    @property
    def box_centre(self) -> NDArray[np.float64]:
        """Particle-frame position of the centre of the box (ADDA's phase origin), um."""
        return self.origin + self.d * (np.asarray(self.shape) - 1) / 2

    def relative_permittivity(self, n_medium: float) -> NDArray[np.complex128]:
        """Effective ``eps_voxel / eps_medium`` of each voxel (Maxwell-Garnett mixing).

        The Clausius-Mossotti factors mix linearly with the volume fractions,
        ``(m_eff^2 - 1)/(m_eff^2 + 2) = sum_k f_k (m_k^2 - 1)/(m_k^2 + 2)`` (Maxwell-Garnett
        with the medium as host; the CM polarisability of a voxel is then the fraction-weighted
        sum of its materials'). A full voxel has its material's permittivity, an empty one the
        medium's, and a voxel's polarisability goes to zero continuously with its filling.
        It is more accurate than linear permittivity mixing (docs: validation, "the DDA").
        """
        m2 = np.array([(complex(n) / n_medium) ** 2 for n in self.indices], dtype=np.complex128)
        s = self.fractions @ ((m2 - 1.0) / (m2 + 2.0))
        return (1.0 + 2.0 * s) / (1.0 - s)

    def binary_dipoles(self, threshold: float = 0.5) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        """The voxels whose total material fraction is at least ``threshold``, as binary dipoles.

        Returns
        -------
        ijk : ndarray of int, shape (M, 3)
            Box indices of the kept voxels.
        domain : ndarray of int, shape (M,)
            0-based dominant material of each.
        """
        keep = self.fractions.sum(axis=1) >= threshold
        return self.ijk[keep], np.argmax(self.fractions[keep], axis=1)

    def component_permittivity(self, n_medium: float) -> NDArray[np.complex128]:
        """Relative permittivity of each voxel along each lattice axis, shape (N, 3).

        A partly filled voxel is a laminate of its materials and the medium with the
        interface normal ``n`` (:attr:`normals`): ``eps_par = f_0 + sum_k f_k eps_k`` for field
        components in the interface, ``eps_perp = 1 / (f_0 + sum_k f_k / eps_k)`` across it
        (``f_0`` the medium's fraction), and ``eps_c = eps_par (1 - n_c^2) + eps_perp n_c^2``
        along lattice axis ``c`` (the diagonal of the laminate's tensor). Full voxels get their
        material's permittivity on every axis. Voxels holding a metal (``Re eps < 0``) and
        lattices without normals: the isotropic :meth:`relative_permittivity` on every axis.
        """
        isotropic = np.repeat(self.relative_permittivity(n_medium)[:, None], 3, axis=1)
        if self.normals is None:
            return isotropic
        m2 = np.array([(complex(n) / n_medium) ** 2 for n in self.indices], dtype=np.complex128)
        f_medium = 1.0 - self.fractions.sum(axis=1)
        eps_par = f_medium + self.fractions @ m2
        with np.errstate(divide="ignore", invalid="ignore"):
            eps_perp = 1.0 / (f_medium + self.fractions @ (1.0 / m2))
        nn = self.normals**2
        laminate = eps_par[:, None] * (1.0 - nn) + eps_perp[:, None] * nn
        # metals (Re eps < 0): the harmonic mean has a spurious plasmon resonance at some
        # filling (f_0 + f / eps = 0); their boundary voxels stay Maxwell-Garnett
        metallic = self.fractions[:, m2.real < 0].sum(axis=1) > 0
        return np.where(metallic[:, None], isotropic, laminate)

    def occupied_volume_um3(self) -> NDArray[np.float64]:
        """Volume of each material, um^3 (sum of fractions times d^3)."""
        return self.fractions.sum(axis=0) * self.d**3

    def cache_key(self) -> tuple:
        """Hashable description of the geometry (positions and fractions)."""
        if "key" not in self._cache:
            self._cache["key"] = (
                self.d,
                self.shape,
                tuple(np.round(self.origin, 12)),
                hash(self.ijk.tobytes()),
                hash(np.round(self.fractions, 14).tobytes()),
                None if self.normals is None else hash(np.round(self.normals, 12).tobytes()),
                self.indices,
            )
        return self._cache["key"]
