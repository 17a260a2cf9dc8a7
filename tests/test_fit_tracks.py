"""Tracks as rows, not stops: each track gets the model that fits it (a statistical test on
chi^2 between the run's models), and a track no model fits is left out with its cause and the
remedy while the others go on (issue 36)."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from holofit.fit.models import DECISIVE_BIC, ModelFits, choose_model, parameter_count
from holofit.particles import Sphere, Spherocylinder

N_PIX = 10_000


def _rows(particle, chi2_red, n=5, status="ok"):
    """Initial rows of one track whose chi^2 per pixel is ``chi2_red`` (noise 0.01)."""
    return pd.DataFrame({"particle": particle, "frame": np.arange(n), "status": status,
                         "chi2": chi2_red * 1e-4, "noise_sd": 0.01, "n_pixels": N_PIX})


def test_the_model_of_lowest_bic_wins_and_a_simpler_one_within_the_margin():
    rod = Spherocylinder(0.3, 0.7, 1.45)
    k_rod = parameter_count(rod, ("x_um", "y_um", "z_um", "orientation", "alpha", "a_um",
                                  "b_um", "n"))
    k_sphere = parameter_count(Sphere(0.4, 1.5), ("x_um", "y_um", "z_um", "orientation",
                                                  "alpha", "radius_um", "n"))
    assert (k_rod, k_sphere) == (9, 6)
    # track 0 a sphere: the rod model (a ~ b) gains a few chi^2 units of noise, far below
    # k ln N; track 1 a rod: the sphere misses it by thousands
    rods = pd.concat([_rows(0, 1.0 - 2e-4), _rows(1, 1.0)])
    spheres = pd.concat([_rows(0, 1.0), _rows(1, 1.8)])
    fits = [ModelFits("spherocylinder", rods, k_rod), ModelFits("sphere", spheres, k_sphere)]
    zero, one = choose_model(fits, 0), choose_model(fits, 1)
    assert zero.label == "sphere" and one.label == "spherocylinder"
    assert zero.n_frames == one.n_frames == 5
    gain = 5 * 2e-4 * N_PIX  # the rod model's chi^2 gain on the sphere track
    assert zero.bic["spherocylinder"] == pytest.approx(zero.bic["sphere"] - gain
                                                       + 5 * 3 * np.log(N_PIX))
    # a more complex model must beat a simpler one by the decisive margin
    close = pd.concat([_rows(0, 1.0 - (3 * np.log(N_PIX) + DECISIVE_BIC / 10) / N_PIX)])
    near = [ModelFits("spherocylinder", close, k_rod), fits[1]]
    assert choose_model(near, 0).label == "sphere"
    # frames one model did not converge on are left out of the comparison
    spheres2 = spheres.copy()
    spheres2.loc[spheres2["frame"] == 0, "status"] = "not_converged"
    assert choose_model([fits[0], ModelFits("sphere", spheres2, k_sphere)], 1).n_frames == 4


@pytest.fixture(scope="module")
def three_spheres(tmp_path_factory):
    """Three spheres (radii 0.5, 0.4 and 0.6 um, ~10 um apart) through crop and prefit; the
    track of the largest."""
    from holofit.config import load_instrument, resolve_config
    from holofit.crop import CropConfig, run_crop
    from holofit.prefit.stage import run_prefit
    from holofit.simulate.field_of_view import ParticleInView, simulate_field_of_view

    out = tmp_path_factory.mktemp("three")
    inst = load_instrument(resolve_config("paper_100x_oil", "instruments"))
    rng = np.random.default_rng(2)
    n = 10

    def walk(x0, y0, z):
        w = 0.02 * np.cumsum(rng.normal(size=(n, 2)), axis=0)
        return np.column_stack([x0 + w[:, 0], y0 + w[:, 1], np.full(n, z)])

    particles = [ParticleInView(Sphere(0.5, 1.59), walk(5.0, 5.0, 10.0)),
                 ParticleInView(Sphere(0.4, 1.59), walk(16.0, 5.0, 12.0)),
                 ParticleInView(Sphere(0.6, 1.59), walk(10.0, 14.0, 11.0))]
    sim = simulate_field_of_view(particles, inst, (192, 240), out_dir=out / "sim", seed=3)
    crop = run_crop(sim.movie, sim.background, inst, out / "crop",
                    CropConfig(size=64, plot=False))
    run_prefit(crop.out_dir, out / "prefit", plot=False)
    frames = crop.frames[crop.frames["frame"] == 0]
    big = int(frames.loc[(frames["y_px"] * inst.pixel_size_um - 14.0).abs().idxmin(),
                         "particle"])
    return crop.out_dir, out / "prefit", big


def test_a_track_no_model_fits_is_left_out_and_the_others_go_on(three_spheres, tmp_path):
    """The 0.6 um sphere's fits end outside the radius range searched (0.3-0.55 um): its
    initial pass has no ok frame. It is left out with the cause (the rule, the frames) and
    the remedy; the other two tracks are fitted; the CLI exits 0 and says so."""
    from click.testing import CliRunner

    import holofit
    from holofit.cli import main
    from holofit.quality import QualityLimits

    crop_dir, prefit, big = three_spheres
    cfg = holofit.load_particle("sphere_ps_1um")
    limits = QualityLimits(ranges={"radius_um": (0.3, 0.55)})
    config = holofit.FitConfig(cfg, initial_frames=3, frame=holofit.FrameFitSettings(
        quality=limits), plot=False)
    run = holofit.run_fit(crop_dir, prefit, None, tmp_path / "fit", config,
                          batch=holofit.BatchSettings(workers=0, progress=False))
    assert list(run.left_out) == [big], run.left_out
    tracks = pd.read_csv(tmp_path / "fit" / "tracks.csv").set_index("particle")
    assert tracks.loc[big, "status"] == "left_out"
    assert "radius_um" in tracks.loc[big, "reason"] and "outside" in tracks.loc[big, "reason"]
    assert "another kind of particle" in tracks.loc[big, "remedy"]
    assert (tracks.drop(index=big)["status"] == "fitted").all()
    # the final pass's rewrite keeps the initial frames each track was judged on
    assert (tracks["n_initial_frames"] == 3).all(), tracks["n_initial_frames"]
    static = json.loads((tmp_path / "fit" / "static.json").read_text())
    assert static["tracks"][str(big)]["status"] == "left_out"
    fit = pd.read_csv(run.final)
    mine = fit[fit["particle"] == big]
    assert (mine["status"] == "skipped").all() and mine["message"].str.contains("left out").all()
    assert (fit[fit["particle"] != big]["status"] == "ok").mean() > 0.9
    res = CliRunner().invoke(main, [
        "fit", str(crop_dir), "--prefit", str(prefit), "-p", "sphere_ps_1um", "-o",
        str(tmp_path / "cli"), "--initial-frames", "3", "--no-plot", "-j", "0",
        "--exclude-particle", str(big)])
    assert res.exit_code == 0, res.output
    cli = pd.read_csv(tmp_path / "cli" / "fit.csv")
    assert big not in set(cli["particle"]) and len(set(cli["particle"])) == 2
