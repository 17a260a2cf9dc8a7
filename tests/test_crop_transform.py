"""The centre-finding numerics against independent references: brute-force sums, exact
paraboloids, patterns with a known centre."""

from __future__ import annotations

import numpy as np
import pytest

from holofit.crop.centerfind import CenterFinder, auto_downsample, find_centers
from holofit.crop.radial import refine_center_radial
from holofit.crop.symmetry import quadratic_peak, refine_center
from holofit.crop.transform import block_mean, gradient, orientation_alignment
from tests.test_crop_synthetic import ring_pattern


def _brute_force_oat(image: np.ndarray, radius: int) -> tuple[np.ndarray, np.ndarray]:
    """The transform by its definition: an explicit sum over vote offsets."""
    gx, gy = gradient(image.astype(np.float64))
    psi = (gx + 1j * gy) ** 2
    rows, cols = image.shape
    b = np.zeros(image.shape, complex)
    total = np.zeros(image.shape)
    weight = 0.0
    for dy in range(-radius, radius + 1):
        for dx in range(-radius, radius + 1):
            r = np.hypot(dx, dy)
            if r == 0 or r > radius:
                continue
            weight += 1 / r
            kernel = (dx - 1j * dy) ** 2 / r**3
            # B(c) += psi(c - d) K(d)
            shifted = np.zeros(image.shape, complex)
            rs = slice(max(dy, 0), rows + min(dy, 0))
            cs = slice(max(dx, 0), cols + min(dx, 0))
            rd = slice(max(-dy, 0), rows + min(-dy, 0))
            cd = slice(max(-dx, 0), cols + min(-dx, 0))
            shifted[rs, cs] = psi[rd, cd]
            b += shifted * kernel
            total += np.abs(shifted) / r
    return np.abs(b) / weight, np.abs(b) / np.maximum(total, 1e-300)


def test_transform_matches_brute_force_sum():
    rng = np.random.default_rng(0)
    image = rng.normal(1.0, 0.1, (23, 31)) + ring_pattern((23, 31), 14.2, 10.7, lz=40.0)
    strength, alignment = orientation_alignment(image, 6)
    ref_strength, ref_alignment = _brute_force_oat(image, 6)
    np.testing.assert_allclose(strength, ref_strength, rtol=2e-4, atol=1e-6 * ref_strength.max())
    np.testing.assert_allclose(alignment, ref_alignment, atol=2e-4)


def test_transform_peaks_at_ring_centre_and_alignment_separates_noise():
    image = ring_pattern((160, 200), 120.4, 70.8)
    strength, alignment = orientation_alignment(image, 50)
    i, j = np.unravel_index(np.argmax(strength), strength.shape)
    # at full resolution the peak has a shallow crater ~2 px across (see transform.py)
    assert np.hypot(j - 120.4, i - 70.8) <= 2.5
    assert alignment[i, j] > 0.9
    small = block_mean(image, 4)
    strength4, _ = orientation_alignment(small, 12)
    i, j = np.unravel_index(np.argmax(strength4), strength4.shape)
    assert np.hypot(4 * j + 1.5 - 120.4, 4 * i + 1.5 - 70.8) <= 2.0
    noise = np.random.default_rng(1).normal(1.0, 0.05, (160, 200))
    _, noise_alignment = orientation_alignment(noise, 50)
    assert np.median(noise_alignment) < 0.1


def test_block_mean_and_gradient():
    image = np.arange(6 * 9, dtype=float).reshape(6, 9)
    small = block_mean(image, 3)
    assert small.shape == (2, 3)
    assert small[1, 2] == pytest.approx(image[3:6, 6:9].mean())
    # linear ramp: exact central differences, zero on the border
    ramp = 2.0 * np.arange(8)[None, :] + 0.5 * np.arange(5)[:, None]
    gx, gy = gradient(ramp.astype(np.float32))
    assert np.allclose(gx[:, 1:-1], 2.0) and np.allclose(gy[1:-1, :], 0.5)
    assert np.all(gx[:, [0, -1]] == 0) and np.all(gy[[0, -1], :] == 0)


def test_quadratic_peak_finds_exact_vertex():
    i, j = np.mgrid[0:7, 0:7].astype(float)
    vi, vj = 3.31, 2.77
    values = 5 - 0.8 * (i - vi) ** 2 - 0.3 * (j - vj) ** 2 + 0.2 * (i - vi) * (j - vj)
    di, dj = quadratic_peak(values, 3, 3)
    assert 3 + di == pytest.approx(vi, abs=1e-12)
    assert 3 + dj == pytest.approx(vj, abs=1e-12)
    assert quadratic_peak(-values, 3, 3) == (0.0, 0.0)  # a minimum is no peak


@pytest.mark.parametrize("x0,y0", [(80.0, 75.0), (80.37, 74.81), (79.5, 75.5)])
def test_symmetry_refinement_recovers_known_centre(x0, y0):
    image = ring_pattern((150, 170), x0, y0)
    fit = refine_center(image, x0 + 2.6, y0 - 1.9, half_width=60, search_px=5)
    assert fit.converged
    assert fit.symmetry > 0.98  # sampling on the pixel lattice breaks exact symmetry
    assert abs(fit.x_px - x0) < 0.03 and abs(fit.y_px - y0) < 0.03


def test_symmetry_refinement_unbiased_by_edges_and_masks():
    # centre 5 px from the left edge and a masked stripe through the pattern
    x0, y0 = 5.3, 70.6
    image = ring_pattern((150, 150), x0, y0)
    valid = np.ones(image.shape, bool)
    valid[40:48, :] = False
    image[~valid] = 50.0  # garbage that must be ignored
    fit = refine_center(image, 8.0, 69.0, valid=valid, half_width=60, search_px=5)
    assert fit.converged
    assert abs(fit.x_px - x0) < 0.05 and abs(fit.y_px - y0) < 0.05


def test_radial_refinement_at_the_edge():
    x0, y0 = 3.4, 80.7  # 3.4 px from the left edge
    image = ring_pattern((160, 160), x0, y0)
    fit = refine_center_radial(image, 5.0, 79.0, radius=60)
    assert fit.converged
    assert abs(fit.x_px - x0) < 0.1 and abs(fit.y_px - y0) < 0.1
    found = find_centers(image)
    assert found["refinement"].iat[0] == "radial"
    assert np.hypot(found["x_px"].iat[0] - x0, found["y_px"].iat[0] - y0) < 0.1
    # a pattern with its centre off the frame has no interior minimum
    assert not refine_center_radial(ring_pattern((160, 160), -30.0, 80.0), 2.0, 80.0).converged


def test_find_centers_on_known_pattern_and_auto_settings():
    shape = (300, 360)
    image = ring_pattern(shape, 211.3, 140.7) + ring_pattern(shape, 60.2, 231.9, amplitude=0.2) - 1
    found = find_centers(image)
    assert len(found) == 2
    assert list(found.columns) == ["x_px", "y_px", "score", "alignment", "symmetry", "refinement",
                                   "zone_px", "reach_px"]
    assert found["score"].is_monotonic_decreasing
    assert np.hypot(found["x_px"].iat[0] - 211.3, found["y_px"].iat[0] - 140.7) < 0.05
    assert np.hypot(found["x_px"].iat[1] - 60.2, found["y_px"].iat[1] - 231.9) < 0.05
    assert auto_downsample(70, (1024, 1280)) == 4
    assert auto_downsample(70, (100, 100)) == 3
    assert auto_downsample(20, (1024, 1280)) == 1
    one = find_centers(image, max_centers=1)
    assert len(one) == 1
    coarse = find_centers(image, refine=False)
    assert (coarse["refinement"] == "none").all() and coarse["symmetry"].isna().all()
    assert np.hypot(coarse["x_px"].iat[0] - 211.3, coarse["y_px"].iat[0] - 140.7) < 4


def test_find_centers_handles_nan_and_empty_images():
    image = ring_pattern((200, 200), 100.2, 90.7)
    image[95:100, 60:140] = np.nan  # masked pixels through the hologram
    found = find_centers(image)
    assert np.hypot(found["x_px"].iat[0] - 100.2, found["y_px"].iat[0] - 90.7) < 0.1
    assert len(find_centers(np.ones((200, 200)))) == 0
    assert len(find_centers(np.full((200, 200), np.nan))) == 0
    with pytest.raises(ValueError, match="min_alignment"):
        CenterFinder(min_alignment=2)


def test_exact_median_is_numpys_median():
    """The bracketed selection gives np.median's value (and dtype) bit for bit: ties, sorted
    and periodic data (a strided sample that sees one phase), NaN, both parities."""
    from holofit.crop.transform import exact_median

    rng = np.random.default_rng(5)
    cases = [rng.normal(size=300_001).astype(np.float32),
             rng.integers(0, 4, 200_000).astype(np.float64),
             np.sort(rng.normal(size=100_000)),
             np.tile(rng.normal(size=64), 2_000),
             np.concatenate([np.zeros(50_000), rng.normal(size=50_001)]),
             rng.normal(size=1_000)]
    with_nan = rng.normal(size=80_000)
    with_nan[12_345] = np.nan
    for values in cases:
        got, want = exact_median(values), np.median(values)
        assert got == want and got.dtype == want.dtype
    assert np.isnan(exact_median(with_nan))


def test_block_mean_is_numpys_block_mean_bit_for_bit():
    """Every block size gives np.mean's float32 block means exactly (the whole-array adds
    follow its order of summation)."""
    rng = np.random.default_rng(6)
    for shape in ((97, 130), (64, 64)):
        image = (rng.uniform(0.1, 50.0) * (1 + 0.1 * rng.normal(size=shape))).astype(np.float32)
        for factor in range(2, 17):
            rows, cols = shape[0] // factor, shape[1] // factor
            view = image[: rows * factor, : cols * factor].reshape(rows, factor, cols, factor)
            want = view.mean(axis=(1, 3), dtype=np.float32)
            got = block_mean(image, factor)
            assert got.dtype == np.float32 and np.array_equal(got, want)


@pytest.mark.parametrize("ci, cj", [(20, 20), (3, 30), (36, 2), (0, 0)])
def test_symmetry_score_map_matches_direct_sums(ci, cj):
    """N, D and the pair weight W at the searched lattice points, against their defining sums
    over the window (module docstring of holofit.crop.symmetry): whole windows, windows cut
    by the frame's edges (a rectangle of valid pixels) and a masked one."""
    from holofit.crop.symmetry import _score_map

    rng = np.random.default_rng(7)
    image = 1 + 0.2 * rng.normal(size=(40, 45))
    hw, sigma, reach = 8, 3.2, 5
    masks = [None, rng.uniform(size=image.shape) > 0.1]
    for valid in masks:
        num, den, pairs, fraction = _score_map(image, valid, ci, cj, hw, sigma, reach)
        size = 2 * hw + 1
        f = np.zeros((size, size))
        m = np.zeros((size, size))
        for a in range(size):
            for b in range(size):
                i, j = ci - hw + a, cj - hw + b
                if 0 <= i < image.shape[0] and 0 <= j < image.shape[1] and (
                        valid is None or valid[i, j]):
                    f[a, b], m[a, b] = image[i, j], 1.0
        f = (f - np.median(f[m > 0])) * m
        g = np.exp(-0.5 * ((np.arange(size) - hw) / sigma) ** 2)
        w = g[:, None] * g[None, :]
        scale = float(np.sum(w * f * f)) * float(w.max())  # the size of every sum below
        for p in range(2 * reach + 1):
            for q in range(2 * reach + 1):
                s = (2 * hw - reach + p, 2 * hw - reach + q)  # lattice point s = 2 m
                n_sum = d_sum = w_sum = full = 0.0
                for a in range(max(0, s[0] - size + 1), min(size, s[0] + 1)):
                    for b in range(max(0, s[1] - size + 1), min(size, s[1] + 1)):
                        a2, b2 = s[0] - a, s[1] - b
                        pw = w[a, b] * w[a2, b2]
                        n_sum += pw * f[a, b] * f[a2, b2]
                        d_sum += pw * f[a, b] ** 2 * m[a2, b2]
                        w_sum += pw * m[a, b] * m[a2, b2]
                        full += pw
                assert abs(num[p, q] - n_sum) <= 1e-10 * scale
                assert abs(den[p, q] - d_sum) <= 1e-10 * scale
                assert abs(pairs[p, q] - w_sum) <= 1e-10 * full
                assert abs(fraction[p, q] - w_sum / full) <= 1e-10
