"""The default filling (:mod:`holofit.dda.filling`): exact plane fractions, faces parallel to
the lattice planes filled exactly whatever their offset, curved volumes kept, and the DDA of a
flat-ended cylinder converging toward the exact T-matrix.

References: the volume of a cube cut by a plane from its convex hull (scipy.spatial), the
bodies' analytic volumes, and the exact (EBCM) T-matrix of the cylinder, itself checked
against Mishchenko's EBCM (pytmatrixc) and an extended-precision EBCM in
``tests/test_exact_bodies.py`` and ``tests/test_exact_references.py`` (far field good to
~2e-5 at order 34).
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy.spatial import ConvexHull

from holofit.dda.filling import body_fraction, box_cdf
from holofit.dda.voxelize import voxelize
from holofit.particles import Cylinder, JanusSphere, Sphere, Spherocylinder, Spheroid

WAVELENGTH_MEDIUM = 0.66 / 1.33


def _rule(dpl: float, n: float = 1.495) -> float:
    """The dipole size of ``dpl`` dipoles per wavelength in silica in water, um."""
    return WAVELENGTH_MEDIUM / (dpl * n / 1.33)


def _cut_cube_volume(n: np.ndarray, t: float) -> float:
    """Volume of ``{u in [-1/2, 1/2]^3 : n . u < t}`` from the convex hull of its vertices."""
    corners = np.array(list(itertools.product((-0.5, 0.5), repeat=3)))
    pts = [c for c in corners if c @ n <= t + 1e-15]
    for a, b in itertools.combinations(corners, 2):
        if np.sum(a != b) == 1 and (a @ n - t) * (b @ n - t) < 0:
            pts.append(a + (t - a @ n) / ((b - a) @ n) * (b - a))
    pts = np.array(pts)
    if len(pts) < 4 or np.linalg.matrix_rank(pts[1:] - pts[0]) < 3:
        return 0.0
    return ConvexHull(pts).volume


def test_plane_fraction_is_the_volume_of_the_cut_voxel() -> None:
    rng = np.random.default_rng(2)
    normals = [np.array(v, float) for v in ((1, 0, 0), (0, 1, 1), (1, 1, 1), (3, 1, 0.2))]
    normals += list(rng.normal(size=(6, 3)))
    for n in normals:
        n = n / np.linalg.norm(n)
        ts = np.linspace(-0.9, 0.9, 19)
        got = box_cdf(ts, np.tile(n, (ts.size, 1)))
        want = [_cut_cube_volume(n, t) if t > -0.5 * np.abs(n).sum() else 0.0 for t in ts]
        np.testing.assert_allclose(got, np.minimum(want, 1.0), atol=1e-12)


@pytest.mark.parametrize("dpl", [10.0, 14.0, 20.0])
@pytest.mark.parametrize("axis", [0, 1, 2])
def test_faces_parallel_to_the_lattice_are_filled_exactly(dpl: float, axis: int) -> None:
    """A cylinder along each lattice axis: its voxelised volume is linear in its length with
    the slope of its voxelised cross-section, for every offset of its ends from the lattice
    planes (the ends are filled exactly), and within 3e-3 of the analytic volume."""
    d = _rule(dpl)
    radius = 0.5
    j = np.arange(-int(1.3 / d) - 2, int(1.3 / d) + 3)
    pts = (np.stack(np.meshgrid(j, j, j, indexing="ij"), -1).reshape(-1, 3) + 0.5) * d
    across = [c for c in range(3) if c != axis]
    disc = body_fraction(lambda q: np.hypot(q[:, across[0]], q[:, across[1]]) - radius, pts, d)
    area = disc.sum() * d**3 / (d * j.size)  # voxelised cross-section, um^2
    assert abs(area / (np.pi * radius**2) - 1) < 3e-3
    for half in 1.0 + d * np.linspace(0.0, 1.0, 7):
        slab = body_fraction(lambda q, h=half: np.abs(q[:, axis]) - h, pts, d)
        volume = np.sum(disc * slab) * d**3
        assert volume == pytest.approx(area * 2 * half, rel=1e-12)


@pytest.mark.parametrize("dpl", [10.0, 20.0])
def test_cylinder_model_volume_exact_at_every_offset_and_the_ramp_is_not(dpl: float) -> None:
    d = _rule(dpl)
    errors = {"fractional": [], "ramp": []}
    for half in 1.0 + d * np.linspace(0.0, 1.0, 6):
        exact = np.pi * 0.25 * 2 * half
        for filling, errs in errors.items():
            lat = voxelize(Cylinder(0.5, half, 1.495), d, filling)
            errs.append(lat.occupied_volume_um3().sum() / exact - 1)
    assert np.ptp(errors["fractional"]) < 2e-4  # the ends: exact at every offset
    assert np.abs(errors["fractional"]).max() < 2e-3  # the curved side: its sampling
    assert np.ptp(errors["ramp"]) > 5e-3  # the ramp moves the ends with their offset


@pytest.mark.parametrize("model,volume", [
    (Sphere(0.5, 1.45), 4 / 3 * np.pi * 0.5**3),
    (Spheroid(0.5, 1.0, 1.495), 4 / 3 * np.pi * 0.25),
    (Spherocylinder(0.501, 1.079, 1.495),
     np.pi * 0.501**2 * 2 * 0.578 + 4 / 3 * np.pi * 0.501**3),
    (JanusSphere(0.443, 0.047, 1.581, 2.74),
     4 / 3 * np.pi * 0.49**3 / 2 + 2 / 3 * np.pi * 0.443**3),
], ids=["sphere", "spheroid", "rod", "janus"])
def test_curved_volumes_within_the_sampling_error(model, volume) -> None:
    for dpl in (10.0, 20.0):
        lat = voxelize(model, _rule(dpl))
        assert abs(lat.occupied_volume_um3().sum() / volume - 1) < 1.5e-3


def _cylinder_dda_error(dpl: float, filling: str, tm) -> float:
    from holofit.dda.engine import BuiltinDDA
    from holofit.dda.settings import DDASettings
    from holofit.optics import Optics
    from holofit.scattering.theory import Orientation
    from holofit.scattering.tmatrix_wave import TMatrixWave

    optics = Optics(0.66, 1.33)
    model = Cylinder(0.5, 1.0, 1.495)
    rng = np.random.default_rng(3)
    dirs = rng.normal(size=(200, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    o = Orientation(np.pi / 6, np.pi / 4, 0.4)
    dda = BuiltinDDA(DDASettings(dipoles_per_wavelength=dpl, filling=filling, tolerance=1e-7))
    fd = dda.solve_direct(model, optics, o).far_field_amplitude(dirs)
    fe = TMatrixWave(model, optics, o, tm).far_field_amplitude(dirs)
    return float(np.abs(fd - fe).max() / np.abs(fe).max())


@pytest.fixture(scope="module")
def cylinder_tmatrix():
    from holofit.optics import Optics
    from holofit.scattering.axisym import build_exact_tmatrix

    return build_exact_tmatrix(Cylinder(0.5, 1.0, 1.495), Optics(0.66, 1.33), order=34)


def test_cylinder_dda_at_the_default_rule_beats_the_ramp(cylinder_tmatrix) -> None:
    frac = _cylinder_dda_error(10.0, "fractional", cylinder_tmatrix)
    ramp = _cylinder_dda_error(10.0, "ramp", cylinder_tmatrix)
    assert frac < 0.5 * ramp


@pytest.mark.slow
def test_cylinder_dda_error_falls_with_the_dipole_size(cylinder_tmatrix) -> None:
    errors = [_cylinder_dda_error(dpl, "fractional", cylinder_tmatrix) for dpl in (10, 20, 28)]
    assert errors[0] > errors[1] > errors[2]
    assert errors[2] < 4e-4
