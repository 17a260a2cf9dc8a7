"""DDAWave's amplitude matrix, cross sections and field_at, and ADDA's -orient in holofit.

References: ADDA's own output for a tilted Janus particle (tests/data/adda/e_janus_o30_60_20,
made with ADDA 1.5 on the shape file of the d_janus case), exact Lorenz-Mie, and direct dipole
sums.
"""

import numpy as np
import pytest

from holofit.conventions import euler_zyz
from holofit.dda.adda.frames import orientation_from_adda
from holofit.dda.engine import BuiltinDDA
from holofit.dda.nearfield import direct_field
from holofit.optics import Optics
from holofit.particles import Sphere, VoxelShape
from holofit.scattering.mie import cross_sections, far_field_amplitudes
from holofit.scattering.theory import Orientation
from tests.conftest import DATA

OPTICS = Optics(0.66, 1.33, 0.0)
JANUS_GEOM = DATA / "adda" / "d_janus_o0_0_0" / "janus_d0.024.geom"
TILTED = DATA / "adda" / "e_janus_o30_60_20"


def _adda_directions(theta_deg, phi_deg):
    th, ph = np.radians(theta_deg), np.radians(phi_deg)
    return np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], axis=1)


def test_adda_orient_zero_puts_the_janus_cap_downstream():
    # ADDA's light travels along +z: its unrotated cap (particle +z) points away from the
    # source, which is holofit's theta = pi
    o = orientation_from_adda((0.0, 0.0, 0.0))
    u = euler_zyz(*o.as_tuple()) @ [0.0, 0.0, 1.0]
    np.testing.assert_allclose(u, [0.0, 0.0, -1.0], atol=1e-12)
    with pytest.raises(ValueError, match="three angles"):
        orientation_from_adda((1.0, 2.0))


@pytest.mark.slow
def test_tilted_janus_matches_adda_through_the_orientation_helper():
    """A z-asymmetric particle at ADDA's -orient 30 60 20, run by the built-in engine on the
    same shape file: same amplitude matrix (ADDA's basis and origin) and extinction."""
    model = VoxelShape(str(JANUS_GEOM), 0.024, (1.59, 2.7), (0.0, 0.0, 0.0))
    ref = np.loadtxt(TILTED / "ampl_scatgrid", skiprows=1)
    # at theta = 0 ADDA writes the forward direction once per phi, each in the basis of its
    # phi; a direction alone (phi = 0 there) names only the first of those rows
    ref = ref[(ref[:, 0] > 0) | (ref[:, 1] == 0)]
    s_ref = ref[:, 2::2] + 1j * ref[:, 3::2]
    # ADDA's prescription (LDR) and default tolerance: within 4e-6 max|S| of its eps-8 output
    engine = BuiltinDDA(polarizability="ldr")
    wave = engine.solve(model, OPTICS, orientation_from_adda((30.0, 60.0, 20.0)))
    n_lab = _adda_directions(ref[:, 0], ref[:, 1]) @ wave._adda_lab()  # ADDA lab -> holofit
    s = wave.amplitude_matrix(n_lab, phase_origin="box")
    err = np.max(np.abs(s - s_ref)) / np.max(np.abs(s_ref))
    assert err < 1e-4, err
    cext_x = float((TILTED / "CrossSec-X").read_text().split()[2])
    assert wave.cross_sections().extinction_um2 == pytest.approx(cext_x, rel=1e-5)
    # the tempting mapping (holofit angles = ADDA's angles) mirrors the particle: its field
    # for the instrument's polarisation differs from the one that matches ADDA
    wrong = engine.solve(model, OPTICS, Orientation(*np.radians([30.0, 60.0, 20.0])))
    f_right = wave.far_field_amplitude(n_lab)
    f_wrong = wrong.far_field_amplitude(n_lab)
    assert np.max(np.abs(f_wrong - f_right)) / np.max(np.abs(f_right)) > 1e-2


def test_sphere_amplitude_matrix_and_cross_sections_against_mie():
    optics = Optics(0.66, 1.33, 0.4)  # polarisation off x: ADDA's frame follows it
    wave = BuiltinDDA(tolerance=1e-7).solve(Sphere(0.3, 1.585), optics)
    th = np.radians(np.linspace(0.0, 180.0, 13))
    for phi_deg in (0.0, 37.0):
        n_lab = _adda_directions(np.degrees(th), np.full(th.size, phi_deg)) @ wave._adda_lab()
        s = wave.amplitude_matrix(n_lab)
        s1, s2 = far_field_amplitudes(1.585 / 1.33, optics.k * 0.3, th)
        scale = np.abs(s2).max()
        assert np.max(np.abs(s[:, 0] - s1)) < 0.02 * scale  # DDA discretisation error
        assert np.max(np.abs(s[:, 1] - s2)) < 0.02 * scale
        assert np.max(np.abs(s[:, 2:])) < 2e-3 * scale  # a sphere does not depolarise
    cs = wave.cross_sections()
    mie = cross_sections(1.585 / 1.33, 0.3, optics.k)
    assert cs.extinction_um2 == pytest.approx(mie.extinction_um2, rel=0.02)
    assert abs(cs.absorption_um2) < 1e-10 * cs.extinction_um2  # lossless
    # optical theorem through the new amplitude matrix: C_ext = (4 pi / k^2) Re S2(0)
    s0 = wave.amplitude_matrix(wave._adda_lab().T @ [0.0, 0.0, 1.0])
    assert cs.extinction_um2 == pytest.approx(4 * np.pi / optics.k**2 * s0[0, 1].real,
                                              rel=1e-6)


def test_absorbing_sphere_cross_sections_balance():
    wave = BuiltinDDA(tolerance=1e-7).solve(Sphere(0.2, 1.2 + 2.0j), OPTICS)
    cs = wave.cross_sections()
    mie = cross_sections((1.2 + 2.0j) / 1.33, 0.2, OPTICS.k)
    assert cs.absorption_um2 > 0.2 * cs.extinction_um2
    assert cs.absorption_um2 == pytest.approx(mie.absorption_um2, rel=0.15)
    # C_sca = C_ext - C_abs must equal the scattered power (integral of |F|^2 / k^2)
    mu, w = np.polynomial.legendre.leggauss(48)
    phi = np.arange(48) * 2 * np.pi / 48
    st = np.sqrt(1 - mu**2)
    n = np.stack([np.outer(st, np.cos(phi)), np.outer(st, np.sin(phi)),
                  np.repeat(mu[:, None], 48, 1)], -1).reshape(-1, 3)
    f = wave.far_field_amplitude(n)
    csca = float(np.sum(np.repeat(w, 48) * (2 * np.pi / 48) * np.sum(abs(f) ** 2, 1))) / (
        OPTICS.k**2)
    assert cs.scattering_um2 == pytest.approx(csca, rel=1e-4)


def test_field_at_many_points_equals_direct_dipole_sums():
    wave = BuiltinDDA().solve(Sphere(0.3, 1.5), OPTICS, Orientation(0.3, 0.7, 0.0))
    rng = np.random.default_rng(2)
    pts = rng.normal(size=(400, 3))
    pts *= (1.0 + 10 * rng.random(400))[:, None] / np.linalg.norm(pts, axis=1)[:, None]
    got = wave.field_at(pts)
    rot = wave.rotation
    ref = direct_field(pts @ rot, wave.lattice.positions, wave.solution.P, OPTICS.k) @ rot.T
    assert np.max(np.abs(got - ref)) < 1e-8 * np.max(np.abs(ref))
