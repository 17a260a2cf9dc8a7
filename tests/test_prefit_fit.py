"""Fit of one crop from the automatic start, on synthetic holograms with known truth."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from holofit.camera import Camera
from holofit.config import load_instrument
from holofit.conventions import DetectorGrid
from holofit.hologram import calc_hologram
from holofit.particles import Sphere
from holofit.prefit.estimate import estimate_starts, profile_table
from holofit.prefit.profile import radial_profile
from holofit.prefit.sphere import SphereFitSettings, fit_sphere_crop
from holofit.scattering.mie import MieWave
from tests.conftest import CONFIGS

INST = load_instrument(CONFIGS / "instruments" / "paper_100x_oil.toml")
# the ideal model the sphere fit uses (the objective lens enters the fits later: issue 16)
OPTICS = replace(INST.optics, numerical_aperture=None)
PX = INST.pixel_size_um
N = 100
CORNER = (210, 330)
TRUTH = {"x_um": 380.3 * PX, "y_um": 259.6 * PX, "z_um": 12.0, "radius_um": 0.65,
         "n": 1.52, "alpha": 0.9}  # fmt: skip
# the crop stage's centre: 0.7 px off the truth
CENTRE = ((380.3 + 0.5) * PX, (259.6 - 0.5) * PX)


def _hologram(truth=TRUTH):
    wave = MieWave(Sphere(truth["radius_um"], truth["n"]), OPTICS)
    pos = (truth["x_um"], truth["y_um"], truth["z_um"])
    return calc_hologram(wave, pos, DetectorGrid((N, N), PX, CORNER), truth["alpha"])


def _noisy(seed, truth=TRUTH):
    cam = Camera(background_counts=120.0)
    return cam.expose(_hologram(truth), np.random.default_rng(seed)) / 120.0


def _fit(data, **kw):
    return fit_sphere_crop(data, CORNER, CENTRE, OPTICS, PX, SphereFitSettings(**kw))


def _errors(fit, truth=TRUTH):
    return {k: fit.values[k] - truth[k] for k in truth}


def test_noise_free_hologram_is_recovered_exactly_from_the_automatic_start():
    fit = _fit(_hologram())
    assert fit.status == "ok", fit.message
    for key, err in _errors(fit).items():
        assert abs(err) < 1e-6, (key, err)
    assert fit.r2 > 1 - 1e-12 and fit.n_pixels == N * N and fit.extra["n_masked"] == 0
    # the automatic start was close already
    assert abs(fit.extra["start_z_um"] - TRUTH["z_um"]) < 0.3
    assert abs(fit.extra["start_radius_um"] - TRUTH["radius_um"]) < 0.05


def test_uncertainties_match_the_scatter_over_noise_realisations():
    fits = [_fit(_noisy(seed)) for seed in range(12)]
    assert all(f.status == "ok" for f in fits)
    for key in ("x_um", "z_um", "radius_um", "n"):
        values = np.array([f.values[key] for f in fits])
        sigma = np.mean([f.errors[key] for f in fits])
        scatter = values.std(ddof=1)
        # 12 samples: the sample std is within a factor 0.55-1.45 of the truth at ~98 %
        assert 0.5 < scatter / sigma < 1.6, (key, scatter, sigma)
        assert abs(values.mean() - TRUTH[key]) < 4 * sigma, key
    # chi^2 per degree of freedom ~1: the noise estimate and the model are right
    assert 0.85 < np.mean([f.chi2_red for f in fits]) < 1.2


def test_nan_and_saturated_pixels_are_left_out():
    data = _noisy(3)
    ref = _fit(data)
    spoiled = data.copy()
    spoiled[40:60, 40:60] = np.nan  # masked by the crop stage
    spoiled[:10, :10] = 7.0  # saturated by some other means
    fit = _fit(spoiled, saturation=5.0)
    assert fit.extra["n_masked"] == 400 + 100 and fit.n_pixels == N * N - 500
    for key in ("x_um", "y_um", "z_um"):
        assert abs(fit.values[key] - ref.values[key]) < 5 * fit.errors[key], key
    assert abs(fit.values["n"] - TRUTH["n"]) < 0.003


def test_random_pixel_subset_is_reproducible_and_accurate():
    data = _noisy(4)
    a = _fit(data, pixel_fraction=0.3)
    b = _fit(data, pixel_fraction=0.3)
    assert a.n_pixels == round(0.3 * N * N) and a.values == b.values
    for key, err in _errors(a).items():
        assert abs(err) < 5 * a.errors[key], key


def test_alpha_can_be_held_fixed():
    truth = dict(TRUTH, alpha=1.0)
    fit = _fit(_hologram(truth), fix_alpha=1.0)
    assert fit.values["alpha"] == 1.0 and np.isnan(fit.errors["alpha"])
    assert abs(fit.values["z_um"] - truth["z_um"]) < 1e-6


def test_several_starts_are_screened_and_the_best_wins():
    data = _noisy(5)
    fit = _fit(data, ambiguity_ratio=1e12, max_starts=3)
    assert fit.extra["n_starts"] >= 2  # distinct minima of the profile misfit, all fitted
    assert abs(fit.values["z_um"] - TRUTH["z_um"]) < 0.02
    assert abs(fit.values["radius_um"] - TRUTH["radius_um"]) < 0.005


def test_profile_estimate_is_close_for_a_range_of_spheres():
    rng = np.random.default_rng(6)
    n_bins = N // 2 - 1
    search = SphereFitSettings().search.for_crop(n_bins * PX, INST.optics.wavelength_medium_um)
    table = profile_table(INST.optics, PX, n_bins, search)
    for _ in range(6):
        truth = dict(TRUTH, z_um=rng.uniform(5, 30), radius_um=rng.uniform(0.4, 1.0),
                     index=rng.uniform(1.42, 1.62), alpha=1.0)  # fmt: skip
        data = _noisy(int(rng.integers(1000)), truth)
        centre_rc = (CENTRE[1] / PX - CORNER[0], CENTRE[0] / PX - CORNER[1])
        starts = estimate_starts(table, radial_profile(data, np.isfinite(data), centre_rc, n_bins))
        best = starts[0]
        assert abs(best.z_um - truth["z_um"]) < 0.05 * truth["z_um"], (best, truth)
        assert abs(best.radius_um - truth["radius_um"]) < 0.1, (best, truth)


def test_too_few_pixels_is_an_error():
    data = np.full((N, N), np.nan)
    data[:5, :5] = 1.0
    with pytest.raises(ValueError, match="usable pixels"):
        _fit(data)


def test_seed_only_places_a_rod_at_a_spheres_cost_with_honest_flags():
    # a rod's hologram (T-matrix, through a 1.2 NA objective) seeded as a sphere: x, y, z and
    # alpha in a few dozen evaluations; a crop without a particle is not an ok seed
    from holofit.prefit.estimate import SearchSpace
    from holofit.scattering.theory import Orientation
    from tests.tracking_helpers import INSTRUMENT, ROD, engine

    theory = engine()
    px = INSTRUMENT.pixel_size_um
    grid = DetectorGrid((80, 80), px, (10, 20))
    truth = ((20 + 39.7) * px, (10 + 40.2) * px, 7.0)
    wave = theory.solve(ROD, INSTRUMENT.optics, Orientation(0.4, 1.1))
    rng = np.random.default_rng(0)
    cam = Camera(background_counts=120.0)
    crop = cam.expose(calc_hologram(wave, truth, grid, 0.9), rng) / 120.0
    opts = SphereFitSettings(seed_only=True, search=SearchSpace(z_range_um=(3.0, 15.0)))
    centre = (truth[0] + 0.3 * px, truth[1] - 0.4 * px)
    res = fit_sphere_crop(crop, grid.corner, centre, INSTRUMENT.optics, px, opts)
    assert res.status == "ok", res.message
    assert abs(res.values["x_um"] - truth[0]) < 0.05 and abs(res.values["y_um"] - truth[1]) < 0.05
    assert abs(res.values["z_um"] - truth[2]) < 0.6
    assert res.n_eval <= 30
    full = fit_sphere_crop(crop, grid.corner, centre, INSTRUMENT.optics, px,
                           SphereFitSettings(search=opts.search))
    assert full.n_eval > 2 * res.n_eval
    flat = cam.expose(np.ones((80, 80)), rng) / 120.0  # no particle at all
    try:
        empty = fit_sphere_crop(flat, grid.corner, centre, INSTRUMENT.optics, px, opts)
    except ValueError:
        return  # no start found: reported as such
    assert empty.status != "ok"
