"""Fits of aberrated sphere holograms: the bias an unmodelled spherical aberration leaves, that
the aberration term removes it, and the joint instrument fit (holofit.calibrate.joint) that
recovers the NA and the coefficients from spheres at several heights.

The holograms are made through the aberrated lens (checked against the brute-force pupil
integral in test_lens_aberration.py); the aberration is the layer model's for a coverslip 5 um
thicker than a 60x water objective's design (holofit.aberration.layer_aberration, about
(-3.6, 11.9) rad), the size Martin, Leahy & Manoharan (2022) report biasing index and radius
by percents.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from holofit.aberration import Aberration, layer_aberration
from holofit.calibrate import JointFitSettings, SphereFrame, calibrate_instrument
from holofit.camera import Camera
from holofit.conventions import DetectorGrid
from holofit.hologram import calc_hologram
from holofit.optics import Optics
from holofit.particles import Sphere
from holofit.prefit.sphere import SphereFitSettings, fit_sphere_crop
from holofit.scattering.mie import MieWave

PIXEL_UM = 0.1767
#: 8-bit camera, background 120 counts (holofit.camera.Camera): pixel noise of the background
NOISE = 0.016


def _frame(optics: Optics, sphere: Sphere, z: float, corner=(300, 200), n=100, alpha=0.9):
    grid = DetectorGrid((n, n), PIXEL_UM, corner)
    xc = (corner[1] + (n - 1) / 2 + 0.31) * PIXEL_UM
    yc = (corner[0] + (n - 1) / 2 - 0.22) * PIXEL_UM
    holo = calc_hologram(MieWave(sphere, optics), (xc, yc, z), grid, alpha)
    truth = {"x_um": xc, "y_um": yc, "z_um": z, "radius_um": sphere.radius_um,
             "n": sphere.index, "alpha": alpha}
    return holo, truth, (xc - 0.4 * PIXEL_UM, yc + 0.3 * PIXEL_UM)


def test_layer_model_gives_the_coverslip_aberration():
    """The layer model's leading term against its series: a layer of glass ``t`` thick in
    place of water gives ``Phi ~ k_0 t (n_g/2) r (1 - r) x^2`` near the axis, ``r =
    (n_w/n_g)^2``; fitted over a pupil of small NA, ``c_0`` approaches ``-`` that."""
    ab, residual = layer_aberration(0.66, 1.33, 0.3, 1.523, 5.0)
    r = (1.33 / 1.523) ** 2
    series = 2 * np.pi / 0.66 * 5.0 * 1.523 / 2 * r * (1 - r)
    assert ab.spherical[0] == pytest.approx(-series, rel=2e-2)
    assert residual < 1e-4
    ab, residual = layer_aberration(0.66, 1.33, 1.2, 1.523, 5.0)
    assert residual < 1e-2 and -5.0 < ab.spherical[0] < -2.0
    with pytest.raises(ValueError, match="reflects"):
        layer_aberration(0.66, 1.33, 1.4, 1.2, 5.0)


def test_unmodelled_aberration_biases_a_sphere_fit_and_the_term_removes_it():
    """One noise-free 0.95 um polystyrene hologram 10 um from focus, fitted as ``holofit
    prefit`` does; the bias in units of the fit's error for the camera's pixel noise (its
    error scales with the noise, so the noise-free fit gives the bias exactly)."""
    ab, _ = layer_aberration(0.66, 1.33, 1.2, 1.523, 5.0)
    aberrated = Optics(0.66, 1.33, 0.0, 1.2, ab)
    ideal = Optics(0.66, 1.33, 0.0, 1.2)
    holo, truth, centre = _frame(aberrated, Sphere(0.475, 1.59), 10.0)
    pulls = {}
    for label, optics, opts in (
            ("ideal_pupil", ideal, SphereFitSettings(noise_sd=NOISE)),
            ("known", aberrated, SphereFitSettings(noise_sd=NOISE)),
            ("fitted", Optics(0.66, 1.33, 0.0, 1.2, Aberration((-2.0, 8.0))),
             SphereFitSettings(noise_sd=NOISE, fit_aberration=("sa4_rad", "sa6_rad")))):
        fit = fit_sphere_crop(holo, (300, 200), centre, optics, PIXEL_UM, opts)
        assert fit.ok
        s = math.sqrt(fit.rss / (fit.n_pixels - len(fit.free)))
        pulls[label] = {k: (fit.values[k] - v) / (fit.errors[k] * NOISE / s)
                        for k, v in truth.items()}
    # without the term: index, radius and height several sigma off (about -16, +7, -24)
    assert pulls["ideal_pupil"]["n"] < -5
    assert pulls["ideal_pupil"]["radius_um"] > 3
    assert pulls["ideal_pupil"]["z_um"] < -5
    # with it, known or fitted (from a start 1.6 and 3.9 rad off): gone
    for label in ("known", "fitted"):
        assert max(abs(p) for p in pulls[label].values()) < 0.1, (label, pulls[label])


def test_joint_fit_recovers_the_instrument_from_spheres_at_several_heights():
    """Three spheres (two materials, 5-18 um from focus) through the aberrated objective with
    an NA other than the start's, with camera noise: the joint fit finds the NA and both
    coefficients within 2 sigma; every frame's sphere too."""
    ab = Aberration((-3.63, 11.89))
    truth_optics = Optics(0.66, 1.33, 0.0, 1.15, ab)
    camera = Camera(background_counts=120.0)
    frames, truths = [], []
    for j, (z, a, n) in enumerate(((5.0, 0.5, 1.59), (10.0, 0.45, 1.45), (18.0, 0.55, 1.59))):
        holo, truth, centre = _frame(truth_optics, Sphere(a, n), z, corner=(100 * j, 50), n=80)
        data = camera.expose(holo, np.random.default_rng(j + 1)) / camera.background_counts
        frames.append(SphereFrame(data, (100 * j, 50), centre))
        truths.append(truth)
    fit = calibrate_instrument(frames, Optics(0.66, 1.33, 0.0, 1.2), PIXEL_UM)
    assert fit.status == "ok"
    for name, value in (("numerical_aperture", 1.15), ("sa4_rad", -3.63), ("sa6_rad", 11.89)):
        assert abs(fit.values[name] - value) < 2 * fit.errors[name], (name, fit.values[name])
    assert fit.optics.aberration == Aberration((fit.values["sa4_rad"], fit.values["sa6_rad"]))
    # the pupil phase at the aperture's edge, the well-fixed combination of the coefficients
    edge = ab.phase(np.array([np.arcsin(1.15 / 1.33)]))[0]
    assert abs(fit.edge_phase_rad - edge) < 2 * fit.edge_phase_error_rad
    assert fit.edge_phase_error_rad < 0.5 * min(fit.errors["sa4_rad"], fit.errors["sa6_rad"])
    assert 0.8 < fit.chi2_red < 1.2
    for result, truth in zip(fit.frames, truths, strict=True):
        for k, v in truth.items():
            assert abs(result.values[k] - v) < 3 * result.errors[k], (k, result.values[k], v)


def test_joint_fit_is_exact_on_noise_free_frames_with_the_polarisation():
    ab = Aberration((-3.63, 11.89))
    truth_optics = Optics(0.66, 1.33, 0.05, 1.15, ab)
    frames = []
    for j, (z, a, n) in enumerate(((5.0, 0.5, 1.59), (12.0, 0.45, 1.45))):
        holo, _, centre = _frame(truth_optics, Sphere(a, n), z, corner=(100 * j, 50), n=70)
        frames.append(SphereFrame(holo, (100 * j, 50), centre, noise_sd=NOISE))
    fit = calibrate_instrument(frames, Optics(0.66, 1.33, 0.0, 1.2), PIXEL_UM,
                         JointFitSettings(fit_polarization=True, aberration_starts=()))
    assert fit.values["numerical_aperture"] == pytest.approx(1.15, abs=1e-6)
    assert fit.values["polarization_rad"] == pytest.approx(0.05, abs=1e-6)
    assert fit.values["sa4_rad"] == pytest.approx(-3.63, abs=1e-4)
    assert fit.values["sa6_rad"] == pytest.approx(11.89, abs=1e-4)
    with pytest.raises(ValueError, match="numerical_aperture"):
        calibrate_instrument(frames, Optics(0.66, 1.33), PIXEL_UM)
    with pytest.raises(ValueError, match="shared parameter"):
        JointFitSettings(fit_na=False, aberration=())
