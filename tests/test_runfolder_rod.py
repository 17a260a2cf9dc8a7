"""A run folder for a rod (anisotropic: the library stage runs), driven by the real make on a
tiny simulated movie with known truth; touching the particle config reruns library and fit but
not crop and prefit. Slow (the DDA fits of the rod: ~1.5 min on 2 cores)."""

from __future__ import annotations

import os

import numpy as np
import pandas as pd
import pytest

from holofit.config import load_instrument, load_particle, resolve_config
from holofit.runfolder import RunInputs, init_run
from holofit.simulate.holograms import simulate_movie
from tests.runfolder_helpers import mtimes, names, needs_make, run_make, stages_run
from tests.stage_helpers import ROD_TOML

pytestmark = [needs_make, pytest.mark.slow]

ANGLES = np.radians([[30, 50, 0], [34, 53, 0], [38, 49, 0]])  # psi, theta, phi
POSITIONS = np.array([[8.0, 8.0, 9.0], [8.1, 7.9, 9.2], [7.9, 8.05, 9.1]])
OPTIONS = {
    "crop": "--size 64 --no-plot",
    "prefit": "--no-plot",
    "library": "--tilt-step 15 --n-phi 64 --candidates 2 --no-plot",
    "fit": "--initial-frames 1 --starts 1 --no-mirror --no-plot",
}


def test_rod_run_folder_runs_the_library_and_reruns_it_for_a_new_particle(tmp_path):
    (tmp_path / "rod.toml").write_text(ROD_TOML)
    particle = load_particle(tmp_path / "rod.toml")
    inst = load_instrument(resolve_config("paper_60x_water", "instruments"))
    sim = simulate_movie(particle.model, inst, POSITIONS, (90, 90), orientations=ANGLES,
                         alpha=0.9, theory=particle.theory(), seed=2, out_dir=tmp_path / "sim")
    run = tmp_path / "rod01"
    made = init_run(
        run,
        RunInputs(sim.movie, backgrounds=[sim.background]),
        instrument="paper_60x_water",
        particle=tmp_path / "rod.toml",
        options=OPTIONS,
    )
    assert made.spec.analysis_model == "rod"

    proc = run_make(run, "fit", "JOBS=0")
    assert proc.returncode == 0, proc.stdout[-3000:]
    assert names(stages_run(proc.stdout, run)) == [
        "crop",
        "prefit",
        "library",
        "fit initial",
        "fit final",
    ]
    fit = pd.read_csv(run / "fit" / "fit.csv")
    assert (fit["status"] == "ok").all(), fit["message"].tolist()
    np.testing.assert_allclose(fit[["x_um", "y_um", "z_um"]], POSITIONS, atol=0.03)
    u_true = np.column_stack(
        [
            np.sin(ANGLES[:, 1]) * np.cos(ANGLES[:, 0]),
            np.sin(ANGLES[:, 1]) * np.sin(ANGLES[:, 0]),
            np.cos(ANGLES[:, 1]),
        ]
    )
    cos = np.abs(np.sum(fit[["ux", "uy", "uz"]].to_numpy() * u_true, axis=1))
    assert np.degrees(np.arccos(np.clip(cos, -1, 1))).max() < 3.0

    before = mtimes(run)
    os.utime(run / "particle.toml")  # touched: newer than every table
    proc = run_make(run, "fit", "JOBS=0")
    assert proc.returncode == 0, proc.stdout[-3000:]
    ran = stages_run(proc.stdout, run)
    assert names(ran) == ["library", "fit initial", "fit final"]
    assert all("--overwrite" in opts for _, opts in ran)
    after = mtimes(run)
    for unchanged in ("crop/crops.csv", "prefit/prefit.csv"):
        assert after[unchanged] == before[unchanged]
    for rerun in ("library/library.csv", "fit/static.json", "fit/fit.csv"):
        assert after[rerun] > before[rerun]
    assert run_make(run, "-q", "fit").returncode == 0
