"""The Bessel tables of the lens transform: single-precision order-major tables, built once per
pupil rule for every order a source can need (holofit.scattering.lens_transform)."""

from __future__ import annotations

import numpy as np
from scipy import special

from holofit.scattering import lens_transform as lt
from holofit.scattering.lens_kernels import bessel_planes


def test_bessel_planes_match_scipy_in_double_and_single_precision():
    x = np.concatenate([np.linspace(0, 2, 50), np.linspace(2, 400, 500), [29.5, 30.0, 31.0]])
    m = 30
    ref = special.jv(np.arange(m + 1)[:, None], x[None, :])
    out = np.empty((m + 1, x.size))
    bessel_planes(x, special.j0(x), special.j1(x), m, out)
    assert np.abs(out - ref).max() < 1e-13
    single = np.empty((m + 1, x.size), dtype=np.float32)
    bessel_planes(x, special.j0(x), special.j1(x), m, single)
    # computed in double precision, rounded once: within half an ulp of float32
    assert np.abs(single - ref).max() < 6e-8


def test_table_rows_are_the_bessel_values_at_every_order():
    x_step = np.linspace(0.02, 0.5, 37)
    table = lt._bessel_rows(x_step, range(3, 300), 12)
    assert table.dtype == lt.TABLE_DTYPE and table.shape == (13, 297, 37)
    arg = np.arange(3, 300)[:, None] * x_step[None, :]
    ref = special.jv(np.arange(13)[:, None, None], arg[None])
    assert np.abs(table - ref).max() < 1e-7


def test_tables_and_products_hold_no_subnormal_numbers():
    """High orders near the axis (``J_40(x)`` at ``x`` < 1 is below 1e-38) would be subnormal in
    single precision, which runs the matrix product several times slower: they are zero, and
    every other entry is the Bessel value; the radial transform equals the double-precision
    sum of the exact values to single precision."""
    x_step = np.linspace(0.005, 0.5, 64)
    table = lt._bessel_rows(x_step, range(0, 120), 40)
    tiny = np.finfo(np.float32).tiny
    assert not np.any((table != 0) & (np.abs(table) < tiny))
    arg = np.arange(120)[:, None] * x_step[None, :]
    ref = special.jv(np.arange(41)[:, None, None], arg[None])
    assert np.abs(table - ref).max() < 1e-7
    assert np.all(table[np.abs(ref) >= 1e-14] != 0)
    rng = np.random.default_rng(4)
    h = (rng.normal(size=(41, 64, 3)) + 1j * rng.normal(size=(41, 64, 3))) * np.logspace(
        0, -45, 41)[:, None, None]  # high orders tiny, as a pupil field's are
    lt.clear_cache()
    got = lt.radial_transform(x_step, h.astype(np.complex64), 120, 40, ("subnormal test",))
    want = np.einsum("orn,onc->orc", ref, h)
    assert np.abs(got - want).max() < 1e-6 * np.abs(want).max()


def test_a_table_is_built_once_for_every_order_of_its_source(monkeypatch):
    """Waves of one source whose trimmed orders differ share one table (before: one rebuild
    per new highest order, ~0.3 s each for a 200 x 200 crop)."""
    lt.clear_cache()
    builds = []
    real = lt._bessel_rows

    def counting(x_step, rows, orders):
        builds.append((rows.stop, orders))
        return real(x_step, rows, orders)

    monkeypatch.setattr(lt, "_bessel_rows", counting)
    rng = np.random.default_rng(0)
    x_step = np.linspace(0.01, 0.5, 40)
    key = ("test-table", 40)
    results = {}
    for orders in (4, 9, 7, 12):
        h = rng.normal(size=(orders + 1, 40, 3)) + 1j * rng.normal(size=(orders + 1, 40, 3))
        got = lt.radial_transform(x_step, h, 200, orders, key, max_orders=12)
        results[orders] = (h, got)
    assert len(builds) == 1 and builds[0][1] == 12
    # and the products are those of the exact Bessel values, to single precision
    h, got = results[9]
    arg = np.arange(200)[:, None] * x_step[None, :]
    ref = np.einsum("oji,oic->ojc", special.jv(np.arange(10)[:, None, None], arg[None]), h)
    assert np.abs(got - ref).max() < 1e-6 * np.abs(h).sum(axis=1).max()
    lt.clear_cache()


def test_tables_too_big_for_the_cache_are_computed_in_row_blocks(monkeypatch):
    rng = np.random.default_rng(1)
    x_step = np.linspace(0.01, 0.5, 30)
    for orders in (None, 6):
        n = 2 if orders is None else orders + 1
        h = rng.normal(size=(n, 30, 2)) + 1j * rng.normal(size=(n, 30, 2))
        lt.clear_cache()
        cached = lt.radial_transform(x_step, h, 150, orders, ("blocks", orders))
        monkeypatch.setattr(lt, "BESSEL_CACHE_BYTES", 1000)
        monkeypatch.setattr(lt, "BLOCK_BYTES", 2000)
        blocks = lt.radial_transform(x_step, h, 150, orders, ("blocks", orders))
        monkeypatch.undo()
        assert blocks.dtype == cached.dtype and blocks.shape == cached.shape == (n, 150, 2)
        np.testing.assert_allclose(blocks, cached, rtol=0, atol=1e-12)
    lt.clear_cache()


def test_far_field_legendre_tables_are_computed_once_per_pupil_rule(monkeypatch):
    """Waves imaged through the same pupil nodes share the Legendre tables (before: one
    recurrence per wave, ~8 ms of a 200 x 200 lens image)."""
    from holofit.scattering import legendre, lens_pupil
    from holofit.scattering.multipole import MultipoleExpansion

    calls = []
    real = legendre.legendre_tables

    def counting(x, order):
        calls.append(order)
        return real(x, order)

    theta = np.linspace(0.05, 1.2, 23)
    rng = np.random.default_rng(2)
    order = 6
    lens_pupil._FAR_TABLES.clear()
    fresh = []
    for _ in range(3):
        shape = (order + 1, 2 * order + 1)
        p = rng.normal(size=shape) + 1j * rng.normal(size=shape)
        q = rng.normal(size=shape) + 1j * rng.normal(size=shape)
        exp = MultipoleExpansion(10.0, p, q, 0.5)
        lens_pupil._FAR_TABLES.clear()
        fresh.append(lens_pupil.expansion_far_modes(exp, theta))  # tables built for it
        fresh[-1] = (fresh[-1], exp)
    lens_pupil._FAR_TABLES.clear()
    monkeypatch.setattr(legendre, "legendre_tables", counting)
    for (ref_t, ref_p), exp in fresh:
        got_t, got_p = lens_pupil.expansion_far_modes(exp, theta)
        np.testing.assert_array_equal(got_t, ref_t)
        np.testing.assert_array_equal(got_p, ref_p)
    assert calls == [order]
    lens_pupil._FAR_TABLES.clear()


def test_derivative_waves_imaged_in_one_pass_are_the_derivatives_of_the_image():
    """``lens_fields_on_pixels`` of a T-matrix wave's Euler-angle derivatives (one table pass)
    equals the central difference of the lens images of the rotated particle, and the
    derivatives imaged one by one."""
    from holofit.optics import Optics
    from holofit.particles import Dimer
    from holofit.scattering.cluster import ClusterEngine
    from holofit.scattering.lens import lens_field_on_pixels, lens_fields_on_pixels
    from holofit.scattering.theory import Orientation

    optics = Optics(0.66, 1.33, 0.3, numerical_aperture=1.2)
    theory = ClusterEngine()
    model = Dimer(0.3, 0.35, 0.0, 1.59, 1.5)
    angles = (0.4, 0.9, 0.2)
    wave = theory.solve(model, optics, Orientation(*angles))
    x, y = np.meshgrid(np.linspace(0.0, 6.0, 31), np.linspace(0.5, 6.5, 29))
    pos = (3.1, 3.4, 7.0)
    names = ("psi", "theta")
    waves = [wave.orientation_derivative(a) for a in names]
    joint = lens_fields_on_pixels(waves, pos, x, y)
    # the images are single-precision sums (~1e-7 of the field): a step of 1e-2 keeps that
    # noise near 1e-5 of the derivative, and the five-point difference's error is ~h^4
    h = 1e-2
    for j, (name, (dex, dey)) in enumerate(zip(names, joint, strict=True)):
        assert dex.shape == x.shape
        sep = np.stack(lens_field_on_pixels(waves[j], pos, x, y))
        got = np.stack([dex, dey])
        scale = np.abs(sep).max()
        assert np.abs(got - sep).max() < 1e-6 * scale
        fd = {}
        for step in (-2, -1, 1, 2):
            a = list(angles)
            a[("psi", "theta", "phi").index(name)] += step * h
            fd[step] = np.stack(lens_field_on_pixels(theory.solve(model, optics,
                                                                  Orientation(*a)), pos, x, y))
        # the five-point central difference (error h^4)
        central = (fd[-2] - 8 * fd[-1] + 8 * fd[1] - fd[2]) / (12 * h)
        assert np.abs(got - central).max() < 1e-4 * scale


def test_height_derivative_of_the_lens_image_is_exact():
    """``height_derivative``: the image's z derivative from the same table pass (the fit's
    z column through the lens) equals the five-point difference of images at z +- h."""
    from holofit.optics import Optics
    from holofit.particles import Dimer
    from holofit.scattering.cluster import ClusterEngine
    from holofit.scattering.lens import lens_field_on_pixels, lens_fields_on_pixels
    from holofit.scattering.theory import Orientation

    optics = Optics(0.66, 1.33, 0.0, numerical_aperture=1.4)
    wave = ClusterEngine().solve(Dimer(0.3, 0.35, 0.0, 1.59, 1.5), optics,
                                 Orientation(1.0, 0.5, 0.0))
    x, y = np.meshgrid(np.linspace(-1.0, 7.0, 33), np.linspace(0.0, 6.0, 27))
    pos = np.array([3.0, 2.6, 9.0])
    (dex, dey), (ex, ey) = lens_fields_on_pixels([wave, wave], pos, x, y,
                                                 height_derivative=[True, False])
    got = np.stack([dex, dey])
    assert np.abs(np.stack([ex, ey]) - np.stack(lens_field_on_pixels(wave, pos, x, y))).max() \
        < 1e-6 * np.abs(ex).max()
    h = 1e-2
    img = {s: np.stack(lens_field_on_pixels(wave, pos + np.array([0, 0, s * h]), x, y))
           for s in (-2, -1, 1, 2)}
    central = (img[-2] - 8 * img[-1] + 8 * img[1] - img[2]) / (12 * h)
    assert np.abs(got - central).max() < 1e-4 * np.abs(central).max()


def test_a_table_grows_by_its_new_rows_only(monkeypatch):
    """A request for more rows (a fit's trial step farther from its pixels) computes only the
    new rows; the grown table equals one built at once."""
    lt.clear_cache()
    x_step = np.linspace(0.01, 0.5, 21)
    rng = np.random.default_rng(3)
    built = []
    real = lt._bessel_rows

    def counting(x, rows, orders):
        built.append((rows.start, rows.stop))
        return real(x, rows, orders)

    monkeypatch.setattr(lt, "_bessel_rows", counting)
    for orders in (None, 5):
        n = 2 if orders is None else orders + 1
        h = rng.normal(size=(n, 21, 2)) + 1j * rng.normal(size=(n, 21, 2))
        lt.clear_cache()
        built.clear()
        lt.radial_transform(x_step, h, 100, orders, ("grow", orders))
        grown = lt.radial_transform(x_step, h, 180, orders, ("grow", orders))
        first = built[0][1]
        assert built == [(0, first), (first, 180)]
        lt.clear_cache()
        once = lt.radial_transform(x_step, h, 180, orders, ("grow", orders))
        np.testing.assert_array_equal(grown, once)
    lt.clear_cache()
