"""Filtered coupled dipoles against ADDA, and the smooth discretisation against exact Mie.

References: ADDA 1.5's output for case a with ``-pol fcd -int fcd`` (tests/data/adda/
a_sphere_fcd), exact Lorenz-Mie. The full accuracy study (materials x discretisations x
dipoles per wavelength) is ``bench/study_dda_discretisation.py``.
"""

import numpy as np
import pytest

from holofit.conventions import DetectorGrid, r_squared
from holofit.dda.adda.frames import adda_amplitude_matrix
from holofit.dda.dipoles import DipoleSystem
from holofit.dda.engine import BuiltinDDA
from holofit.dda.farfield import far_field
from holofit.dda.voxelize import voxelize
from holofit.hologram import calc_hologram
from holofit.optics import Optics
from holofit.particles import Sphere, VoxelShape
from holofit.scattering.mie import MieWave
from tests.conftest import DATA

OPTICS = Optics(0.66, 1.33, 0.0)


def test_filtered_coupled_dipoles_match_adda():
    d = 0.8959543581 / 26
    model = VoxelShape(str(DATA / "adda" / "a_sphere_r0.45" / "sphere.geom"), d,
                       (1.191729323,), (0.0, 0.0, 0.0))
    lat = voxelize(model, d)
    k = 2 * np.pi / 0.4962406015
    system = DipoleSystem(lat, k, 1.0, "fcd")
    sols = [system.solve([0, 0, 1.0], e, tol=1e-9) for e in ([1.0, 0, 0], [0, 1.0, 0])]
    # ADDA's CoupleConstant (log), um^3
    assert sols[0].alpha[0] == pytest.approx(1.209070559e-06 + 1.978226053e-09j, rel=1e-9)
    ref = np.loadtxt(DATA / "adda" / "a_sphere_fcd" / "ampl_scatgrid", skiprows=1)
    ref = ref[(ref[:, 0] > 0) | (ref[:, 1] == 0)]  # one basis per direction
    th, ph = np.radians(ref[:, 0]), np.radians(ref[:, 1])
    n = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], axis=1)
    f = [far_field(lat, s.P, k, n) for s in sols]
    s_mat = adda_amplitude_matrix(f[0], f[1], th, ph)
    s_ref = ref[:, 2::2] + 1j * ref[:, 3::2]
    assert np.max(np.abs(s_mat - s_ref)) < 1e-7 * np.max(np.abs(s_ref))


@pytest.mark.parametrize("radius,index", [(0.4, 1.59), (0.2, 1.2 + 2.0j)])
def test_smooth_default_beats_binary_voxels_against_mie(radius, index):
    """The default smooth discretisation is closer to exact Lorenz-Mie than ADDA-style binary
    voxels (LDR) at the same dipole-size rule: polystyrene, and the issue's absorbing sphere."""
    grid = DetectorGrid((60, 60), 0.12)
    pos = (3.6, 3.6, 8.0)
    exact = calc_hologram(MieWave(Sphere(radius, index), OPTICS), pos, grid)
    errors = {}
    for name, options in (("smooth", {}), ("binary", {"filling": "binary",
                                                       "polarizability": "ldr"})):
        wave = BuiltinDDA(tolerance=1e-7, **options).solve(Sphere(radius, index), OPTICS)
        errors[name] = 1.0 - r_squared(exact, calc_hologram(wave, pos, grid))
    assert errors["smooth"] < 0.8 * errors["binary"], errors
