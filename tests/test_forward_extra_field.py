"""Issue 22, item 3: the neighbour's scattered field added to the model field before the
intensity (holofit.holomodel.forward, ``extra_field``). The truth: two spheres' exact
Lorenz-Mie fields superposed at the camera."""

from __future__ import annotations

import numpy as np
import pytest

from holofit.conventions import hologram_intensity
from holofit.holomodel.forward import HologramModel
from holofit.holomodel.leastsq import solve_least_squares
from holofit.holomodel.parameters import ParameterSpace, State, static_values
from holofit.optics import Optics
from holofit.particles import Sphere
from holofit.scattering.mie import LorenzMie
from holofit.scattering.recorded_field import recorded_field

OPTICS = Optics(0.66, 1.33, 0.0)
A, B = Sphere(0.5, 1.59), Sphere(0.6, 1.59)
PA, PB = np.array([3.0, 3.0, 9.0]), np.array([5.0, 3.4, 10.0])  # 2 um apart: overlapping
ALPHA_A, ALPHA_B = 0.9, 0.8


@pytest.fixture(scope="module")
def pair():
    ys, xs = np.mgrid[0:60, 0:60] * 0.1
    xs, ys = xs.ravel(), ys.ravel()
    ea = recorded_field(LorenzMie().solve(A, OPTICS), PA, xs, ys)
    eb = recorded_field(LorenzMie().solve(B, OPTICS), PB, xs, ys)
    data = hologram_intensity(ALPHA_A * ea[0] + ALPHA_B * eb[0],
                              ALPHA_A * ea[1] + ALPHA_B * eb[1], OPTICS.polarization_rad)
    extra = (ALPHA_B * eb[0], ALPHA_B * eb[1])
    return xs, ys, data, extra


def _model(xs, ys, extra, start):
    state = State(tuple(start), None, 0.85, static_values(A))
    space = ParameterSpace(A, ("x_um", "y_um", "z_um", "alpha"), state)
    return space, HologramModel(LorenzMie(), space, OPTICS, xs, ys, extra_field=extra)


def test_the_model_with_the_neighbour_is_the_superposed_hologram(pair):
    xs, ys, data, extra = pair
    space, model = _model(xs, ys, extra, PA)
    vector = space.initial_vector()
    vector[-1] = ALPHA_A
    np.testing.assert_allclose(model.hologram(vector), data, rtol=1e-12, atol=1e-12)
    # the analytic alpha column against a central difference
    jac = model.jacobian(vector)
    h = 1e-6
    up, down = vector.copy(), vector.copy()
    up[-1] += h
    down[-1] -= h
    fd = (model.hologram(up) - model.hologram(down)) / (2 * h)
    np.testing.assert_allclose(jac[:, -1], fd, rtol=1e-6, atol=1e-8)
    # the restricted model keeps the neighbour's field on its pixels
    index = np.arange(0, xs.size, 7)
    np.testing.assert_allclose(model.restricted(index).hologram(vector), data[index],
                               rtol=1e-12, atol=1e-12)


def test_fitting_with_the_neighbour_recovers_the_particle(pair):
    xs, ys, data, extra = pair
    start = PA + np.array([0.05, -0.04, 0.3])
    found = {}
    for name, field in (("with", extra), ("without", None)):
        space, model = _model(xs, ys, field, start)
        sol = solve_least_squares(model, data, space.initial_vector(), ftol=1e-12, xtol=1e-12)
        found[name] = space.state(sol.vector).position
    assert np.abs(found["with"] - PA).max() < 1e-4  # exact model: the truth
    # without the neighbour the fit is pulled off by tens of nm or more
    assert np.abs(found["without"] - PA).max() > 10 * np.abs(found["with"] - PA).max()
