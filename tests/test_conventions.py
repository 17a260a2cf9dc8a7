"""The conventions module: rotations, axes, pixel coordinates, hologram formula."""

import json

import numpy as np
import pytest

from holofit import conventions as cv
from tests.conftest import DATA


def test_euler_matches_adda_rotation_matrix():
    # ADDA reference case c(30, 60, 0): R printed by the data set's preparer, checked there
    # against ADDA itself (capsule axis along (0.75, 0.433, 0.5)).
    cases = json.loads((DATA / "adda" / "cases.json").read_text())
    for case in cases.values():
        a, b, g = np.radians(case["orient_deg"])
        r_ref = np.array(case["rotation_matrix_R_particle_to_lab"])
        np.testing.assert_allclose(cv.euler_zyz(a, b, g), r_ref, atol=1e-11)


@pytest.mark.parametrize("psi,theta,phi", [(0.3, 1.1, -0.7), (2.0, 0.2, 1.3), (-1.0, 2.9, 0.0)])
def test_rotation_is_proper_and_axis_is_r_zhat(psi, theta, phi):
    r = cv.euler_zyz(psi, theta, phi)
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-14)
    assert np.linalg.det(r) == pytest.approx(1.0)
    u = cv.axis_from_angles(theta, psi)
    np.testing.assert_allclose(r @ [0, 0, 1], u, atol=1e-14)
    th, ps = cv.angles_from_axis(u)
    assert th == pytest.approx(theta) and np.cos(ps - psi) == pytest.approx(1.0)


def test_theta_zero_points_toward_source():
    # light travels along -z, so the source is at +z: theta = 0 axis points along +z
    assert cv.PROPAGATION_DIRECTION @ cv.axis_from_angles(0.0, 0.0) == pytest.approx(-1.0)


def test_pixel_axes_x_is_column_y_is_row():
    x, y = cv.pixel_centres((3, 5), 0.1, corner=(10, 20))
    assert x.shape == (3, 5)
    assert x[0, 4] == pytest.approx((20 + 4) * 0.1)  # x grows along columns
    assert y[2, 0] == pytest.approx((10 + 2) * 0.1)  # y grows along rows
    assert np.all(x[:, 0] == x[0, 0]) and np.all(y[0, :] == y[0, 0])


def test_right_handed_frame():
    assert np.allclose(np.cross([1, 0, 0], [0, 1, 0]), [0, 0, 1])


def test_hologram_intensity_limits():
    zero = np.zeros(4, complex)
    assert np.allclose(cv.hologram_intensity(zero, zero, 0.7, 0.5), 1.0)
    # a field along the polarisation, in phase, adds amplitude: (1 + a)^2
    pol = 0.4
    e = 0.1 * np.array([np.cos(pol), np.sin(pol)], complex)
    assert cv.hologram_intensity(e[0], e[1], pol, 1.0) == pytest.approx(1.1**2)
    # a field perpendicular to the polarisation adds intensity only
    assert cv.hologram_intensity(-0.1 * np.sin(pol), 0.1 * np.cos(pol), pol) == pytest.approx(1.01)


def test_incident_phase_travels_down():
    k = 10.0
    # the wave exp(-ikz) has phase decreasing with z: a crest moves toward -z as time goes
    ph = cv.incident_phase_at([0.0, 0.1], k)
    assert np.angle(ph[1] / ph[0]) == pytest.approx(-1.0)


def test_r_squared():
    d = np.array([1.0, 2.0, 3.0, 4.0])
    assert cv.r_squared(d, d) == 1.0
    assert cv.r_squared(d, np.full(4, d.mean())) == pytest.approx(0.0)
    assert cv.r_squared(d, d + 1, mask=[True, True, False, False]) == pytest.approx(1 - 2 / 0.5)
