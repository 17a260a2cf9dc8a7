"""Smooth fractional filling: the residual of a fit is a smooth function of every size
parameter and of the orientation (no voxel switches on or off).

For each parameter, the residual sum of squares (RSS) between a fixed target hologram and the
model is sampled in steps of d/20 (sizes) or 0.05 degree (theta). A smooth RSS has third
differences far below its first differences (they scale as h^2); a voxel switching on or off
makes a jump, whose third difference is as large as the first (the binary voxelisation shows
it, so the test can fail). The solver runs at a tight tolerance to isolate the discretisation.
"""

import numpy as np
import pytest

from holofit.conventions import DetectorGrid
from holofit.dda.engine import BuiltinDDA
from holofit.hologram import calc_hologram
from holofit.optics import Optics
from holofit.particles import JanusSphere, Sphere, Spherocylinder
from holofit.scattering.theory import Orientation

OPTICS = Optics(0.66, 1.33, 0.0)
GRID = DetectorGrid((40, 40), 0.12)
POS = (2.4, 2.35, 6.0)
D = 0.05
TILT = Orientation(0.3, 1.0, 0.0)
CASES = {
    "sphere radius": (lambda v: Sphere(v, 1.5), 0.35, Orientation()),
    "rod a": (lambda v: Spherocylinder(v, 0.6, 1.45), 0.25, TILT),
    "rod b": (lambda v: Spherocylinder(0.25, v, 1.45), 0.6, TILT),
    "janus cap thickness": (lambda v: JanusSphere(0.3, v, 1.59, 2.4), 0.06, TILT),
}


def _rss_curve(make, p0, orientation, filling, n=21, step=D / 20):
    eng = BuiltinDDA(dipole_size_um=D, filling=filling, tolerance=1e-10)
    target = calc_hologram(eng.solve(make(p0 + 0.013), OPTICS, orientation), POS, GRID)
    return np.array([
        np.sum((calc_hologram(eng.solve(make(p0 + i * step), OPTICS, orientation), POS, GRID)
                - target) ** 2)
        for i in range(n)
    ])


def _jumpiness(f):
    return np.abs(np.diff(f, 3)).max() / np.abs(np.diff(f)).max()


@pytest.mark.parametrize("name", list(CASES))
def test_rss_smooth_in_size(name):
    make, p0, orientation = CASES[name]
    f = _rss_curve(make, p0, orientation, "fractional")
    assert _jumpiness(f) < 0.1
    d2 = np.abs(np.diff(f, 2))
    assert d2.max() < 4 * np.median(d2) + 1e-12 * f.max()  # bounded second differences


def test_binary_voxels_jump():
    """The same test on binary (centre-inside) voxels fails: they switch on and off."""
    make, p0, orientation = CASES["sphere radius"]
    assert _jumpiness(_rss_curve(make, p0, orientation, "binary")) > 0.5


def test_rss_smooth_in_theta():
    rod = Spherocylinder(0.25, 0.6, 1.45)
    eng = BuiltinDDA(dipole_size_um=D, tolerance=1e-10)
    target = calc_hologram(eng.solve(rod, OPTICS, Orientation(0.3, 1.02, 0.0)), POS, GRID)
    step = np.radians(0.05)
    f = np.array([
        np.sum((calc_hologram(eng.solve(rod, OPTICS, Orientation(0.3, 1.0 + i * step, 0.0)),
                              POS, GRID) - target) ** 2)
        for i in range(21)
    ])
    assert _jumpiness(f) < 0.01
    d2 = np.abs(np.diff(f, 2))
    assert d2.max() < 4 * np.median(d2)
