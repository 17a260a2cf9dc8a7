"""A run folder driven by the real make, on a tiny simulated sphere movie (known truth).

The first ``make`` runs every stage in order and recovers the simulated particle; a second
``make`` does nothing; editing the particle config reruns fit and analyze but not crop and
prefit; a stage setting given on make's command line reruns that stage only; a make killed
(SIGKILL to its process group) in the middle of a stage resumes that stage from its journal
and ends with the table of an uninterrupted run.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import time

import numpy as np
import pandas as pd
import pytest

from holofit.config import load_instrument, resolve_config
from holofit.particles import Sphere
from holofit.runfolder import RunInputs, init_run
from holofit.simulate.holograms import simulate_movie
from tests.runfolder_helpers import make_env, mtimes, names, needs_make, run_make, stages_run

pytestmark = needs_make

N_FRAMES = 12  # the analysis needs at least 10
RADIUS_UM, INDEX = 0.5, 1.59
#: stage options that keep the tiny run fast (no pictures, a narrow automatic start)
OPTIONS = {
    "crop": "--size 64 --no-plot",
    "prefit": "--z-range 5,15 --radius-range 0.4,0.6 --index-range 1.5,1.7 --no-plot",
    "fit": "--no-plot",
    "analyze": "--no-plots",
}
TIMING = ["fit_time_s", "setup_time_s"]


@pytest.fixture(scope="module")
def movie(tmp_path_factory):
    """12 frames of a 1-um sphere diffusing (D = 0.45 um^2/s) 10 um above focus."""
    root = tmp_path_factory.mktemp("sphere_movie")
    inst = load_instrument(resolve_config("paper_100x_oil", "instruments"))
    rng = np.random.default_rng(4)
    steps = rng.normal(0.0, np.sqrt(2 * 0.45 / inst.frame_rate_hz), (N_FRAMES, 3))
    steps[0] = 0.0
    pos = np.array([5.3, 5.3, 10.0]) + np.cumsum(steps, axis=0)
    sim = simulate_movie(Sphere(radius_um=RADIUS_UM, index=INDEX), inst, pos, (100, 100),
                         alpha=0.85, seed=3, out_dir=root / "sim")
    return sim.movie, sim.background, pos


@pytest.fixture(scope="module")
def finished(movie, tmp_path_factory):
    """A run folder after its first make (the tests copy it before changing anything)."""
    movie_path, background, _ = movie
    run = tmp_path_factory.mktemp("runs") / "sphere01"
    init_run(
        run,
        RunInputs(movie_path, backgrounds=[background]),
        instrument="paper_100x_oil",
        particle="sphere_ps_1um",
        options=OPTIONS,
    )
    proc = run_make(run, "JOBS=0")
    assert proc.returncode == 0, proc.stdout[-3000:]
    return run, proc.stdout


def _copy(run, tmp_path):
    dst = tmp_path / run.name
    shutil.copytree(run, dst)  # copy2: modification times are kept
    return dst


def test_first_make_runs_every_stage_in_order_and_recovers_the_sphere(finished, movie):
    run, output = finished
    ran = stages_run(output, run)
    assert names(ran) == ["crop", "prefit", "fit initial", "fit final", "analyze"]
    assert not any("--overwrite" in opts for _, opts in ran)  # nothing to discard
    _, _, truth = movie
    fit = pd.read_csv(run / "fit" / "fit.csv")
    assert (fit["status"] == "ok").all(), fit["message"].tolist()
    np.testing.assert_allclose(fit[["x_um", "y_um", "z_um"]], truth, atol=0.03)
    static = json.loads((run / "fit" / "static.json").read_text())["values"]
    assert static["radius_um"] == pytest.approx(RADIUS_UM, abs=0.02)
    assert static["n"] == pytest.approx(INDEX, abs=0.01)
    summary = pd.read_csv(run / "analysis" / "summary.csv")
    assert len(summary) > 0
    # a sphere has no library stage: the target says so and writes nothing
    proc = run_make(run, "library")
    assert proc.returncode == 0 and "library: skipped: a sphere" in proc.stdout
    assert not (run / "library").exists()


def test_the_analysis_step_reads_the_model_and_forcing_it_changes_nothing(finished, tmp_path):
    """A run of one particle model passes no --model: the analysis reads the track's model
    from the fit table (the fit's particle, a sphere), as in a population; forcing it
    (make MODEL=sphere, holofit init --model) reruns the analysis only, with the same
    result."""
    run, output = finished
    analyze = dict(stages_run(output, run))["analyze"]
    assert "--model" not in analyze.split(), analyze
    assert re.search(r"^MODEL\s*=$", (run / "Makefile").read_text(), re.M)
    forced = _copy(run, tmp_path)
    proc = run_make(forced, "MODEL=sphere", "JOBS=0")
    assert proc.returncode == 0, proc.stdout[-3000:]
    ran = stages_run(proc.stdout, forced)
    assert names(ran) == ["analyze"] and "--model sphere" in ran[0][1]
    free = pd.read_csv(run / "analysis" / "summary.csv")
    given = pd.read_csv(forced / "analysis" / "summary.csv")
    assert len(free) > 0 and free["quantity"].astype(str).str.startswith("D").any()
    pd.testing.assert_frame_equal(free, given)
    model = json.loads((run / "analysis" / "summary.json").read_text())["analysis"]
    assert model["settings"]["model"] == "sphere"


def test_a_second_make_does_nothing(finished):
    run, _ = finished
    before = mtimes(run)
    assert run_make(run, "-q").returncode == 0  # make -q: everything is up to date
    proc = run_make(run)
    assert proc.returncode == 0
    assert "Nothing to be done" in proc.stdout and stages_run(proc.stdout, run) == []
    assert mtimes(run) == before  # not one file touched, the settings records included


def test_editing_the_particle_reruns_fit_and_analyze_not_crop_and_prefit(finished, tmp_path):
    run = _copy(finished[0], tmp_path)
    before = mtimes(run)
    particle = run / "particle.toml"
    particle.write_text(particle.read_text().replace("radius_um = 0.5", "radius_um = 0.46"))
    proc = run_make(run, "JOBS=0")
    assert proc.returncode == 0, proc.stdout[-3000:]
    ran = stages_run(proc.stdout, run)
    assert names(ran) == ["fit initial", "fit final", "analyze"]
    # the fit's earlier results were made with the other particle: discarded, not mixed
    assert all("--overwrite" in opts for stage, opts in ran if stage.startswith("fit"))
    after = mtimes(run)
    for unchanged in ("crop/crops.csv", "crop/crops.tif", "prefit/prefit.csv"):
        assert after[unchanged] == before[unchanged], unchanged
    for rerun in ("fit/static.json", "fit/fit.csv", "analysis/summary.csv"):
        assert after[rerun] > before[rerun], rerun
    static = json.loads((run / "fit" / "static.json").read_text())
    assert static["start"]["radius_um"] == pytest.approx(0.46)  # the edited config was used
    assert static["values"]["radius_um"] == pytest.approx(RADIUS_UM, abs=0.02)  # the truth
    assert run_make(run, "-q").returncode == 0


def test_a_stage_setting_reruns_that_stage_only(finished, tmp_path):
    run = _copy(finished[0], tmp_path)
    before = mtimes(run)
    proc = run_make(run, "ANALYZE_OPTS=--no-plots --temperature-err-c 0.5")
    assert proc.returncode == 0, proc.stdout[-3000:]
    assert names(stages_run(proc.stdout, run)) == ["analyze"]
    settings = json.loads((run / "analysis" / "summary.json").read_text())["analysis"]
    assert settings["settings"]["temperature_err_c"] == 0.5
    after = mtimes(run)
    assert {k for k in after if after[k] != before.get(k)} <= {
        "settings/analyze",
        *(k for k in after if k.startswith("analysis/")),
    }
    # back to the Makefile's own setting: analyze is out of date again
    assert run_make(run, "-q").returncode == 1


def _journal_rows(path):
    """Complete lines after the header (a line torn by the kill has no newline yet)."""
    try:
        return max(path.read_text().count("\n") - 1, 0)
    except FileNotFoundError:
        return 0


def test_a_killed_make_resumes_the_stage_from_its_journal(finished, tmp_path):
    reference, _ = finished
    run = _copy(reference, tmp_path)
    for stage in ("prefit", "fit", "analysis"):
        shutil.rmtree(run / stage)
    table = run / "prefit" / "prefit.csv"
    journal = run / "prefit" / "prefit.csv.journal"
    with (tmp_path / "make.log").open("w") as log:
        proc = subprocess.Popen(
            ["make", "-C", str(run), "prefit", "JOBS=1"],
            stdout=log,
            stderr=subprocess.STDOUT,
            env=make_env(),
            start_new_session=True,
        )  # its own process group
        try:
            deadline = time.monotonic() + 300
            while _journal_rows(journal) < 2 and proc.poll() is None:
                assert time.monotonic() < deadline, "prefit never started"
                time.sleep(0.01)
        finally:
            os.killpg(proc.pid, signal.SIGKILL)  # make, the stage and its worker
            proc.wait(timeout=60)
    assert not table.exists(), "prefit finished before it could be killed"
    done = _journal_rows(journal)
    assert 2 <= done < N_FRAMES

    # make's decision: the journal is newer than every prerequisite -> resume (no --overwrite);
    # were a prerequisite newer (changed inputs or settings), it would be discarded
    assert "--overwrite" not in run_make(run, "-n", "prefit").stdout
    settings = run / "settings" / "prefit"
    stamp = settings.stat().st_mtime_ns
    newer = journal.stat().st_mtime_ns + 10**9
    os.utime(settings, ns=(newer, newer))
    assert "--overwrite" in run_make(run, "-n", "prefit").stdout
    os.utime(settings, ns=(stamp, stamp))

    proc = run_make(run, "prefit", "JOBS=0")
    assert proc.returncode == 0, proc.stdout[-3000:]
    assert f"{N_FRAMES - done} fitted now, {done} done before" in proc.stdout
    assert not journal.exists()
    want = pd.read_csv(reference / "prefit" / "prefit.csv").drop(columns=TIMING)
    got = pd.read_csv(table).drop(columns=TIMING)
    pd.testing.assert_frame_equal(got, want, check_exact=True)
