"""Synthetic sphere movies (simulate -> crop -> prefit), automatic start, known truth.

Issue target: rms errors x, y <= 5 nm, z <= 20 nm, a <= 5 nm, n <= 0.003 for a = 0.5-1 um,
n = 1.45-1.6, z = 5-30 um, 8-bit camera noise, with the paper's 60x water set-up and 140x140
crops. The finder's centre is the truth moved by up to 0.5 px in x and y. The default suite runs
a small movie through the process pool; the slow test runs 40 frames.

Far from focus: set-ups with a long working distance (the Grier lab's, whose instrument the
pylorenzmie data come from) put particles 50-85 um from focus; the prefit's default z search
(no ``--z-range``) reaches them when the crop is large enough to show their fringes.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from holofit.batch import BatchSettings
from holofit.config import load_instrument
from holofit.particles import Sphere
from holofit.prefit.stage import run_prefit
from holofit.simulate.holograms import simulate_movie
from tests.conftest import CONFIGS
from tests.prefit_helpers import make_crops_from_movies

INST = load_instrument(CONFIGS / "instruments" / "paper_60x_water.toml")
LIMITS = {"x_um": 0.005, "y_um": 0.005, "z_um": 0.020, "radius_um": 0.005, "n": 0.003}


def _prefit_movies(tmp_path, inst, spheres, positions, centres, frame_shape, crop_size, seed,
                   workers):
    """Simulate one movie per sphere (``positions[k]``: its frames' (x, y, z), um), crop them
    into one folder around the finder's ``centres`` (column, row, px; one per frame, all movies
    in turn), prefit with the stage's defaults; the prefit table and the truth, row for row."""
    movies, truths = [], []
    for k, ((a, n), pos) in enumerate(zip(spheres, positions, strict=True)):
        sim = simulate_movie(
            Sphere(a, n), inst, pos, frame_shape, seed=seed + k, out_dir=tmp_path / f"sim{k}"
        )
        movies.append((sim.movie, sim.background))
        truths.append(sim.truth.assign(radius_um=a, n=n))
    crops = make_crops_from_movies(movies, centres, crop_size, inst, tmp_path / "crops")
    res = run_prefit(
        crops, tmp_path / "prefit", batch=BatchSettings(workers=workers, progress=False), plot=False
    )
    return pd.read_csv(res.table), pd.concat(truths, ignore_index=True)


def _finder_centres(pos, px, rng):
    """The crop stage's centres: the truth moved by up to 0.5 px in x and y."""
    return [(x / px + rng.uniform(-0.5, 0.5), y / px + rng.uniform(-0.5, 0.5))
            for x, y, _ in pos]  # fmt: skip


def _movie_errors(tmp_path, particles, frames_each, seed, workers):
    """Spheres 5-30 um from focus through the paper's 60x set-up, 140 x 140 crops; the errors
    of every frame."""
    px = INST.pixel_size_um
    rng = np.random.default_rng(seed)
    positions, centres = [], []
    for _ in particles:
        z = rng.uniform(5, 30, frames_each)
        xy = (100 + rng.uniform(-10, 10, (frames_each, 2))) * px
        positions.append(np.column_stack([xy, z]))
        centres += _finder_centres(positions[-1], px, rng)
    table, truth = _prefit_movies(tmp_path, INST, particles, positions, centres, (200, 200), 140,
                                  seed, workers)
    assert (table["status"] == "ok").all(), table["message"].tolist()
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


#: the Grier lab's instrument (447 nm, 0.048 um/px, water, NA 0.86) and a silica-like sphere
FAR_INST = load_instrument(CONFIGS / "instruments" / "pylorenzmie.toml")
FAR_SPHERE = (0.75, 1.45)
FAR_Z_UM = (55.0, 70.0, 85.0)
FAR_KEYS = ("x_um", "y_um", "z_um", "radius_um", "n", "alpha")


def _far_movie(tmp_path, crop_size, frame_size, seed=30):
    """One sphere at 55, 70 and 85 um from focus (one frame each), prefit with the defaults."""
    px = FAR_INST.pixel_size_um
    rng = np.random.default_rng(seed)
    xy = (frame_size / 2 + rng.uniform(-3, 3, (len(FAR_Z_UM), 2))) * px
    pos = np.column_stack([xy, FAR_Z_UM])
    centres = _finder_centres(pos, px, rng)
    table, truth = _prefit_movies(tmp_path, FAR_INST, [FAR_SPHERE], [pos], centres,
                                  (frame_size, frame_size), crop_size, seed, workers=0)
    return table, truth.assign(alpha=1.0)


def test_particles_far_from_focus_are_found_by_the_default_search(tmp_path):
    # 301 x 301 crops (as pylorenzmie's own fits of these data): rho_max 7.2 um, so the default
    # search reaches rho_max^2 / lambda_medium = 153 um. Tolerance 4 sigma of the reported
    # errors: over 12 noise realisations at z = 70 um they match the scatter (ratio 0.9-1.15;
    # sigma_z 6, 11, 17 nm at 55, 70, 85 um), and 4 sigma on 18 numbers fails by chance with
    # probability ~1e-3 (the seeds are fixed)
    table, truth = _far_movie(tmp_path, 301, 320)
    assert (table["status"] == "ok").all(), table["message"].tolist()
    # the automatic start found the height (the fit did not have to travel there)
    assert np.all(np.abs(table["start_z_um"] / truth["z_um"] - 1) < 0.02), table["start_z_um"]
    for key in FAR_KEYS:
        err = table[key] - truth[key]
        assert np.all(np.abs(err) < 4 * table[f"d_{key}"]), (key, err.tolist())
    assert np.all(table["d_z_um"] < 0.03)


def test_a_crop_too_small_for_the_height_is_not_a_silent_ok(tmp_path):
    # 101 px: rho_max 2.4 um, the first Fresnel zone is 4.3-5.3 um at 55-85 um; such fits
    # converge near the top of the default search (50 um) with chi2_red ~1
    table, truth = _far_movie(tmp_path, 101, 120)
    flagged = table[table["status"] != "ok"]
    assert len(flagged) > 0 and flagged["message"].str.contains("Fresnel zone").all()
    for k in range(len(table)):
        row = table.iloc[k]
        if row["status"] != "ok":
            continue  # flagged: the user is told
        for key in FAR_KEYS:
            assert abs(row[key] - truth[key][k]) < 4 * row[f"d_{key}"], (k, key, row[key])
