"""The aberrated objective (holofit.aberration through holofit.scattering.lens) against
independent evaluations.

* zero coefficients, however given, are the unaberrated image bit for bit (np.array_equal), and
  the ideal path never evaluates a pupil phase;
* aberrated Lorenz-Mie and built-in DDA images against the brute-force 2-D pupil integral of
  tests/lens_reference.py (each engine's own far field sampled direction by direction, the
  phase ``exp(i Phi)`` written out by hand there), to the lens's stated accuracy;
* the exact derivatives with respect to the coefficients against the same integral with
  ``i dPhi/dc exp(i Phi)`` in the integrand, and the forward model's Jacobian columns against
  finite differences of its holograms;
* the phase itself against the hand-written HoloPy form (conjugated for holofit's time
  convention), the instrument file's key, and the radial lines of the prefit's start estimator.
"""

from __future__ import annotations

import numpy as np
import pytest

import holofit.aberration as aberration_module
from holofit.aberration import Aberration, spherical_basis, spherical_phase
from holofit.config import ConfigError, instrument_from_dict, load_instrument
from holofit.dda.engine import BuiltinDDA
from holofit.holomodel import HologramModel, ParameterSpace, State
from holofit.optics import Optics
from holofit.particles import Sphere, Spherocylinder
from holofit.scattering.lens import LensImage, lens_field_on_pixels, lens_fields_on_pixels
from holofit.scattering.lens_lines import sphere_lens_lines
from holofit.scattering.lens_pupil import aperture_angle
from holofit.scattering.mie import LorenzMie, MieWave
from holofit.scattering.theory import Orientation
from tests.lens_reference import (
    aberrated_factor,
    mie_far_field,
    pupil_integral,
    spherical_pupil_phase,
)
from tests.test_lens import pixels, rel_error

#: the lens's stated accuracy (holofit.scattering.lens_transform: 2.2e-7 of the field at
#: worst, single-precision tables of many orders ~1e-7 more)
LENS_ACCURACY = 1e-6


@pytest.fixture(scope="module")
def rod_wave():
    optics = Optics(0.66, 1.33, 0.4)
    return BuiltinDDA(dipole_size_um=0.08).solve(Spherocylinder(0.3, 0.7, 1.495), optics,
                                                 Orientation(0.5, 1.0, 0.2))


def test_zero_aberration_is_the_unaberrated_image_bit_for_bit(rod_wave, monkeypatch):
    def no_phase(*args, **kwargs):
        raise AssertionError("the ideal objective evaluated a pupil phase")

    monkeypatch.setattr(aberration_module, "spherical_phase", no_phase)
    xs, ys = pixels(120, seed=6)
    pos = (5.0, 5.0, 9.0)
    plain = Optics(0.66, 1.33, 0.3, 1.2)
    zeros = Optics(0.66, 1.33, 0.3, 1.2, Aberration((0.0, 0.0)))
    for wave, wave0 in ((MieWave(Sphere(0.5, 1.59), plain), MieWave(Sphere(0.5, 1.59), zeros)),
                        (rod_wave, rod_wave)):
        ref = LensImage(wave).field_on_pixels(pos, xs, ys, 1.2)
        for got in (LensImage(wave0).field_on_pixels(pos, xs, ys, 1.2),
                    LensImage(wave).field_on_pixels(pos, xs, ys, 1.2, Aberration()),
                    LensImage(wave).field_on_pixels(pos, xs, ys, 1.2, Aberration((0.0,))),
                    lens_field_on_pixels(wave0, pos, xs, ys, 1.2)):
            assert np.array_equal(got[0], ref[0]) and np.array_equal(got[1], ref[1])
    # the several-wave pass (T-matrix derivative waves, height derivative)
    ref = lens_fields_on_pixels([rod_wave, rod_wave], pos, xs, ys, 1.2,
                                height_derivative=[False, True])
    got = lens_fields_on_pixels([rod_wave, rod_wave], pos, xs, ys, 1.2,
                                height_derivative=[False, True], aberration=Aberration((0.0,)))
    for a, b in zip(ref, got, strict=True):
        assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    # the prefit's radial lines
    p0, b0 = sphere_lens_lines(MieWave(Sphere(0.5, 1.59), plain), [3.0, -4.0],
                               np.linspace(0, 4, 30))
    p1, b1 = sphere_lens_lines(MieWave(Sphere(0.5, 1.59), zeros), [3.0, -4.0],
                               np.linspace(0, 4, 30))
    assert np.array_equal(p0, p1) and np.array_equal(b0, b1)
    # the forward model: hologram and Jacobian with a zero aberration in the state
    space = dict(model=Sphere(0.5, 1.59),
                 free=("x_um", "y_um", "z_um", "radius_um", "n", "alpha"))
    start = State((5.0, 5.0, 9.0), None, 0.8, (("radius_um", 0.5), ("n", 1.59)), 1.2)
    holo = []
    for ab in (None, Aberration((0.0, 0.0))):
        sp = ParameterSpace(start=State(**{**start.__dict__, "aberration": ab}), **space)
        m = HologramModel(LorenzMie(), sp, plain, xs, ys)
        v = sp.initial_vector()
        holo.append((m.hologram(v), m.jacobian(v)))
    assert np.array_equal(holo[0][0], holo[1][0]) and np.array_equal(holo[0][1], holo[1][1])


@pytest.mark.parametrize(
    ("na", "z", "coefficients", "beta"),
    [
        (1.2, 10.0, (-2.5, 0.6), 0.0),  # 60x water, a coverslip off its design thickness
        (1.4, 6.0, (6.0, -2.0), 0.7),  # 100x oil into water: every propagating wave
        (1.2, -7.0, (3.0, 1.0, -0.5, 0.2), 1.2),  # below focus, four terms
    ],
)
def test_aberrated_mie_matches_brute_force_pupil_integral(na, z, coefficients, beta):
    optics = Optics(0.66, 1.33, beta, na, Aberration(coefficients))
    wave = LorenzMie().solve(Sphere(0.5, 1.59), optics)
    xs, ys = pixels()
    pos = (5.0, 5.0, z)
    theta_max = aperture_angle(na, optics.n_medium)
    got = lens_field_on_pixels(wave, pos, xs, ys)
    ref = pupil_integral(mie_far_field(wave), optics.k, pos, xs, ys, theta_max,
                         pupil_factor=aberrated_factor(coefficients))
    assert rel_error(got, ref) < LENS_ACCURACY
    # and the aberration is no small change: the ideal pupil is far from it
    ideal = pupil_integral(mie_far_field(wave), optics.k, pos, xs, ys, theta_max)
    assert rel_error(ideal, ref) > 1e-2


def test_aberrated_dda_rod_matches_brute_force_pupil_integral(rod_wave):
    xs, ys = pixels(70, seed=1, reach=6.0)
    k = rod_wave.optics.k
    for na, z, c in ((1.2, 8.0, (-2.5, 0.6)), (1.45, -4.0, (6.0, -2.0))):
        pos = (5.0, 5.0, z)
        got = lens_field_on_pixels(rod_wave, pos, xs, ys, na, aberration=Aberration(c))
        # far_field_amplitude: direct dipole sums, not the multipole expansion the lens uses
        ref = pupil_integral(rod_wave.far_field_amplitude, k, pos, xs, ys,
                             aperture_angle(na, 1.33), n_v=200, n_phi=128,
                             pupil_factor=aberrated_factor(c))
        assert rel_error(got, ref) < LENS_ACCURACY


def test_coefficient_derivatives_match_brute_force(rod_wave):
    """``dE/dc_k`` is the same pupil integral with ``i dPhi/dc_k`` in it; the derivatives are
    ~1e-2 of the field, so the bound is relative to their own largest value (their absolute
    error is ~1e-8 of the field)."""
    c = (-2.5, 0.6)
    sphere = LorenzMie().solve(Sphere(0.5, 1.59), Optics(0.66, 1.33, 0.3, 1.2, Aberration(c)))
    cases = ((sphere, mie_far_field(sphere), pixels(), 1.2, 10.0, {}),
             (rod_wave, rod_wave.far_field_amplitude, pixels(70, seed=1, reach=6.0), 1.2, 8.0,
              dict(n_v=200, n_phi=128)))
    for wave, far, (xs, ys), na, z, rule in cases:
        pos = (5.0, 5.0, z)
        got = LensImage(wave).field_derivatives(pos, xs, ys, ["sa4_rad", "sa6_rad"], na,
                                                Aberration(c))
        for j in range(2):
            ref = pupil_integral(far, wave.optics.k, pos, xs, ys, aperture_angle(na, 1.33),
                                 pupil_factor=aberrated_factor(c, j), **rule)
            assert rel_error(got[j], ref) < 5e-6


def test_phase_is_holopys_form_conjugated():
    """``Phi = -x^2 sum c_k P_k(x)``, ``x = cos th - 1`` (HoloPy's coefficients, holofit's time
    convention), its basis is its derivative, the axis is untouched, and the first two terms
    are the pure 4th- and 6th-order terms."""
    rng = np.random.default_rng(0)
    theta = np.linspace(0.0, 1.4, 57)
    c = rng.normal(0.0, 3.0, 4)
    ref = spherical_pupil_phase(c)(np.cos(theta))
    assert np.abs(spherical_phase(theta, c) - ref).max() < 1e-12
    assert np.abs(Aberration(tuple(c)).phase(theta) - ref).max() < 1e-12
    basis = spherical_basis(theta, 4)
    assert np.abs(c @ basis - ref).max() < 1e-12
    x = np.cos(theta) - 1.0
    assert np.abs(basis[0] + x**2).max() < 1e-15 and np.abs(basis[1] + x**3).max() < 1e-15
    assert Aberration((5.0, 2.0)).phase(np.zeros(1))[0] == 0.0


def test_aberrated_lens_lines_are_the_lens_image_on_two_lines():
    optics = Optics(0.66, 1.33, 0.0, 1.2, Aberration((-2.5, 0.6)))
    wave = MieWave(Sphere(0.5, 1.59), optics)
    rho = np.linspace(0.0, 4.0, 25)
    p, b = sphere_lens_lines(wave, [6.0], rho)
    along = lens_field_on_pixels(wave, (0.0, 0.0, 6.0), rho, np.zeros_like(rho))
    across = lens_field_on_pixels(wave, (0.0, 0.0, 6.0), np.zeros_like(rho), rho)
    assert np.abs(p[0] - along[0]).max() < LENS_ACCURACY
    assert np.abs(b[0] - across[0]).max() < LENS_ACCURACY


def test_model_aberration_columns_match_finite_differences(rod_wave):
    c = (-2.5, 0.6)
    optics = Optics(0.66, 1.33, 0.3, 1.2)
    xs, ys = pixels(200, seed=7, reach=7.0)
    sphere = Sphere(0.5, 1.59)
    rod = rod_wave.model if hasattr(rod_wave, "model") else Spherocylinder(0.3, 0.7, 1.495)
    # the DDA image's tables of many orders are single precision (~1e-7 of the field), so its
    # finite difference needs a larger step and is good to ~1 % only (central: truncation
    # ~h^2, rounding ~1e-7 / h); the exact field derivative itself is checked to 5e-6 against
    # the brute-force integral above
    cases = (
        (LorenzMie(), sphere, None, (("radius_um", 0.5), ("n", 1.59)), 1e-4, 1e-5),
        (BuiltinDDA(dipole_size_um=0.08), rod, np.eye(3), (("a_um", 0.3), ("b_um", 0.7),
                                                            ("n", 1.495)), 0.02, 2e-2),
    )
    for theory, model, rotation, statics, h, tol in cases:
        start = State((5.0, 5.0, 9.0), rotation, 0.8, statics, 1.2, Aberration(c))
        space = ParameterSpace(model, ("z_um", "alpha", "sa4_rad", "sa6_rad"), start)
        m = HologramModel(theory, space, optics, xs, ys)
        v = space.initial_vector()
        jac = m.jacobian(v)
        for name in ("sa4_rad", "sa6_rad"):
            i = space.names.index(name)
            up, dn = v.copy(), v.copy()
            up[i] += h
            dn[i] -= h
            fd = (m.hologram(up) - m.hologram(dn)) / (2 * h)
            assert np.abs(jac[:, i] - fd).max() < tol * np.abs(fd).max()
        assert space.report(v)[0]["sa6_rad"] == 0.6


def test_instrument_file_gives_the_aberration(tmp_path):
    text = """[instrument]
name = "t"
wavelength_um = 0.66
medium_index = 1.33
pixel_size_um = 0.1
polarization_deg = 0.0
bit_depth = 8
"""
    path = tmp_path / "i.toml"
    path.write_text(text + "numerical_aperture = 1.2\nspherical_aberration_rad = [-2.5, 0.6]\n")
    inst = load_instrument(path)
    assert inst.optics.aberration == Aberration((-2.5, 0.6))
    assert inst.optics.numerical_aperture == 1.2
    again = instrument_from_dict(inst.as_dict())
    assert again.optics.aberration == inst.optics.aberration
    assert inst.with_aberration(Aberration()).optics.aberration.is_zero
    # no objective, no pupil: the ideal model drops the aberration with the NA
    assert inst.with_numerical_aperture(None).optics == Optics(0.66, 1.33)
    assert load_instrument(tmp_path / "i.toml").optics == inst.optics
    path.write_text(text + "spherical_aberration_rad = [-2.5]\n")
    with pytest.raises(ConfigError, match="needs an objective"):
        load_instrument(path)
    path.write_text(text + "numerical_aperture = 1.2\nspherical_aberration_rad = [1, 2, 3, 4, 5]\n")
    with pytest.raises(ConfigError, match="at most 4"):
        load_instrument(path)
    path.write_text(text + "numerical_aperture = 1.2\nspherical_aberration_rad = 2.0\n")
    with pytest.raises(ConfigError, match="list of numbers"):
        load_instrument(path)
    with pytest.raises(ValueError, match="needs an objective"):
        Optics(0.66, 1.33, 0.0, None, Aberration((1.0,)))
    assert load_instrument("paper_60x_water").optics.aberration.is_zero


def test_model_pictures_use_a_fitted_aberration():
    from holofit.conventions import DetectorGrid
    from holofit.hologram import calc_hologram
    from holofit.holomodel.pictures import model_image

    optics = Optics(0.66, 1.33, 0.0, 1.2)
    row = {"x_um": 3.0, "y_um": 3.0, "z_um": 9.0, "radius_um": 0.5, "n": 1.59, "alpha": 0.8,
           "sa4_rad": -2.5, "sa6_rad": 0.6}
    got = model_image(row, Sphere(0.5, 1.59), LorenzMie(), optics, (40, 40), (0, 0), 0.15)
    wave = MieWave(Sphere(0.5, 1.59), Optics(0.66, 1.33, 0.0, 1.2, Aberration((-2.5, 0.6))))
    ref = calc_hologram(wave, (3.0, 3.0, 9.0), DetectorGrid((40, 40), 0.15), 0.8)
    assert np.abs(got - ref).max() < 1e-12
