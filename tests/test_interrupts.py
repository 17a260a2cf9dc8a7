"""Ctrl-C as a user meets it (issue 24, item 8): the command says how to resume and exits
with 130; the table a stage publishes (what make waits for) is the last file it writes, so an
interruption while the pictures are drawn leaves no table, and a rerun draws them without
refitting.
"""

from __future__ import annotations

import os

import pandas as pd
import pytest
from click.testing import CliRunner

from holofit.batch import BatchSettings, journal_path, partial_path, run_batch
from holofit.cli import main
from tests.batch_helpers import ToyConfig, calls, toy_frame, toy_payload, toy_table
from tests.test_prefit_cli import _crop_folder


def _run(out, config, before_publish):
    return run_batch(toy_frame, config, list(range(6)), toy_payload,
                     toy_table(out, meta={"kind": "toy"}, desc="toy"),
                     options=BatchSettings(workers=0, progress=False),
                     before_publish=before_publish)


def test_the_table_is_published_after_the_pictures(tmp_path):
    logs = tmp_path / "logs"
    logs.mkdir()
    cfg = ToyConfig(log_dir=str(logs))
    out = tmp_path / "run" / "table.csv"
    seen = []

    def interrupted(staged):
        seen.append(pd.read_csv(staged)["frame"].tolist())
        raise KeyboardInterrupt  # Ctrl-C while the pictures are drawn

    with pytest.raises(KeyboardInterrupt):
        _run(out, cfg, interrupted)
    assert seen == [list(range(6))]  # the complete table, under the partial name
    assert not out.exists() and journal_path(out).exists()

    def draw(staged):
        assert staged == partial_path(out) and not out.exists()
        (out.parent / "table.png").write_text("picture")

    summary = _run(out, cfg, draw)
    assert calls(logs) == list(range(6))  # nothing refitted
    assert summary.n_run == 0 and summary.n_done_before == 6
    assert out.exists() and not journal_path(out).exists() and not partial_path(out).exists()
    assert pd.read_csv(out)["frame"].tolist() == list(range(6))
    assert (out.parent / "table.csv.json").exists()
    assert os.stat(out.parent / "table.png").st_mtime_ns <= os.stat(out).st_mtime_ns


def test_ctrl_c_says_how_to_resume_and_exits_130(tmp_path, monkeypatch):
    crops, _ = _crop_folder(tmp_path, 2)
    out = tmp_path / "prefit"
    import holofit.prefit.plots as plots

    real = plots.plot_prefit

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(plots, "plot_prefit", interrupted)
    args = ["prefit", str(crops), "-o", str(out), "-j", "0", "--no-progress"]
    res = CliRunner().invoke(main, args)
    assert res.exit_code == 130, res.output
    assert "holofit prefit: interrupted: what is done is kept; run the same command again" in (
        res.output)
    assert "Aborted" not in res.output
    # the fits are kept, the table is not published: make runs the stage again
    assert not (out / "prefit.csv").exists() and journal_path(out / "prefit.csv").exists()
    monkeypatch.setattr(plots, "plot_prefit", real)
    res = CliRunner().invoke(main, args)
    assert res.exit_code == 0, res.output
    assert "0 fitted now, 2 done before" in res.output
    png, table = out / "prefit.png", out / "prefit.csv"
    assert png.exists() and table.exists()
    assert os.stat(png).st_mtime_ns <= os.stat(table).st_mtime_ns


def test_analyze_writes_summary_csv_last(tmp_path):
    res = CliRunner().invoke(main, ["simulate", "trajectory", "--n-frames", "150", "--d-t",
                                    "0.3", "--d-r", "0.5", "--a-um", "0.3", "--b-um", "1.0",
                                    "-o", str(tmp_path / "traj")])
    assert res.exit_code == 0, res.output
    out = tmp_path / "analysis"
    res = CliRunner().invoke(main, ["analyze", str(tmp_path / "traj" / "trajectory.csv"),
                                    "-m", "rod", "-o", str(out)])
    assert res.exit_code == 0, res.output
    last = os.stat(out / "summary.csv").st_mtime_ns
    others = [p for p in out.iterdir() if p.name != "summary.csv"]
    assert any(p.suffix == ".png" for p in others)
    assert all(os.stat(p).st_mtime_ns <= last for p in others)
