"""The per-frame batch runner: failures isolated, results identical across backends, resume
after an interruption gives the table of an uninterrupted run."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from holofit.batch import (
    BatchError,
    BatchSettings,
    DaskBackend,
    Precomputed,
    ProcessPoolBackend,
    journal_path,
    partial_path,
    run_batch,
)
from holofit.batch.journal import Journal, JournalError, read_journal
from tests.batch_helpers import COLUMNS, ToyConfig, calls, toy_frame, toy_payload, toy_table

FRAMES = list(range(12))
TIMING = ["fit_time_s"]


def _run(tmp_path, name, config=None, frames=FRAMES, load=toy_payload, **opts):
    config = config or ToyConfig()
    out = tmp_path / name / "table.csv"
    backend = opts.pop("backend", None)
    summary = run_batch(
        toy_frame,
        config,
        frames,
        load,
        toy_table(out, fingerprint=opts.pop("fingerprint", "toy-1"), meta={"kind": "toy"},
                  desc="toy"),
        options=BatchSettings(**({"workers": 0, "progress": False} | opts)),
        backend=backend,
    )
    return out, summary


def _values(path):
    return pd.read_csv(path).drop(columns=[*TIMING, "threads"])


def test_rows_in_frame_order_with_errors_and_nonconvergence_recorded(tmp_path):
    cfg = ToyConfig(fail_frames=(3,), nonconverged_frames=(5,))
    out, summary = _run(tmp_path, "serial", cfg)
    table = pd.read_csv(out)
    assert list(table.columns) == list(COLUMNS)
    assert table["frame"].tolist() == FRAMES
    assert table.loc[3, "status"] == "error"
    assert "ValueError: bad data in frame 3" in table.loc[3, "message"]
    assert np.isnan(table.loc[3, "a"])
    assert table.loc[5, "status"] == "not_converged" and "ran out" in table.loc[5, "message"]
    ok = table["status"] == "ok"
    assert ok.sum() == 10
    # independent check of the values: the quadratic's true coefficients, within the noise
    np.testing.assert_allclose(table.loc[ok, "a"], 1 + 0.1 * table.loc[ok, "frame"], atol=0.01)
    np.testing.assert_allclose(table.loc[ok, "b"], 2.0, atol=0.01)
    assert summary.statuses == {"ok": 10, "error": 1, "not_converged": 1}
    assert summary.n_failed == 2
    meta = json.loads(out.with_name("table.csv.json").read_text())
    assert meta["kind"] == "toy" and meta["batch"]["complete"] is True
    assert meta["batch"]["frames_done"] == 12
    assert not journal_path(out).exists()  # consolidated and removed


def test_load_errors_and_precomputed_rows(tmp_path):
    def load(frame):
        if frame == 2:
            raise OSError("page 2 unreadable")
        if frame == 4:
            return Precomputed({"status": "skipped", "message": "no particle"})
        return toy_payload(frame)

    out, _ = _run(tmp_path, "load", load=load)
    table = pd.read_csv(out)
    assert table.loc[2, "status"] == "error" and "page 2 unreadable" in table.loc[2, "message"]
    assert table.loc[4, "status"] == "skipped" and table.loc[4, "message"] == "no particle"


def test_process_pool_matches_serial_and_workers_are_single_threaded(tmp_path):
    cfg = ToyConfig(fail_frames=(3,))
    serial, _ = _run(tmp_path, "serial", cfg)
    pool, summary = _run(tmp_path, "pool", cfg, workers=2)
    assert summary.backend == {"backend": "processes", "workers": 2}
    pd.testing.assert_frame_equal(_values(serial), _values(pool))
    threads = pd.read_csv(pool)["threads"]
    assert (threads[pd.read_csv(pool)["status"] == "ok"] == 1).all()


def test_a_worker_that_dies_is_recorded_and_the_batch_goes_on(tmp_path):
    cfg = ToyConfig(crash_frames=(4,))
    serial, _ = _run(tmp_path, "serial", ToyConfig())
    pool, summary = _run(tmp_path, "pool", cfg, workers=2)
    table = pd.read_csv(pool)
    assert table.loc[4, "status"] == "error" and "died" in table.loc[4, "message"]
    assert summary.statuses == {"ok": 11, "error": 1}
    keep = table["frame"] != 4
    pd.testing.assert_frame_equal(
        _values(serial)[keep].drop(columns="message"), _values(pool)[keep].drop(columns="message")
    )


def test_resume_after_interruption_skips_finished_frames_and_gives_the_same_table(tmp_path):
    full, _ = _run(tmp_path, "full", ToyConfig(fail_frames=(7,)))
    logs = tmp_path / "logs"
    logs.mkdir()
    cfg = ToyConfig(fail_frames=(7,), log_dir=str(logs))

    def interrupted(frame):
        if frame == 5:
            raise KeyboardInterrupt  # the user presses Ctrl-C while frame 5 is loaded
        return toy_payload(frame)

    with pytest.raises(KeyboardInterrupt):
        _run(tmp_path, "resumed", cfg, load=interrupted)
    out = tmp_path / "resumed" / "table.csv"
    assert calls(logs) == [0, 1, 2, 3, 4]
    assert not out.exists()  # the table appears only when complete (Make-friendly)
    partial = pd.read_csv(partial_path(out))  # what was done is in the partial table
    assert partial["frame"].tolist() == [0, 1, 2, 3, 4]
    meta = json.loads(partial_path(out).with_name("table.partial.csv.json").read_text())
    assert meta["batch"]["complete"] is False
    # a torn last line (killed mid-write) is ignored
    with journal_path(out).open("ab") as fh:
        fh.write(b'{"frame": 5, "status": "o')
    _, summary = _run(tmp_path, "resumed", cfg)
    assert summary.n_done_before == 5 and summary.n_run == 7
    assert calls(logs) == list(range(12))  # each frame fitted exactly once
    pd.testing.assert_frame_equal(_values(full), _values(out))
    assert not partial_path(out).exists() and not journal_path(out).exists()
    # a rerun of a finished batch runs only its error frame again (its cause may be fixed)
    _, again = _run(tmp_path, "resumed", cfg)
    assert again.n_run == 1 and again.n_done_before == 11
    assert calls(logs) == sorted([*range(12), 7])


def test_other_settings_refuse_to_mix_unless_overwrite(tmp_path):
    _run(tmp_path, "a", fingerprint="one")
    with pytest.raises(BatchError, match="other settings"):
        _run(tmp_path, "a", fingerprint="two")
    _, summary = _run(tmp_path, "a", fingerprint="two", overwrite=True)
    assert summary.n_run == 12


def test_retry_failed_reruns_only_failed_frames(tmp_path):
    logs = tmp_path / "logs"
    logs.mkdir()
    _run(tmp_path, "r", ToyConfig(fail_frames=(2, 9)))
    cfg = ToyConfig(log_dir=str(logs))  # the cause of the failures is fixed
    out, summary = _run(tmp_path, "r", cfg, retry_failed=True)
    assert calls(logs) == [2, 9] and summary.statuses == {"ok": 12}
    assert (pd.read_csv(out)["status"] == "ok").all()


def test_new_frames_extend_a_finished_table(tmp_path):
    logs = tmp_path / "logs"
    logs.mkdir()
    cfg = ToyConfig(log_dir=str(logs))
    _run(tmp_path, "x", cfg, frames=FRAMES[:6])
    out, summary = _run(tmp_path, "x", cfg)
    assert summary.n_done_before == 6 and calls(logs) == FRAMES
    full, _ = _run(tmp_path, "full")
    pd.testing.assert_frame_equal(_values(full), _values(out))


def test_dask_local_cluster_matches_process_pool(tmp_path):
    pytest.importorskip("distributed")
    cfg = ToyConfig(fail_frames=(3,), nonconverged_frames=(8,))
    pool, _ = _run(tmp_path, "pool", cfg, workers=2)
    with DaskBackend(scheduler=None, workers=2) as backend:
        dask_out, summary = _run(tmp_path, "dask", cfg, backend=backend)
        assert summary.backend["backend"] == "dask" and summary.backend["workers"] == 2
    pd.testing.assert_frame_equal(_values(pool), _values(dask_out))
    table = pd.read_csv(dask_out)
    assert (table.loc[table["status"] == "ok", "threads"] == 1).all()


def test_process_pool_backend_validates_workers():
    with pytest.raises(ValueError):
        ProcessPoolBackend(0)
    with pytest.raises(ValueError):
        BatchSettings(workers=-1)


def test_journal_round_trips_floats_exactly_and_rejects_foreign_files(tmp_path):
    path = tmp_path / "j.journal"
    values = [0.1 + 0.2, 1 / 3, float("nan"), 1e-300, np.float64(2.5), np.int64(7)]
    with Journal(path, {"fingerprint": "f"}) as j:
        for k, v in enumerate(values):
            j.append({"frame": k, "v": v})
    header, rows, _ = read_journal(path)
    assert header["fingerprint"] == "f"
    got = [rows[k]["v"] for k in range(len(values))]
    assert got[0] == 0.1 + 0.2 and got[1] == 1 / 3 and np.isnan(got[2]) and got[3] == 1e-300
    assert got[4] == 2.5 and got[5] == 7
    other = tmp_path / "other.txt"
    other.write_text('{"a": 1}\n')
    with pytest.raises(JournalError, match="not a holofit batch journal"):
        read_journal(other)


def test_a_dask_worker_that_dies_is_recorded_and_the_batch_goes_on(tmp_path):
    dask = pytest.importorskip("dask")
    pytest.importorskip("distributed")
    serial, _ = _run(tmp_path, "serial")
    # the scheduler gives up on a task after it killed one worker (default: 3 workers)
    with dask.config.set({"distributed.scheduler.allowed-failures": 0}):
        with DaskBackend(scheduler=None, workers=2) as backend:
            out, summary = _run(tmp_path, "dask", ToyConfig(crash_frames=(6,)), backend=backend)
    table = pd.read_csv(out)
    assert table.loc[6, "status"] == "error" and "died" in table.loc[6, "message"]
    assert summary.statuses == {"ok": 11, "error": 1}
    keep = table["frame"] != 6
    cols = ["frame", "status", "a", "b", "c"]
    pd.testing.assert_frame_equal(_values(serial)[keep][cols], _values(out)[keep][cols])
