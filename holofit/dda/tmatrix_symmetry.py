"""Symmetries of a dipole lattice and the right-hand sides they let a T-matrix build skip.

Lattice symmetries
------------------
A cubic lattice can only be mapped onto itself by the 48 signed permutation matrices (the
rotations and rotation-reflections of a cube). :func:`lattice_symmetries` keeps those that map
the dipole positions about the expansion centre onto themselves *and* every dipole onto one
with the same permittivity (what the DDA sees; two materials of equal index are one); they are
detected from the lattice, never assumed (a rod on its lattice has 16, a Janus particle 8, a
particle whose lattice is off-centre may have 1).

Why they save solves
--------------------
If ``S`` is such an operation, the DDA system commutes with it: the dipoles of the incident
field ``S E(S^T r)`` are ``S P(S^T r)``, and their scattered coefficients are ``rho(S)`` times
the original ones, where ``rho`` is the (block-diagonal, Wigner) representation of the group
``G`` on coefficient vectors (:func:`holofit.scattering.wigner.operation_blocks`). One DDA
solve of an incident coefficient vector ``c`` with outgoing coefficients ``o`` therefore gives
the pairs
``(rho(g) c, rho(g) o)`` for all ``g`` in ``G``: up to ``|G|`` columns of the T-matrix.

Design of the right-hand sides
------------------------------
Decompose the coefficient space into irreducible representations ``Gamma`` (dimension
``d_G``, multiplicity ``m_G``): ``V = sum_G Gamma (x) C^(m_G)``. A vector
``c = sum_G sqrt(d_G/|G|) sum_i e_i (x) u_i`` (``e_i`` an orthonormal basis of ``Gamma``,
``u_i`` orthonormal) has images that, by Schur's orthogonality, form a Parseval frame of the
space they span: ``sum_g rho(g) c c^H rho(g)^H = sum_G 1 (x) sum_i u_i u_i^H``. Taking fresh
orthonormal ``u``'s for every solve until each multiplicity space is used up gives design
vectors ``c_s`` with ``sum_s sum_g rho(g) c_s c_s^H rho(g)^H = 1``, hence exactly

    T = sum_g rho(g) (sum_s o_s c_s^H) rho(g)^H,

with ``max_G ceil(m_G / d_G) ~ N/|G|`` solves instead of ``N`` and no amplification of solver
errors (the frame is tight). The decomposition is numerical and needs no character tables:
the isotypic components are the eigenspaces of a random Hermitian element of the centre of the
group algebra (a combination of class sums), the ``e_i (x) C^m`` subspaces those of a random
Hermitian element of the algebra within each component, and the maps between them come from
one more random element of the algebra.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from holofit.dda.lattice import Lattice
from holofit.scattering.vsw import n_terms
from holofit.scattering.wigner import operation_blocks

__all__ = ["SymmetryGroup", "design_vectors", "lattice_symmetries", "symmetrize"]


def _cube_operations() -> list[NDArray[np.int64]]:
    ops = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1, -1), repeat=3):
            s = np.zeros((3, 3), dtype=np.int64)
            s[np.arange(3), perm] = signs
            ops.append(s)
    # identity first
    ops.sort(key=lambda s: (not np.array_equal(s, np.eye(3, dtype=np.int64)),))
    return ops


def lattice_symmetries(lattice: Lattice, values: NDArray | None = None, per_axis: bool = False,
                       tol: float = 1e-10) -> list[NDArray[np.int64]]:
    """The cube operations (3x3 signed permutations, particle frame) that map the lattice
    about the expansion centre (the particle centre) onto itself with the same value on
    every dipole.

    Parameters
    ----------
    lattice : Lattice
        The dipoles.
    values : ndarray, shape (N,) or (N, n), optional
        What must match per dipole (the relative permittivity for the DDA); the material
        fractions by default.
    per_axis : bool
        ``values`` (N, 3) are along the lattice axes (the diagonal permittivity of laminate
        voxels): an operation permuting the axes permutes them too (component ``i`` of the
        image is component ``pi(i)`` of the original, ``S[i, pi(i)] = +-1``).
    tol : float
        Largest difference of matched values.

    Returns
    -------
    list of ndarray
        The operations, the identity first; the identity alone if the dipole positions are
        not on a lattice symmetric under any operation about the centre.
    """
    half = 2.0 * lattice.positions / lattice.d  # integers where the centre is a (half) node
    rounded = np.rint(half)
    identity = np.eye(3, dtype=np.int64)
    if np.max(np.abs(half - rounded)) > 1e-6:
        return [identity]
    u = rounded.astype(np.int64)
    ref = np.lexsort(u.T[::-1])
    u_ref = u[ref]
    vals = lattice.fractions if values is None else np.asarray(values)
    f_ref = vals[ref]
    found = []
    if per_axis and (vals.ndim != 2 or vals.shape[1] != 3):
        raise ValueError("per-axis values must have shape (N, 3)")
    for op in _cube_operations():
        v = u @ op.T
        order = np.lexsort(v.T[::-1])
        if not np.array_equal(v[order], u_ref):
            continue
        # dipole ref[j] is the image of dipole order[j]
        image = vals[order][:, np.argmax(np.abs(op), axis=1)] if per_axis else vals[order]
        if np.max(np.abs(image - f_ref), initial=0.0) > tol:
            continue
        found.append(op)
    return found


def _key(op: NDArray) -> tuple[int, ...]:
    return tuple(int(v) for v in np.rint(op).ravel())


@dataclass
class SymmetryGroup:
    """A finite group of lattice operations and its representation on coefficient vectors.

    Attributes
    ----------
    ops : list of ndarray (3, 3)
        The operations (particle frame), identity first.
    order : int
        Multipole order ``L`` of the representation.
    blocks : list of list of ndarray
        ``blocks[g][n - 1]``: ``D^n`` of the proper part of ``ops[g]``.
    sign_n, sign_m : ndarray, shape (|G|, L)
        Inversion signs of the N- and M-type blocks.
    """

    ops: list[NDArray[np.int64]]
    order: int
    blocks: list[list[NDArray[np.complex128]]]
    sign_n: NDArray[np.float64]
    sign_m: NDArray[np.float64]

    @classmethod
    def from_operations(cls, ops: list[NDArray], order: int) -> SymmetryGroup:
        keys = {_key(o) for o in ops}
        for a in ops:
            for b in ops:
                if _key(a @ b) not in keys:
                    raise ValueError("lattice operations do not form a group")
        blocks: list[list[NDArray[np.complex128]]] = []
        sn, sm = [], []
        for op in ops:
            op_blocks, s_n, s_m = operation_blocks(op, order)
            blocks.append(op_blocks)
            sn.append(s_n)
            sm.append(s_m)
        return cls(list(ops), order, blocks, np.array(sn), np.array(sm))

    @property
    def size(self) -> int:
        return len(self.ops)

    def block(self, g: int, kind: int, n: int) -> NDArray[np.complex128]:
        """The (2n+1)-square matrix of ``ops[g]`` on the (kind, n) block."""
        sign = (self.sign_n if kind == 0 else self.sign_m)[g, n - 1]
        return sign * self.blocks[g][n - 1]

    def classes(self) -> list[list[int]]:
        """Conjugacy classes (indices into ``ops``)."""
        index = {_key(o): i for i, o in enumerate(self.ops)}
        seen: set[int] = set()
        out = []
        for i, g in enumerate(self.ops):
            if i in seen:
                continue
            cls_ = sorted({index[_key(h @ g @ h.T)] for h in self.ops})
            seen.update(cls_)
            out.append(cls_)
        return out


def _block_slices(order: int) -> list[tuple[int, int, slice]]:
    half = order * (order + 2)
    out = []
    for kind in (0, 1):
        for n in range(1, order + 1):
            lo = kind * half + n * n - 1
            out.append((kind, n, slice(lo, lo + 2 * n + 1)))
    return out


def _cluster(values: NDArray, tol: float) -> NDArray[np.int64]:
    """Labels of 1-D values grouped so that members of a group lie within ``tol``."""
    order = np.argsort(values)
    labels = np.empty(values.size, dtype=np.int64)
    label = -1
    last = -np.inf
    for i in order:
        if values[i] - last > tol:
            label += 1
        labels[i] = label
        last = values[i]
    return labels


def design_vectors(group: SymmetryGroup, seed: int = 20140101) -> NDArray[np.complex128]:
    """Incident coefficient vectors ``c_s`` (columns) whose images under the group form a
    Parseval frame: ``sum_s sum_g rho(g) c_s c_s^H rho(g)^H = 1`` (see the module docstring).

    Their number is ``max_G ceil(m_G / d_G)``; for the trivial group, the columns of a random
    unitary matrix (not the unit vectors: a single regular wave of odd ``m`` on a lattice with
    a fourfold axis has ``b^T b = 0`` on the dipoles, a breakdown of the complex-symmetric
    Lanczos process that QMR runs on).
    """
    order = group.order
    size = n_terms(order)
    rng = np.random.default_rng(seed)
    if group.size == 1:
        q, r = np.linalg.qr(rng.normal(size=(size, size)) + 1j * rng.normal(size=(size, size)))
        # complex already (numpy's stubs type an untyped-dtype quotient as float64)
        return np.asarray(q * (np.diag(r) / np.abs(np.diag(r)))[None, :], dtype=np.complex128)
    classes = group.classes()
    c_class = rng.normal(size=len(classes)) + 1j * rng.normal(size=len(classes))
    r_alg = rng.normal(size=group.size) + 1j * rng.normal(size=group.size)
    r_map = rng.normal(size=group.size) + 1j * rng.normal(size=group.size)
    slices = _block_slices(order)

    def element(kind: int, n: int, weights: NDArray) -> NDArray:
        return sum(w * group.block(g, kind, n) for g, w in enumerate(weights))

    weights_centre = np.zeros(group.size, dtype=complex)
    for cl, c in zip(classes, c_class, strict=True):
        weights_centre[cl] = c
    # 1. isotypic components: eigenspaces of a Hermitian central element, per block
    per_block = []
    all_vals = []
    for kind, n, _ in slices:
        z = element(kind, n, weights_centre)
        vals, vecs = np.linalg.eigh(z + z.conj().T)
        per_block.append((vals, vecs))
        all_vals.append(vals)
    vals_all = np.concatenate(all_vals)
    scale = float(np.abs(vals_all).max())
    labels_all = _cluster(vals_all, 1e-7 * scale)
    n_irreps = int(labels_all.max()) + 1
    if n_irreps > len(classes):
        raise RuntimeError("symmetry decomposition failed: more isotypic components than "
                           "conjugacy classes")
    # 2. within each component, eigenspaces E_i of a random Hermitian algebra element
    pos = 0
    comps: dict[int, list[tuple[int, NDArray, NDArray]]] = {g: [] for g in range(n_irreps)}
    for b, (vals, vecs) in enumerate(per_block):
        labels = labels_all[pos : pos + vals.size]
        pos += vals.size
        kind, n, _ = slices[b]
        a = element(kind, n, r_alg)
        a = a + a.conj().T
        for gam in np.unique(labels):
            q = vecs[:, labels == gam]
            w, u = np.linalg.eigh(q.conj().T @ a @ q)
            comps[int(gam)].append((b, w, q @ u))
    columns_per_irrep = [_irrep_vectors(comps[gam], slices,
                                        lambda kind, n: element(kind, n, r_map))
                         for gam in range(n_irreps)]
    n_solves = max(-(-len(mv) // dim) for dim, mv in columns_per_irrep)
    design = np.zeros((size, n_solves), dtype=complex)
    for dim, mv in columns_per_irrep:
        scale_g = np.sqrt(dim / group.size)
        for s in range(n_solves):
            chunk = mv[s * dim : (s + 1) * dim]
            for i, (b, _, images) in enumerate(chunk):
                design[slices[b][2], s] += scale_g * images[i]
    return design


def _irrep_vectors(
    items: list[tuple[int, NDArray, NDArray]], slices: list,
    map_block: Callable[[int, int], NDArray],
) -> tuple[int, list[tuple[int, int, list[NDArray]]]]:
    """One isotypic component of :func:`design_vectors`: its irrep's dimension ``d`` and, per
    multiplicity direction, ``(block, n, [unit vectors in E_1 .. E_d])``, low orders first.

    ``items`` are ``(block, eigenvalues, eigenvectors)`` of a random Hermitian algebra element
    in the component; ``map_block(kind, n)`` is a random algebra element's block, which maps
    ``E_1`` to every other ``E_i``.
    """
    w_all = np.concatenate([w for _, w, _ in items])
    span = float(np.abs(w_all).max()) or 1.0
    sub = _cluster(w_all, 1e-7 * span)
    dim = int(sub.max()) + 1
    # E_1 basis (multiplicity directions) and the maps E_1 -> E_i, per block
    mult_vectors = []  # list of (block, n, list over i of unit vectors in E_i)
    p0 = 0
    for b, w, u in items:
        s = sub[p0 : p0 + w.size]
        p0 += w.size
        kind, n, _ = slices[b]
        counts = np.bincount(s, minlength=dim)
        if np.any(counts != counts[0]):
            raise RuntimeError("symmetry decomposition failed: unequal eigenspaces")
        a_map = map_block(kind, n)
        spaces = [u[:, s == i] for i in range(dim)]
        for col in range(counts[0]):
            w1 = spaces[0][:, col]
            images = [w1]
            for i in range(1, dim):
                e_i = spaces[i]
                img = e_i @ (e_i.conj().T @ (a_map @ w1))
                norm = np.linalg.norm(img)
                if norm < 1e-6:
                    raise RuntimeError("symmetry decomposition failed: degenerate map")
                images.append(img / norm)
            mult_vectors.append((b, n, images))
    mult_vectors.sort(key=lambda t: (t[1], t[0]))  # low orders first
    return dim, mult_vectors


def _monomial(group: SymmetryGroup, g: int) -> tuple[NDArray, NDArray] | None:
    """``(perm, phase)`` with ``rho(g) v = phase * v[perm]`` if ``rho(g)`` has one nonzero per
    row (rotations by multiples of 90 deg about z and the two-fold axes and mirrors of the
    coordinate planes), else None."""
    slices = _block_slices(group.order)
    perm = np.empty(n_terms(group.order), dtype=np.int64)
    phase = np.empty(n_terms(group.order), dtype=complex)
    for kind, n, sl in slices:
        b = group.block(g, kind, n)
        big = np.abs(b) > 1e-12
        if np.any(big.sum(axis=1) != 1):
            return None
        cols = np.argmax(big, axis=1)
        perm[sl] = sl.start + cols
        phase[sl] = b[np.arange(b.shape[0]), cols]
    return perm, phase


def symmetrize(t_partial: NDArray[np.complex128], group: SymmetryGroup) -> NDArray[np.complex128]:
    """``sum_g rho(g) T~ rho(g)^H`` (the T-matrix from the design's partial sum)."""
    if group.size == 1:
        return t_partial
    slices = _block_slices(group.order)
    out = np.zeros_like(t_partial)
    for g in range(group.size):
        mono = _monomial(group, g)
        if mono is not None:
            perm, phase = mono
            out += (phase[:, None] * t_partial[np.ix_(perm, perm)]) * phase.conj()[None, :]
            continue
        tmp = np.empty_like(t_partial)
        for kind, n, sl in slices:
            tmp[sl] = group.block(g, kind, n) @ t_partial[sl]
        tmp = np.ascontiguousarray(tmp.T)  # rows of tmp^T are columns of tmp
        for kind, n, sl in slices:
            tmp[sl] = group.block(g, kind, n).conj() @ tmp[sl]
        out += tmp.T
    return out
