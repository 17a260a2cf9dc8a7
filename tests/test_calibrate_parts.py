"""The calibrate stage's parts: the choice of frames over the heights, the instrument file's
writer (read back to the same values), the joint fit's normal-equation Levenberg-Marquardt
against MINPACK, and a stated material (held, or a prior) in the joint fit.

Truths: hand-made heights; tomllib reading the written text; scipy's MINPACK on a small
nonlinear problem; noise-free sphere holograms whose instrument is known.
"""

from __future__ import annotations

import math
import tomllib

import numpy as np
import pytest
from scipy.optimize import least_squares

from holofit.aberration import Aberration
from holofit.calibrate import JointFitSettings, SphereFrame, calibrate_instrument
from holofit.calibrate.solver import covariance_from_normal, solve_normal_lm
from holofit.calibrate.stage import choose_frames
from holofit.config import ConfigError, Instrument, instrument_toml, load_instrument
from holofit.conventions import DetectorGrid
from holofit.hologram import calc_hologram
from holofit.holomodel.statistics import covariance_from_jacobian
from holofit.optics import Optics
from holofit.particles import Sphere
from holofit.scattering.mie import MieWave

PIXEL_UM = 0.1767


def test_frames_are_chosen_evenly_over_the_heights():
    heights = [((0, k), z) for k, z in enumerate([5.0, 5.1, 5.2, 5.3, 5.4, 15.0, 24.9, 25.0])]
    assert choose_frames(heights, 3) == [(0, 0), (0, 5), (0, 7)]
    # fewer than asked: all, by height
    assert choose_frames(heights[::-1][:2], 5) == [(0, 6), (0, 7)]
    chosen = choose_frames(heights, 5)
    assert len(set(chosen)) == 5 and (0, 5) in chosen


def test_the_instrument_file_reads_back_to_the_same_values(tmp_path):
    inst = load_instrument("paper_60x_water").with_aberration(Aberration((-3.63, 11.89)))
    inst = inst.with_numerical_aperture(1.1508)
    tables = {"calibration": {"note": 'quotes " and \\ and ünïcode', "chi2": float("nan"),
                              "frames": [1, 2, 3], "flag": True,
                              "errors": {"numerical_aperture": 9.5e-4},
                              "covariance": {"matrix": [[1e-7, 2e-5], [2e-5, 0.6]]}}}
    text = instrument_toml(inst, comments=["first line", "second"], tables=tables)
    assert text.startswith("# first line\n# second\n[instrument]\n")
    path = tmp_path / "inst.toml"
    path.write_text(text)
    back = load_instrument(path)
    assert back.optics == inst.optics
    assert back.as_dict() == {**inst.as_dict(), "path": str(path)}
    doc = tomllib.loads(text)
    cal = doc["calibration"]
    assert math.isnan(cal.pop("chi2"))
    assert cal == {k: v for k, v in tables["calibration"].items() if k != "chi2"}
    with pytest.raises(ConfigError, match="instrument"):
        instrument_toml(inst, tables={"instrument": {}})
    bad = Instrument("x", 0.66, 1.33, 0.1, extra={"spherical_aberration_rad": [1.0]})
    with pytest.raises(ConfigError, match="numerical_aperture"):
        instrument_toml(bad)


class _Exponentials:
    """``y = a exp(-b t) + c exp(-d t)``, the normal equations from the Jacobian."""

    def __init__(self, t):
        self.t = t

    def hologram(self, v):
        a, b, c, d = v
        return a * np.exp(-b * self.t) + c * np.exp(-d * self.t)

    def jacobian(self, v):
        a, b, c, d = v
        e1, e2 = np.exp(-b * self.t), np.exp(-d * self.t)
        return np.column_stack([e1, -a * self.t * e1, e2, -c * self.t * e2])

    def normal(self, v, r):
        j = self.jacobian(v)
        return j.T @ j, j.T @ r


def test_normal_equation_lm_finds_minpacks_minimum_and_covariance():
    t = np.linspace(0, 5, 200)
    model = _Exponentials(t)
    truth = np.array([2.0, 1.3, 0.7, 0.2])
    data = model.hologram(truth) + np.random.default_rng(0).normal(0, 0.01, t.size)
    start = np.array([1.0, 2.0, 1.0, 0.5])
    sol = solve_normal_lm(model, data, start, ftol=1e-12, xtol=1e-12)
    ref = least_squares(lambda v: model.hologram(v) - data, start, jac=model.jacobian,
                        method="lm", xtol=1e-12, ftol=1e-12)
    assert sol.converged
    np.testing.assert_allclose(sol.vector, ref.x, rtol=1e-7)
    assert sol.rss == pytest.approx(float(ref.fun @ ref.fun), rel=1e-10)
    cov = covariance_from_normal(sol.normal, sol.rss, t.size)
    np.testing.assert_allclose(cov, covariance_from_jacobian(model.jacobian(sol.vector),
                                                             sol.rss, t.size), rtol=1e-6)
    assert np.isnan(covariance_from_normal(np.zeros((2, 2)), 1.0, 10)).all()


def _frames(optics, spheres):
    frames = []
    for j, (z, a, n) in enumerate(spheres):
        corner = (100 * j, 50)
        grid = DetectorGrid((60, 60), PIXEL_UM, corner)
        xc, yc = (corner[1] + 30.2) * PIXEL_UM, (corner[0] + 29.7) * PIXEL_UM
        holo = calc_hologram(MieWave(Sphere(a, n), optics), (xc, yc, z), grid, 0.9)
        start = {"x_um": xc + 0.05, "y_um": yc - 0.04, "z_um": z + 0.2, "radius_um": a * 1.02,
                 "n": n + 0.01, "alpha": 0.85}
        frames.append(SphereFrame(holo, corner, (xc, yc), noise_sd=0.01, start=start))
    return frames


def test_a_stated_index_is_held_or_a_prior_pulls_toward_it():
    """Noise-free frames of two spheres of index 1.59: held at 1.59 the NA and coefficients
    are exact; a tight prior at 1.60 holds every index near 1.60, a loose one leaves the data
    to decide."""
    ab = Aberration((-3.63, 11.89))
    truth = Optics(0.66, 1.33, 0.0, 1.15, ab)
    frames = _frames(truth, ((6.0, 0.5, 1.59), (12.0, 0.5, 1.59)))
    start = Optics(0.66, 1.33, 0.0, 1.18, Aberration((-3.0, 10.0)))
    held = calibrate_instrument(frames, start, PIXEL_UM,
                                JointFitSettings(fix_index=1.59, aberration_starts=()))
    assert held.values["numerical_aperture"] == pytest.approx(1.15, abs=1e-6)
    assert held.values["sa4_rad"] == pytest.approx(-3.63, abs=1e-3)
    assert all(f.values["n"] == 1.59 and math.isnan(f.errors["n"]) for f in held.frames)
    tight = calibrate_instrument(frames, truth, PIXEL_UM, JointFitSettings(
        fit_na=False, priors=(("n", (1.60, 1e-5)),), aberration_starts=()))
    assert all(abs(f.values["n"] - 1.60) < 1e-4 for f in tight.frames)
    loose = calibrate_instrument(frames, truth, PIXEL_UM, JointFitSettings(
        fit_na=False, priors=(("n", (1.60, 10.0)),), aberration_starts=()))
    assert all(abs(f.values["n"] - 1.59) < 1e-5 for f in loose.frames)
    with pytest.raises(ValueError, match="both fixed"):
        JointFitSettings(fix_index=1.59, priors=(("n", (1.6, 0.1)),))
    with pytest.raises(ValueError, match="only on"):
        JointFitSettings(priors=(("alpha", (1.0, 0.1)),))
