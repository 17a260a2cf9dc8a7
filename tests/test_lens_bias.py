"""The bias the objective lens removes, as users meet it: the prefit of a lens hologram with the
ideal model (bench/lens_bias.py has the whole study).

The case: the paper's 60x water-immersion set-up (NA 1.20, 0.1767 um pixels), a 0.95 um
polystyrene sphere 5 um above the focus, a 100 x 100 crop (it reaches 56 degrees, past the
aperture angle of 64.5 degrees only in its corners), noise-free. Truths: the simulation's
parameters, and a direct least-squares fit of the ideal model to the same pixels
(``scipy.optimize.least_squares`` on the Lorenz-Mie field, started from the truth: no automatic
start, no forward-model class), which must find the same biased minimum.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares

from holofit.conventions import DetectorGrid, hologram_intensity
from holofit.hologram import calc_hologram
from holofit.optics import Optics
from holofit.particles import Sphere
from holofit.prefit.sphere import SphereFitSettings, fit_sphere_crop
from holofit.scattering.mie import MieWave

PX = 0.1767
LENS = Optics(0.66, 1.33, 0.0, 1.2)
IDEAL = Optics(0.66, 1.33, 0.0)
TRUTH = np.array([0.0, 0.0, 5.0, 0.475, 1.59, 0.9])  # x, y filled in below


def _crop():
    corner = (300, 200)
    grid = DetectorGrid((100, 100), PX, corner)
    truth = TRUTH.copy()
    truth[0] = (corner[1] + 49.5 + 0.31) * PX
    truth[1] = (corner[0] + 49.5 - 0.22) * PX
    holo = calc_hologram(MieWave(Sphere(truth[3], truth[4]), LENS), truth[:3], grid, truth[5])
    return holo, corner, grid, truth


@pytest.mark.slow
def test_ideal_prefit_of_a_lens_hologram_has_the_direct_fits_bias():
    holo, corner, grid, truth = _crop()
    centre = (truth[0] - 0.4 * PX, truth[1] + 0.3 * PX)
    opts = SphereFitSettings(noise_sd=0.02)
    ideal = fit_sphere_crop(holo, corner, centre, IDEAL, PX, opts)
    lens = fit_sphere_crop(holo, corner, centre, LENS, PX, opts)
    names = ("x_um", "y_um", "z_um", "radius_um", "n", "alpha")
    got = np.array([ideal.values[k] for k in names])
    # the lens model recovers the truth
    np.testing.assert_allclose([lens.values[k] for k in names], truth, atol=2e-5)

    x, y = (c.ravel() for c in grid.coordinates())

    def residuals(p):
        ex, ey = MieWave(Sphere(p[3], p[4]), IDEAL).field_on_pixels(p[:3], x, y)
        return hologram_intensity(ex, ey, 0.0, p[5]) - holo.ravel()

    direct = least_squares(residuals, truth, x_scale=[0.01, 0.01, 0.01, 1e-3, 1e-3, 1e-3],
                           diff_step=1e-7, xtol=1e-12, ftol=1e-12, gtol=1e-12, method="lm").x
    assert np.all(np.abs(got - direct) <= [2e-4, 2e-4, 2e-4, 1e-5, 2e-5, 1e-4]), got - direct
    # the pinned numbers (README, "The objective lens"): the index 3.1e-3 low, the radius
    # 3.5 nm large, alpha 0.01 low, z within 2 nm, i.e. 3.7, 3.9 and 0.9 noise-limited
    # standard errors at pixel noise 0.02
    bias = got - truth
    assert bias[4] == pytest.approx(-3.1e-3, abs=0.2e-3)
    assert bias[3] == pytest.approx(3.5e-3, abs=0.3e-3)
    assert bias[5] == pytest.approx(-0.010, abs=0.002)
    assert abs(bias[2]) < 4e-3
    assert ideal.r2 < lens.r2 and ideal.r2 == pytest.approx(0.9951, abs=5e-4)
