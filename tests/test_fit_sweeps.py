"""The continuity sweeps after a tracked final pass (holofit.fit.sweeps through
holofit.fit.stage.run_fit), on a short simulated rod movie with known truth: a clean tracked
table is not refitted at all; a frame the tracker re-acquired with a jump is."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pandas as pd
import pytest

from holofit.config import load_instrument, load_particle, resolve_config
from holofit.fit.config import FitConfig
from holofit.fit.continuity import ContinuitySettings
from holofit.fit.stage import run_fit
from holofit.simulate.holograms import simulate_movie
from tests.stage_helpers import ROD_TOML, SERIAL, crop_prefit_library

N = 6


def _axes(angles: np.ndarray) -> np.ndarray:
    return np.column_stack([np.sin(angles[:, 1]) * np.cos(angles[:, 0]),
                            np.sin(angles[:, 1]) * np.sin(angles[:, 0]), np.cos(angles[:, 1])])


@pytest.fixture(scope="module")
def tracked(tmp_path_factory):
    """A 6-frame rod movie (~3 deg and ~50 nm per frame) through the tracked final pass with
    the sweeps off: the run folder, the particle and the true axes."""
    root = tmp_path_factory.mktemp("sweeps")
    (root / "rod.toml").write_text(ROD_TOML)
    particle = load_particle(root / "rod.toml")
    inst = load_instrument(resolve_config("paper_60x_water", "instruments"))
    rng = np.random.default_rng(7)
    pos = np.array([8.0, 8.0, 9.0]) + np.cumsum(rng.normal(0, 0.03, (N, 3)), axis=0)
    angles = np.zeros((N, 3))
    angles[:, :2] = np.radians([30, 50]) + np.cumsum(rng.normal(0, np.radians(2), (N, 2)),
                                                     axis=0)
    sim = simulate_movie(particle.model, inst, pos, (90, 90), orientations=angles, alpha=0.9,
                         theory=particle.theory(), seed=2, out_dir=root / "sim")
    crop_prefit_library(sim, inst, particle, root)
    (root / "static.json").write_text(json.dumps({
        "particle_model": "spherocylinder", "values": {"a_um": 0.3, "b_um": 0.7, "n": 1.5}}))
    _fit(root, particle, root / "fit", ContinuitySettings(enabled=False))
    return root, particle, _axes(angles)


def _fit(root, particle, out, continuity):
    return run_fit(
        root / "crop",
        root / "prefit",
        root / "lib",
        out,
        FitConfig(
            particle, passes="final", static=root / "static.json", plot=False, continuity=continuity
        ),
        batch=SERIAL,
    )


def _off_deg(table: pd.DataFrame, u_true: np.ndarray) -> np.ndarray:
    cos = np.abs(np.sum(table[["ux", "uy", "uz"]].to_numpy() * u_true, axis=1))
    return np.degrees(np.arccos(np.clip(cos, -1, 1)))


def test_a_clean_followed_run_is_not_refitted(tracked, tmp_path):
    """Every frame warm, in its right minimum: the sweeps refit none (the untracked rule
    refits the frames whose step is above the median: 4 of the 6 here)."""
    root, particle, u_true = tracked
    shutil.copytree(root / "fit", tmp_path / "fit")
    before = pd.read_csv(tmp_path / "fit" / "fit.csv").sort_values("frame")
    assert (before["status"] == "ok").all() and (before["follow_source"] != "reacquired").all()
    assert _off_deg(before, u_true).max() < 2
    run = _fit(root, particle, tmp_path / "fit", ContinuitySettings())
    assert run.summaries["final"].n_run == 0
    assert run.continuity.refitted == 0 and run.continuity.sweeps == 0


def test_a_reacquired_frame_with_a_jump_is_still_refitted(tracked, tmp_path):
    """Frame 3 put into a wrong orientation (90 deg off, chi^2 three times its own, still
    ``ok``) as a re-acquisition with a jump: the sweeps refit it (and its neighbours) from the
    neighbours' orientations and bring it back to the truth."""
    root, particle, u_true = tracked
    shutil.copytree(root / "fit", tmp_path / "fit")
    path = tmp_path / "fit" / "fit.csv"
    table = pd.read_csv(path).sort_values("frame").reset_index(drop=True)
    psi, theta = np.radians(124.0), np.radians(90.0)
    wrong = {
        "psi_rad": psi,
        "theta_rad": theta,
        "ux": np.sin(theta) * np.cos(psi),
        "uy": np.sin(theta) * np.sin(psi),
        "uz": np.cos(theta),
        "chi2": 3 * table["chi2"][3],
        "chi2_red": 3 * table["chi2_red"][3],
        "follow_source": "reacquired",
        "follow_jump": 1,
    }
    for col, value in wrong.items():
        table.loc[3, col] = value
    # the pass's own rows (its batch table, from which fit.csv is derived) so changed
    chunks_csv = tmp_path / "fit" / "fit_chunks.csv"
    rows = pd.read_csv(chunks_csv)
    for col, value in wrong.items():
        rows.loc[rows["frame"] == 3, col] = value
    rows.to_csv(chunks_csv, index=False)
    assert _off_deg(table, u_true)[3] > 60
    run = _fit(root, particle, tmp_path / "fit", ContinuitySettings())
    assert run.continuity.replaced == 1 and 3 <= run.continuity.refitted <= 5
    t = pd.read_csv(path).sort_values("frame")
    assert _off_deg(t, u_true).max() < 2 and (t["status"] == "ok").all()
    assert "trajectory continuity" in t["message"].iloc[3]
