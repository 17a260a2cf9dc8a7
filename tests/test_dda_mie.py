"""The built-in DDA reproduces exact Lorenz-Mie holograms of a sphere, near field included.

The paper's test (its figure 4b): r = 0.45 um, n = 1.585, water, 660 nm, dipole size ~0.034
um, 140x140 pixels of 0.1 um, alpha = 1; ADDA's far-field-only holograms degrade below ~5 um.
"""

import numpy as np
import pytest

from holofit.conventions import DetectorGrid, r_squared
from holofit.dda.engine import BuiltinDDA
from holofit.hologram import calc_hologram
from holofit.optics import Optics
from holofit.particles import Sphere
from holofit.scattering.mie import LorenzMie

OPTICS = Optics(0.66, 1.33, 0.0)
SPHERE = Sphere(0.45, 1.585)
GRID = DetectorGrid((140, 140), 0.1)


@pytest.fixture(scope="module")
def waves():
    dda = BuiltinDDA(dipole_size_um=0.0345).solve(SPHERE, OPTICS)
    return dda, LorenzMie().solve(SPHERE, OPTICS)


@pytest.mark.parametrize("z", [2.0, 5.0, 10.0, 20.0])
def test_dda_hologram_matches_mie(waves, z):
    dda, mie = waves
    pos = (7.03, 6.98, z)
    exact = calc_hologram(mie, pos, GRID)
    assert r_squared(exact, calc_hologram(dda, pos, GRID)) >= 0.999


def test_far_field_only_degrades_near_focus(waves):
    """The asymptotic field (ADDA's) misses the near-field terms: worse at small z."""
    dda, mie = waves
    r2 = {}
    for z in (2.0, 5.0, 20.0):
        pos = (7.0, 7.0, z)
        far = calc_hologram(dda, pos, GRID, far_field=True)
        r2[z] = r_squared(calc_hologram(mie, pos, GRID), far)
    assert r2[2.0] < 0.95 < r2[20.0]
    assert r2[2.0] < r2[5.0] < r2[20.0]


def test_far_field_mode_matches_mie_far_field(waves):
    dda, mie = waves
    pos = (7.0, 7.0, 3.0)
    a = calc_hologram(mie, pos, GRID, far_field=True)
    b = calc_hologram(dda, pos, GRID, far_field=True)
    assert r_squared(a, b) >= 0.999


def test_cross_section_close_to_mie(waves):
    dda, _ = waves
    k = OPTICS.k
    # optical theorem on the DDA far field: C_ext = 4 pi / k^2 Re(e* . F(forward)) ...
    f = dda.far_field_amplitude(np.array([[0.0, 0.0, -1.0]]))[0]
    cext = 4 * np.pi / k**2 * np.real(np.dot(OPTICS.polarization, f))
    from holofit.scattering.mie import cross_sections

    mie = cross_sections(1.585 / 1.33, 0.45, k).extinction_um2
    assert cext == pytest.approx(mie, rel=5e-3)
