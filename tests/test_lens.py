"""The objective lens (holofit.scattering.lens) against independent evaluations.

* a brute-force 2-D pupil integral (tests/lens_reference.py: Gauss-Legendre in v = sqrt(cos th)
  times the trapezoid rule in phi, F sampled direction by direction from each engine's own
  far-field routine, apodisation applied with explicit e_m / e_phi vectors), for Lorenz-Mie, the
  built-in DDA and ADDA (stand-in executable);
* the plane-wave (Weyl) identity: the lens image with NA = n_medium and no apodisation plus the
  evanescent waves (a separate 1-D integral of Bohren & Huffman's S1, S2 continued to complex
  angles) is the exact near-field Lorenz-Mie field of holofit's ideal model;
* a DDA sphere against Lorenz-Mie through the same lens (DDA accuracy).
"""

from __future__ import annotations

import gc
import sys
import weakref
from pathlib import Path

import numpy as np
import pytest
from scipy import special

from holofit.config import load_instrument
from holofit.conventions import DetectorGrid, hologram_intensity
from holofit.dda.engine import BuiltinDDA
from holofit.hologram import calc_hologram
from holofit.optics import Optics
from holofit.particles import Sphere, Spherocylinder
from holofit.scattering.lens import (
    LensImage,
    lens_field_on_detector,
    lens_field_on_pixels,
    lens_image,
)
from holofit.scattering.lens_kernels import bessel_table
from holofit.scattering.lens_pupil import aperture_angle
from holofit.scattering.lens_transform import node_count
from holofit.scattering.mie import LorenzMie
from holofit.scattering.theory import Orientation
from tests.lens_reference import mie_evanescent, mie_far_field, pupil_integral

CONFIGS = Path(__file__).resolve().parents[1] / "configs" / "instruments"


def pixels(n: int = 90, seed: int = 0, reach: float = 9.0) -> tuple[np.ndarray, np.ndarray]:
    """Random pixel centres within ``reach`` um of (5, 5), the centre itself included."""
    rng = np.random.default_rng(seed)
    r = reach * np.sqrt(rng.uniform(0, 1, n))
    a = rng.uniform(0, 2 * np.pi, n)
    xs, ys = 5.0 + r * np.cos(a), 5.0 + r * np.sin(a)
    xs[0], ys[0] = 5.0, 5.0
    return xs, ys


def rel_error(got: tuple, ref: tuple) -> float:
    scale = max(np.abs(ref[0]).max(), np.abs(ref[1]).max())
    return max(np.abs(got[0] - ref[0]).max(), np.abs(got[1] - ref[1]).max()) / scale


@pytest.mark.parametrize(
    ("na", "apodization", "beta", "z"),
    [
        (1.2, "aplanatic", 0.0, 10.0),  # 60x water
        (1.4, "aplanatic", 0.7, 6.0),  # 100x oil in water: every propagating wave
        (1.0, "none", 0.3, 15.0),
        (1.2, "aplanatic", 1.2, -7.0),  # below the focal plane
        (1.2, "aplanatic", 0.0, 0.0),  # in it
    ],
)
def test_mie_lens_matches_brute_force_pupil_integral(na, apodization, beta, z):
    optics = Optics(0.66, 1.33, beta)
    wave = LorenzMie().solve(Sphere(0.5, 1.59), optics)
    xs, ys = pixels()
    pos = (5.0, 5.0, z)
    got = lens_field_on_pixels(wave, pos, xs, ys, na, apodization)
    ref = pupil_integral(mie_far_field(wave), optics.k, pos, xs, ys,
                         aperture_angle(na, optics.n_medium), apodization)
    assert rel_error(got, ref) < 1e-6


def test_reference_integral_is_converged():
    optics = Optics(0.66, 1.33, 0.0)
    wave = LorenzMie().solve(Sphere(0.5, 1.59), optics)
    xs, ys = pixels(30)
    args = (mie_far_field(wave), optics.k, (5.0, 5.0, 10.0), xs, ys, aperture_angle(1.2, 1.33))
    a = pupil_integral(*args)  # the default rule, reach 9 um as in the tests
    b = pupil_integral(*args, n_v=500, n_phi=256)
    assert rel_error(a, b) < 1e-10


def test_full_aperture_without_apodisation_plus_evanescent_waves_is_the_exact_field():
    """Weyl: the exact field on the focal plane = propagating part (the NA = n image, no
    apodisation) + evanescent part. Also shows the evanescent part is not negligible."""
    optics = Optics(0.66, 1.33, 0.0)
    wave = LorenzMie().solve(Sphere(0.5, 1.59), optics)
    xs, ys = pixels(120, seed=3)
    for z in (4.0, 12.0):
        pos = (5.0, 5.0, z)
        prop = lens_field_on_pixels(wave, pos, xs, ys, optics.n_medium, "none")
        evan = mie_evanescent(wave, pos, xs, ys)
        exact = wave.field_on_pixels(pos, xs, ys)
        total = (prop[0] + evan[0], prop[1] + evan[1])
        assert rel_error(total, exact) < 1e-6
        # the evanescent waves are ~|S(90 deg)| / (k z): small, but far above 1e-6
        assert 1e-4 < rel_error(prop, exact) < 5e-2


def test_dda_lens_matches_brute_force_pupil_integral_of_its_own_far_field():
    optics = Optics(0.66, 1.33, 0.4)
    wave = BuiltinDDA(dipole_size_um=0.08).solve(Spherocylinder(0.3, 0.7, 1.495), optics,
                                                   Orientation(0.5, 1.0, 0.2))
    xs, ys = pixels(70, seed=1, reach=6.0)
    for na, apodization, z in ((1.2, "aplanatic", 8.0), (1.45, "aplanatic", -4.0),
                               (0.9, "none", 12.0)):
        pos = (5.0, 5.0, z)
        got = lens_field_on_pixels(wave, pos, xs, ys, na, apodization)
        # far_field_amplitude: direct dipole sums, not the multipole expansion the lens uses
        ref = pupil_integral(wave.far_field_amplitude, optics.k, pos, xs, ys,
                             aperture_angle(na, optics.n_medium), apodization, n_v=200,
                             n_phi=128)
        assert rel_error(got, ref) < 1e-6


def test_dda_sphere_through_the_lens_agrees_with_mie_at_dda_accuracy():
    optics = Optics(0.66, 1.33, 0.0)
    sphere = Sphere(0.4, 1.5)
    mie = LorenzMie().solve(sphere, optics)
    dda = BuiltinDDA(dipole_size_um=0.04).solve(sphere, optics)
    xs, ys = pixels(80, seed=2)
    pos = (5.0, 5.0, 8.0)
    lens_err = rel_error(lens_field_on_pixels(dda, pos, xs, ys, 1.2),
                         lens_field_on_pixels(mie, pos, xs, ys, 1.2))
    ideal_err = rel_error(dda.field_on_pixels(pos, xs, ys) if hasattr(dda, "field_on_pixels")
                          else _ideal_on_pixels(dda, pos, xs, ys),
                          mie.field_on_pixels(pos, xs, ys))
    assert lens_err < 1e-2
    # the lens adds no error of its own: same level as the DDA's ideal-model field
    assert lens_err < 2.0 * ideal_err + 1e-5


def _ideal_on_pixels(wave, pos, xs, ys):
    pts = np.stack([xs - pos[0], ys - pos[1], np.full(xs.size, -pos[2])], axis=1)
    e = wave.field_at(pts) * np.exp(-1j * wave.optics.k * pos[2])
    return e[:, 0], e[:, 1]


def test_adda_wave_through_the_lens(tmp_path, monkeypatch):
    from holofit.dda import adda as ae

    stub = Path(__file__).parent / "stubs" / "fake_adda.py"
    exe = tmp_path / "adda"
    exe.write_text(f'#!/bin/sh\nexec "{sys.executable}" "{stub}" "$@"\n')
    exe.chmod(0o755)
    monkeypatch.delenv(ae.ADDA_ENV_VAR, raising=False)
    monkeypatch.delenv("FAKE_ADDA_MODE", raising=False)
    optics = Optics(0.66, 1.33, 0.4)
    engine = ae.AddaEngine(adda_path=exe, dipole_size_um=0.05)
    wave = engine.solve(Spherocylinder(0.2, 0.5, 1.45), optics, Orientation(0.3, 0.9))
    xs, ys = pixels(50, seed=4, reach=4.0)
    pos = (5.0, 5.0, 7.0)
    got = lens_field_on_pixels(wave, pos, xs, ys, 1.2)
    # every direction of the reference is asked of the stand-in ADDA (one run)
    ref = pupil_integral(wave.far_field_amplitude, optics.k, pos, xs, ys,
                         aperture_angle(1.2, 1.33), n_v=160, n_phi=128)
    assert rel_error(got, ref) < 1e-6


def test_pixel_lists_shapes_and_caches():
    optics = Optics(0.66, 1.33, 0.2)
    wave = LorenzMie().solve(Sphere(0.6, 1.45), optics)
    grid = DetectorGrid((40, 50), 0.12, corner=(3, 7))
    full = lens_field_on_detector(wave, (4.0, 3.5, 9.0), grid, 1.2)
    x, y = grid.coordinates()
    mask = np.random.default_rng(0).uniform(size=x.shape) < 0.3
    sub = lens_field_on_pixels(wave, (4.0, 3.5, 9.0), x[mask], y[mask], 1.2)
    np.testing.assert_allclose(sub[0], full[0][mask], rtol=0, atol=1e-13)
    np.testing.assert_allclose(sub[1], full[1][mask], rtol=0, atol=1e-13)
    # another aperture, then back; a fresh image must agree with the cached one
    other = lens_field_on_detector(wave, (4.0, 3.5, 9.0), grid, 1.0)
    assert rel_error(other, full) > 1e-3
    again = LensImage(wave).field_on_detector((4.0, 3.5, 9.0), grid, 1.2)
    assert rel_error(again, full) < 1e-14
    empty = lens_field_on_pixels(wave, (0, 0, 5.0), np.zeros(0), np.zeros(0), 1.2)
    assert empty[0].shape == (0,)


def test_lateral_move_is_a_translation():
    optics = Optics(0.66, 1.33, 0.0)
    wave = BuiltinDDA(dipole_size_um=0.1).solve(Spherocylinder(0.25, 0.5, 1.5), optics,
                                                  Orientation(0.4, 0.8))
    xs, ys = pixels(60, seed=5)
    a = lens_field_on_pixels(wave, (5.0, 5.0, 6.0), xs, ys, 1.2)
    b = lens_field_on_pixels(wave, (5.7, 4.6, 6.0), xs + 0.7, ys - 0.4, 1.2)
    assert rel_error(b, a) < 1e-9


def test_calc_hologram_uses_the_lens_when_the_optics_has_an_aperture():
    grid = DetectorGrid((30, 30), 0.15)
    pos = (2.2, 2.3, 8.0)
    ideal = Optics(0.66, 1.33, 0.0)
    with_na = Optics(0.66, 1.33, 0.0, numerical_aperture=1.2)
    holo = calc_hologram(LorenzMie().solve(Sphere(0.5, 1.59), with_na), pos, grid, 0.8)
    wave = LorenzMie().solve(Sphere(0.5, 1.59), ideal)
    ex, ey = lens_field_on_detector(wave, pos, grid, 1.2)
    np.testing.assert_allclose(holo, hologram_intensity(ex, ey, 0.0, 0.8), atol=1e-14)
    assert np.abs(holo - calc_hologram(wave, pos, grid, 0.8)).max() > 1e-3


def test_instrument_passes_its_aperture_to_the_optics():
    assert load_instrument(CONFIGS / "paper_60x_water.toml").optics.numerical_aperture == 1.2
    assert load_instrument(CONFIGS / "pylorenzmie.toml").optics.numerical_aperture == 0.86
    inst = load_instrument(CONFIGS / "holopy_image0001.toml")
    assert inst.optics.numerical_aperture == 1.4
    assert inst.with_numerical_aperture(None).optics.numerical_aperture is None


def test_bad_apertures_and_apodisations_are_refused():
    with pytest.raises(ValueError, match="numerical_aperture"):
        Optics(0.66, 1.33, numerical_aperture=0.0)
    wave = LorenzMie().solve(Sphere(0.5, 1.59), Optics(0.66, 1.33))
    with pytest.raises(ValueError, match="numerical aperture"):
        lens_field_on_pixels(wave, (0, 0, 5.0), np.ones(3), np.ones(3))
    with pytest.raises(ValueError, match="apodization"):
        lens_field_on_pixels(wave, (0, 0, 5.0), np.ones(3), np.ones(3), 1.2, "gaussian")
    assert aperture_angle(1.5, 1.33) == pytest.approx(np.pi / 2)


def test_bessel_table_matches_scipy():
    x = np.concatenate([np.linspace(0, 2, 50), np.linspace(2, 400, 500), [29.5, 30.0, 31.0]])
    m = 30
    out = np.empty((x.size, m + 1))
    bessel_table(x, special.j0(x), special.j1(x), m, out)
    ref = special.jv(np.arange(m + 1)[None, :], x[:, None])
    assert np.abs(out - ref).max() < 1e-13


def test_node_rule_grows_with_height_reach_and_order():
    k = 2 * np.pi * 1.33 / 0.66
    th = aperture_angle(1.2, 1.33)
    base = node_count(k, 5.0, 5.0, th, 10)
    assert node_count(k, 20.0, 5.0, th, 10) > base
    assert node_count(k, 5.0, 20.0, th, 10) > base
    assert node_count(k, -5.0, 5.0, th, 10) == base


def test_images_are_reused_per_wave_and_released_with_it():
    wave = LorenzMie().solve(Sphere(0.5, 1.59), Optics(0.66, 1.33))
    image = lens_image(wave)
    assert lens_image(wave) is image and lens_image(wave, "none") is not image
    ref = weakref.ref(wave)
    del wave
    gc.collect()
    assert ref() is None  # the cache holds no reference to the wave


def test_a_trial_step_far_off_is_refused_not_computed_for_minutes():
    """A least-squares trial step can put a particle absurdly far from focus; the pupil's
    node count grows with k z, and its eigenvalue problem would run for minutes (seen in a
    replicate run: a prefit worker stuck on one frame). Such a height is refused at once and
    the forward model turns the refusal into an invalid step."""
    from holofit.holomodel.forward import HologramModel, InvalidParameters
    from holofit.holomodel.parameters import ParameterSpace, State, static_values

    optics = Optics(0.66, 1.33, 0.0, 1.2)
    wave = LorenzMie().solve(Sphere(0.5, 1.59), optics)
    xs, ys = pixels(50, seed=2)
    assert node_count(optics.k, 50.0, 7.0, aperture_angle(1.2, 1.33), 20) < 400
    with pytest.raises(ValueError, match="pupil nodes"):
        lens_field_on_pixels(wave, (5.0, 5.0, 1e5), xs, ys)
    sphere = Sphere(0.5, 1.59)
    space = ParameterSpace(sphere, ("x_um", "y_um", "z_um"),
                           State((5.0, 5.0, 1e5), None, 1.0, static_values(sphere)))
    model = HologramModel(LorenzMie(), space, optics, xs, ys)
    with pytest.raises(InvalidParameters, match="pupil nodes"):
        model.hologram(space.initial_vector())
