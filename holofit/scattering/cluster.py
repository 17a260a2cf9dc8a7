"""Exact scattering by clusters of spheres: the superposition T-matrix (multisphere Mie).

Each sphere ``i`` (centre ``x_i`` in the particle frame, radius ``a_i``) is a Lorenz-Mie
scatterer, ``T_i = diag(-a_n)`` on N-type and ``diag(-b_n)`` on M-type coefficients
(:func:`sphere_tmatrix`; the Bohren & Huffman coefficients in :mod:`holofit.scattering.multipole`'s
waves). Its scattered field ``p_i`` (outgoing about ``x_i``) answers the incident field and
the fields of all the others (Mackowski 1996; Mackowski & Mishchenko 2011):

    p_i = T_i (J_i a + sum_{j != i} H_ij p_j),

with ``a`` the incident field's regular coefficients about the particle centre, ``J_i`` the
regular translation from the centre to ``x_i`` and ``H_ij`` the outgoing-to-regular
translation from ``x_j`` to ``x_i`` (:mod:`holofit.scattering.translation`). Solved once for
every incident coefficient (``X = (I - T H)^-1 T J``), the cluster's scattered field about its
centre is ``p = sum_i K_i p_i`` (``K_i``: outgoing-to-outgoing translation from ``x_i`` to the
centre), so the cluster's T-matrix is

    T_cluster = K (I - T H)^-1 T J,

an ordinary :class:`holofit.scattering.tmatrix.TMatrix` in the particle frame: every orientation is
``D T D^H a`` (Wigner rotation, no new solve), and the wave of an orientation is a
:class:`holofit.scattering.tmatrix_wave.TMatrixWave` (the camera plane's interpolated multipole
grid, the lens model through its expansion, exact orientation derivatives). Points closer than
``NEAR_ZONE`` circumscribing radii to the centre are summed from the spheres' own outgoing
expansions (exact outside every sphere).

Truncation
----------
Sphere ``i`` keeps ``L_i = n_stop(k a_i) + SPHERE_MARGIN`` orders (the Lorenz-Mie series length
of :func:`holofit.scattering.mie_coefficients.n_stop`, plus a margin for the near fields of
touching neighbours); the cluster expansion keeps ``L = n_stop(k R)`` with ``R`` the radius of
the sphere about the centre that contains every sphere: more orders change nothing a fit can
see, even for touching spheres (docs: validation, "T-matrices").

Conditioning
------------
Written for the outgoing coefficients ``p``, the system's entries span hundreds of orders of
magnitude (``T_n`` falls and ``H_{n nu} ~ h_{n+nu}(k d)`` grows with the orders), and an
unscaled solve loses every digit once the orders exceed the spheres' size parameters by a few.
It is solved for ``s_n p_n`` with ``s_n = |h_n(k a_i)|`` (the scattered field's size at the
sphere's surface): the entries become ``(h_n T_n / j_n) (j_n(k a_i) H_{n nu} / h_nu(k a_j))``,
both at most of order one for spheres that do not overlap.

Clusters whose spheres all lie on the particle z axis (a dimer) conserve ``m``: the solve and
the T-matrix split into one block per ``m`` (milliseconds); any other cluster is solved as one
dense system.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.special import spherical_jn, spherical_yn

from holofit.cache import LRUCache
from holofit.conventions import euler_zyz
from holofit.optics import Optics
from holofit.particles import Cluster, Dimer, ParticleModel, Sphere
from holofit.scattering.mie_coefficients import mie_coefficients, n_stop
from holofit.scattering.multipole import MultipoleExpansion
from holofit.scattering.theory import Orientation, ScatteredWave, ScatteringEngine
from holofit.scattering.tmatrix import TMatrix
from holofit.scattering.tmatrix_wave import TMatrixWave
from holofit.scattering.translation import axial_entries, translation_matrix, wigner_matrix
from holofit.scattering.vsw import n_terms, term_indices, unpack

__all__ = [
    "SPHERE_MARGIN",
    "ClusterEngine",
    "ClusterSolution",
    "ClusterWave",
    "SphereSumWave",
    "cluster_spheres",
    "solve_cluster",
    "sphere_tmatrix",
]

#: orders added to each sphere's Lorenz-Mie series length (module docstring)
SPHERE_MARGIN = 2
#: the spheres are on the z axis if their distance from it is below this fraction of the size
AXIAL_TOLERANCE = 1e-12


def sphere_tmatrix(m_rel: complex, x: float, order: int) -> NDArray[np.complex128]:
    """Diagonal of a homogeneous sphere's T-matrix (flat layout, order ``order``): ``-a_n``
    on N-type and ``-b_n`` on M-type coefficients, for relative index ``m_rel`` and size
    parameter ``x = k a``."""
    a, b = mie_coefficients(m_rel, x, order)
    _, n, _ = term_indices(order)
    half = n.size // 2
    return np.concatenate([-a[n[:half] - 1], -b[n[half:] - 1]])


def cluster_spheres(model: ParticleModel) -> tuple[NDArray, NDArray, NDArray]:
    """Positions (N, 3) in the particle frame (um), radii (N,) (um) and absolute indices (N,)
    of the spheres of a sphere, dimer or cluster model.

    Raises
    ------
    TypeError
        For any other model.
    """
    if isinstance(model, Sphere):
        return np.zeros((1, 3)), np.array([model.radius_um]), np.array([complex(model.index)])
    if isinstance(model, Dimer):
        z1, z2 = model.sphere_centres_z()
        pos = np.array([[0.0, 0.0, z1], [0.0, 0.0, z2]])
        return (pos, np.array([model.radius1_um, model.radius2_um]),
                np.array([complex(model.index1), complex(model.index2)]))
    if isinstance(model, Cluster):
        return (np.asarray(model.positions_um, dtype=float), np.asarray(model.radii_um),
                np.asarray(model.indices, dtype=complex))
    raise TypeError(f"the cluster engine handles spheres, dimers and clusters, not "
                    f"{model.kind!r}")


@dataclass(eq=False)
class ClusterSolution:
    """The solved interaction problem of one cluster geometry (particle frame).

    Attributes
    ----------
    tmatrix : TMatrix
        The cluster's T-matrix about the particle centre.
    positions_um, radii_um : ndarray
        Sphere centres (N, 3) and radii (N,), um.
    orders : tuple of int
        Each sphere's order ``L_i``.
    offsets : tuple of int
        Start of each sphere's coefficients in the stacked sphere vector.
    blocks : list of (ndarray, ndarray, ndarray)
        ``(sphere_rows, centre_cols, X)`` per conserved-``m`` class: the stacked sphere
        coefficients are ``X @ a[centre_cols]`` at ``sphere_rows``.
    build_s : float
        Wall time of the build, s.
    """

    tmatrix: TMatrix
    positions_um: NDArray[np.float64]
    radii_um: NDArray[np.float64]
    orders: tuple[int, ...]
    offsets: tuple[int, ...]
    blocks: list[tuple[NDArray, NDArray, NDArray]] = field(repr=False)
    build_s: float = 0.0

    def sphere_coefficients(self, incident: NDArray[np.complex128]) -> list[NDArray]:
        """Each sphere's outgoing coefficients (particle frame, its own order) for incident
        regular coefficients about the centre (particle frame, the T-matrix's order)."""
        total = self.offsets[-1] + n_terms(self.orders[-1])
        stacked = np.zeros(total, dtype=complex)
        for rows, cols, x in self.blocks:
            stacked[rows] = x @ incident[cols]
        return [stacked[o:o + n_terms(L)]
                for o, L in zip(self.offsets, self.orders, strict=True)]


def solve_cluster(positions_um: ArrayLike, radii_um: ArrayLike, indices: ArrayLike,
                  optics: Optics, sphere_margin: int = SPHERE_MARGIN,
                  order: int | None = None) -> ClusterSolution:
    """Solve the multiple-scattering problem of a sphere cluster and collapse it to the
    T-matrix about the particle centre (module docstring).

    Parameters
    ----------
    positions_um : array_like, shape (N, 3)
        Sphere centres in the particle frame, um.
    radii_um : array_like, shape (N,)
        Radii, um.
    indices : array_like, shape (N,)
        Absolute refractive indices.
    optics : Optics
        Wavelength and medium.
    sphere_margin : int
        Orders added to each sphere's Lorenz-Mie series length.
    order : int, optional
        Order of the cluster expansion (default ``n_stop(k R)``).
    """
    t0 = time.perf_counter()
    pos = np.atleast_2d(np.asarray(positions_um, dtype=float))
    radii = np.asarray(radii_um, dtype=float).ravel()
    idx = np.asarray(indices, dtype=complex).ravel()
    k = optics.k
    radius = float(np.max(np.linalg.norm(pos, axis=1) + radii))
    big = int(order) if order is not None else n_stop(k * radius)
    orders = tuple(n_stop(k * a) + int(sphere_margin) for a in radii)
    offsets = tuple(int(v) for v in np.cumsum([0, *[n_terms(L) for L in orders[:-1]]]))
    size = float(np.max(radii))
    axial = bool(np.all(np.hypot(pos[:, 0], pos[:, 1]) <= AXIAL_TOLERANCE * size))

    t_diag = np.concatenate([sphere_tmatrix(n / optics.n_medium, k * a, L)
                             for n, a, L in zip(idx, radii, orders, strict=True)])
    scale = np.concatenate([np.abs(_hankel(term_indices(L)[1], k * a))
                            for a, L in zip(radii, orders, strict=True)])
    modulus = 2 * big + 1 if axial else 1
    centre = _Classes(term_indices(big)[2], modulus)
    spheres = _Classes(np.concatenate([term_indices(L)[2] for L in orders]), modulus)
    j_b, k_b, h_b = _translation_blocks(pos, k, orders, offsets, big, spheres, centre, axial)
    blocks_t, blocks_x = _solve_blocks(modulus, spheres, centre, t_diag, scale, j_b, k_b, h_b)
    build_s = time.perf_counter() - t0
    provenance: dict[str, Any] = {
        "engine": "cluster", "positions_um": pos.tolist(), "radii_um": radii.tolist(),
        "indices": [str(v) for v in idx], "wavelength_um": optics.wavelength_um,
        "n_medium": optics.n_medium, "order": big, "sphere_orders": list(orders),
        "axial": axial, "build_s": build_s,
    }
    tm = TMatrix(big, k, radius, modulus, blocks_t, provenance)
    return ClusterSolution(tm, pos, radii, orders, offsets, blocks_x, build_s)


def _translation_blocks(
    pos: NDArray, k: float, orders: tuple[int, ...], offsets: tuple[int, ...], big: int,
    spheres: _Classes, centre: _Classes, axial: bool,
) -> tuple[list[NDArray], list[NDArray], list[NDArray]]:
    """The per-class blocks of the translations centre -> spheres (``J``), spheres -> centre
    (``K``, both regular) and sphere -> sphere (``H``, outgoing) of :func:`solve_cluster`."""
    j_b = [np.zeros((a, b), dtype=complex) for a, b in zip(spheres.sizes, centre.sizes,
                                                           strict=True)]
    k_b = [np.zeros((b, a), dtype=complex) for a, b in zip(spheres.sizes, centre.sizes,
                                                           strict=True)]
    h_b = [np.zeros((a, a), dtype=complex) for a in spheres.sizes]

    def add(blocks: list[NDArray], rows_of: _Classes, cols_of: _Classes, row0: int, col0: int,
            d: NDArray, order_to: int, order_from: int, kind: str) -> None:
        if axial:
            kd = k * float(d[2])
            rows, cols, vals = axial_entries(kd, order_to, order_from, kind)
        else:
            dense = translation_matrix(d, k, order_to, order_from, kind)
            rows, cols = (v.ravel() for v in np.indices(dense.shape))
            vals = dense.ravel()
        rows, cols = rows + row0, cols + col0
        cls = rows_of.cls[rows]
        for r in np.unique(cls):
            sel = cls == r
            blocks[r][rows_of.rank[rows[sel]], cols_of.rank[cols[sel]]] = vals[sel]

    for i, (oi, li) in enumerate(zip(offsets, orders, strict=True)):
        add(j_b, spheres, centre, oi, 0, pos[i], li, big, "regular")
        add(k_b, centre, spheres, 0, oi, -pos[i], big, li, "regular")
        for j, (oj, lj) in enumerate(zip(offsets, orders, strict=True)):
            if j != i:
                add(h_b, spheres, spheres, oi, oj, pos[i] - pos[j], li, lj, "outgoing")
    return j_b, k_b, h_b


def _solve_blocks(
    modulus: int, spheres: _Classes, centre: _Classes, t_diag: NDArray, scale: NDArray,
    j_b: list[NDArray], k_b: list[NDArray], h_b: list[NDArray],
) -> tuple[list[NDArray], list[tuple[NDArray, NDArray, NDArray]]]:
    """The cluster T-matrix's blocks ``K x`` and the spheres' solutions ``x`` per class, from
    ``(1 - T H) x = T J`` (:func:`solve_cluster`)."""
    blocks_t: list[NDArray] = []
    blocks_x: list[tuple[NDArray, NDArray, NDArray]] = []
    for r in range(modulus):
        rows, cols = spheres.members[r], centre.members[r]
        if rows.size == 0:
            blocks_t.append(np.zeros((cols.size, cols.size), dtype=complex))
            continue
        t = t_diag[rows]
        # equilibrated: unknowns s p with s = |h_n(k a_i)|, the scattered field's size at
        # the sphere's surface, so that every entry of the system is O(1) (module docstring)
        sc = scale[rows]
        system = np.eye(rows.size) - (sc * t)[:, None] * h_b[r] / sc[None, :]
        x = np.linalg.solve(system, (sc * t)[:, None] * j_b[r]) / sc[:, None]
        blocks_t.append(k_b[r] @ x)
        blocks_x.append((rows, cols, x))
    return blocks_t, blocks_x


def _hankel(n: NDArray[np.int64], x: float) -> NDArray[np.complex128]:
    return spherical_jn(n, x) + 1j * spherical_yn(n, x)


class _Classes:
    """Flat coefficient indices grouped by ``m mod modulus``: each index's class and its rank
    within it (the order of :meth:`holofit.scattering.tmatrix.TMatrix.class_indices`)."""

    def __init__(self, m: NDArray[np.int64], modulus: int) -> None:
        self.cls = m % modulus
        self.members = [np.nonzero(self.cls == r)[0] for r in range(modulus)]
        self.sizes = [v.size for v in self.members]
        self.rank = np.empty(m.size, dtype=np.int64)
        for v in self.members:
            self.rank[v] = np.arange(v.size)


class SphereSumWave(ScatteredWave):
    """The cluster's scattered field as the sum of its spheres' outgoing expansions, exact
    everywhere outside the spheres (the near field of :class:`ClusterWave`).

    Parameters
    ----------
    solution : ClusterSolution
        The solved cluster.
    optics : Optics
        Illumination.
    orientation : Orientation
        zyz Euler angles of the particle.
    """

    exact_near_field = True

    def __init__(self, solution: ClusterSolution, optics: Optics,
                 orientation: Orientation) -> None:
        self.optics = optics
        self.solution = solution
        psi, theta, phi = orientation.as_tuple()
        rot = euler_zyz(psi, theta, phi)
        tm = solution.tmatrix
        a_lab = tm.incident_coefficients(optics.polarization)
        a_part = wigner_matrix(tm.order, psi, theta, phi).conj().T @ a_lab
        self.centres = solution.positions_um @ rot.T
        self.expansions = []
        for c, L, a in zip(solution.sphere_coefficients(a_part), solution.orders,
                           solution.radii_um, strict=True):
            p, q = unpack(wigner_matrix(L, psi, theta, phi) @ c, L)
            self.expansions.append(MultipoleExpansion(optics.k, p, q, float(a)))

    def field_at(self, points_um: ArrayLike, far_field: bool = False) -> NDArray[np.complex128]:
        pts = np.atleast_2d(np.asarray(points_um, dtype=float))
        out = np.zeros((pts.shape[0], 3), dtype=complex)
        for c, e in zip(self.centres, self.expansions, strict=True):
            rel = pts - c
            dist = np.linalg.norm(rel, axis=1)
            inside = int(np.sum(dist <= e.radius_um))
            if inside:
                raise ValueError(f"the cluster's scattered field is defined outside its spheres "
                                 f"only; {inside} point(s) lie inside one")
            if far_field:
                # each sphere's far field with its own phase exp(-ik n.c) about the centre
                r = np.linalg.norm(pts, axis=1)
                n_hat = pts / r[:, None]
                amp = e.far_amplitude(n_hat) * np.exp(-1j * self.optics.k * (n_hat @ c))[:, None]
                kr = self.optics.k * r
                out += amp * (np.exp(1j * kr) / kr)[:, None]
            else:
                out += e.field_at(rel)
        return out


class ClusterWave(TMatrixWave):
    """The scattered wave of a sphere cluster at one orientation (its T-matrix's
    :class:`~holofit.scattering.tmatrix_wave.TMatrixWave`, with the spheres' own expansions near
    the particle)."""

    def __init__(self, model: ParticleModel, optics: Optics, orientation: Orientation,
                 solution: ClusterSolution) -> None:
        self.solution = solution

        def direct(o: Orientation) -> ScatteredWave:
            return SphereSumWave(solution, optics, o)

        super().__init__(model, optics, orientation, solution.tmatrix, direct)


#: cluster solutions kept per engine (one per geometry and optics)
CACHE_SIZE = 8


class ClusterEngine(ScatteringEngine):
    """Exact multiple-sphere scattering (the superposition T-matrix) for spheres, dimers and
    clusters; one solve per geometry and illumination, every orientation by rotation.

    Parameters
    ----------
    sphere_margin : int
        Orders added to each sphere's Lorenz-Mie series length.
    """

    name = "cluster"
    models = (Sphere, Dimer, Cluster)
    handles = "spheres, dimers and sphere clusters"
    #: every solve is served from the cluster's T-matrix (the fit stage builds no other)
    own_tmatrix = True

    def __init__(self, sphere_margin: int = SPHERE_MARGIN, **_ignored: Any) -> None:
        self.sphere_margin = int(sphere_margin)
        self._solutions: LRUCache[tuple, ClusterSolution] = LRUCache(CACHE_SIZE)

    def solution(self, model: ParticleModel, optics: Optics) -> ClusterSolution:
        """The solved cluster for ``(model, optics)`` (cached)."""
        key = (model, optics.wavelength_um, optics.n_medium)
        sol = self._solutions.get(key)
        if sol is None:
            pos, radii, idx = cluster_spheres(model)
            sol = self._solutions.put(key, solve_cluster(pos, radii, idx, optics,
                                                         self.sphere_margin))
        return sol

    def solve(self, model: ParticleModel, optics: Optics,
              orientation: Orientation | None = None) -> ClusterWave:
        return ClusterWave(model, optics, orientation or Orientation(),
                           self.solution(model, optics))


#: the former name, kept for existing code (deprecated)
ClusterTheory = ClusterEngine
