"""Discretisation: volumes, material split, lattice placement, ADDA shape files, settings."""

import numpy as np
import pytest

from holofit.config import ConfigError, load_particle
from holofit.dda.settings import DDASettings
from holofit.dda.voxelize import dipole_size, ramp, voxelize
from holofit.io.shapefile import read_shape_file, write_shape_file
from holofit.particles import (
    Cylinder,
    Dimer,
    Ellipsoid,
    JanusSphere,
    Sphere,
    Spherocylinder,
    Spheroid,
    VoxelShape,
)
from tests.conftest import CONFIGS, DATA

D = 0.03
VOLUMES = [
    (Sphere(0.5, 1.5), [4 / 3 * np.pi * 0.5**3]),
    (Spherocylinder(0.4, 1.0, 1.5), [np.pi * 0.4**2 * 1.2 + 4 / 3 * np.pi * 0.4**3]),
    (Cylinder(0.4, 0.7, 1.5), [np.pi * 0.4**2 * 1.4]),
    (Spheroid(0.3, 0.6, 1.5), [4 / 3 * np.pi * 0.3 * 0.3 * 0.6]),
    (Ellipsoid(0.3, 0.45, 0.6, 1.5), [4 / 3 * np.pi * 0.3 * 0.45 * 0.6]),
    (JanusSphere(0.45, 0.09, 1.59, 2.7),
     [4 / 3 * np.pi * 0.45**3, 2 / 3 * np.pi * (0.54**3 - 0.45**3)]),
    (Dimer(0.3, 0.4, 0.05, 1.5, 1.6), [4 / 3 * np.pi * 0.3**3, 4 / 3 * np.pi * 0.4**3]),
]


@pytest.mark.parametrize("model,volumes", VOLUMES, ids=lambda v: getattr(v, "kind", ""))
def test_fractional_volumes_match_shapes(model, volumes):
    lat = voxelize(model, D)
    np.testing.assert_allclose(lat.occupied_volume_um3(), volumes, rtol=2e-3)
    assert np.all(lat.fractions >= 0) and np.all(lat.fractions.sum(axis=1) <= 1 + 1e-12)


def test_ramp_spans_one_voxel_like_the_plane_volume_fraction():
    # the exact fraction of a voxel cut by a face-parallel plane is 1/2 - s on |s| <= 1/2:
    # the C2 ramp (the default filling's profile away from the lattice planes, and the whole
    # "ramp" filling) has its support, its end values and its value at the surface
    s = np.linspace(-0.5, 0.5, 11)
    np.testing.assert_allclose(ramp(s), 0.5 - s, atol=0.15)
    assert ramp(np.array([0.0]))[0] == 0.5
    assert ramp(np.array([-0.5]))[0] == 1.0 and ramp(np.array([0.5]))[0] == 0.0
    # antisymmetric about the surface, so an oblique interface, sampled at every offset from
    # the lattice planes, keeps its volume on average (one parallel to them does not: that is
    # the default filling's exact plane fraction, tests/test_dda_filling.py)
    t = np.linspace(0, 1.2, 13)
    np.testing.assert_allclose(ramp(t) + ramp(-t), 1.0, atol=1e-15)
    # C2: first and second derivatives vanish at the ends of the support
    h = 1e-4
    for end in (-0.5, 0.5):
        assert abs(ramp(np.array([end + h]))[0] - ramp(np.array([end - h]))[0]) < 1e-9


def test_boundary_voxels_are_laminates_with_radial_normals():
    lat = voxelize(Sphere(0.3, 1.5), D)
    total = lat.fractions.sum(axis=1)
    partial = (total > 0) & (total < 1)
    radial = lat.positions[partial] / np.linalg.norm(lat.positions[partial], axis=1)[:, None]
    np.testing.assert_allclose(lat.normals[partial], radial, atol=1e-4)
    assert np.all(lat.normals[total == 1] == 0)
    eps = lat.component_permittivity(1.0)
    np.testing.assert_allclose(eps[total == 1], 1.5**2)  # full voxels: isotropic material
    # a partly filled voxel: arithmetic mean along the interface, harmonic across it
    i = np.flatnonzero(partial)[np.argmin(np.abs(total[partial] - 0.5))]
    f, n = total[i], lat.normals[i]
    par, perp = 1 + f * (1.5**2 - 1), 1 / (1 - f + f / 1.5**2)
    np.testing.assert_allclose(eps[i], par * (1 - n**2) + perp * n**2)
    assert voxelize(Sphere(0.3, 1.5), D, filling="binary").normals is None


def test_lattice_fixed_to_particle_centre():
    """Voxel centres sit at d(j + 1/2) whatever the size: the lattice never moves."""
    for r in (0.3, 0.31, 0.333):
        lat = voxelize(Sphere(r, 1.5), D)
        frac = lat.positions / D - 0.5
        np.testing.assert_allclose(frac, np.round(frac), atol=1e-9)
    centre = voxelize(Sphere(0.3, 1.5), D).positions.mean(axis=0)
    np.testing.assert_allclose(centre, 0.0, atol=1e-12)


def test_janus_cap_on_plus_z_and_centre_is_core_centre():
    lat = voxelize(JanusSphere(0.4, 0.1, 1.59, 2.7), D)
    cap = lat.fractions[:, 1] > 0.5
    assert lat.positions[cap, 2].min() > -D  # the cap sits on the +z hemisphere
    core = lat.fractions[:, 0] > 0.999
    np.testing.assert_allclose(lat.positions[core].mean(axis=0), 0.0, atol=1e-9)


def test_dimer_centre_of_volume():
    model = Dimer(0.3, 0.45, 0.1, 1.5, 1.5)
    z1, z2 = model.sphere_centres_z()
    assert z2 - z1 == pytest.approx(0.85)
    assert z1 * 0.3**3 + z2 * 0.45**3 == pytest.approx(0.0, abs=1e-12)
    lat = voxelize(model, D)
    w = lat.fractions.sum(axis=1)
    assert np.sum(w * lat.positions[:, 2]) / w.sum() == pytest.approx(0.0, abs=2e-3)


def test_binary_sphere_matches_adda_dipole_count():
    # ADDA's sphere of grid 26 with d0 = 0.9/26 keeps 9328 dipoles (before its volume correction)
    lat = voxelize(Sphere(0.45, 1.585), 0.9 / 26, filling="binary")
    assert lat.n_dipoles == 9328


def test_adda_shape_roundtrip(tmp_path):
    lat = voxelize(JanusSphere(0.3, 0.06, 1.59, 2.7), D, filling="binary")
    path = tmp_path / "j.geom"
    written, written_domain = lat.binary_dipoles()
    write_shape_file(path, written, written_domain)
    ijk, domain = read_shape_file(path)
    assert written.shape[0] == lat.n_dipoles == ijk.shape[0]
    assert set(domain) == {0, 1}
    back = voxelize(VoxelShape(str(path), D, (1.59, 2.7)), D)
    np.testing.assert_allclose(back.occupied_volume_um3(), lat.occupied_volume_um3())


def test_read_reference_janus_geometry():
    ijk, domain = read_shape_file(DATA / "adda" / "d_janus_o0_0_0" / "janus_d0.024.geom")
    assert ijk.shape == (30488, 3)
    assert np.sum(domain == 0) == 25576 and np.sum(domain == 1) == 4912


def test_bad_shape_file(tmp_path):
    p = tmp_path / "bad.geom"
    p.write_text("1 2\n")
    with pytest.raises(ValueError, match=r"bad\.geom:1"):
        read_shape_file(p)


def test_dipoles_per_wavelength_rule():
    # the paper's rod: 10 dipoles per wavelength in silica gives its 44 nm
    d = dipole_size(Spherocylinder(0.5, 1.0, 1.495), 0.66 / 1.33, 1.33)
    assert d == pytest.approx(0.0441, abs=2e-4)
    # Janus: the TiO2 cap decides: ~24 nm
    assert dipole_size(JanusSphere(0.439, 0.05, 1.59, 2.7), 0.66 / 1.33, 1.33) == pytest.approx(
        0.0244, abs=3e-4)


def test_particle_configs_and_dda_settings(tmp_path):
    cfg = load_particle(CONFIGS / "particles" / "rod_paper.toml")
    assert isinstance(cfg.model, Spherocylinder) and cfg.dda_settings().dipole_size_um == 0.044
    bad = tmp_path / "rod.toml"
    bad.write_text('[particle]\nmodel = "spherocylinder"\na_um = 0.5\nb_um = 1.0\n'
                   'index = 1.5\n[dda]\nfiling = "binary"\n')
    with pytest.raises(ConfigError, match=r"rod\.toml.*\[dda\].*unknown key.*filing"):
        load_particle(bad)
    with pytest.raises(ValueError, match="b_um"):
        Spherocylinder(0.5, 0.4, 1.5)
    with pytest.raises(ValueError, match="polarizability"):
        DDASettings(polarizability="xyz")
