"""The fit's Jacobian through the lens for T-matrix waves (holofit.holomodel.forward): the
orientation columns and the exact height column come from one pass over the Bessel table
(holofit.scattering.lens.lens_fields_on_pixels); they equal central differences of the
model's own holograms."""

from __future__ import annotations

import numpy as np
import pytest

from holofit.conventions import euler_zyz
from holofit.holomodel.forward import HologramModel
from holofit.holomodel.parameters import ParameterSpace, State, static_values
from holofit.optics import Optics
from holofit.particles import Dimer
from holofit.scattering.cluster import ClusterEngine

OPTICS = Optics(0.66, 1.33, 0.0, numerical_aperture=1.3)


@pytest.mark.parametrize("free", [["x_um", "z_um", "orientation", "alpha"],
                                  ["x_um", "y_um", "z_um", "alpha"]],
                         ids=["with orientation", "position only"])
def test_lens_jacobian_columns_are_the_derivatives_of_the_hologram(free):
    model = Dimer(0.3, 0.35, 0.0, 1.59, 1.5)
    x, y = np.meshgrid(np.linspace(0.0, 6.0, 25), np.linspace(0.2, 6.2, 23))
    start = State(position=(3.05, 3.1, 8.0), rotation=euler_zyz(0.7, 1.1, 0.0), alpha=0.9,
                  statics=static_values(model))
    space = ParameterSpace(model, free, start)
    fm = HologramModel(ClusterEngine(), space, OPTICS, x.ravel(), y.ravel())
    v0 = space.initial_vector()
    jac = fm.jacobian(v0)
    # five-point central differences of the model's holograms (single-precision images:
    # a step of 1e-2 keeps their rounding near 1e-5 of a column)
    h = 1e-2
    checked = []
    for i, name in enumerate(space.names):
        if name not in ("z_um", "rot_a", "rot_b"):
            continue
        holo = {}
        for s in (-2, -1, 1, 2):
            v = v0.copy()
            v[i] += s * h
            holo[s] = fm.hologram(v)
        fd = (holo[-2] - 8 * holo[-1] + 8 * holo[1] - holo[2]) / (12 * h)
        assert np.abs(jac[:, i] - fd).max() <= 1e-4 * np.abs(fd).max(), name
        checked.append(name)
    assert "z_um" in checked
