"""Each track analysed with its own model, against simulated tracks with known truth.

A fit of a population (a rod run that also fits spheres) writes a table whose rows name the
particle model each track was given, and a table of tracks with the tracks it left out
(:mod:`holofit.fit.track_status`). Here both are built from Brownian simulations
(:mod:`holofit.simulate.brownian`): a paper rod, two 1 um spheres (whose rows, like the fit's,
hold no orientation and no rod lengths) and a track the fit left out.
"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from holofit.analysis import AnalysisConfig, AnalysisError, TrackSelection, analyze_tracks
from holofit.analysis.hydrodynamics import sphere_diffusion
from holofit.analysis.population import (
    analysis_model_of,
    model_from_sidecar,
    read_fit_tracks,
    settings_for_model,
)
from holofit.analysis.track_tables import write_tracks
from holofit.cli import main
from holofit.simulate.brownian import BrownianParameters, MeasurementNoise, simulate_trajectory
from holofit.studies.diffusion import PAPER_ROD as ROD

DT = 0.01
D_SPHERE = sphere_diffusion(0.5, 21.0)["D_t"]  # a 1 um sphere in water at 21 C, um^2/s
ORIENTATION = ("ux", "uy", "uz", "theta_rad", "psi_rad", "phi_rad")
#: the fit's reason and remedy for the track it left out (as holofit.fit.track_status words them)
LEFT_OUT_REASON = ("no model of the run fits it: its initial pass (spherocylinder) has no ok "
                   "frame: 12 poor_fit (frames 0-220)")
LEFT_OUT_REMEDY = "no model of the run describes its hologram: give its model with another -p"


def _rod(particle: int, n: int, seed: int) -> pd.DataFrame:
    sim = simulate_trajectory(
        BrownianParameters(n, DT, ROD["d_par"], ROD["d_perp"], ROD["d_r"]),
        MeasurementNoise(ROD["eps_um"], None, ROD["eps_r"], ROD["flip"], ROD["mirror"]),
        seed=seed, static={"a_um": 0.501, "b_um": 1.079})
    return sim.table.assign(particle=particle, model="spherocylinder", radius_um=np.nan)


def _sphere(particle: int, n: int, seed: int) -> pd.DataFrame:
    sim = simulate_trajectory(
        BrownianParameters(n, DT, D_SPHERE, D_SPHERE, 1.0,
                           start_position_um=(15.0 * particle, 10.0, 15.0)),
        MeasurementNoise(eps_xy_um=0.01), seed=seed, static={"radius_um": 0.5})
    t = sim.table.assign(particle=particle, model="sphere", a_um=np.nan, b_um=np.nan)
    t[list(ORIENTATION)] = np.nan  # a sphere's fit has no orientation
    return t


def _left_out(particle: int, n: int) -> pd.DataFrame:
    """The final-pass rows of a track the initial pass left out: every frame skipped."""
    return pd.DataFrame({"frame": np.arange(n), "time_s": np.arange(n) * DT,
                         "status": "skipped", "particle": particle, "model": "spherocylinder",
                         "message": f"track {particle} left out (unmodelled): "
                                    f"{LEFT_OUT_REASON}"})


def _fit_folder(root, rod_frames: int = 1000, sphere_frames: int = 600):
    """``root/fit``: fit.csv (+ sidecar) and the fit's tracks.csv, of tracks 0 (rod),
    1 and 3 (spheres) and 2 (left out)."""
    fit = root / "fit"
    fit.mkdir(parents=True)
    table = pd.concat([_rod(0, rod_frames, 0), _sphere(1, sphere_frames, 4),
                       _left_out(2, 200), _sphere(3, sphere_frames, 5)], ignore_index=True)
    table.to_csv(fit / "fit.csv", index=False)
    (fit / "fit.csv.json").write_text(json.dumps({
        "frame_interval_s": DT, "particle_model": "spherocylinder",
        "config": {"particle": {"model": "spherocylinder", "a_um": 0.5, "b_um": 1.08}}}))
    tracks = pd.DataFrame([
        {"particle": 0, "model": "spherocylinder", "status": "fitted",
         "reason": "BIC lower by 900", "remedy": "", "static_a_um": 0.501, "static_b_um": 1.079},
        {"particle": 1, "model": "sphere", "status": "fitted", "reason": "BIC lower by 400",
         "remedy": "", "static_radius_um": 0.5},
        {"particle": 2, "model": "spherocylinder", "status": "unmodelled",
         "reason": LEFT_OUT_REASON, "remedy": LEFT_OUT_REMEDY},
        {"particle": 3, "model": "sphere", "status": "fitted", "reason": "BIC lower by 380",
         "remedy": "", "static_radius_um": 0.5}])
    tracks.to_csv(fit / "tracks.csv", index=False)
    (fit / "tracks.csv.json").write_text(json.dumps(
        {"kind": "the fit's tracks: one row per track, its model, statics and status"}))
    return fit / "fit.csv"


@pytest.fixture(scope="module")
def mixed(tmp_path_factory):
    return _fit_folder(tmp_path_factory.mktemp("mixed"))


#: the settings of a rod run (what holofit analyze takes from the fit's sidecar)
ROD_RUN = AnalysisConfig(model="rod", temperature_c=21.0)


def test_each_track_is_analysed_with_its_own_model_and_pooled_with_its_own(mixed, tmp_path):
    res = analyze_tracks(mixed, ROD_RUN)
    by = {t.particle: t for t in res.tracks}
    assert {p: t.status for p, t in by.items()} == {
        0: "analysed", 1: "analysed", 2: "unmodelled", 3: "analysed"}
    assert res.models == {0: "rod", 1: "sphere", 2: "", 3: "sphere"}
    # the rod turns: D_par, D_perp, D_r, each within 3 sigma of the simulation's
    rod = by[0].result.measured
    for q, truth in (("D_par", ROD["d_par"]), ("D_perp", ROD["d_perp"]), ("D_r", ROD["d_r"])):
        assert abs(rod[q].pull(truth)) < 3, (q, rod[q], truth)
    # a sphere translates only: no rotational diffusion, no axis, no rod coefficients
    for p in (1, 3):
        m = by[p].result.measured
        assert abs(m["D_t"].pull(D_SPHERE)) < 3, (p, m["D_t"])
        assert not {"D_r", "D_par", "D_perp", "eps_r"} & set(m), sorted(m)
        assert by[p].result.settings.model == "sphere"
        assert by[p].result.sizes["a_um"][0] == pytest.approx(0.5)  # its radius, not the rod's
    # pooled within a model only: the spheres' D_t apart from the rod's
    assert set(res.pooled) == {("rod", "D_t"), ("rod", "D_par"), ("rod", "D_perp"),
                               ("rod", "D_r"), ("sphere", "D_t")}
    assert res.pooled[("rod", "D_t")].particles == [0]
    assert res.pooled[("sphere", "D_t")].particles == [1, 3]
    assert abs(res.pooled[("sphere", "D_t")].value - D_SPHERE) < 3 * res.pooled[
        ("sphere", "D_t")].error
    # the track the fit left out keeps the fit's reason and remedy, not 'short: 0 ok frames'
    assert by[2].message == LEFT_OUT_REASON and by[2].remedy == LEFT_OUT_REMEDY
    assert by[2].kind == "spherocylinder" and by[2].result is None
    files = write_tracks(res, tmp_path, inputs=[mixed])
    table = pd.read_csv(files["tracks"]).set_index("particle")
    assert list(table.index) == [0, 1, 2, 3]  # one row per track
    assert table.loc[2, "reason"] == LEFT_OUT_REASON
    assert table.loc[2, "remedy"] == LEFT_OUT_REMEDY
    assert np.isnan(table.loc[1, "D_r"]) and np.isfinite(table.loc[0, "D_r"])
    assert table.loc[1, "static_radius_um"] == 0.5 and table.loc[0, "static_b_um"] == 1.079
    pooled = pd.read_csv(files["pooled"])
    assert sorted(zip(pooled["model"], pooled["quantity"], strict=True)) == sorted(res.pooled)
    side = json.loads((tmp_path / "tracks.csv.json").read_text())
    assert side["models"]["1"] == {"model": "sphere", "particle_model": "sphere",
                                   "source": "the fit's particle, a sphere",
                                   "status": "analysed"}


def test_a_model_given_for_all_is_every_tracks(mixed):
    # --model rod imposed: the spheres are analysed as rods, which need an axis they lack
    res = analyze_tracks(mixed, ROD_RUN, selection=TrackSelection(model="rod"))
    by = {t.particle: t for t in res.tracks}
    assert by[1].status == "failed" and "rod analysis" in by[1].message
    assert by[0].status == "analysed" and by[2].status == "unmodelled"
    assert {m for m, _ in res.pooled} == {"rod"}


def test_the_selection_leaves_tracks_out_as_rows(mixed):
    res = analyze_tracks(mixed, ROD_RUN, selection=TrackSelection(exclude_particles=(3, 0)))
    by = {t.particle: t for t in res.tracks}
    assert by[3].status == "excluded" and "--exclude-particle 3" in by[3].message
    assert by[0].status == "excluded" and by[0].result is None
    assert res.pooled[("sphere", "D_t")].particles == [1]
    assert set(res.pooled) == {("sphere", "D_t")}
    only = analyze_tracks(mixed, ROD_RUN, selection=TrackSelection(particles=(1,)))
    assert [t.particle for t in only.tracks if t.result is not None] == [1]
    with pytest.raises(AnalysisError, match=r"no track\(s\) \[9\] \(tracks: 0, 1, 2, 3\)"):
        analyze_tracks(mixed, ROD_RUN, selection=TrackSelection(exclude_particles=(9,)))
    with pytest.raises(AnalysisError, match="leave no track"):
        analyze_tracks(mixed, ROD_RUN, selection=TrackSelection(particles=(1,),
                                                                exclude_particles=(1,)))


def test_settings_of_another_model_take_its_defaults_and_its_own_sizes() -> None:
    rod = AnalysisConfig(model="rod", a_um=0.25, b_um=1.0, temperature_c=25.0)
    sphere = settings_for_model(rod, "sphere")
    assert (sphere.model, sphere.head_tail, sphere.reject) == ("sphere", False, False)
    assert sphere.a_um is None and sphere.b_um is None and sphere.temperature_c == 25.0
    back = settings_for_model(AnalysisConfig(model="sphere"), "rod")
    assert back.head_tail is True and back.reject is True and back.drop_ambiguous is True
    # a choice that differs from the run model's default is the user's and stays
    kept = settings_for_model(AnalysisConfig(model="rod", head_tail=False), "janus")
    assert kept.head_tail is False
    assert settings_for_model(rod, "rod") is rod


def test_analysis_model_of_each_particle_model() -> None:
    assert {k: analysis_model_of(k)[0] for k in (
        "sphere", "coated_sphere", "spherocylinder", "cylinder", "spheroid", "ellipsoid",
        "janus", "voxels")} == {
        "sphere": "sphere", "coated_sphere": "sphere", "spherocylinder": "rod",
        "cylinder": "rod", "spheroid": "rod", "ellipsoid": "rod", "janus": "janus",
        "voxels": None}
    equal = {"radius1_um": 0.5, "radius2_um": 0.5, "index1": 1.59, "index2": 1.59}
    assert analysis_model_of("dimer", equal)[0] == "rod"
    assert analysis_model_of("dimer", {**equal, "radius2_um": 0.3})[0] is None


def test_only_the_fits_table_of_tracks_is_read(tmp_path) -> None:
    path = tmp_path / "fit.csv"
    assert read_fit_tracks(path) == {}  # none beside it
    pd.DataFrame({"particle": [0], "status": ["analysed"]}).to_csv(tmp_path / "tracks.csv")
    (tmp_path / "tracks.csv.json").write_text(json.dumps({"kind": "diffusion per track"}))
    assert read_fit_tracks(path) == {}  # an analysis' own tracks.csv
    (tmp_path / "tracks.csv.json").unlink()
    pd.DataFrame({"particle": [0]}).to_csv(tmp_path / "tracks.csv")
    with pytest.raises(AnalysisError, match=r"tracks\.csv: the fit's table of tracks has no"):
        read_fit_tracks(path)
    assert model_from_sidecar(path)[0] is None


def test_cli_analyze_a_population_run_folder(tmp_path) -> None:
    fit = _fit_folder(tmp_path, rod_frames=600, sphere_frames=400)
    out = tmp_path / "analysis"
    res = CliRunner().invoke(main, ["analyze", str(fit), "-o", str(out),
                                    "--exclude-particle", "3"])
    assert res.exit_code == 0, res.output
    assert "particle 1: sphere (sphere)" in res.output
    assert f"particle 2: unmodelled: {LEFT_OUT_REASON}; remedy: {LEFT_OUT_REMEDY}" in res.output
    assert "particle 3: excluded: left out by --exclude-particle 3" in res.output
    summary = pd.read_csv(out / "summary.csv")
    assert sorted(summary["particle"].unique()) == [0, 1, 2, 3]
    models = summary.groupby("particle")["model"].first()
    assert models[0] == "rod" and models[1] == "sphere"
    assert not summary[(summary["particle"] == 1) & summary["quantity"].eq("D_r")].shape[0]
    assert summary.loc[summary["particle"] == 2, "track_status"].tolist() == ["unmodelled"]
    for name in ("tracks.csv", "pooled.csv", "tracks.png", "track_msds.png",
                 "particle_0_summary.csv", "particle_1_msd.png"):
        assert (out / name).is_file(), name
    side = json.loads((out / "summary.csv.json").read_text())
    assert side["models"]["0"]["model"] == "rod" and side["models"]["3"]["status"] == "excluded"
    bad = CliRunner().invoke(main, ["analyze", str(fit), "-o", str(out), "--particle", "7",
                                    "--no-plot"])
    assert bad.exit_code == 1 and "no track(s) [7]" in bad.output


def test_a_table_of_one_track_takes_its_own_model(tmp_path) -> None:
    # a rod run whose one track the fit gave the sphere: analysed as a sphere, not a rod
    fit = tmp_path / "fit.csv"
    _sphere(0, 300, 6).to_csv(fit, index=False)
    (tmp_path / "fit.csv.json").write_text(json.dumps(
        {"frame_interval_s": DT, "particle_model": "spherocylinder"}))
    from holofit.analysis import run_analysis

    run = run_analysis(fit, ROD_RUN, tmp_path / "an", plots=False)
    assert run.result is not None and run.result.settings.model == "sphere"
    assert "D_r" not in run.result.measured
    assert abs(run.result.measured["D_t"].pull(D_SPHERE)) < 3
    with pytest.raises(AnalysisError, match=r"no track\(s\) \[4\]"):
        run_analysis(fit, ROD_RUN, tmp_path / "an", selection=TrackSelection(particles=(4,)))
