"""Issue 22: a movie of several particles through ``holofit init`` + ``make`` with no new
option, and through the README's first example (crop, prefit, analyze); the truth is the
simulation's (``holofit simulate field-of-view``). Slow: ~1-1.5 min on 2 busy cores."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

from holofit.analysis.hydrodynamics import sphere_diffusion
from tests.runfolder_helpers import make_env, names, needs_make, run_make, stages_run

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
