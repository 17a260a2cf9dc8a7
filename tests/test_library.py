"""The orientation library: polar sampling, the psi-by-polarisation identity (checked against
direct solves at every tested psi), grids by symmetry, and candidate picking."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from holofit.conventions import DetectorGrid, hologram_intensity
from holofit.dda.engine import BuiltinDDA
from holofit.hologram import calc_hologram
from holofit.library.polar import polar_grid, sample_crop
from holofit.library.search import OrientationLibrary, Tilt, pick_candidates, tilt_grid
from holofit.optics import Optics
from holofit.particles import Ellipsoid, JanusSphere, Spherocylinder
from holofit.scattering.theory import Orientation

OPTICS = Optics(0.66, 1.33, 0.3)  # polarised 17 deg from x: the identity must handle it
PX = 0.1
GRID = DetectorGrid((90, 90), PX, (10, 20))
POS = (20 * PX + 4.5, 10 * PX + 4.5, 8.0)
ROD = Spherocylinder(0.3, 0.7, 1.5)


@pytest.fixture(scope="module")
def engine():
    # CM polarisability does not depend on the incident wave: the identity is then exact
    return BuiltinDDA(dipole_size_um=0.09, polarizability="cm")


def test_bilinear_samples_of_a_plane_are_exact_and_nan_pixels_get_no_weight():
    rows, cols = np.mgrid[0:40, 0:50]
    crop = 1.0 + 0.01 * rows - 0.02 * cols
    grid = polar_grid(((20 + 25.3) * PX, (10 + 19.7) * PX), 15 * PX, PX, 32)
    values, weights = sample_crop(crop, (10, 20), PX, grid)
    r = grid.ys_um / PX - 10
    c = grid.xs_um / PX - 20
    np.testing.assert_allclose(values, 1.0 + 0.01 * r - 0.02 * c, atol=1e-12)
    np.testing.assert_allclose(weights.sum(), np.pi * (15 * PX) ** 2, rtol=1e-12)
    crop[30, 25] = np.nan
    _, w = sample_crop(crop, (10, 20), PX, grid)
    assert 0 < (w == 0).sum() <= 4 * 4  # only samples touching the NaN pixel


def test_tilt_grids_follow_the_particle_symmetry():
    rod = tilt_grid(ROD, math.radians(10))
    assert [round(math.degrees(t.theta)) for t in rod] == list(range(0, 91, 10))
    janus = tilt_grid(JanusSphere(0.4, 0.05, 1.58, 2.7), math.radians(10))
    assert math.isclose(janus[-1].theta, math.pi) and len(janus) == 19
    ell = tilt_grid(Ellipsoid(0.3, 0.4, 0.6, 1.5), math.radians(30))
    assert len({t.phi for t in ell}) == 12 and len({t.theta for t in ell}) == 4


def _direct_r2(engine, data, weights, grid, psi, theta):
    wave = engine.solve(ROD, OPTICS, Orientation(psi, theta))
    ex, ey = wave.field_on_pixels(POS, grid.xs_um.ravel(), grid.ys_um.ravel())
    model = hologram_intensity(ex, ey, OPTICS.polarization_rad, 0.9).reshape(grid.shape)
    mean = (weights * data).sum() / weights.sum()
    return 1 - (weights * (data - model) ** 2).sum() / (weights * (data - mean) ** 2).sum()


def test_every_psi_from_two_solves_equals_a_direct_solve(engine):
    truth = Orientation(1.1, 0.7)
    holo = calc_hologram(engine.solve(ROD, OPTICS, truth), POS, GRID, 0.9)
    grid = polar_grid(POS[:2], 4.2, PX, 64)
    data, weights = sample_crop(holo, GRID.corner, PX, grid)
    lib = OrientationLibrary(engine, ROD, OPTICS, [Tilt(0.5), Tilt(0.7)])
    scores = lib.scores(grid, data, weights, POS, 0.9)
    for j in (0, 9, 31, 50):
        direct = _direct_r2(engine, data, weights, grid, grid.phi[j], 0.7)
        assert scores[1, j] == pytest.approx(direct, abs=1e-6)
    # the best psi at the true tilt is the grid point next to the truth
    assert abs(grid.phi[np.argmax(scores[1])] - 1.1) <= np.pi / 64 + 1e-9
    assert scores[1].max() > 0.999 > scores[0].max()


def test_candidates_are_distinct_local_maxima_best_first(engine):
    truth = Orientation(2.0, 0.8)
    holo = calc_hologram(engine.solve(ROD, OPTICS, truth), POS, GRID, 0.9)
    grid = polar_grid(POS[:2], 4.2, PX, 64)
    data, weights = sample_crop(holo, GRID.corner, PX, grid)
    tilts = tilt_grid(ROD, math.radians(15))
    lib = OrientationLibrary(engine, ROD, OPTICS, tilts)
    scores = lib.scores(grid, data, weights, POS, 0.9)
    cands = pick_candidates(scores, tilts, grid.phi, ROD, 3, math.radians(20))
    assert cands[0].r2 == pytest.approx(scores.max())
    assert all(a.r2 >= b.r2 for a, b in itertools.pairwise(cands))
    best = cands[0]
    assert abs(best.theta - 0.8) <= math.radians(7.5) + 1e-9
    assert abs((best.psi - 2.0 + np.pi) % (2 * np.pi) - np.pi) <= np.pi / 64 + 1e-9
    u = [np.array([math.sin(c.theta) * math.cos(c.psi), math.sin(c.theta) * math.sin(c.psi),
                   math.cos(c.theta)]) for c in cands]
    for i in range(len(u)):
        for k in range(i):
            assert math.degrees(math.acos(min(1.0, abs(float(u[i] @ u[k]))))) >= 20 - 1e-9


def test_fields_are_reused_for_frames_at_nearly_the_same_height(engine):
    lib = OrientationLibrary(engine, ROD, OPTICS, [Tilt(0.7)], z_step_um=0.05)
    exact = OrientationLibrary(engine, ROD, OPTICS, [Tilt(0.7)], z_step_um=None)
    grid = polar_grid(POS[:2], 4.2, PX, 64)
    holo = calc_hologram(engine.solve(ROD, OPTICS, Orientation(1.1, 0.7)), POS, GRID, 0.9)
    data, weights = sample_crop(holo, GRID.corner, PX, grid)
    first = lib.scores(grid, data, weights, POS, 0.9)
    cached = len(lib._fields)
    near = (POS[0], POS[1], POS[2] + 0.02)  # rounds to the same height
    again = lib.scores(grid, data, weights, near, 0.9)
    assert len(lib._fields) == cached
    np.testing.assert_array_equal(first, again)
    # the rounding moves R^2 by little, and not which psi ranks first
    own = exact.scores(grid, data, weights, near, 0.9)
    assert np.abs(own - again).max() < 0.02
    assert np.argmax(own[0]) == np.argmax(again[0])


def test_frames_run_by_height_one_run_per_worker():
    """The library's work order (holofit.library.stage.by_height) is a permutation of the
    frames: rounded heights ascending along each worker's run, frame order within a height,
    frames without a prefit height last, the runs taking turns."""
    import pandas as pd

    from holofit.library.stage import by_height

    class Crops:  # a crop folder of one track: keys are (particle, frame)
        def key(self, frame):
            return (0, frame)

    rng = np.random.default_rng(3)
    frames = list(range(40))
    z = 10 + np.cumsum(rng.normal(0, 0.08, len(frames)))
    z[[5, 17]] = np.nan
    prefit = pd.DataFrame({"z_um": z},
                          index=pd.MultiIndex.from_tuples([(0, f) for f in frames]))
    step = 0.05
    one = by_height(frames, Crops(), prefit, step)
    assert sorted(one) == frames and one[-2:] == [5, 17]
    bins = [round(z[f] / step) for f in one[:-2]]
    assert bins == sorted(bins)
    assert all(a < b for a, b, c, d in zip(one, one[1:], bins, bins[1:], strict=False) if c == d)
    two = by_height(frames, Crops(), prefit, step, lanes=2)
    assert sorted(two) == frames
    assert two[0::2] == one[:20] and two[1::2] == one[20:]
