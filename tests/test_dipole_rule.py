"""The dipole-size rule for layered particles (holofit.dda.voxelize.dipole_size,
DDASettings.layer_dipoles): d <= t / k for the thinnest layer t, measured against exact
coated-sphere Lorenz-Mie."""

from __future__ import annotations

import numpy as np
import pytest

from holofit.config import ConfigError
from holofit.conventions import DetectorGrid
from holofit.dda.engine import BuiltinDDA
from holofit.dda.settings import DDASettings
from holofit.dda.voxelize import dipole_size, thinnest_layer_um
from holofit.hologram import calc_hologram
from holofit.optics import Optics
from holofit.particles import CoatedSphere, JanusSphere, Sphere
from holofit.scattering.coated_mie import CoatedMie

OPTICS = Optics(0.66, 1.33, 0.0)
LAM = 0.66 / 1.33


def test_layer_rule_caps_the_dipole_at_a_fraction_of_the_thinnest_layer():
    coated = CoatedSphere(0.443, 0.047, 1.581, 2.74)
    janus = JanusSphere(0.439, 0.05, 1.59, 2.7)
    assert thinnest_layer_um(coated) == 0.047 and thinnest_layer_um(janus) == 0.05
    assert thinnest_layer_um(Sphere(0.5, 1.59)) is None
    wave_rule = dipole_size(coated, LAM, 1.33)
    assert wave_rule == pytest.approx(0.66 / (10 * 2.74))  # the default: TiO2 decides
    assert dipole_size(coated, LAM, 1.33, layer_dipoles=4) == pytest.approx(0.047 / 4)
    assert dipole_size(janus, LAM, 1.33, layer_dipoles=4) == pytest.approx(0.05 / 4)
    # a thick layer leaves the wavelength rule in charge; spheres have no layer
    assert dipole_size(coated, LAM, 1.33, layer_dipoles=1) == pytest.approx(wave_rule)
    assert dipole_size(Sphere(0.5, 2.74), LAM, 1.33, layer_dipoles=4) == pytest.approx(
        wave_rule)


def test_layer_rule_in_the_dda_table():
    s = DDASettings.from_dict({"layer_dipoles": 4.0})
    assert s.layer_dipoles == 4.0
    assert s.dipole_size_for(CoatedSphere(0.3, 0.04, 1.58, 2.74), OPTICS) == pytest.approx(0.01)
    assert DDASettings.from_dict({}).layer_dipoles is None
    with pytest.raises(ConfigError, match="layer_dipoles"):
        DDASettings.from_dict({"layer_dipoles": 0.5}, "p.toml")


def test_layer_rule_brings_a_thin_tio2_shell_closer_to_exact_mie():
    """A 30 nm TiO2 shell (a dipole and a quarter thick at the default rule): the hologram
    error against exact coated-sphere Mie falls several-fold at 4 dipoles across the shell."""
    model = CoatedSphere(0.12, 0.03, 1.581, 2.74)
    grid = DetectorGrid((48, 48), 0.1)
    pos = (2.4, 2.4, 4.0)
    exact = calc_hologram(CoatedMie().solve(model, OPTICS), pos, grid)

    def one_minus_r2(settings: DDASettings) -> float:
        d = settings.dipole_size_for(model, OPTICS)
        holo = calc_hologram(BuiltinDDA(settings.replace(dipole_size_um=d)).solve(
            model, OPTICS), pos, grid)
        return float(np.sum((holo - exact) ** 2) / np.sum((exact - exact.mean()) ** 2))

    default = one_minus_r2(DDASettings())
    layered = one_minus_r2(DDASettings(layer_dipoles=4.0))
    assert layered < default / 3, (default, layered)
