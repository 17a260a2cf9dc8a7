"""Issue 22: a movie of several particles through ``holofit init`` + ``make`` with no new
option (two spheres; two rods, through the library), and through the README's first example
(crop, prefit, analyze); the truth is the simulation's (``holofit simulate field-of-view``).
Slow: ~2 and ~1.3 min on 2 busy cores."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

from holofit.analysis.hydrodynamics import sphere_diffusion
from tests.runfolder_helpers import make_env, names, needs_make, run_make, stages_run
from tests.stage_helpers import ROD_TOML

pytestmark = [needs_make, pytest.mark.slow]

#: two 1 um polystyrene spheres 22 um apart (no overlap), 30 frames of the 100x oil set-up
SCENE = """\
instrument = "paper_100x_oil"
frames = 30
shape = [200, 400]
seed = 2

[[particle]]
config = "sphere_ps_1um"
start_um = [8.0, 10.6, 10.0]

[[particle]]
config = "sphere_ps_1um"
start_um = [30.0, 10.0, 11.0]
"""


def _holofit(*args: str, cwd) -> subprocess.CompletedProcess[str]:
    proc = subprocess.run([sys.executable, "-m", "holofit.cli", *args], cwd=cwd, env=make_env(),
                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                          timeout=600, check=False)
    assert proc.returncode == 0, proc.stdout[-3000:]
    return proc


def _matched(table: pd.DataFrame, truth: pd.DataFrame) -> pd.DataFrame:
    """Each row beside its particle's truth (a track is the particle nearest its rows)."""
    ids = {}
    for p, rows in table.groupby("particle"):
        at = truth[truth["frame"].isin(rows["frame"])].groupby("particle")["x_um"].mean()
        ids[p] = int((at - rows["x_um"].mean()).abs().idxmin())
    assert sorted(ids.values()) == sorted(truth["particle"].unique())  # one track each
    return table.assign(true_id=table["particle"].map(ids)).merge(
        truth.rename(columns={"particle": "true_id"}), on=["true_id", "frame"],
        suffixes=("", "_true"))


def test_a_run_folder_fits_every_particle_of_a_field_of_view(tmp_path):
    (tmp_path / "scene.toml").write_text(SCENE)
    _holofit("simulate", "field-of-view", "scene.toml", "-o", "sim", cwd=tmp_path)
    truth = pd.read_csv(tmp_path / "sim" / "truth.csv")
    _holofit("init", "run", "--movie", "sim/movie.tif", "-b", "sim/background.tif",
             "-i", "paper_100x_oil", "-p", "sphere_ps_1um", cwd=tmp_path)
    run = tmp_path / "run"
    proc = run_make(run, "JOBS=1")
    assert proc.returncode == 0, proc.stdout[-3000:]
    assert names(stages_run(proc.stdout, run)) == ["crop", "prefit", "fit initial", "fit final",
                                                   "analyze"]
    fit = pd.read_csv(run / "fit" / "fit.csv")
    assert list(fit.columns[:2]) == ["particle", "frame"]
    assert sorted(fit["particle"].unique()) == [0, 1] and len(fit) == 60
    assert (fit["status"] == "ok").all(), fit["message"].tolist()
    both = _matched(fit, truth)
    err = both[["x_um", "y_um"]].to_numpy() - both[["x_um_true", "y_um_true"]].to_numpy()
    assert np.sqrt(np.mean(err ** 2)) <= 0.010  # issue 22: x/y rms <= 10 nm
    static = json.loads((run / "fit" / "static.json").read_text())
    assert set(static["tracks"]) == {"0", "1"}
    d_true = sphere_diffusion(0.5, 21.0)["D_t"]  # the scene's Stokes-Einstein D (um^2/s)
    tracks = pd.read_csv(run / "analysis" / "tracks.csv")
    pooled = pd.read_csv(run / "analysis" / "pooled.csv").set_index("quantity")
    assert len(tracks) == 2
    assert abs(pooled.loc["D_t", "value"] - d_true) < 3 * pooled.loc["D_t", "error"]
    for name in ("summary.csv", "tracks.png", "track_msds.png"):
        assert (run / "analysis" / name).exists()
    assert run_make(run, "-q").returncode == 0  # a second make does nothing

    # the README's first example on the same movie: crop, prefit, analyze the prefit table
    _holofit("crop", "sim/movie.tif", "--background", "sim/background.tif",
             "-i", "paper_100x_oil", "-o", "crop/", cwd=tmp_path)
    _holofit("prefit", "crop/", "-o", "prefit/", cwd=tmp_path)
    out = _holofit("analyze", "prefit/prefit.csv", "--temperature-c", "21", "-o", "analysis/",
                   cwd=tmp_path)
    assert "pooled over tracks" in out.stdout
    prefit = _matched(pd.read_csv(tmp_path / "prefit" / "prefit.csv"), truth)
    assert (prefit["status"] == "ok").all()
    readme = pd.read_csv(tmp_path / "analysis" / "pooled.csv").set_index("quantity")
    assert abs(readme.loc["D_t", "value"] - d_true) < 3 * readme.loc["D_t", "error"]


#: the single-rod run folder test's small settings (tests/test_runfolder_rod.py)
ROD_OPTIONS = {
    "crop": "--size 64 --no-plot",
    "prefit": "--no-plot",
    "library": "--tilt-step 15 --n-phi 64 --candidates 2 --no-plot",
    "fit": "--initial-frames 1 --starts 1 --no-mirror --no-plot",
}


def test_a_run_folder_of_two_rods_runs_the_library_and_the_fit_per_track(tmp_path):
    """Two rods 12 um apart, 3 frames: make runs crop, prefit, library and both fit passes
    on (particle, frame) rows; each track is its rod (position and axis against the truth)."""
    from holofit.config import load_instrument, load_particle, resolve_config
    from holofit.runfolder import RunInputs, init_run
    from holofit.simulate.field_of_view import ParticleInView, simulate_field_of_view

    (tmp_path / "rod.toml").write_text(ROD_TOML)
    rod = load_particle(tmp_path / "rod.toml")
    inst = load_instrument(resolve_config("paper_60x_water", "instruments"))
    step = np.array([[0.0, 0.0, 0.0], [0.1, -0.1, 0.2], [-0.1, 0.05, 0.1]])
    pos = {0: step + np.array([7.0, 8.0, 9.0]), 1: step[::-1] + np.array([19.0, 8.5, 9.5])}
    ang = {0: np.radians([[30, 50, 0], [34, 53, 0], [38, 49, 0]]),
           1: np.radians([[120, 60, 0], [117, 64, 0], [121, 61, 0]])}
    sim = simulate_field_of_view(
        [ParticleInView(rod.model, pos[k], ang[k], 0.9, rod.theory()) for k in (0, 1)], inst,
        (96, 150), out_dir=tmp_path / "sim", seed=2)
    run = tmp_path / "rods"
    init_run(
        run,
        RunInputs(sim.movie, backgrounds=[sim.background]),
        instrument="paper_60x_water",
        particle=tmp_path / "rod.toml",
        options=ROD_OPTIONS,
    )
    proc = run_make(run, "fit", "JOBS=0")
    assert proc.returncode == 0, proc.stdout[-3000:]
    assert names(stages_run(proc.stdout, run)) == [
        "crop",
        "prefit",
        "library",
        "fit initial",
        "fit final",
    ]
    assert list(pd.read_csv(run / "library" / "library.csv").columns[:2]) == ["particle", "frame"]
    fit = pd.read_csv(run / "fit" / "fit.csv")
    assert (fit["status"] == "ok").all(), fit["message"].tolist()
    assert sorted(fit["particle"].unique()) == [0, 1] and len(fit) == 6
    for _, rows in fit.groupby("particle"):
        k = 0 if rows["x_um"].mean() < 13 else 1
        np.testing.assert_allclose(rows[["x_um", "y_um", "z_um"]], pos[k], atol=0.03)
        a = ang[k]
        u = np.column_stack(
            [np.sin(a[:, 1]) * np.cos(a[:, 0]), np.sin(a[:, 1]) * np.sin(a[:, 0]), np.cos(a[:, 1])]
        )
        cos = np.abs(np.sum(rows[["ux", "uy", "uz"]].to_numpy() * u, axis=1))
        assert np.degrees(np.arccos(np.clip(cos, -1, 1))).max() < 3.0
