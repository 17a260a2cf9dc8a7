"""The mathematics under the T-matrix: regular waves, Wigner rotations, lattice symmetries.

Independent references: the plane wave itself (its truncated regular-wave series), regular
waves summed term by term with scipy's spherical Bessel functions, Wigner matrices from the
eigen-decomposition of J_y (a different construction from the recurrence), finite differences,
and Schur's orthogonality (the design's Parseval frame).
"""

import itertools

import numpy as np
import pytest
from scipy.special import spherical_jn

from holofit.conventions import euler_zyz, euler_zyz_from_matrix
from holofit.dda.tmatrix_incident import incident_on_lattice
from holofit.dda.tmatrix_symmetry import SymmetryGroup, design_vectors, lattice_symmetries
from holofit.dda.voxelize import voxelize
from holofit.io.shapefile import write_shape_file
from holofit.particles import Dimer, JanusSphere, Sphere, Spherocylinder, VoxelShape
from holofit.scattering.multipole import _full_tables
from holofit.scattering.tmatrix import TMatrix
from holofit.scattering.vsw import (
    n_terms,
    pack,
    plane_wave_coefficients,
    unpack,
)
from holofit.scattering.wigner import (
    apply_blocks,
    operation_blocks,
    rotation_blocks,
    wigner_d_all,
)

K = 12.66


def regular_field(vec, order, k, pts):
    """``sum a RgN + b RgM`` term by term (scipy's j_n, the module's Legendre tables)."""
    a, b = unpack(vec, order)
    r = np.linalg.norm(pts, axis=1)
    th = np.arccos(np.clip(pts[:, 2] / r, -1, 1))
    ph = np.arctan2(pts[:, 1], pts[:, 0])
    kr = k * r
    n = np.arange(order + 1)
    j = spherical_jn(n[None, :], kr[:, None])
    jd = spherical_jn(n[None, :], kr[:, None], derivative=True)
    dx = (j + kr[:, None] * jd) / kr[:, None]  # (x j_n)'/x
    pf, df, mf = _full_tables(np.cos(th), order)
    e = np.exp(1j * np.outer(ph, np.arange(-order, order + 1)))[:, None, :]
    nn = (n * (n + 1))[None, :, None]
    jj, dd = j[:, :, None], dx[:, :, None]
    e_r = np.sum(a[None] * nn * (jj / kr[:, None, None]) * pf * e, axis=(1, 2))
    # RgN = ... + dx Psi, RgM = -j Phi; Psi = df e_t + i mf e_p, Phi = df e_p - i mf e_t
    e_t = np.sum((a[None] * dd * df + b[None] * jj * 1j * mf) * e, axis=(1, 2))
    e_p = np.sum((a[None] * dd * 1j * mf - b[None] * jj * df) * e, axis=(1, 2))
    st, ct, sp, cp = np.sin(th), np.cos(th), np.sin(ph), np.cos(ph)
    return np.stack([e_r * st * cp + e_t * ct * cp - e_p * sp,
                     e_r * st * sp + e_t * ct * sp + e_p * cp,
                     e_r * ct - e_t * st], axis=1)


def random_pair(rng):
    a = rng.normal(size=3)
    a /= np.linalg.norm(a)
    e = np.cross(a, rng.normal(size=3))
    return a, e / np.linalg.norm(e)


def test_plane_wave_series_converges_to_the_plane_wave():
    rng = np.random.default_rng(1)
    pts = rng.normal(size=(60, 3))
    pts *= (0.8 * rng.uniform(size=60) / np.linalg.norm(pts, axis=1))[:, None]
    pairs = [random_pair(rng), (np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0])),
             (np.array([0.0, 0.0, -1.0]), np.array([np.cos(0.3), np.sin(0.3), 0.0]))]
    for a, e in pairs:
        exact = e[None, :] * np.exp(1j * K * pts @ a)[:, None]
        errors = [np.abs(regular_field(plane_wave_coefficients(a, e, L), L, K, pts)
                         - exact).max() for L in (10, 20, 35)]
        assert errors[0] > 1e-2  # truncated too early: visibly wrong
        assert errors[2] < 1e-12
        assert errors[1] < errors[0]


def test_incident_field_on_lattice_equals_the_regular_wave_sum():
    lat = voxelize(Spherocylinder(0.3, 0.6, 1.5), 0.05)
    L = 18
    rng = np.random.default_rng(2)
    vecs = rng.normal(size=(n_terms(L), 2)) + 1j * rng.normal(size=(n_terms(L), 2))
    fields = incident_on_lattice(lat, vecs, K, L)
    for j in range(2):
        direct = regular_field(vecs[:, j], L, K, lat.positions)
        assert np.abs(fields[j] - direct).max() <= 1e-12 * np.abs(direct).max()


def test_pack_unpack_roundtrip():
    L = 7
    v = np.arange(n_terms(L)) + 1j
    assert np.array_equal(pack(*unpack(v, L)), v)


@pytest.mark.parametrize("angles", [(0.3, 0.7, -1.1), (0.0, 0.0, 0.0), (1.0, np.pi, 2.0),
                                    (0.1, 3.0, 0.5)])
def test_wigner_recurrence_matches_eigen_construction(angles):
    L = 30
    big, derivs = wigner_d_all(L, *angles, derivatives=True)
    blocks, dblocks = rotation_blocks(L, *angles, derivatives=True)
    for n in range(1, L + 1):
        sl = slice(L - n, L + n + 1)
        assert np.abs(big[n][sl, sl] - blocks[n - 1]).max() < 1e-12
        for j in range(3):
            assert np.abs(derivs[j][n][sl, sl] - dblocks[n - 1][j]).max() < 1e-10 * n
    # finite differences of the recurrence itself
    h = 1e-6
    for j in range(3):
        up, down = list(angles), list(angles)
        up[j] += h
        down[j] -= h
        fd = (wigner_d_all(L, *up) - wigner_d_all(L, *down)) / (2 * h)
        assert np.abs(fd - derivs[j]).max() < 1e-6 * L


def test_cube_operations_act_on_plane_wave_coefficients():
    """rho(S) c(k, e) = c(S k, S e) for all 48 rotations and rotation-reflections."""
    L = 12
    rng = np.random.default_rng(3)
    a, e = random_pair(rng)
    c = plane_wave_coefficients(a, e, L)
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1, -1), repeat=3):
            s = np.zeros((3, 3))
            s[np.arange(3), perm] = signs
            blocks, sn, sm = operation_blocks(s, L)
            got = apply_blocks(blocks, c, L, sn, sm)
            assert np.abs(got - plane_wave_coefficients(s @ a, s @ e, L)).max() < 1e-13


def _eps(lat, n_medium=1.33):
    return lat.relative_permittivity(n_medium)


def _symmetries(lat, n_medium=1.33):
    """As the build detects them: per-axis permittivities of laminate boundary voxels."""
    eps = lat.component_permittivity(n_medium)
    return lattice_symmetries(lat, eps, per_axis=True)


@pytest.mark.parametrize("model,d,count", [
    (Spherocylinder(0.501, 1.079, 1.495), 0.0441, 16),
    (JanusSphere(0.443, 0.047, 1.581, 2.74), 0.04, 8),
    (Dimer(0.25, 0.25, 0.0, 1.5, 1.5), 0.05, 16),  # two materials, one index
    (Dimer(0.25, 0.2, 0.0, 1.5, 1.5), 0.05, 8),
    (Sphere(0.3, 1.5), 0.05, 48),
])
def test_lattice_symmetries_are_detected(model, d, count):
    lat = voxelize(model, d)
    assert lat.normals is not None  # laminate boundary voxels: anisotropic permittivities
    ops = _symmetries(lat)
    assert len(ops) == count
    assert len(lattice_symmetries(lat, _eps(lat))) == count  # isotropic voxels alike
    group = SymmetryGroup.from_operations(ops, 2)  # raises unless closed
    assert group.size == count


def test_axis_permutations_permute_per_axis_permittivities():
    """A laminate voxel's permittivity along x is its image's along y after a swap of x and y:
    without permuting the components, the rod's eight axis-swapping operations are lost."""
    lat = voxelize(Spherocylinder(0.3, 0.6, 1.5), 0.05)
    eps = lat.component_permittivity(1.33)
    assert np.abs(eps[:, 0] - eps[:, 1]).max() > 1e-3  # genuinely anisotropic voxels
    assert len(lattice_symmetries(lat, eps, per_axis=True)) == 16
    assert len(lattice_symmetries(lat, eps, per_axis=False)) == 8


def test_off_centre_voxel_file_has_no_symmetry(tmp_path):
    lat = voxelize(Sphere(0.2, 1.5), 0.05, "binary")
    path = write_shape_file(tmp_path / "ball.geom", lat.ijk)
    centred = voxelize(VoxelShape(str(path), 0.05, (1.5,)), 0.05)
    shifted = voxelize(VoxelShape(str(path), 0.05, (1.5,), (0.013, 0.0, 0.0)), 0.05)
    assert len(lattice_symmetries(centred, _eps(centred))) == 48
    assert len(lattice_symmetries(shifted, _eps(shifted))) == 1


@pytest.mark.parametrize("model,d", [
    (Spherocylinder(0.3, 0.6, 1.5), 0.06),
    (JanusSphere(0.3, 0.05, 1.58, 2.7), 0.06),
    (Sphere(0.3, 1.5), 0.06),
])
def test_design_images_form_a_parseval_frame(model, d):
    """sum_s sum_g rho(g) c_s c_s^H rho(g)^H = 1 with ~N/|G| design vectors."""
    lat = voxelize(model, d)
    L = 9
    group = SymmetryGroup.from_operations(_symmetries(lat), L)
    design = design_vectors(group)
    size = n_terms(L)
    assert design.shape[1] == -(-size // group.size)
    frame = np.zeros((size, size), dtype=complex)
    for g in range(group.size):
        x = apply_blocks(group.blocks[g], design, L, group.sign_n[g], group.sign_m[g])
        frame += x @ x.conj().T
    assert np.abs(frame - np.eye(size)).max() < 1e-12


def test_orientation_derivatives_of_lab_coefficients():
    """Euler-angle and lab-axis derivatives against central differences (any matrix T)."""
    L = 9
    size = n_terms(L)
    rng = np.random.default_rng(4)
    tm = TMatrix.from_dense(rng.normal(size=(size, size)) + 1j * rng.normal(size=(size, size)),
                            L, K, 1.0)
    pol = np.array([np.cos(0.3), np.sin(0.3), 0.0])
    euler = (0.4, 1.1, -0.7)
    got = tm.lab_coefficients(euler, pol, derivatives=True)
    h = 1e-5
    for j, name in enumerate(("psi", "theta", "phi")):
        up, down = list(euler), list(euler)
        up[j] += h
        down[j] -= h
        fd = (tm.lab_coefficients(up, pol).vector - tm.lab_coefficients(down, pol).vector) / (
            2 * h)
        assert np.abs(fd - got.derivatives[name]).max() < 1e-8 * np.abs(fd).max()
    rot = euler_zyz(*euler)
    for axis in (np.array([1.0, 0.0, 0.0]), np.array([0.3, -0.5, 0.8]) / np.sqrt(0.98)):
        kx = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
        vals = []
        for a in (h, -h):
            r = (np.eye(3) + np.sin(a) * kx + (1 - np.cos(a)) * kx @ kx) @ rot
            vals.append(tm.lab_coefficients(euler_zyz_from_matrix(r), pol).vector)
        fd = (vals[0] - vals[1]) / (2 * h)
        assert np.abs(tm.rotation_derivative(euler, pol, axis) - fd).max() < 1e-8 * np.abs(
            fd).max()
