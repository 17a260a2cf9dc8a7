"""Validation studies of the DDA fit against exact solutions (slow: `make test-all`).

The paper's own validation (section 4.1): DDA fits of holograms of a 0.95 um-radius polystyrene
sphere 15-18 um from focus, position free, radius and index fixed. Its DDA (ADDA's far field)
put z 194 nm off the Lorenz-Mie fit's. Here the holograms are exact Lorenz-Mie (near field
included) with camera noise, fitted once with Lorenz-Mie and once with the built-in DDA (exact
near field, smooth voxels): the z offset against the truth and the displacements against the
Mie fit's measure the DDA model's error in a fit.
"""

from __future__ import annotations

import numpy as np
import pytest

from holofit.camera import Camera
from holofit.conventions import DetectorGrid
from holofit.dda.engine import BuiltinDDA
from holofit.hologram import calc_hologram
from holofit.holomodel.forward import HologramModel
from holofit.holomodel.leastsq import solve_least_squares
from holofit.holomodel.parameters import ParameterSpace, State, static_values
from holofit.holomodel.pixels import select_pixels
from holofit.optics import Optics
from holofit.particles import Sphere
from holofit.scattering.mie import LorenzMie, MieWave

pytestmark = pytest.mark.slow

OPTICS = Optics(0.66, 1.33, 0.0)
SPHERE = Sphere(0.95, 1.585)
PX = 0.106
SIZE = 140


def _fit(theory, crop, corner, start):
    pix = select_pixels(crop, corner, PX)
    state = State(tuple(start), None, 0.85, static_values(SPHERE))
    space = ParameterSpace(SPHERE, ("x_um", "y_um", "z_um", "alpha"), state)
    model = HologramModel(theory, space, OPTICS, pix.xs_um, pix.ys_um)
    sol = solve_least_squares(model, pix.data, space.initial_vector(), ftol=1e-10, xtol=1e-10)
    assert sol.converged, sol.message
    return space.state(sol.vector).position


def test_dda_fit_of_exact_sphere_holograms_matches_lorenz_mie():
    rng = np.random.default_rng(5)
    cam = Camera(background_counts=120.0)
    mie_wave = MieWave(SPHERE, OPTICS)
    dda = BuiltinDDA()
    n = 12
    truth = np.column_stack([7.4 + np.cumsum(rng.normal(0, 0.05, n)),
                             7.4 + np.cumsum(rng.normal(0, 0.05, n)),
                             np.linspace(15.0, 18.0, n)])
    fits = {"mie": [], "dda": []}
    for k in range(n):
        corner = (0, 0)
        holo = calc_hologram(mie_wave, truth[k], DetectorGrid((SIZE, SIZE), PX, corner), 0.9)
        crop = cam.expose(holo, rng) / 120.0
        start = truth[k] + np.array([0.02, -0.02, 0.2])
        fits["mie"].append(_fit(LorenzMie(), crop, corner, start))
        fits["dda"].append(_fit(dda, crop, corner, start))
    mie, ddaf = np.array(fits["mie"]), np.array(fits["dda"])
    z_offset_dda = 1e3 * np.mean(ddaf[:, 2] - truth[:, 2])
    z_offset_mie = 1e3 * np.mean(mie[:, 2] - truth[:, 2])
    disp_mie = np.linalg.norm(mie - mie[0], axis=1)
    disp_dda = np.linalg.norm(ddaf - ddaf[0], axis=1)
    disp_diff = 1e3 * np.abs(disp_dda - disp_mie)
    xy_diff = 1e3 * np.abs(ddaf[:, :2] - mie[:, :2])
    print(f"\nz offset vs truth: DDA {z_offset_dda:.1f} nm, Mie {z_offset_mie:.1f} nm; "
          f"|DDA - Mie| in x, y: max {xy_diff.max():.2f} nm; displacement difference: "
          f"median {np.median(disp_diff):.2f} nm, max {disp_diff.max():.2f} nm")
    assert abs(z_offset_dda) <= 20.0  # the paper's DDA: 194 nm
    assert np.median(disp_diff) <= 0.5 and disp_diff.max() <= 2.0  # the paper's numbers
