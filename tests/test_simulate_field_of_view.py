"""Multi-particle movies (holofit.simulate.field_of_view): fields superposed at the camera."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from holofit.camera import Camera
from holofit.config import load_instrument, resolve_config
from holofit.conventions import DetectorGrid
from holofit.hologram import calc_hologram
from holofit.models import Sphere
from holofit.scattering.lens import lens_field_on_detector
from holofit.scattering.mie import LorenzMie
from holofit.simulate.field_of_view import ParticleInView, simulate_field_of_view
from holofit.simulate.holograms import SimulationError, simulate_movie

SHAPE = (64, 96)


@pytest.fixture(scope="module")
def inst():
    return load_instrument(resolve_config("paper_100x_oil", "instruments"))


def _exact(inst, sphere, position, alpha=1.0):
    wave = LorenzMie().solve(sphere, inst.optics)
    return calc_hologram(wave, position, DetectorGrid(SHAPE, inst.pixel_size_um), alpha)


def test_one_particle_is_the_single_particle_movie(inst):
    sphere = Sphere(0.5, 1.59)
    pos = [(3.0, 2.5, 8.0), (3.3, 2.4, 9.0)]
    fov = simulate_field_of_view(
        [ParticleInView(sphere, pos, alpha=0.9)], inst, SHAPE, noise=False, keep_frames=True
    )
    one = simulate_movie(sphere, inst, pos, SHAPE, alpha=0.9, noise=False, keep_frames=True)
    for a, b in zip(fov.frames, one.frames, strict=True):
        # the same hologram through the pixel-list and the detector-grid paths, quantised
        assert np.abs(a.astype(int) - b.astype(int)).max() <= 1
        assert np.mean(a != b) < 1e-3


def test_two_particles_interfere_as_fields(inst):
    """I = |e + a1 E1 + a2 E2|^2 = I1 + I2 - 1 + 2 a1 a2 Re(E1 . E2*): the cross term is there.

    Through the instrument's objective (NA 1.4) the fields are the lens images.
    Each single hologram comes from the exact Lorenz-Mie solution through ``calc_hologram``
    (the path the fits use); the pair's frame must equal their fields' sum, not the sum of
    their intensities.
    """
    a, b = Sphere(0.5, 1.59), Sphere(0.4, 1.45)
    pa, pb = (4.0, 3.0, 7.0), (6.5, 4.5, 9.0)  # close: the holograms overlap
    camera = Camera(bit_depth=16, background_counts=20000.0, read_noise_counts=0.0)
    fov = simulate_field_of_view(
        [ParticleInView(a, [pa], alpha=0.8), ParticleInView(b, [pb], alpha=1.1)],
        inst, SHAPE, camera=camera, noise=False, keep_frames=True,
    )
    measured = fov.frames[0] / camera.background_counts
    ia, ib = _exact(inst, a, pa, 0.8), _exact(inst, b, pb, 1.1)
    # the cross term from the two polarisation-resolved fields
    grid = DetectorGrid(SHAPE, inst.pixel_size_um)
    ea = lens_field_on_detector(LorenzMie().solve(a, inst.optics), pa, grid)
    eb = lens_field_on_detector(LorenzMie().solve(b, inst.optics), pb, grid)
    cross = 2 * 0.8 * 1.1 * np.real(ea[0] * np.conj(eb[0]) + ea[1] * np.conj(eb[1]))
    quantum = 1 / camera.background_counts
    assert np.abs(measured - (ia + ib - 1 + cross)).max() <= quantum
    assert np.abs(cross).max() > 100 * quantum  # a real effect, far above quantisation
    assert np.abs(measured - (ia + ib - 1)).max() > 50 * quantum


def test_truth_is_keyed_by_particle_and_frame(inst, tmp_path):
    parts = [
        ParticleInView(Sphere(0.5, 1.59), [(2.0, 2.0, 8.0)] * 3),
        ParticleInView(Sphere(0.4, 1.45), [(-5.0, 2.0, 8.0), (1.0, 3.0, 8), (5.0, 3.0, 8)]),
    ]
    out = simulate_field_of_view(parts, inst, SHAPE, out_dir=tmp_path / "fov")
    truth = pd.read_csv(tmp_path / "fov" / "truth.csv")
    assert list(truth[["particle", "frame"]].itertuples(index=False, name=None)) == [
        (0, 0), (0, 1), (0, 2), (1, 0), (1, 1), (1, 2)
    ]
    assert truth.loc[3, "x_px"] == pytest.approx(-5.0 / inst.pixel_size_um)
    assert out.movie is not None and out.movie.exists()
    assert (tmp_path / "fov" / "background.tif").exists()


def test_bad_particles_are_named(inst):
    with pytest.raises(SimulationError, match="no particles"):
        simulate_field_of_view([], inst, SHAPE)
    with pytest.raises(SimulationError, match="particle 1 has 1 positions"):
        simulate_field_of_view(
            [ParticleInView(Sphere(0.5, 1.59), [(2, 2, 8)] * 2),
             ParticleInView(Sphere(0.5, 1.59), [(2, 2, 8)])],
            inst, SHAPE,
        )
    with pytest.raises(SimulationError, match="particle 0: frame 1"):
        simulate_field_of_view(
            [ParticleInView(Sphere(0.5, 1.59), [(2, 2, 8), (2, 2, np.nan)])], inst, SHAPE
        )
