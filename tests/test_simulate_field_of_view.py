"""Multi-particle movies (holofit.simulate.field_of_view): fields superposed at the camera."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from holofit.camera import Camera
from holofit.config import load_instrument, resolve_config
from holofit.conventions import DetectorGrid
from holofit.hologram import calc_hologram
from holofit.particles import Sphere
from holofit.scattering.lens import lens_field_on_detector
from holofit.scattering.mie import LorenzMie
from holofit.simulate.field_of_view import ParticleInView, simulate_field_of_view
from holofit.simulate.holograms import Exposure, SimulationError, simulate_movie

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
    one = simulate_movie(
        sphere, inst, pos, SHAPE, alpha=0.9, keep_frames=True, exposure=Exposure(noise=False)
    )
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
        inst,
        SHAPE,
        camera=camera,
        noise=False,
        keep_frames=True,
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
        (0, 0),
        (0, 1),
        (0, 2),
        (1, 0),
        (1, 1),
        (1, 2),
    ]
    assert truth.loc[3, "x_px"] == pytest.approx(-5.0 / inst.pixel_size_um)
    assert out.movie is not None and out.movie.exists()
    assert (tmp_path / "fov" / "background.tif").exists()


def test_bad_particles_are_named(inst):
    with pytest.raises(SimulationError, match="no particles"):
        simulate_field_of_view([], inst, SHAPE)
    with pytest.raises(SimulationError, match="particle 1 has 1 positions"):
        simulate_field_of_view(
            [
                ParticleInView(Sphere(0.5, 1.59), [(2, 2, 8)] * 2),
                ParticleInView(Sphere(0.5, 1.59), [(2, 2, 8)]),
            ],
            inst,
            SHAPE,
        )
    with pytest.raises(SimulationError, match="particle 0: frame 1"):
        simulate_field_of_view(
            [ParticleInView(Sphere(0.5, 1.59), [(2, 2, 8), (2, 2, np.nan)])], inst, SHAPE
        )


def _scene(tmp_path, body: str):
    path = tmp_path / "scene.toml"
    path.write_text(body)
    return path


SCENE = """
instrument = "paper_60x_water"
frames = 6
shape = [64, 96]
seed = 3

[[particle]]
config = "sphere_ps_1um"
start_um = [3.0, 3.5, 12.0]

[[particle]]
config = "sphere_ps_1um"
start_um = [8.0, 3.5, 12.0]
drift_um_s = [400.0, 0.0, 0.0]
"""


def test_scene_file_makes_a_field_of_view(tmp_path) -> None:
    from click.testing import CliRunner

    from holofit.analysis.hydrodynamics import sphere_diffusion
    from holofit.cli import main
    from holofit.simulate.scene import load_scene

    scene = load_scene(_scene(tmp_path, SCENE))
    assert len(scene.particles) == 2 and scene.frame_shape == (64, 96)
    # the second particle drifts 4 um per frame (100 frames/s): it leaves the 9.6 um wide field
    x1 = np.asarray(scene.particles[1].positions_um)[:, 0]
    assert x1[-1] - x1[0] == pytest.approx(5 * 4.0, abs=0.5)
    # a sphere's D comes from Stokes-Einstein: the steps of the first particle scale with it
    steps = np.diff(np.asarray(scene.particles[0].positions_um)[:, :2], axis=0)
    d = sphere_diffusion(0.5, 21.0)["D_t"]
    assert np.mean(steps**2) < 20 * 2 * d * 0.01
    out = tmp_path / "movie"
    res = CliRunner().invoke(
        main, ["simulate", "field-of-view", str(tmp_path / "scene.toml"), "-o", str(out)]
    )
    assert res.exit_code == 0, res.output
    truth = pd.read_csv(out / "truth.csv")
    assert len(truth) == 12 and set(truth["particle"]) == {0, 1}


@pytest.mark.parametrize(
    "body, message",
    [
        (SCENE.replace("start_um = [3.0", "strat_um = [3.0"), "particle 0.*strat_um"),
        (SCENE.split("[[particle]]")[0], "no \\[\\[particle\\]\\] tables"),
        (
            SCENE.replace('"sphere_ps_1um"\nstart_um = [8.0', '"rod_paper"\nstart_um = [8.0'),
            "particle 1.*needs d_par_um2_s",
        ),
    ],
)
def test_scene_errors_name_the_particle_and_key(tmp_path, body, message) -> None:
    from holofit.config_schema import ConfigError
    from holofit.simulate.scene import load_scene

    with pytest.raises(ConfigError, match=message):
        load_scene(_scene(tmp_path, body))
