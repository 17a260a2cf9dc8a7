"""Analysis settings held to the configuration files' rules, errors that name the file once, and
a model added as nothing but a recipe."""

from __future__ import annotations

import dataclasses

import pandas as pd
import pytest
from click.testing import CliRunner

from holofit.analysis import AnalysisConfig, SettingError, Trajectory, analyze_trajectory
from holofit.analysis import recipes as recipes_mod
from holofit.analysis.linefit import linear_msd_model
from holofit.analysis.measurement import Measurement
from holofit.analysis.plots import write_plots
from holofit.analysis.recipes import Compared, Curve, MsdPanel, Probe, Recipe
from holofit.analysis.summary import write_summary
from holofit.cli import main
from holofit.config import ConfigError, load_particle
from holofit.simulate.brownian import BrownianParameters, MeasurementNoise, simulate_trajectory
from holofit.tables.fit import validate_fit_table


def _sim_table(tmp_path, n=300):
    p = BrownianParameters(n, 0.01, 0.5, 0.5, 1.0)
    sim = simulate_trajectory(p, MeasurementNoise(0.01), seed=1, static={"radius_um": 0.5},
                              out_dir=tmp_path / "sim")
    return tmp_path / "sim" / "trajectory.csv", sim


def _analyze(*args):
    return CliRunner().invoke(main, ["analyze", *map(str, args), "--no-plots"])


def test_kelvin_for_celsius_and_nm_for_um_are_refused_naming_the_option(tmp_path):
    table, _ = _sim_table(tmp_path)
    res = _analyze(table, "-m", "sphere", "-o", tmp_path / "o", "--temperature-c", "294")
    assert res.exit_code == 2
    assert "--temperature-c" in res.output and "looks like kelvin" in res.output
    assert "use 20.85 C" in res.output  # 294 K - 273.15
    res = _analyze(table, "-m", "sphere", "-o", tmp_path / "o", "--a-um", "500")
    assert res.exit_code == 2
    assert "--a-um" in res.output and "looks like nanometres: use 0.5 um" in res.output
    res = _analyze(table, "-m", "rod", "-o", tmp_path / "o", "--db-um", "250")
    assert res.exit_code == 2 and "--db-um" in res.output and "use 0.25 um" in res.output
    assert not (tmp_path / "o" / "summary.csv").exists()


def test_settings_and_config_files_share_one_rule(tmp_path):
    with pytest.raises(SettingError) as info:
        AnalysisConfig("sphere", a_um=500.0)
    assert info.value.setting == "a_um"
    # the particle-file loader says the same about the same slip
    cfg = tmp_path / "p.toml"
    cfg.write_text('[particle]\nmodel = "sphere"\nradius_um = 500.0\nindex = 1.59\n')
    with pytest.raises(ConfigError) as from_file:
        load_particle(cfg)
    advice = "(500.0 looks like nanometres: use 0.5 um)"
    assert str(info.value).endswith(advice) and str(from_file.value).endswith(advice)
    for kwargs, setting in (
        ({"temperature_c": -300.0}, "temperature_c"),
        ({"temperature_c": float("nan")}, "temperature_c"),
        ({"temperature_err_c": -1.0}, "temperature_err_c"),
        ({"eps_r_est": 10.0}, "eps_r_est"),
        ({"max_lag": 0}, "max_lag"),
        ({"d_est": 0.0}, "d_est"),
        ({"reject_probability": 1.0}, "reject_probability"),
    ):
        with pytest.raises(SettingError) as bad:
            AnalysisConfig("rod", **kwargs)
        assert bad.value.setting == setting
    # in range: accepted (the default analysis of the paper's rod at 21 C)
    assert AnalysisConfig("rod", temperature_c=21.0, a_um=0.5, b_um=1.08).head_tail is True


def test_errors_name_the_table_once(tmp_path):
    three = tmp_path / "three.csv"
    pd.DataFrame({"frame": [0, 1, 2], "time_s": [0, 0.1, 0.2], "status": "ok", "x_um": 0.0,
                  "y_um": 0.0, "z_um": 0.0}).to_csv(three, index=False)
    res = _analyze(three, "-m", "sphere", "-o", tmp_path / "o")
    assert res.exit_code == 1 and "only 3 frames with a fit" in res.output
    assert res.output.count("three.csv") == 1, res.output
    table, _ = _sim_table(tmp_path)
    res = _analyze(table, "-m", "sphere", "-o", tmp_path / "o", "--fit-lags-t", "400:500")
    assert res.exit_code == 1 and "leaves fewer than 2 lags" in res.output
    assert res.output.count("trajectory.csv") == 1, res.output
    res = _analyze(table, "-m", "rod", "-o", tmp_path / "o")
    assert res.exit_code == 0  # the simulated table has an orientation
    no_axis = tmp_path / "no_axis.csv"
    pd.read_csv(table).drop(columns=["ux", "uy", "uz", "theta_rad", "psi_rad"]).to_csv(
        no_axis, index=False)
    res = _analyze(no_axis, "-m", "rod", "-o", tmp_path / "o")
    assert res.exit_code == 1 and "needs the orientation" in res.output
    assert res.output.count("no_axis.csv") == 1, res.output


def test_a_long_given_translation_range_is_fitted_at_every_lag(tmp_path):
    # lags beyond 60 used to be computed on a sparse grid but fitted on the dense one
    _, sim = _sim_table(tmp_path)
    traj = Trajectory.from_fit_table(validate_fit_table(sim.table))
    res = analyze_trajectory(traj, AnalysisConfig("sphere", fit_lags_translation=(1, 100)))
    assert list(res.fits["xy"].lags) == list(range(1, 101))


def _measure_3d(fit, t_lags, r_lags, options):
    f = fit("lab_3d", "lab_3d", linear_msd_model(6, "lab_3d"), t_lags)
    return {"D_t": Measurement(f.value("D"), f.error("D"), "um^2/s")}


def test_a_new_model_is_a_new_recipe(tmp_path, monkeypatch):
    # a sphere tracked in 3-D: nothing but a recipe, run by the unchanged pipeline
    recipe = Recipe(
        name="sphere3d",
        observables=("lab_3d",),
        translation_probe=Probe("lab_3d", lambda: linear_msd_model(6, "lab_3d")),
        rotation=None,
        orientation=False,
        head_tail=False,
        reject=False,
        sizes=("a_um",),
        measure=_measure_3d,
        predict=recipes_mod.SPHERE.predict,
        summary=(Compared("D_t", "D (3-D MSD)", "D_t", "um^2/s"),),
        radius_is_hydrodynamic=True,
        msd_panels=(MsdPanel(None, (Curve("lab_3d", "k", "D_t", "D"),)),),
    )
    monkeypatch.setitem(recipes_mod.RECIPES, "sphere3d", recipe)
    d_t = 0.5
    p = BrownianParameters(3000, 0.02, d_t, d_t, 1.0)
    sim = simulate_trajectory(p, MeasurementNoise(0.01), seed=9, static={"radius_um": 0.5})
    traj = Trajectory.from_fit_table(validate_fit_table(sim.table))
    res = analyze_trajectory(traj, AnalysisConfig("sphere3d"))
    m = res.measured["D_t"]
    assert abs(m.value - d_t) < 4 * m.error  # the simulation's truth
    row = next(r for r in res.rows if r["quantity"] == "D (3-D MSD)")
    assert row["expected"] == pytest.approx(res.predictions["D_t"][0].value)
    write_summary(res, tmp_path / "out")
    names = {p.name for p in write_plots(res, tmp_path / "out")}
    assert names == {"msd.png", "trajectory.png"}
    assert dataclasses.asdict(res.settings)["model"] == "sphere3d"
