"""Orientation by rotating the incident wave and the observation directions into the particle
frame gives the same hologram as voxelising the rotated particle directly (a test-only path)."""

import numpy as np
import pytest

from holofit.conventions import PROPAGATION_DIRECTION, DetectorGrid, euler_zyz, r_squared
from holofit.dda.dipoles import DipoleSystem
from holofit.dda.engine import BuiltinDDA, DDAWave
from holofit.dda.lattice import Lattice
from holofit.dda.settings import DDASettings
from holofit.dda.voxelize import _interface_normals, _shape_fractions
from holofit.hologram import calc_hologram
from holofit.optics import Optics
from holofit.particles import JanusSphere, Spherocylinder
from holofit.scattering.theory import Orientation

OPTICS = Optics(0.66, 1.33, np.radians(10))
GRID = DetectorGrid((100, 100), 0.1)
POS = (5.0, 5.0, 8.0)


def _lattice_of_rotated(model, rot, d, extent):
    """Voxelise the rotated particle on a lab-aligned lattice (what the engine never does)."""
    j = np.arange(-int(np.ceil(extent / d)) - 2, int(np.ceil(extent / d)) + 2)
    jj = np.stack(np.meshgrid(j, j, j, indexing="ij"), -1).reshape(-1, 3)
    lab = (jj + 0.5) * d
    frac = _shape_fractions(model, lab @ rot, d, binary=False)  # particle-frame coordinates
    keep = frac.sum(axis=1) > 0
    jj, frac, lab = jj[keep], frac[keep], lab[keep]
    normals = _interface_normals(model, lab @ rot, frac, d) @ rot.T  # lab-frame normals
    j0 = jj.min(axis=0)
    ijk = jj - j0
    order = np.lexsort((ijk[:, 2], ijk[:, 1], ijk[:, 0]))
    indices = tuple(complex(getattr(model, f)) for f in model.index_fields)
    return Lattice(d, tuple(int(v) for v in ijk.max(axis=0) + 1), (j0 + 0.5) * d,
                   ijk[order], frac[order], indices, normals[order])


@pytest.mark.parametrize("model,extent", [
    (Spherocylinder(0.35, 0.8, 1.495), 0.8),
    (JanusSphere(0.35, 0.06, 1.59, 2.4), 0.41),
])
@pytest.mark.parametrize("psi,theta", [(30.0, 60.0), (-70.0, 125.0)])
def test_rotated_wave_equals_rotated_voxels(model, extent, psi, theta):
    d = 0.04
    ori = Orientation(np.radians(psi), np.radians(theta), 0.0)
    engine_wave = BuiltinDDA(dipole_size_um=d, tolerance=1e-8).solve(model, OPTICS, ori)
    rot = euler_zyz(*ori.as_tuple())
    lat = _lattice_of_rotated(model, rot, d, extent)
    system = DipoleSystem(lat, OPTICS.k, OPTICS.n_medium, DDASettings().polarizability)
    sol = system.solve(PROPAGATION_DIRECTION, OPTICS.polarization, tol=1e-8)
    direct_wave = DDAWave(model, OPTICS, Orientation(), sol, np.eye(3))
    a = calc_hologram(engine_wave, POS, GRID)
    b = calc_hologram(direct_wave, POS, GRID)
    assert r_squared(a, b) >= 0.999
