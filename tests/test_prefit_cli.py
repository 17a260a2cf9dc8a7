"""`holofit prefit` from the command line: outputs, errors, SIGKILL + resume, Dask."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from holofit.batch import journal_path
from holofit.batch.journal import read_journal
from holofit.cli import main
from holofit.config import load_instrument
from holofit.particles import Sphere
from holofit.simulate.holograms import simulate_movie
from tests.conftest import CONFIGS
from tests.prefit_helpers import make_crops_from_movie

INST = load_instrument(CONFIGS / "instruments" / "paper_100x_oil.toml")
TIMING = ["fit_time_s", "setup_time_s"]


def _crop_folder(tmp_path, n_frames, size=90, no_particle=(), seed=0):
    px = INST.pixel_size_um
    rng = np.random.default_rng(seed)
    pos = np.column_stack(
        [(60 + rng.uniform(-5, 5, (n_frames, 2))) * px, rng.uniform(6, 25, n_frames)]
    )
    sim = simulate_movie(Sphere(0.6, 1.55), INST, pos, (120, 120), seed=seed, out_dir=tmp_path)
    centres = [
        None if k in no_particle else (x / px + rng.uniform(-0.5, 0.5), y / px + 0.3)
        for k, (x, y, _) in enumerate(pos)
    ]
    crops = make_crops_from_movie(
        sim.movie, sim.background, centres, size, INST, tmp_path / "crops"
    )
    return crops, sim


def _invoke(*args):
    return CliRunner().invoke(main, ["prefit", *map(str, args), "--no-progress"])


def _values(path):
    return pd.read_csv(path).drop(columns=TIMING)


@pytest.fixture(scope="module")
def crops6(tmp_path_factory):
    return _crop_folder(tmp_path_factory.mktemp("c6"), 6, no_particle=(2,))


def test_cli_fits_every_frame_and_writes_table_sidecar_and_plot(tmp_path, crops6):
    crops, sim = crops6
    out = tmp_path / "out"
    res = _invoke(crops, "-o", out, "--workers", "0")
    assert res.exit_code == 0, res.output
    assert "6 frame(s) [ok 5, skipped 1]" in res.output
    table = pd.read_csv(out / "prefit.csv")
    assert table["frame"].tolist() == list(range(6))
    assert table.loc[2, "status"] == "skipped" and "no_particle" in table.loc[2, "message"]
    ok = table["status"] == "ok"
    truth = sim.truth
    assert np.abs(table.loc[ok, "z_um"] - truth.loc[ok, "z_um"]).max() < 0.05
    assert np.abs(table.loc[ok, "x_um"] - truth.loc[ok, "x_um"]).max() < 0.01
    assert (table.loc[ok, "n_eval"] > 0).all() and (table.loc[ok, "r2"] > 0.9).all()
    meta = json.loads((out / "prefit.csv.json").read_text())
    assert meta["units"]["z_um"].startswith("um")
    assert meta["config"]["instrument"]["name"] == INST.name
    assert meta["config"]["fit"]["fix_alpha"] is None
    assert meta["batch"]["complete"] is True
    assert (out / "prefit.png").stat().st_size > 1000
    # a rerun of the finished command does nothing
    again = _invoke(crops, "-o", out, "--workers", "0")
    assert again.exit_code == 0 and "0 fitted now, 6 done before" in again.output


def test_cli_options_reach_the_fit(tmp_path, crops6):
    crops, _ = crops6
    out = tmp_path / "out"
    res = _invoke(
        crops, "-o", out, "-j", "0", "--fix-alpha", "1", "--pixel-fraction", "0.5",
        "--frames", "0:2", "--no-plot", "--z-range", "3,40",
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    table = pd.read_csv(out / "prefit.csv")
    assert table["frame"].tolist() == [0, 1]
    assert (table["alpha"] == 1.0).all() and table["d_alpha"].isna().all()
    assert (table["n_pixels"] == round(0.5 * 90 * 90)).all()
    assert not (out / "prefit.png").exists()
    # other settings in the same output folder are refused, with advice
    res = _invoke(crops, "-o", out, "-j", "0", "--frames", "0:2", "--no-plot")
    assert res.exit_code != 0 and "other settings" in res.output and "--overwrite" in res.output


def test_cli_errors_name_the_problem(tmp_path, crops6):
    crops, _ = crops6
    res = _invoke(tmp_path, "-o", tmp_path / "o")
    assert res.exit_code != 0 and "crops.tif: not found" in res.output
    res = _invoke(crops, "-o", tmp_path / "o", "--z-range", "30,5")
    assert res.exit_code != 0 and "MIN < MAX" in res.output
    res = _invoke(crops, "-o", tmp_path / "o", "--pixel-fraction", "0")
    assert res.exit_code != 0
    # a crop folder whose sidecar names no instrument needs --instrument
    bare = tmp_path / "bare"
    shutil.copytree(crops, bare)
    doc = json.loads((bare / "crops.csv.json").read_text())
    doc["config"] = {}
    (bare / "crops.csv.json").write_text(json.dumps(doc))
    res = _invoke(bare, "-o", tmp_path / "o", "-j", "0", "--frames", "0:1", "--no-plot")
    assert res.exit_code != 0 and "names no instrument" in res.output
    res = _invoke(bare, "-o", tmp_path / "o", "-j", "0", "--frames", "0:1", "--no-plot",
                  "-i", "paper_100x_oil")  # fmt: skip
    assert res.exit_code == 0, res.output


def _holofit_command():
    script = Path(sys.executable).with_name("holofit")
    if script.exists():
        return [str(script)]
    return [sys.executable, "-c", "from holofit.cli import main; main()"]


def test_sigkill_halfway_then_rerun_finishes_without_refitting(tmp_path):
    n = 30
    crops, _ = _crop_folder(tmp_path / "data", n, size=80, seed=4)
    reference = tmp_path / "reference"
    res = _invoke(crops, "-o", reference, "--workers", "1", "--no-plot")
    assert res.exit_code == 0, res.output

    out = tmp_path / "killed"
    cmd = [*_holofit_command(), "prefit", str(crops), "-o", str(out), "--workers", "1",
           "--no-plot", "--no-progress"]  # fmt: skip
    proc = subprocess.Popen(cmd, start_new_session=True, stdout=subprocess.PIPE)
    journal = journal_path(out / "prefit.csv")
    done_at_kill = 0
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        if journal.exists():
            done_at_kill = journal.read_bytes().count(b"\n") - 1  # minus the header
            if done_at_kill >= n // 3:
                break
        time.sleep(0.01)
    os.killpg(proc.pid, signal.SIGKILL)  # the driver and its worker, at once
    proc.wait()
    assert proc.returncode == -signal.SIGKILL
    _, rows_at_kill, _ = read_journal(journal)
    assert 0 < len(rows_at_kill) < n, "the run was not killed halfway"
    assert not (out / "prefit.csv").exists()  # a Makefile sees the stage as not done

    res = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert f"{n - len(rows_at_kill)} fitted now, {len(rows_at_kill)} done before" in res.stdout
    final = pd.read_csv(out / "prefit.csv").set_index(["particle", "frame"])
    # the frames finished before the kill were not fitted again: their rows, timings
    # included, are the ones recorded before the kill
    for frame, row in rows_at_kill.items():
        assert final.loc[frame, "fit_time_s"] == pytest.approx(row["fit_time_s"], rel=1e-9)
    pd.testing.assert_frame_equal(_values(reference / "prefit.csv"), _values(out / "prefit.csv"))
    assert not journal.exists()


def test_dask_gives_the_process_pool_table(tmp_path, crops6):
    distributed = pytest.importorskip("distributed")
    crops, _ = crops6
    pool = _invoke(crops, "-o", tmp_path / "pool", "--workers", "2", "--no-plot")
    assert pool.exit_code == 0, pool.output
    reference = _values(tmp_path / "pool" / "prefit.csv")
    # a local cluster started by holofit (loopback only)
    dask = _invoke(crops, "-o", tmp_path / "dask", "--dask-local", "--workers", "2", "--no-plot")
    assert dask.exit_code == 0, dask.output
    meta = json.loads((tmp_path / "dask" / "prefit.csv.json").read_text())
    assert meta["batch"]["backend"] == "dask" and meta["batch"]["scheduler"] == "local cluster"
    pd.testing.assert_frame_equal(reference, _values(tmp_path / "dask" / "prefit.csv"))
    # a running scheduler given by its address, as on a cluster
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, host="127.0.0.1", dashboard_address=None
    ) as cluster:
        address = cluster.scheduler_address
        res = _invoke(crops, "-o", tmp_path / "sched", "--scheduler", address, "--no-plot")
    assert res.exit_code == 0, res.output
    meta = json.loads((tmp_path / "sched" / "prefit.csv.json").read_text())
    assert meta["batch"]["scheduler"] == address
    pd.testing.assert_frame_equal(reference, _values(tmp_path / "sched" / "prefit.csv"))


def test_prefit_draws_data_model_and_residual_of_chosen_frames(tmp_path, crops6):
    crops, _ = crops6
    out = tmp_path / "out"
    res = _invoke(crops, "-o", out, "-j", "0", "--frames", "0:4", "--plot-frames", "1,2,3")
    assert res.exit_code == 0, res.output
    pictures = sorted(p.name for p in (out / "frames").glob("*.png"))
    # frame 2 has no particle (skipped: nothing to draw)
    assert pictures == ["frame_000001.png", "frame_000003.png"]
    assert (out / "frames" / "frame_000001.png").stat().st_size > 5000


def test_an_instrument_that_contradicts_the_crops_needs_an_explicit_flag(tmp_path, crops6):
    crops, _ = crops6
    res = _invoke(crops, "-o", tmp_path / "a", "-j", "0", "--frames", "0:1", "--no-plot",
                  "-i", "pylorenzmie")
    assert res.exit_code == 1
    assert "contradicts the one the crops" in res.output and "paper-100x-oil" in res.output
    assert "wavelength_um 0.447 vs 0.66" in res.output and "--override-instrument" in res.output
    res = _invoke(crops, "-o", tmp_path / "b", "-j", "0", "--frames", "0:1", "--no-plot",
                  "-i", "pylorenzmie", "--override-instrument")
    assert res.exit_code == 0, res.output
