"""The built-in DDA of a dimer converges to the exact superposition T-matrix as the dipoles
shrink (the full ladder is bench/study_dimer_dda_convergence.py: camera-field error 2.0e-3,
9.2e-4, 5.4e-4 and hologram 1 - R^2 4.0e-6, 1.6e-6, 5.4e-7 at 10, 14 and 20 dipoles per
wavelength)."""

from __future__ import annotations

import numpy as np

from holofit.conventions import DetectorGrid
from holofit.dda.engine import BuiltinDDA
from holofit.hologram import calc_hologram
from holofit.optics import Optics
from holofit.particles import Dimer
from holofit.scattering.cluster import ClusterEngine
from holofit.scattering.theory import Orientation

OPTICS = Optics(0.66, 1.33, 0.0)
GRID = DetectorGrid((140, 140), 0.1)
POS = (7.0, 7.0, 12.0)
MODEL = Dimer(0.35, 0.35, 0.0, 1.59, 1.59)
ORIENTATION = Orientation(0.4, 1.0, 0.3)


def test_dda_dimer_converges_to_the_cluster_engine() -> None:
    exact = ClusterEngine().solve(MODEL, OPTICS, ORIENTATION)
    e_ref = np.stack(exact.field_on_detector(POS, GRID))
    h_ref = calc_hologram(exact, POS, GRID)
    errors, misfit, sizes = [], [], []
    for dpl in (10, 14, 20):
        engine = BuiltinDDA(dipoles_per_wavelength=dpl, tolerance=1e-8)
        wave = engine.solve_direct(MODEL, OPTICS, ORIENTATION)
        e = np.stack(wave.field_on_detector(POS, GRID))
        errors.append(float(np.abs(e - e_ref).max() / np.abs(e_ref).max()))
        h = calc_hologram(wave, POS, GRID)
        misfit.append(float(np.sum((h - h_ref) ** 2) / np.sum((h_ref - h_ref.mean()) ** 2)))
        sizes.append(engine.settings.dipole_size_for(MODEL, OPTICS))
    assert errors[0] > errors[1] > errors[2]
    # about first order in d: the plane-cut filling (holofit.dda.voxelize) gives order 0.96
    # on these spheres between 10 and 20 dipoles per wavelength (the C2 ramp gave > 1)
    assert errors[2] / errors[0] < (sizes[2] / sizes[0]) ** 0.9
    assert errors[2] < 1e-3
    assert misfit[0] < 1e-5  # the default rule on this hologram
    assert misfit[2] < misfit[0] * (sizes[2] / sizes[0]) ** 1.8  # the square of the above
