"""Building blocks of the prefit: the hologram on pixel lists, residuals and Jacobian, the exact
azimuthal average, the radial profile, and fit statistics."""

from __future__ import annotations

import numpy as np
import pytest

from holofit.conventions import DetectorGrid, hologram_intensity, incident_phase_at
from holofit.hologram import calc_hologram
from holofit.holomodel.forward import HologramModel, InvalidParameters
from holofit.holomodel.leastsq import INVALID_RESIDUAL, solve_least_squares
from holofit.holomodel.parameters import ParameterSpace, State
from holofit.holomodel.pixels import select_pixels
from holofit.holomodel.statistics import covariance_from_jacobian, estimate_noise_sd
from holofit.optics import Optics
from holofit.particles import Sphere
from holofit.prefit.estimate import SearchSpace, z_grid
from holofit.prefit.profile import annulus_mean_radius, profile_terms, radial_profile
from holofit.scattering.mie import LorenzMie, MieWave

OPTICS = Optics(0.66, 1.33, 0.35)
SPHERE_FREE = ("x_um", "y_um", "z_um", "radius_um", "n", "alpha")


def _grid():
    return DetectorGrid((40, 50), 0.12, corner=(300, 200))


def test_pixel_list_hologram_equals_grid_hologram():
    wave = MieWave(Sphere(0.6, 1.55), OPTICS)
    grid = _grid()
    pos = (203 * 0.12 + 2.0, 301 * 0.12 + 2.5, 9.0)
    ref = calc_hologram(wave, pos, grid, 0.8)
    x, y = grid.coordinates()
    ex, ey = wave.field_on_pixels(pos, x.ravel(), y.ravel())
    got = hologram_intensity(ex, ey, OPTICS.polarization_rad, 0.8)
    np.testing.assert_allclose(got, ref.ravel(), rtol=0, atol=1e-13)
    with pytest.raises(ValueError, match="cuts the sphere"):
        wave.field_on_pixels((0, 0, 0.5), x.ravel(), y.ravel())


def _model(free=SPHERE_FREE):
    grid = _grid()
    x, y = grid.coordinates()
    p = np.array([26.0, 38.5, 8.0, 0.55, 1.5, 0.85])
    wave = MieWave(Sphere(p[3], p[4]), OPTICS)
    data = calc_hologram(wave, p[:3], grid, p[5]).ravel()
    state = State((p[0], p[1], p[2]), None, p[5], (("radius_um", p[3]), ("n", p[4])))
    space = ParameterSpace(Sphere(p[3], p[4]), free, state,
                           step_overrides={"radius_um": 1e-5, "n": 1e-5})
    return HologramModel(LorenzMie(), space, OPTICS, x.ravel(), y.ravel()), data, p


def test_model_reproduces_the_truth_and_invalid_steps_are_penalised():
    model, data, p = _model()
    assert model.space.names == SPHERE_FREE
    assert np.abs(model.hologram(p) - data).max() < 1e-13
    bad = p.copy()
    bad[2] = 0.3  # detector plane inside the sphere
    with pytest.raises(InvalidParameters):
        model.hologram(bad)
    bad = p.copy()
    bad[3] = -0.1
    with pytest.raises(InvalidParameters):
        model.hologram(bad)
    # the optimiser wrapper turns invalid parameters into a rejected step
    sol = solve_least_squares(model, data, p, max_nfev=5)
    assert sol.rss < 1e-20 and INVALID_RESIDUAL > 1


def test_jacobian_matches_central_differences():
    model, _, p = _model()
    jac = model.jacobian(p)
    steps = np.array([1e-4, 1e-4, 1e-4, 1e-4, 1e-4, 1e-4])
    for i in range(6):
        dp = np.zeros(6)
        dp[i] = steps[i]
        central = (model.hologram(p + dp) - model.hologram(p - dp)) / (2 * steps[i])
        scale = np.abs(central).max()
        # alpha is exact; the others are forward differences with a 1e-5 step
        tol = 1e-9 if i == 5 else 2e-4
        assert np.abs(jac[:, i] - central).max() <= tol * scale, i


def test_fixed_parameters_leave_the_jacobian():
    model, _, p = _model(free=SPHERE_FREE[:5])
    full, _, _ = _model()
    np.testing.assert_array_equal(model.jacobian(p[:5]), full.jacobian(p)[:, :5])
    assert model.space.state(p[:5]).alpha == p[5]


def test_exact_azimuthal_average_equals_dense_numerical_average():
    wave = MieWave(Sphere(0.9, 1.55), OPTICS)
    z, rho, alpha = 6.0, np.linspace(0.1, 10, 40), 0.8
    phis = np.linspace(0, 2 * np.pi, 361)[:-1]
    dense = np.zeros_like(rho)
    for phi in phis:
        pts = np.stack([rho * np.cos(phi), rho * np.sin(phi), np.full_like(rho, -z)], axis=1)
        e = wave.field_at(pts) * incident_phase_at(z, OPTICS.k)
        dense += hologram_intensity(e[:, 0], e[:, 1], OPTICS.polarization_rad, alpha)
    dense /= phis.size
    lin, quad = profile_terms(wave, [z], rho)
    np.testing.assert_allclose(1 + 2 * alpha * lin[0] + alpha**2 * quad[0], dense, atol=1e-13)


def test_radial_profile_of_a_radial_function():
    rows, cols = np.indices((61, 71))
    centre = (30.3, 34.8)
    r = np.hypot(rows - centre[0], cols - centre[1])
    img = 1 + 0.01 * r
    valid = np.ones(img.shape, bool)
    valid[:5] = False
    prof = radial_profile(img, valid, centre, 25)
    # the mean of 1 + 0.01 r over the annulus [b, b+1) is 1 + 0.01 * (mean radius)
    np.testing.assert_allclose(prof.mean[3:], 1 + 0.01 * annulus_mean_radius(25)[3:], atol=2e-3)
    assert prof.counts.sum() == np.sum(valid & (r < 25))


def test_z_grid_keeps_the_fringe_phase_step():
    space = SearchSpace(z_range_um=(3.0, 40.0), phase_step_rad=0.7)
    k, rho = 12.0, 8.0
    z = z_grid(space, k, rho)
    assert z[0] == pytest.approx(3.0) and z[-1] == pytest.approx(40.0)
    phase = 0.5 * k * rho**2 / z
    assert np.abs(np.diff(phase)).max() <= 0.7 + 1e-12


def test_search_space_rejects_bad_ranges():
    with pytest.raises(ValueError, match="focal plane"):
        SearchSpace(z_range_um=(-5.0, 5.0))
    # the ideal model needs the focal plane outside the spheres and above it; the lens does not
    near = SearchSpace(z_range_um=(1.0, 5.0), radius_range_um=(0.2, 1.5))
    with pytest.raises(ValueError, match="reaches into"):
        near.check_heights(lens=False)
    near.check_heights(lens=True)
    below = SearchSpace(z_range_um=(-8.0, -2.0))
    with pytest.raises(ValueError, match="below the focal plane"):
        below.check_heights(lens=False)
    below.check_heights(lens=True)


def test_covariance_of_a_straight_line_fit():
    # textbook: var(slope) = s^2 / sum (t - mean t)^2 for y = a + b t
    rng = np.random.default_rng(1)
    t = np.linspace(0, 10, 30)
    y = 2 + 0.5 * t + rng.normal(0, 0.3, t.size)
    jac = np.stack([np.ones_like(t), t], axis=1)
    _coef, rss, *_ = np.linalg.lstsq(jac, y, rcond=None)
    cov = covariance_from_jacobian(jac, float(rss[0]), t.size)
    s2 = float(rss[0]) / (t.size - 2)
    assert cov[1, 1] == pytest.approx(s2 / np.sum((t - t.mean()) ** 2), rel=1e-12)
    assert np.isnan(covariance_from_jacobian(jac[:2], 0.0, 2)).all()


def test_noise_estimate_on_a_smooth_image_with_white_noise():
    rng = np.random.default_rng(2)
    rows, cols = np.indices((150, 150))
    smooth = 1 + 0.2 * np.sin(rows / 15.0) * np.cos(cols / 20.0)
    img = smooth + rng.normal(0, 0.02, smooth.shape)
    img[60:70, 60:70] = np.nan
    assert estimate_noise_sd(img) == pytest.approx(0.02, rel=0.05)


def test_pixel_selection_masks_subsets_and_places_pixels():
    grid = _grid()
    crop = np.ones(grid.shape)
    crop[3, 4] = np.nan
    crop[5, 6] = 9.0
    sel = select_pixels(crop, grid.corner, grid.pixel_size_um, saturation=5.0)
    assert sel.n_masked == 2 and sel.size == grid.size - 2 and not sel.valid[5, 6]
    x, y = grid.coordinates()
    np.testing.assert_array_equal(sel.xs_um, x.ravel()[sel.index])
    np.testing.assert_array_equal(sel.ys_um, y.ravel()[sel.index])
    a = select_pixels(crop, grid.corner, 0.12, fraction=0.25, rng=np.random.default_rng(3))
    b = select_pixels(crop, grid.corner, 0.12, fraction=0.25, rng=np.random.default_rng(3))
    assert a.size == round(0.25 * (grid.size - 1)) and np.array_equal(a.index, b.index)
    with pytest.raises(ValueError, match="usable pixels"):
        select_pixels(crop, grid.corner, 0.12, min_pixels=10**6)
