"""The library and fit stages end to end on a tiny simulated rod movie (known truth), their
reruns, and bad input: tables made from other crops or for another particle, missing prefit
rows, a frame that cannot be fitted."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from holofit.cli import main
from holofit.config import load_instrument, load_particle, resolve_config
from holofit.crop import CropConfig, run_crop
from holofit.fit import follower, stage, task, tmatrix_policy
from holofit.fit.config import FitConfig
from holofit.fit.continuity import ContinuitySettings
from holofit.fit.settings import FollowSettings, FrameFitSettings
from holofit.fit.stage import run_fit
from holofit.library.stage import LibrarySettings, run_library
from holofit.prefit import run_prefit
from holofit.simulate.holograms import simulate_movie
from holofit.tables.fit import read_fit_table
from holofit.tables.inputs import StageInputError
from tests.stage_helpers import ROD_TOML, SERIAL

TRUTH_ANGLES = np.radians([[30, 50, 0], [34, 53, 0], [38, 49, 0]])
LIB = LibrarySettings(tilt_step_deg=15, n_phi=64, n_candidates=2)


@pytest.fixture(scope="module")
def movie(tmp_path_factory):
    """A 3-frame movie of a small rod, cropped and prefitted (shared by the tests)."""
    root = tmp_path_factory.mktemp("rodmovie")
    (root / "rod.toml").write_text(ROD_TOML)
    particle = load_particle(root / "rod.toml")
    inst = load_instrument(resolve_config("paper_60x_water", "instruments"))
    pos = np.array([[8.0, 8.0, 9.0], [8.1, 7.9, 9.2], [7.9, 8.05, 9.1]])
    sim = simulate_movie(particle.model, inst, pos, (90, 90), orientations=TRUTH_ANGLES,
                         alpha=0.9, theory=particle.theory(), seed=2, out_dir=root / "sim")
    run_crop(sim.movie, sim.background, inst, root / "crop", CropConfig(size=64, plot=False))
    run_prefit(root / "crop", root / "prefit", batch=SERIAL, plot=False)
    run_library(root / "crop", root / "prefit", particle, root / "lib", settings=LIB,
                batch=SERIAL, plot=False)
    return root, particle, pos


def test_library_tilts_solved_once_for_the_workers_give_the_same_candidates(movie, tmp_path):
    """On two worker processes the driver has the tilts solved once (``tilts.npz``, their
    expansions) and the workers score the frames with them: the same candidates as the serial
    library, which solves the tilts itself."""
    from holofit.batch import BatchSettings

    root, particle, _ = movie
    run_library(root / "crop", root / "prefit", particle, tmp_path / "lib",
                settings=LIB, batch=BatchSettings(workers=2, progress=False), plot=False)
    assert (tmp_path / "lib" / "tilts.npz").exists()
    assert not (root / "lib" / "tilts.npz").exists()  # serial: nothing shared
    shared = pd.read_csv(tmp_path / "lib" / "library.csv").drop(columns="fit_time_s")
    own = pd.read_csv(root / "lib" / "library.csv").drop(columns="fit_time_s")
    pd.testing.assert_frame_equal(shared, own, rtol=1e-6, atol=1e-9)


def test_library_then_both_passes_recover_the_truth(movie, tmp_path):
    root, particle, pos = movie
    lib = pd.read_csv(root / "lib" / "library.csv")
    assert (lib["status"] == "ok").all() and (lib["n_candidates"] >= 1).all()
    run = run_fit(
        root / "crop",
        root / "prefit",
        root / "lib",
        tmp_path / "fit",
        FitConfig(particle, initial_frames=2, plot=True),
        batch=SERIAL,
    )
    static = json.loads(run.static.read_text())
    assert static["n_frames"] == 2 and static["particle_model"] == "spherocylinder"
    assert static["values"]["a_um"] == pytest.approx(0.3, abs=0.01)
    assert static["values"]["b_um"] == pytest.approx(0.7, abs=0.02)
    fit = read_fit_table(run.final)  # the fit-table schema, as analyze reads it
    table = fit.table
    assert (table["status"] == "ok").all(), table["message"].tolist()
    np.testing.assert_allclose(table[["x_um", "y_um", "z_um"]], pos, atol=0.02)
    u_true = np.column_stack(
        [
            np.sin(TRUTH_ANGLES[:, 1]) * np.cos(TRUTH_ANGLES[:, 0]),
            np.sin(TRUTH_ANGLES[:, 1]) * np.sin(TRUTH_ANGLES[:, 0]),
            np.cos(TRUTH_ANGLES[:, 1]),
        ]
    )
    cos = np.abs(np.sum(table[["ux", "uy", "uz"]].to_numpy() * u_true, axis=1))
    assert np.degrees(np.arccos(np.clip(cos, -1, 1))).max() < 2.0
    for col in (
        "d_x_um",
        "d_theta_rad",
        "chi2",
        "chi2_red",
        "r2",
        "n_eval",
        "delta_chi2",
        "ambiguous",
    ):
        assert col in table.columns
    assert (tmp_path / "fit" / "fit.png").exists()
    assert list((tmp_path / "fit" / "frames_final").glob("frame_*.png"))
    # the initial pass's 2 frames are checked against their initial fits (one hologram
    # each) and, on the right branch, not changed; the count is in the notes and the sidecar
    assert table["follow_initial"].tolist() == [0, 0, -1]
    assert (table["follow_initial_dchi2"].iloc[:2] < 9.0).all()
    assert any(
        "2 frame(s) checked against their initial-pass fit" in n and "0 changed" in n
        for n in run.notes
    ), run.notes
    assert fit.meta["follow"]["initial_check"] == {"checked": 2, "refitted": 0, "changed": 0}
    # a rerun finds everything done and changes nothing
    before = run.final.read_bytes()
    again = run_fit(
        root / "crop",
        root / "prefit",
        root / "lib",
        tmp_path / "fit",
        FitConfig(particle, initial_frames=2, plot=False),
        batch=SERIAL,
    )
    assert again.summaries["final"].n_run == 0 and run.final.read_bytes() == before


def test_a_library_for_another_particle_is_refused(movie, tmp_path):
    root, _, _ = movie
    other = tmp_path / "rod2.toml"
    other.write_text(ROD_TOML.replace("b_um = 0.7", "b_um = 0.9"))
    with pytest.raises(StageInputError, match=r"library made for another spherocylinder.*b_um"):
        run_fit(
            root / "crop",
            root / "prefit",
            root / "lib",
            tmp_path / "fit",
            FitConfig(load_particle(other), plot=False),
            batch=SERIAL,
        )
    janus = tmp_path / "janus.toml"
    janus.write_text(
        '[particle]\nmodel = "janus"\nradius_um = 0.4\ncap_thickness_um = 0.05\n'
        "index_core = 1.58\nindex_cap = 2.7\n"
    )
    with pytest.raises(StageInputError, match="library made for a 'spherocylinder'"):
        run_fit(
            root / "crop",
            root / "prefit",
            root / "lib",
            tmp_path / "fit",
            FitConfig(load_particle(janus), plot=False),
            batch=SERIAL,
        )


def test_tables_made_from_other_crops_are_refused(movie, tmp_path):
    root, particle, _ = movie
    crop2 = tmp_path / "crop2"
    shutil.copytree(root / "crop", crop2)
    table = pd.read_csv(crop2 / "crops.csv")
    table.loc[0, "x_px"] += 0.5
    table.to_csv(crop2 / "crops.csv", index=False)
    with pytest.raises(StageInputError, match="made from other crops"):
        run_library(
            crop2,
            root / "prefit",
            particle,
            tmp_path / "lib",
            settings=LIB,
            batch=SERIAL,
            plot=False,
        )
    with pytest.raises(StageInputError, match="made from other crops"):
        run_fit(
            crop2,
            root / "prefit",
            root / "lib",
            tmp_path / "fit",
            FitConfig(particle, plot=False),
            batch=SERIAL,
        )
    # the command line names the table, not an option (it blamed --particle)
    from click.testing import CliRunner

    from holofit.cli import main

    res = CliRunner().invoke(
        main,
        [
            "library",
            str(crop2),
            "--prefit",
            str(root / "prefit"),
            "-p",
            str(root / "rod.toml"),
            "-o",
            str(tmp_path / "l2"),
            "-j",
            "0",
            "--no-progress",
        ],
    )
    assert res.exit_code == 1, res.output
    assert res.output.startswith("holofit library: error: ") and "made from other crops" in (
        res.output
    )
    assert "--particle" not in res.output and "Usage:" not in res.output


def test_missing_prefit_rows_and_unfittable_frames_are_recorded_and_the_batch_goes_on(
    movie, tmp_path, monkeypatch
):
    root, particle, _ = movie
    pre = tmp_path / "prefit"
    shutil.copytree(root / "prefit", pre)
    table = pd.read_csv(pre / "prefit.csv")
    table = table[table["frame"] != 1]
    table.to_csv(pre / "prefit.csv", index=False)
    real_fit = task.fit_frame

    def failing(problem, *args, **kwargs):
        if problem.seed == 2:
            raise ValueError("the hologram of frame 2 cannot be fitted")
        return real_fit(problem, *args, **kwargs)

    monkeypatch.setattr(task, "fit_frame", failing)
    run = run_fit(
        root / "crop",
        pre,
        root / "lib",
        tmp_path / "fit",
        FitConfig(
            particle,
            passes="final",
            static=_static(tmp_path),
            plot=False,
            frame=FrameFitSettings(mirror=False),
            follow=FollowSettings(warm=False),
        ),
        batch=SERIAL,
    )  # independent frames
    out = pd.read_csv(run.final).set_index("frame")
    assert out.loc[0, "status"] == "ok"
    assert out.loc[1, "status"] == "skipped" and "prefit: no row" in out.loc[1, "message"]
    assert out.loc[2, "status"] == "error" and "frame 2 cannot be fitted" in out.loc[2, "message"]


def test_followed_final_pass_records_failing_frames_and_goes_on(movie, tmp_path, monkeypatch):
    """The followed final pass (the default): a frame whose fit raises is an error row, and
    the frame after it is fitted along the track from the last accepted fit."""
    root, particle, _ = movie
    monkeypatch.setattr(follower, "fit_frame_warm", _raising_on(1, follower.fit_frame_warm))
    monkeypatch.setattr(follower, "fit_frame", _raising_on(1, follower.fit_frame))
    run = run_fit(
        root / "crop",
        root / "prefit",
        root / "lib",
        tmp_path / "fit",
        FitConfig(
            particle,
            passes="final",
            static=_static(tmp_path),
            plot=False,
            frame=FrameFitSettings(mirror=False),
        ),
        batch=SERIAL,
    )
    out = pd.read_csv(run.final).set_index("frame")
    assert out.loc[1, "status"] == "error" and "frame 1 cannot be fitted" in out.loc[1, "message"]
    rest = out.drop(index=1)
    assert (rest["status"] == "ok").all()
    # one library fit opens the chunk (the frame the library reads best); every other frame,
    # on either side of the error, is fitted warm along the track
    assert (rest["follow_source"] == "library").sum() == 1
    assert (rest["follow_source"] == "warm").sum() == len(rest) - 1
    assert (tmp_path / "fit" / "fit_chunks.csv").exists()


def _raising_on(frame, real):
    def fit(problem, *args, **kwargs):
        if problem.seed == frame:
            raise ValueError(f"the hologram of frame {frame} cannot be fitted")
        return real(problem, *args, **kwargs)

    return fit


def _static(tmp_path):
    path = tmp_path / "static.json"
    path.write_text(
        json.dumps(
            {"particle_model": "spherocylinder", "values": {"a_um": 0.3, "b_um": 0.7, "n": 1.5}}
        )
    )
    return path


def test_cli_runs_the_final_pass_from_a_static_file(movie, tmp_path):
    root, _, _ = movie
    res = CliRunner().invoke(
        main,
        [
            "fit",
            str(root / "crop"),
            "--prefit",
            str(root / "prefit"),
            "--library",
            str(root / "lib"),
            "-p",
            str(root / "rod.toml"),
            "-o",
            str(tmp_path / "fit"),
            "--pass",
            "final",
            "--static",
            str(_static(tmp_path)),
            "-j",
            "0",
            "--no-plot",
            "--frames",
            "0:1",
            "--starts",
            "1",
            "--no-mirror",
        ],
    )
    assert res.exit_code == 0, res.output
    assert "fit (final): 1 frame(s) [ok 1]" in res.output
    wrong = tmp_path / "wrong.json"
    wrong.write_text(json.dumps({"particle_model": "janus", "values": {}}))
    res = CliRunner().invoke(
        main,
        [
            "fit",
            str(root / "crop"),
            "--prefit",
            str(root / "prefit"),
            "--library",
            str(root / "lib"),
            "-p",
            str(root / "rod.toml"),
            "-o",
            str(tmp_path / "fit2"),
            "--pass",
            "final",
            "--static",
            str(wrong),
            "-j",
            "0",
            "--no-plot",
        ],
    )
    assert res.exit_code == 1 and "wrong.json: static parameters of a 'janus'" in res.output


def test_final_pass_from_the_tmatrix_equals_direct_solves(movie, tmp_path):
    root, particle, _ = movie
    common = dict(passes="final", static=_static(tmp_path), plot=False)
    direct = run_fit(
        root / "crop",
        root / "prefit",
        root / "lib",
        tmp_path / "d",
        FitConfig(particle, tmatrix="never", **common),
        batch=SERIAL,
    )
    served = run_fit(
        root / "crop",
        root / "prefit",
        root / "lib",
        tmp_path / "t",
        FitConfig(particle, tmatrix="always", **common),
        batch=SERIAL,
    )
    assert direct.tmatrix is None and served.tmatrix == tmp_path / "t" / "tmatrix.npz"
    assert served.tmatrix.exists() and any("T-matrix" in n for n in served.notes)
    a = pd.read_csv(direct.final).set_index("frame")
    b = pd.read_csv(served.final).set_index("frame")
    assert (a["status"] == "ok").all() and (b["status"] == "ok").all()
    # the same minimum: the T-matrix is the lattice's exact linear map (to solver precision)
    np.testing.assert_allclose(b[["x_um", "y_um", "z_um"]], a[["x_um", "y_um", "z_um"]], atol=2e-3)
    np.testing.assert_allclose(b[["ux", "uy", "uz"]].abs(), a[["ux", "uy", "uz"]].abs(), atol=5e-3)
    assert (b["n_solves"] > 0).all()
    # a rerun reuses the saved T-matrix
    again = run_fit(
        root / "crop",
        root / "prefit",
        root / "lib",
        tmp_path / "t",
        FitConfig(particle, tmatrix="always", **common),
        batch=SERIAL,
    )
    assert any("loaded" in n for n in again.notes)


def test_a_polarizability_without_a_tmatrix(movie, tmp_path, monkeypatch):
    """LDR's polarisability depends on the incident wave, so its lattice has no T-matrix:
    ``--tmatrix always`` is refused before any frame is fitted, ``auto`` solves directly."""
    root, _, _ = movie
    (tmp_path / "ldr.toml").write_text(ROD_TOML + 'polarizability = "ldr"\n')
    ldr = load_particle(tmp_path / "ldr.toml")
    common = dict(passes="final", static=_static(tmp_path), plot=False)
    with pytest.raises(stage.FitStageError, match="polarizability 'ldr' depends on the inc"):
        run_fit(
            root / "crop",
            root / "prefit",
            root / "lib",
            tmp_path / "a",
            FitConfig(ldr, tmatrix="always", **common),
            batch=SERIAL,
        )
    assert not (tmp_path / "a" / "fit.csv").exists()
    monkeypatch.setattr(tmatrix_policy, "TMATRIX_MIN_FRAMES", 1)
    run = run_fit(
        root / "crop",
        root / "prefit",
        root / "lib",
        tmp_path / "b",
        FitConfig(ldr, tmatrix="auto", frames=(0,), **common),
        batch=SERIAL,
    )
    assert run.tmatrix is None and any("direct DDA solves" in n for n in run.notes)
    assert (pd.read_csv(run.final)["status"] == "ok").all()


def test_continuity_refits_a_wrong_frame_from_its_neighbours(movie, tmp_path):
    """Frame 1 of a finished final pass put into a wrong orientation (90 deg off the truth,
    chi^2 far above the others, poor_fit), as a frame left in a wrong minimum is: the
    continuity sweep refits it with the DDA from its neighbours' orientations into the true
    one, records it, and a rerun changes nothing."""
    root, particle, _ = movie
    u_true = np.column_stack(
        [
            np.sin(TRUTH_ANGLES[:, 1]) * np.cos(TRUTH_ANGLES[:, 0]),
            np.sin(TRUTH_ANGLES[:, 1]) * np.sin(TRUTH_ANGLES[:, 0]),
            np.cos(TRUTH_ANGLES[:, 1]),
        ]
    )

    def off_deg(t):
        cos = np.abs(np.sum(t[["ux", "uy", "uz"]].to_numpy() * u_true, axis=1))
        return np.degrees(np.arccos(np.clip(cos, -1, 1)))

    common = dict(passes="final", static=_static(tmp_path), plot=False)
    first = run_fit(
        root / "crop",
        root / "prefit",
        root / "lib",
        tmp_path / "fit",
        FitConfig(particle, continuity=ContinuitySettings(enabled=False), **common),
        batch=SERIAL,
    )
    table = pd.read_csv(first.final)
    assert off_deg(table).max() < 2
    psi, theta = np.radians(124.0), np.radians(90.0)
    wrong = {
        "psi_rad": psi,
        "theta_rad": theta,
        "ux": np.sin(theta) * np.cos(psi),
        "uy": np.sin(theta) * np.sin(psi),
        "uz": np.cos(theta),
        "chi2": 50 * table["chi2"][1],
        "chi2_red": 50 * table["chi2_red"][1],
        "status": "poor_fit",
        "message": "far from the data",
    }
    table["message"] = table["message"].astype(object)
    for col, value in wrong.items():
        table.loc[1, col] = value
    # the pass's own rows (its batch table, from which fit.csv is derived) left in the wrong
    # minimum
    chunks_csv = tmp_path / "fit" / "fit_chunks.csv"
    rows = pd.read_csv(chunks_csv)
    rows["message"] = rows["message"].astype(object)
    for col, value in wrong.items():
        rows.loc[rows["frame"] == 1, col] = value
    rows.to_csv(chunks_csv, index=False)
    assert off_deg(table)[1] > 80

    run = run_fit(
        root / "crop",
        root / "prefit",
        root / "lib",
        tmp_path / "fit",
        FitConfig(particle, **common),
        batch=SERIAL,
    )
    assert run.summaries["final"].n_run == 0  # the final pass itself was done
    t = pd.read_csv(run.final).sort_values("frame")
    assert off_deg(t).max() < 2 and (t["status"] == "ok").all(), t["message"].tolist()
    assert "trajectory continuity" in t["message"].iloc[1]
    assert t["chi2_red"].iloc[1] == pytest.approx(table["chi2_red"].iloc[1] / 50, rel=1e-3)
    assert run.continuity.replaced == 1
    doc = json.loads((tmp_path / "fit" / "fit.csv.json").read_text())
    assert doc["continuity"]["replaced"] == 1
    before = run.final.read_bytes()
    again = run_fit(
        root / "crop",
        root / "prefit",
        root / "lib",
        tmp_path / "fit",
        FitConfig(particle, **common),
        batch=SERIAL,
    )
    assert again.continuity.replaced == 1 and run.final.read_bytes() == before


def test_an_interrupted_initial_pass_resumes_to_the_rows_of_an_uninterrupted_one(
        movie, tmp_path, monkeypatch):
    """The initial pass (sizes free, direct DDA solves, independent frames) killed after its
    first frame and resumed: the resumed rows are those of an uninterrupted run, digit for
    digit (each item starts from its own inputs only, not from the solver's history of the
    frames its worker ran before)."""
    root, particle, _ = movie
    common = dict(passes="initial", initial_frames=3, plot=False, tmatrix="never",
                  follow=FollowSettings(warm=False), model_test=False)
    whole = run_fit(root / "crop", root / "prefit", root / "lib", tmp_path / "whole",
                    FitConfig(particle, **common), batch=SERIAL)
    real = task.fit_frame_task
    calls = []

    def stop_after_one(config, key, payload):
        calls.append(key)
        if len(calls) > 1:
            raise KeyboardInterrupt  # killed, not a frame's error
        return real(config, key, payload)

    monkeypatch.setattr(task, "fit_frame_task", stop_after_one)
    from holofit.fit import passes

    monkeypatch.setattr(passes, "fit_frame_task", stop_after_one)
    with pytest.raises(KeyboardInterrupt):
        run_fit(root / "crop", root / "prefit", root / "lib", tmp_path / "cut",
                FitConfig(particle, **common), batch=SERIAL)
    monkeypatch.setattr(passes, "fit_frame_task", real)
    again = run_fit(root / "crop", root / "prefit", root / "lib", tmp_path / "cut",
                    FitConfig(particle, **common), batch=SERIAL)
    assert again.summaries["initial"].n_done_before == 1
    a = pd.read_csv(whole.initial).drop(columns="fit_time_s")
    b = pd.read_csv(again.initial).drop(columns="fit_time_s")
    pd.testing.assert_frame_equal(a, b, rtol=0, atol=0)
