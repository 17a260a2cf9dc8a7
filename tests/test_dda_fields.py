"""Fields of a solved dipole set: multipole expansion, camera-plane evaluation, reuse.

References: direct summation of the dipoles' exact Green's-tensor fields, and the exact
Lorenz-Mie field (whose multipole expansion is known exactly).
"""

import numpy as np
import pytest

from holofit.conventions import DetectorGrid, incident_phase_at
from holofit.dda.engine import NEAR_ZONE, BuiltinDDA
from holofit.dda.nearfield import direct_field
from holofit.hologram import calc_hologram
from holofit.optics import Optics
from holofit.particles import Dimer, JanusSphere, Sphere, Spherocylinder
from holofit.scattering.mie import LorenzMie
from holofit.scattering.multipole import (
    default_order,
    evaluate_plane,
    expansion_from_far_field,
    plane_grid,
)
from holofit.scattering.theory import Orientation

OPTICS = Optics(0.66, 1.33, np.radians(20))


@pytest.fixture(scope="module")
def janus_wave():
    eng = BuiltinDDA(dipole_size_um=0.04)
    return eng.solve(JanusSphere(0.4, 0.06, 1.59, 2.7), OPTICS, Orientation(0.4, 1.1, -0.3))


@pytest.fixture(scope="module")
def rod_wave():
    eng = BuiltinDDA(dipole_size_um=0.06)
    return eng.solve(Spherocylinder(0.4, 0.9, 1.45), OPTICS, Orientation(2.0, 0.7, 0.5))


@pytest.mark.parametrize("which", ["janus_wave", "rod_wave"])
def test_multipole_field_equals_direct_sum(which, request):
    wave = request.getfixturevalue(which)
    rng = np.random.default_rng(2)
    dirs = rng.normal(size=(30, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    pts = dirs * rng.uniform(NEAR_ZONE, 30.0, 30)[:, None] * wave.radius_um
    expansion = wave.expansion.field_at(pts)
    direct = wave._direct_lab(pts)
    assert np.max(np.abs(expansion - direct)) <= 1e-9 * np.max(np.abs(direct))


def test_near_zone_uses_direct_sum(rod_wave):
    pts = np.array([[0.0, 0.0, -1.0], [0.3, -0.2, 1.1]])  # inside the near zone
    lab = rod_wave.field_at(pts)
    p_frame = pts @ rod_wave.rotation
    ref = direct_field(p_frame, rod_wave.lattice.positions, rod_wave.solution.P, OPTICS.k)
    np.testing.assert_allclose(lab, ref @ rod_wave.rotation.T, rtol=1e-12, atol=0)


@pytest.mark.parametrize("z", [1.0, 4.0, 15.0, -6.0])
def test_plane_grid_reproduces_exact_mie_field(z):
    """The interpolated camera-plane evaluation of an exactly known expansion (Lorenz-Mie)."""
    mie = LorenzMie().solve(Sphere(0.5, 1.59), OPTICS)
    k = OPTICS.k

    def amplitude(d):
        r = 100.0
        return mie.field_at(d * r, far_field=True) * k * r * np.exp(-1j * k * r)

    exp = expansion_from_far_field(amplitude, k, default_order(k, 0.5), 0.5)
    grid = DetectorGrid((96, 110), 0.1, corner=(5, 3))
    xp, yp = 6.03, 5.97
    rows = (5 + np.arange(96)) * 0.1
    cols = (3 + np.arange(110)) * 0.1
    rho = np.hypot(np.maximum(abs(cols[0] - xp), abs(cols[-1] - xp)),
                   np.maximum(abs(rows[0] - yp), abs(rows[-1] - yp)))
    for far in (False, True):
        pg = plane_grid(exp, z, np.arctan2(rho, abs(z)), far)
        ex, ey = evaluate_plane(pg, cols, rows, xp, yp, complex(incident_phase_at(z, k)))
        rx, ry = mie.field_on_detector((xp, yp, z), grid, far_field=far)
        scale = np.abs(rx).max()
        assert np.max(np.abs(ex - rx)) < 1e-9 * scale
        assert np.max(np.abs(ey - ry)) < 1e-9 * scale


def test_detector_field_equals_direct_sum_at_pixels(janus_wave):
    grid = DetectorGrid((40, 50), 0.1, corner=(30, 20))
    pos = (4.3, 4.7, 2.5)
    ex, ey = janus_wave.field_on_detector(pos, grid)
    x, y = grid.coordinates()
    pts = np.column_stack([x.ravel() - pos[0], y.ravel() - pos[1], np.full(x.size, -pos[2])])
    ref = janus_wave._direct_lab(pts) * incident_phase_at(pos[2], OPTICS.k)
    scale = np.abs(ref[:, :2]).max()
    assert np.max(np.abs(ex.ravel() - ref[:, 0])) < 1e-8 * scale
    assert np.max(np.abs(ey.ravel() - ref[:, 1])) < 1e-8 * scale


def test_close_particle_mixes_direct_and_multipole(rod_wave):
    """z = 1 um with a 0.9-um rod: pixels near the axis fall in the direct-sum zone."""
    grid = DetectorGrid((30, 30), 0.1, corner=(35, 35))
    pos = (5.0, 5.0, 1.0)
    ex, _ = rod_wave.field_on_detector(pos, grid)
    x, y = grid.coordinates()
    pts = np.column_stack([x.ravel() - 5.0, y.ravel() - 5.0, np.full(x.size, -1.0)])
    ref = rod_wave._direct_lab(pts)[:, 0] * incident_phase_at(1.0, OPTICS.k)
    assert np.max(np.abs(ex.ravel() - ref)) < 1e-8 * np.abs(ref).max()


def test_one_solve_serves_every_position():
    eng = BuiltinDDA(dipole_size_um=0.05)
    wave = eng.solve(Dimer(0.3, 0.35, 0.0, 1.59, 1.59), OPTICS, Orientation(0.2, 1.2, 0.0))
    grid = DetectorGrid((64, 64), 0.1)
    system = next(v for _, v in eng._systems.items())
    before = system.matvecs
    holos = [calc_hologram(wave, (3.2 + 0.05 * i, 3.1, 6.0 + 0.3 * i), grid) for i in range(5)]
    assert system.matvecs == before  # no new solve
    assert len({h.tobytes() for h in holos}) == 5
    # a lateral shift by whole pixels shifts the hologram
    a = calc_hologram(wave, (3.2, 3.1, 6.0), grid)
    b = calc_hologram(wave, (3.3, 3.1, 6.0), grid)
    np.testing.assert_allclose(a[:, :-1], b[:, 1:], atol=1e-9)


def test_far_field_amplitude_is_transverse(janus_wave):
    d = np.array([[0.3, -0.4, -0.866], [0.0, 0.0, 1.0]])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    f = janus_wave.far_field_amplitude(d)
    assert np.max(np.abs(np.sum(f * d, axis=1))) < 1e-12 * np.abs(f).max()


@pytest.mark.parametrize("model", [
    Sphere(0.3, 1.5 + 0.01j),
    Spherocylinder(0.25, 0.5, 1.45),
    JanusSphere(0.25, 0.05, 1.59, 2.4),
    Dimer(0.2, 0.25, 0.05, 1.5, 1.6),
], ids=lambda m: m.kind)
def test_optical_theorem_for_every_model(model):
    """Extinction from the dipoles' work equals 4 pi/k^2 Re(e* . F(forward)) (optical theorem)."""
    eng = BuiltinDDA(dipole_size_um=0.04, tolerance=1e-9)
    wave = eng.solve(model, OPTICS, Orientation(0.4, 1.0, 0.2))
    k = OPTICS.k
    sol = wave.solution
    e_inc = incident_field_of(wave)
    cext_dipoles = 4 * np.pi * k * np.sum(np.imag(np.sum(sol.P * np.conj(e_inc), axis=1)))
    forward = np.array([[0.0, 0.0, -1.0]])  # the propagation direction, lab frame
    f = wave.far_field_amplitude(forward)[0]
    cext_forward = 4 * np.pi / k**2 * np.real(np.dot(OPTICS.polarization, f))
    assert cext_dipoles == pytest.approx(cext_forward, rel=1e-7)
    assert cext_dipoles > 0


def incident_field_of(wave):
    from holofit.dda.dipoles import incident_field

    s = wave.solution
    return incident_field(s.lattice.positions, OPTICS.k, s.propagation, s.polarization)
