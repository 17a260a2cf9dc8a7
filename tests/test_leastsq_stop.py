"""The Gauss-Newton stopping rule of the least-squares fit (``stop_rss``): exact on a linear
problem, and on a sphere's hologram a fit that stops early is within the bar of the minimum,
with fewer Jacobians and the exact Jacobian at the point it reports."""

from __future__ import annotations

import numpy as np

from holofit.conventions import DetectorGrid
from holofit.hologram import calc_hologram
from holofit.holomodel.forward import HologramModel
from holofit.holomodel.leastsq import predicted_decrease, solve_least_squares
from holofit.holomodel.parameters import ParameterSpace, State, static_values
from holofit.holomodel.pixels import select_pixels
from holofit.optics import Optics
from holofit.particles import Sphere
from holofit.scattering.mie import LorenzMie, MieWave

OPTICS = Optics(0.66, 1.33, 0.0)
SPHERE = Sphere(0.5, 1.59)
PX = 0.106
NOISE = 0.02


def test_predicted_decrease_is_the_linear_least_squares_decrease():
    rng = np.random.default_rng(3)
    jac = rng.normal(size=(200, 4)) * np.array([1e-3, 1.0, 50.0, 2.0])  # columns of any scale
    res = rng.normal(size=200)
    step, *_ = np.linalg.lstsq(jac, -res, rcond=None)
    exact = float(res @ res - (res + jac @ step) @ (res + jac @ step))
    assert np.isclose(predicted_decrease(jac, res), exact, rtol=1e-10)


class _Counted(HologramModel):
    n_jac = 0

    def jacobian(self, vector):
        self.n_jac += 1
        return super().jacobian(vector)


def _model_and_data():
    rng = np.random.default_rng(8)
    truth = (3.7, 3.7, 8.0)
    grid = DetectorGrid((70, 70), PX, (0, 0))
    holo = calc_hologram(MieWave(SPHERE, OPTICS), truth, grid, 0.9)
    crop = holo + rng.normal(0, NOISE, holo.shape)
    pix = select_pixels(crop, (0, 0), PX)
    start = State((3.74, 3.66, 8.15), None, 0.85, static_values(SPHERE))
    space = ParameterSpace(SPHERE, ("x_um", "y_um", "z_um", "alpha"), start)

    def model():
        return _Counted(LorenzMie(), space, OPTICS, pix.xs_um, pix.ys_um)

    return model, pix.data, space.initial_vector()


def test_a_fit_stopped_by_the_predicted_decrease_is_within_the_bar_of_the_minimum():
    make, data, start = _model_and_data()
    bar = 0.02 * NOISE**2
    ref_model = make()
    ref = solve_least_squares(ref_model, data, start, ftol=1e-12, xtol=1e-12)
    usual_model = make()
    solve_least_squares(usual_model, data, start, ftol=1e-6, xtol=1e-6)
    stop_model = make()
    stop = solve_least_squares(stop_model, data, start, ftol=1e-6, xtol=1e-6, stop_rss=bar)
    assert stop.converged and "Gauss-Newton" in stop.message
    assert ref.rss <= stop.rss <= ref.rss + bar
    assert stop_model.n_jac < usual_model.n_jac
    # the Jacobian reported (for the covariance) is the model's at the point reported
    assert np.allclose(stop.jacobian, make().jacobian(stop.vector), rtol=1e-12, atol=0)
    # the position is as good as the tight fit's, well inside its uncertainty (~nm)
    assert np.max(np.abs(stop.vector[:3] - ref.vector[:3])) < 2e-4
