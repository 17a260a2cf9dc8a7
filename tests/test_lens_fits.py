"""The objective lens in the fits: the NA as a fit parameter, the prefit through the lens, near
and below the focal plane, the stage and command-line options.

Truths: the lens image itself (:func:`holofit.scattering.lens.lens_field_on_pixels`, checked
against a brute-force pupil integral in tests/test_lens.py), a dense numerical azimuthal
average, central differences of lens holograms computed directly, and simulations with known
truth (the particle, its height and the NA they were made with).
"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from holofit.batch.aperture import fit_instrument, parse_numerical_aperture
from holofit.cli import main
from holofit.config import load_instrument
from holofit.config_schema import ConfigError
from holofit.conventions import DetectorGrid, euler_zyz, hologram_intensity
from holofit.hologram import calc_hologram
from holofit.holomodel.aperture import scan_aperture
from holofit.holomodel.forward import HologramModel, InvalidParameters
from holofit.holomodel.parameters import ParameterSpace, State
from holofit.optics import Optics
from holofit.particles import Sphere, Spherocylinder
from holofit.prefit.estimate import SearchSpace
from holofit.prefit.profile import profile_terms
from holofit.prefit.sphere import SphereFitSettings, fit_sphere_crop
from holofit.prefit.stage import run_prefit
from holofit.scattering.lens import lens_field_on_pixels
from holofit.scattering.lens_lines import SphereLensLines
from holofit.scattering.mie import LorenzMie, MieWave
from holofit.simulate.holograms import simulate_movie
from tests.conftest import CONFIGS
from tests.prefit_helpers import make_crops_from_movie

LENS = Optics(0.66, 1.33, 0.0, 1.2)
SPHERE = ("x_um", "y_um", "z_um", "radius_um", "n", "alpha")


@pytest.mark.parametrize("na, pol", [(0.9, 0.0), (1.2, 0.5), (1.45, 1.2)])
def test_sphere_lines_are_the_lens_image_on_two_lines(na, pol):
    optics = Optics(0.66, 1.33, pol, na)
    z = np.array([-6.0, -1.0, 0.0, 0.4, 3.0, 12.0, 40.0])
    rho = np.linspace(0.0, 9.0, 57)
    lines = SphereLensLines(optics, z, rho, order=40)
    for sphere in (Sphere(0.3, 1.45), Sphere(1.1, 1.6)):
        wave = MieWave(sphere, optics)
        p, b = lines(wave)
        cb, sb = np.cos(pol), np.sin(pol)
        xs = np.concatenate([rho * cb, -rho * sb])
        ys = np.concatenate([rho * sb, rho * cb])
        for i, zi in enumerate(z):
            ex, ey = lens_field_on_pixels(wave, (0.0, 0.0, zi), xs, ys)
            ref = ex * cb + ey * sb
            got = np.concatenate([p[i], b[i]])
            # the lines are exact; the camera image is interpolated from the lens's polar grid
            # (holofit.scattering.lens_transform: within 1e-6 of the field, as in test_lens)
            assert np.abs(got - ref).max() <= 1e-6 * np.abs(ref).max(), (sphere, zi)
    with pytest.raises(ValueError, match="set up for 40"):
        lines(MieWave(Sphere(3.0, 1.5), optics))


def test_lens_profile_terms_equal_a_dense_average_of_the_lens_hologram():
    optics = Optics(0.66, 1.33, 0.35, 1.1)
    wave = MieWave(Sphere(0.8, 1.55), optics)
    z, rho, alpha = -4.0, np.linspace(0.1, 8, 30), 0.8
    phis = np.linspace(0, 2 * np.pi, 181)[:-1]
    xs = (rho[None, :] * np.cos(phis)[:, None]).ravel()
    ys = (rho[None, :] * np.sin(phis)[:, None]).ravel()
    ex, ey = lens_field_on_pixels(wave, (0.0, 0.0, z), xs, ys)
    dense = hologram_intensity(ex, ey, optics.polarization_rad, alpha).reshape(phis.size, -1)
    lin, quad = profile_terms(wave, [z], rho)
    np.testing.assert_allclose(1 + 2 * alpha * lin[0] + alpha**2 * quad[0], dense.mean(axis=0),
                               atol=1e-7)


def _space(na_start, free=(*SPHERE, "numerical_aperture")):
    state = State((5.0, 5.0, 8.0), None, 0.85, (("radius_um", 0.55), ("n", 1.5)), na_start)
    return ParameterSpace(Sphere(0.55, 1.5), free, state,
                          step_overrides={"radius_um": 1e-5, "n": 1e-5})


def test_aperture_is_an_optics_parameter_reported_only_when_fitted():
    space = _space(1.1)
    assert space.names[-1] == "numerical_aperture"
    assert space.parameters[-1].kind == "optics"
    v = space.initial_vector()
    assert v[-1] == 1.1
    v[-1] = 0.95
    assert space.state(v).numerical_aperture == 0.95
    values, errors = space.report(v, np.eye(v.size) * 4e-6)
    assert values["numerical_aperture"] == 0.95 and errors["numerical_aperture"] == 0.002
    held = _space(1.1, SPHERE)
    values, _ = held.report(held.initial_vector())
    assert "numerical_aperture" not in values  # a held NA is the instrument's: not a column
    assert held.state(held.initial_vector()).numerical_aperture == 1.1
    with pytest.raises(ValueError, match="needs a start value"):
        _space(None)


def test_holding_the_aperture_keeps_the_meaning_of_the_other_components():
    # a rod, its orientation already moved by the optimiser: the space without the NA must
    # map its share of the vector onto the same particle state
    rod = Spherocylinder(0.5, 1.0, 1.5)
    start = State((5.0, 5.0, 8.0), euler_zyz(0.4, 1.1, 0.0), 0.9,
                  (("a_um", 0.5), ("b_um", 1.0), ("n", 1.5)), 1.2)
    space = ParameterSpace(rod, ("x_um", "z_um", "orientation", "alpha", "b_um",
                                 "numerical_aperture"), start)
    v = space.initial_vector()
    v[space.names.index("rot_a")] = 0.2
    v[space.names.index("rot_b")] = -0.1
    v[space.names.index("numerical_aperture")] = 0.9
    v[space.names.index("b_um")] = 1.1
    held, index = space.holding("numerical_aperture", v)
    assert "numerical_aperture" not in held.names and len(index) == len(v) - 1
    a, b = space.state(v), held.state(v[index])
    np.testing.assert_allclose(b.rotation, a.rotation, atol=1e-14)
    assert b.position == a.position and b.statics == a.statics and b.alpha == a.alpha
    assert b.numerical_aperture == 0.9


def test_aperture_column_reimages_the_solved_wave():
    grid = DetectorGrid((60, 60), 0.1)
    x, y = (c.ravel() for c in grid.coordinates())
    model = HologramModel(LorenzMie(), _space(0.9), LENS, x, y)
    v = model.space.initial_vector()
    jac = model.jacobian(v)
    assert model.n_solves == 3  # the wave, the radius and index columns: none for the NA
    # central difference of lens holograms computed directly at NA +- h
    wave = MieWave(Sphere(0.55, 1.5), LENS)
    h = 1e-4
    holo = [hologram_intensity(*lens_field_on_pixels(wave, (5.0, 5.0, 8.0), x, y, na), 0.0,
                               0.85) for na in (0.9 + h, 0.9 - h)]
    central = (holo[0] - holo[1]) / (2 * h)
    assert np.abs(jac[:, -1] - central).max() <= 0.02 * np.abs(central).max()
    # at the medium's index the lens collects everything: the column looks toward smaller NAs
    v[-1] = 1.33
    assert np.abs(model.jacobian(v)[:, -1]).max() > 0
    v[-1] = -0.1
    with pytest.raises(InvalidParameters, match="not positive"):
        model.hologram(v)


def test_focal_plane_through_the_particle_is_valid_only_through_the_lens():
    grid = DetectorGrid((30, 30), 0.1)
    x, y = (c.ravel() for c in grid.coordinates())
    space = _space(None, SPHERE)
    v = space.initial_vector()
    v[2] = 0.2  # the focal plane cuts the 0.55 um sphere
    ideal = HologramModel(LorenzMie(), space, Optics(0.66, 1.33, 0.0), x, y)
    with pytest.raises(InvalidParameters, match="cuts the particle"):
        ideal.hologram(v)
    lens = HologramModel(LorenzMie(), space, LENS, x, y)
    wave = MieWave(Sphere(0.55, 1.5), LENS)
    direct = hologram_intensity(*lens_field_on_pixels(wave, (5.0, 5.0, 0.2), x, y), 0.0, 0.85)
    np.testing.assert_allclose(lens.hologram(v), direct, rtol=0, atol=1e-12)


def _lens_crop(z, na, size=100, a=0.5, n=1.59, alpha=0.9, noise=0.01, seed=0):
    optics = Optics(0.66, 1.33, 0.0, na)
    corner = (40, 60)
    grid = DetectorGrid((size, size), 0.1, corner)
    xc, yc = (corner[1] + size / 2 - 0.3) * 0.1, (corner[0] + size / 2 + 0.2) * 0.1
    holo = calc_hologram(MieWave(Sphere(a, n), optics), (xc, yc, z), grid, alpha)
    holo += np.random.default_rng(seed).normal(0.0, noise, holo.shape)
    # the crop stage's centre is within half a pixel
    return holo, corner, (xc + 0.03, yc - 0.04), (xc, yc)


def test_fitted_aperture_recovers_the_objective():
    # 0.95 um sphere 6 um above focus; the crop reaches 40 deg, past the NA 0.8 cut (37 deg)
    holo, corner, centre, (xc, yc) = _lens_crop(6.0, 0.8)
    model = HologramModel(LorenzMie(), _space(1.2), LENS, np.zeros(1), np.zeros(1))
    assert model.aperture(State((0, 0, 1), None, 1.0)) == 1.2  # the optics' when not fitted
    fit = fit_sphere_crop(holo, corner, centre, LENS, 0.1, SphereFitSettings(fit_na=True))
    v, e = fit.values, fit.errors
    assert fit.status == "ok", fit.message
    assert v["numerical_aperture"] == pytest.approx(0.8, abs=3 * e["numerical_aperture"] + 1e-3)
    assert v["z_um"] == pytest.approx(6.0, abs=0.01)
    assert v["radius_um"] == pytest.approx(0.5, abs=0.003)
    assert v["n"] == pytest.approx(1.59, abs=0.003)
    assert abs(v["x_um"] - xc) < 0.01 and abs(v["y_um"] - yc) < 0.01


def test_aperture_scan_finds_the_global_minimum():
    # the misfit in NA alone has local minima every few hundredths; a local fit from 1.2
    # stays in one, the scan does not
    holo, corner, _, (xc, yc) = _lens_crop(10.0, 1.0, noise=0.0)
    x, y = (c.ravel() for c in DetectorGrid(holo.shape, 0.1, corner).coordinates())
    state = State((xc, yc, 10.0), None, 0.9, (("radius_um", 0.5), ("n", 1.59)), 1.2)
    model = HologramModel(LorenzMie(), ParameterSpace(Sphere(0.5, 1.59),
                                                      ("numerical_aperture",), state),
                          LENS, x, y)
    best, grid, rss = scan_aperture(model, holo.ravel(), np.array([1.2]))
    assert best[0] == pytest.approx(1.0, abs=1e-9)
    assert grid[0] == pytest.approx(0.2) and grid[-1] == pytest.approx(1.33)
    local = ((rss[1:-1] < rss[:-2]) & (rss[1:-1] < rss[2:])).sum()
    assert local >= 5  # rugged: many local minima


@pytest.mark.parametrize("z", [-3.0, 1.0])
def test_prefit_through_the_lens_near_and_below_focus(z):
    holo, corner, centre, (xc, yc) = _lens_crop(z, 1.2)
    search = SearchSpace(z_range_um=(-6.0, -1.0) if z < 0 else (0.5, 3.0))
    fit = fit_sphere_crop(holo, corner, centre, LENS, 0.1, SphereFitSettings(search=search))
    v = fit.values
    assert fit.status == "ok", fit.message
    assert v["z_um"] == pytest.approx(z, abs=0.005)
    assert v["radius_um"] == pytest.approx(0.5, abs=0.002)
    assert v["n"] == pytest.approx(1.59, abs=0.002)
    assert v["alpha"] == pytest.approx(0.9, abs=0.005)
    assert abs(v["x_um"] - xc) < 0.005 and abs(v["y_um"] - yc) < 0.005
    # the default search (2 um and up) cannot reach them: flagged, not passed off as ok
    if z < 0:
        default = fit_sphere_crop(holo, corner, centre, LENS, 0.1)
        assert default.status == "poor_fit"
    # the ideal model cannot describe a particle below the focus at all
    with pytest.raises(ValueError, match="below the focal plane"):
        fit_sphere_crop(holo, corner, centre, Optics(0.66, 1.33, 0.0), 0.1,
                        SphereFitSettings(search=SearchSpace(z_range_um=(-10.0, -0.5))))


def test_numerical_aperture_choices():
    inst = load_instrument(CONFIGS / "instruments" / "holopy_image0001.toml")
    assert inst.optics.numerical_aperture == 1.4
    inst = inst.with_numerical_aperture(None)
    assert inst.optics.numerical_aperture is None and "numerical_aperture" not in inst.as_dict()
    assert fit_instrument(inst, 1.3).optics.numerical_aperture == 1.3
    assert fit_instrument(inst, 1.3).as_dict()["numerical_aperture"] == 1.3
    assert fit_instrument(fit_instrument(inst, 1.3), None).optics.numerical_aperture is None
    assert fit_instrument(inst).optics.numerical_aperture is None
    with pytest.raises(ConfigError, match=r"holopy-image0001.*no numerical_aperture"):
        fit_instrument(inst, fit=True)
    assert parse_numerical_aperture("none") is None
    assert parse_numerical_aperture(" 1.25") == 1.25
    for bad in ("-1", "big", "0"):
        with pytest.raises(ValueError):
            parse_numerical_aperture(bad)


@pytest.fixture(scope="module")
def lens_crops(tmp_path_factory):
    """Two frames of a sphere through the paper's 100x oil objective (NA 1.40)."""
    tmp = tmp_path_factory.mktemp("lens")
    inst = load_instrument(CONFIGS / "instruments" / "paper_100x_oil.toml")
    px = inst.pixel_size_um
    pos = np.array([[60 * px, 61 * px, 9.0], [61 * px, 60 * px, 12.0]])
    sim = simulate_movie(Sphere(0.6, 1.55), inst, pos, (120, 120), seed=2, out_dir=tmp)
    centres = [(x / px + 0.3, y / px - 0.2) for x, y, _ in pos]
    return make_crops_from_movie(sim.movie, sim.background, centres, 90, inst, tmp / "crops")


def _invoke(*args):
    return CliRunner().invoke(main, [*map(str, args), "--no-progress"])


def test_prefit_options_set_and_fit_the_aperture(lens_crops, tmp_path):
    res = _invoke("prefit", lens_crops, "-o", tmp_path / "fit", "-j", "0", "--no-plot",
                  "--numerical-aperture", "1.2", "--fit-na")
    assert res.exit_code == 0, res.output
    table = pd.read_csv(tmp_path / "fit" / "prefit.csv")
    assert {"numerical_aperture", "d_numerical_aperture"} <= set(table.columns)
    assert (table["status"] == "ok").all()
    # the truth is 1.40, beyond the medium's 1.33: every propagating wave is collected. The
    # crops reach 37 deg (NA 0.8) at most; larger NAs show only in the faint ring the pupil's
    # edge sends over the image, whose misfit has minima of nearly equal depth (with this
    # camera noise the best is 1.08, the truth a few units of chi^2 worse): the error says so
    na, d_na = table["numerical_aperture"], table["d_numerical_aperture"]
    assert ((na - 1.33).abs() <= 2 * d_na + 0.01).all()
    assert (d_na > 0.05).all()
    side = json.loads((tmp_path / "fit" / "prefit.csv.json").read_text())
    assert side["config"]["instrument"]["numerical_aperture"] == 1.2
    assert side["config"]["fit"]["fit_na"] is True
    res = _invoke("prefit", lens_crops, "-o", tmp_path / "ideal", "-j", "0", "--no-plot",
                  "--numerical-aperture", "none")
    assert res.exit_code == 0, res.output
    ideal = pd.read_csv(tmp_path / "ideal" / "prefit.csv")
    assert "numerical_aperture" not in ideal.columns
    side = json.loads((tmp_path / "ideal" / "prefit.csv.json").read_text())
    assert "numerical_aperture" not in side["config"]["instrument"]
    res = _invoke("prefit", lens_crops, "-o", tmp_path / "bad", "--numerical-aperture", "wide")
    assert res.exit_code == 2 and "--numerical-aperture" in res.output
    res = _invoke("prefit", lens_crops, "-o", tmp_path / "bad", "--numerical-aperture", "none",
                  "--fit-na")
    assert res.exit_code == 1 and "needs a start value" in res.output
    res = _invoke("prefit", lens_crops, "-o", tmp_path / "bad", "--numerical-aperture", "none",
                  "--z-range", "-10,-2")
    assert res.exit_code == 1 and "below the focal plane" in res.output


def test_prefit_stage_keeps_the_instrument_aperture(lens_crops, tmp_path):
    result = run_prefit(lens_crops, tmp_path / "o", plot=False)
    side = json.loads(result.table.with_suffix(".csv.json").read_text())
    assert side["config"]["instrument"]["numerical_aperture"] == 1.4
    table = pd.read_csv(result.table)
    assert (table["status"] == "ok").all()
    np.testing.assert_allclose(table["z_um"], [9.0, 12.0], atol=0.05)


def test_fit_stage_fits_the_aperture_and_draws_it(lens_crops, tmp_path):
    # the sphere's "DDA fit" stage with the exact Lorenz-Mie engine (the config has no [dda])
    res = _invoke("prefit", lens_crops, "-o", tmp_path / "prefit", "-j", "0", "--no-plot")
    assert res.exit_code == 0, res.output
    args = ["fit", lens_crops, "--prefit", tmp_path / "prefit", "-p", "sphere_ps_1um", "-j", "0",
            "--pass", "initial", "--initial-frames", "2"]
    res = _invoke(*args, "-o", tmp_path / "fit", "--numerical-aperture", "1.3", "--fit-na",
                  "--plot-frames", "0")
    assert res.exit_code == 0, res.output
    table = pd.read_csv(tmp_path / "fit" / "initial.csv")
    assert {"numerical_aperture", "d_numerical_aperture"} <= set(table.columns)
    assert (table["status"] == "ok").all()
    np.testing.assert_allclose(table["z_um"], [9.0, 12.0], atol=0.05)
    np.testing.assert_allclose(table["radius_um"], 0.6, atol=0.01)
    side = json.loads((tmp_path / "fit" / "initial.csv.json").read_text())
    assert "numerical_aperture" in side["config"]["free"]
    assert side["config"]["instrument"]["numerical_aperture"] == 1.3
    assert (tmp_path / "fit" / "frames_initial" / "frame_000000.png").exists()
    res = _invoke(*args, "-o", tmp_path / "bad", "--numerical-aperture", "none", "--fit-na")
    assert res.exit_code == 1 and "needs a start value" in res.output
