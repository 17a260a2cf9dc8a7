"""Issue 24, item 14: the initial pass's default length follows the movie's (a 30-frame
movie's initial pass once fitted every frame with everything free: 259 s of its 5 min 48 s),
and the choice is said."""

from __future__ import annotations

import numpy as np
import pytest

from holofit.batch import BatchSettings
from holofit.batch import stage as skeleton
from holofit.config import load_instrument, load_particle, resolve_config
from holofit.crop import CropConfig, run_crop
from holofit.fit import stage
from holofit.fit.config import FitConfig
from holofit.fit.defaults import default_initial_frames
from holofit.prefit import run_prefit
from holofit.simulate.holograms import simulate_movie

SERIAL = BatchSettings(workers=0, progress=False)


@pytest.mark.parametrize(("n", "k"), [(1, 1), (5, 5), (8, 8), (30, 8), (150, 8), (161, 9),
                                      (2000, 100), (10000, 500), (50000, 500)])
def test_the_default_is_one_frame_in_twenty_between_8_and_500(n, k):
    assert default_initial_frames(n) == k


class _Stop(Exception):
    pass


def test_a_30_frame_movie_fits_8_frames_everything_free_and_says_so(tmp_path, monkeypatch):
    """A 30-frame sphere movie (Lorenz-Mie: cheap) through crop and prefit; the fit stage's
    batch is intercepted to see which frames the initial pass is given."""
    particle = load_particle(resolve_config("sphere_ps_1um", "particles"))
    inst = load_instrument(resolve_config("paper_100x_oil", "instruments"))
    rng = np.random.default_rng(0)
    pos = np.column_stack([5.0 + 0.05 * rng.normal(size=30), 5.0 + 0.05 * rng.normal(size=30),
                           np.full(30, 10.0)])
    sim = simulate_movie(particle.model, inst, pos, (72, 72), theory=particle.theory(), seed=1,
                         out_dir=tmp_path / "sim")
    run_crop(sim.movie, sim.background, inst, tmp_path / "crop", CropConfig(size=48, plot=False))
    run_prefit(tmp_path / "crop", tmp_path / "prefit", batch=SERIAL, plot=False)
    given: list[list[int]] = []

    def intercept(func, config, frames, *args, **kwargs):
        given.append([k[1] for k in frames])  # the (particle, frame) keys of track 0
        raise _Stop

    monkeypatch.setattr(skeleton, "run_batch", intercept)
    run = stage.FitRun()
    monkeypatch.setattr(stage, "FitRun", lambda: run)
    with pytest.raises(_Stop):
        stage.run_fit(
            tmp_path / "crop",
            tmp_path / "prefit",
            None,
            tmp_path / "fit",
            FitConfig(particle, passes="initial", plot=False),
            batch=SERIAL,
        )
    assert given == [list(range(8))]
    assert any("first 8 of the 30 frames" in n and "--initial-frames" in n for n in run.notes)
    given.clear()
    with pytest.raises(_Stop):
        stage.run_fit(
            tmp_path / "crop",
            tmp_path / "prefit",
            None,
            tmp_path / "fit",
            FitConfig(particle, passes="initial", initial_frames=12, plot=False),
            batch=SERIAL,
        )
    assert given == [list(range(12))]
