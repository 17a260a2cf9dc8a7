"""Synthetic sphere movies (simulate -> crop -> prefit), automatic start, known truth.

Issue target: rms errors x, y <= 5 nm, z <= 20 nm, a <= 5 nm, n <= 0.003 for a = 0.5-1 um,
n = 1.45-1.6, z = 5-30 um, 8-bit camera noise, with the paper's 60x water set-up and 140x140
crops. The finder's centre is the truth moved by up to 0.5 px in x and y. The default suite runs
a small movie through the process pool; the slow test runs 40 frames.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from holofit.batch import BatchOptions
from holofit.config import load_instrument
from holofit.models import Sphere
from holofit.prefit.stage import run_prefit
from holofit.simulate.holograms import simulate_movie
from tests.conftest import CONFIGS
from tests.prefit_helpers import make_crops_from_movies

INST = load_instrument(CONFIGS / "instruments" / "paper_60x_water.toml")
LIMITS = {"x_um": 0.005, "y_um": 0.005, "z_um": 0.020, "radius_um": 0.005, "n": 0.003}


def _movie_errors(tmp_path, particles, frames_each, seed, workers):
    """Simulate one movie per particle, crop them into one folder, prefit; errors per frame."""
    px = INST.pixel_size_um
    rng = np.random.default_rng(seed)
    movies, centres, truths = [], [], []
    for k, (a, n) in enumerate(particles):
        z = rng.uniform(5, 30, frames_each)
        xy = (100 + rng.uniform(-10, 10, (frames_each, 2))) * px
        pos = np.column_stack([xy, z])
        sim = simulate_movie(
            Sphere(a, n), INST, pos, (200, 200), seed=seed + k, out_dir=tmp_path / f"sim{k}"
        )
        movies.append((sim.movie, sim.background))
        centres += [(x / px + rng.uniform(-0.5, 0.5), y / px + rng.uniform(-0.5, 0.5))
                    for x, y, _ in pos]  # fmt: skip
        truths.append(sim.truth.assign(radius_um=a, n=n))
    crops = make_crops_from_movies(movies, centres, 140, INST, tmp_path / "crops")
    res = run_prefit(
        crops, tmp_path / "prefit", batch=BatchOptions(workers=workers, progress=False), plot=False
    )
    table = pd.read_csv(res.table)
    assert (table["status"] == "ok").all(), table["message"].tolist()
    truth = pd.concat(truths, ignore_index=True)
    return table[list(LIMITS)] - truth[list(LIMITS)]


def _check(errors):
    rms = np.sqrt((errors**2).mean())
    for key, limit in LIMITS.items():
        assert rms[key] <= limit, (key, rms[key], limit)
    return rms


def test_small_synthetic_movie_in_the_process_pool(tmp_path):
    errors = _movie_errors(tmp_path, [(0.55, 1.47), (0.95, 1.58)], 3, seed=10, workers=2)
    _check(errors)


@pytest.mark.slow
def test_synthetic_movies_forty_frames(tmp_path):
    particles = [(0.5, 1.45), (0.65, 1.6), (0.8, 1.5), (1.0, 1.55)]
    errors = _movie_errors(tmp_path, particles, 10, seed=20, workers=2)
    assert len(errors) == 40
    _check(errors)
