"""Issue 24, item 3: a script that runs stages without ``if __name__ == "__main__":`` (the
README's example as once pasted), an all-error batch, and reruns of ``error`` frames."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import pandas as pd
import pytest

from holofit.batch import BatchError, BatchSettings, partial_path, run_batch
from tests.batch_helpers import ToyConfig, calls, toy_frame, toy_payload, toy_table

REPO = Path(__file__).resolve().parents[1]
FRAMES = list(range(6))

#: a script with no main guard that runs a batch on two worker processes
_UNGUARDED = """
import sys
sys.path.insert(0, {repo!r})
print("script body ran", flush=True)
from holofit.batch import BatchSettings, run_batch
from tests.batch_helpers import ToyConfig, toy_frame, toy_payload, toy_table
summary = run_batch(toy_frame, ToyConfig(), range(6), toy_payload, toy_table({out!r}, desc="toy"),
                    options=BatchSettings(workers=2, progress=False))
print("statuses", summary.statuses, flush=True)
"""


def _run(tmp_path, config, name="t", frames=FRAMES, **opts):
    out = tmp_path / name / "table.csv"
    summary = run_batch(toy_frame, config, frames, toy_payload, toy_table(out, desc="toy"),
                        options=BatchSettings(**({"workers": 0, "progress": False} | opts)))
    return out, summary


@pytest.mark.parametrize("how", ["file", "stdin"])
def test_a_script_without_the_main_guard_runs_once_and_its_batch_succeeds(tmp_path, how):
    """Before: every spawned worker ran the script again (its batch found the folder locked,
    the worker died), every frame was ``error`` and the script exited 0."""
    script = _UNGUARDED.format(repo=str(REPO), out=str(tmp_path / "out" / "table.csv"))
    if how == "file":
        path = tmp_path / "pasted.py"
        path.write_text(script)
        done = subprocess.run([sys.executable, str(path)], cwd=tmp_path, capture_output=True,
                              text=True, timeout=300)
    else:
        done = subprocess.run([sys.executable, "-"], input=script, cwd=tmp_path,
                              capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert done.stdout.count("script body ran") == 1, done.stdout
    assert "statuses {'ok': 6}" in done.stdout
    assert "Traceback" not in done.stderr
    assert (pd.read_csv(tmp_path / "out" / "table.csv")["status"] == "ok").all()


def test_a_worker_starting_up_refuses_to_run_a_stage(tmp_path):
    """A pool of the user's own (or Dask's local workers) still runs the script again: the
    stage it calls then ends that worker with one line saying what to do, no traceback."""
    script = textwrap.dedent(f"""
        import multiprocessing, sys
        sys.path.insert(0, {str(REPO)!r})
        import holofit
        from holofit.batch.mainguard import worker_is_starting
        if worker_is_starting():  # the script's top level, as a spawned worker re-runs it
            holofit.run_crop("movie.tif", "background.tif", "paper_60x_water", "crop/")
        else:
            p = multiprocessing.get_context("spawn").Process(target=print, args=("child",))
            p.start()
            p.join()
            print("worker exit", p.exitcode)
    """)
    path = tmp_path / "own_pool.py"
    path.write_text(script)
    done = subprocess.run([sys.executable, str(path)], cwd=tmp_path, capture_output=True,
                          text=True, timeout=300)
    assert "worker exit 1" in done.stdout, (done.stdout, done.stderr)
    assert "run_crop was called again by a worker process" in done.stderr
    assert 'if __name__ == "__main__":' in done.stderr
    assert "Traceback" not in done.stderr and not (tmp_path / "crop").exists()


def test_a_batch_whose_every_frame_fails_is_an_error_and_a_rerun_retries(tmp_path):
    """10/10 ``error`` used to be a table and exit 0, and a rerun kept it as it was."""
    with pytest.raises(BatchError, match=r"every frame failed: 6 of 6 in error.*"
                                         r"ValueError: bad data in frame"):
        _run(tmp_path, ToyConfig(fail_frames=tuple(FRAMES)))
    out = tmp_path / "t" / "table.csv"
    assert not out.exists()  # no table: make does not take the stage as done
    assert (pd.read_csv(partial_path(out))["status"] == "error").all()
    logs = tmp_path / "logs"
    logs.mkdir()
    out, summary = _run(tmp_path, ToyConfig(log_dir=str(logs)))  # the cause is fixed
    assert calls(logs) == FRAMES and summary.statuses == {"ok": 6}
    assert (pd.read_csv(out)["status"] == "ok").all()


def test_a_rerun_retries_error_frames_and_keeps_the_others(tmp_path):
    _run(tmp_path, ToyConfig(fail_frames=(1, 4), nonconverged_frames=(2,)))
    logs = tmp_path / "logs"
    logs.mkdir()
    _, summary = _run(tmp_path, ToyConfig(nonconverged_frames=(2,), log_dir=str(logs)))
    assert calls(logs) == [1, 4]  # not the ok frames, not the one that did not converge
    assert summary.statuses == {"ok": 5, "not_converged": 1}
    assert summary.n_done_before == 4 and summary.n_run == 2


def test_workers_that_die_on_every_frame_name_the_likely_cause(tmp_path):
    with pytest.raises(BatchError, match=r"every frame failed.*a worker process died.*"
                                         r'if __name__ == "__main__":'):
        _run(tmp_path, ToyConfig(crash_frames=(0, 1)), frames=[0, 1], workers=1)
