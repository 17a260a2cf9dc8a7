"""What a batch leaves behind when things go wrong around it: a killed driver takes its workers
with it, a second run into the same folder is refused, a dead run's lock is taken over, and a
Dask scheduler that is not there is reported within seconds."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pandas as pd
import psutil
import pytest
from click.testing import CliRunner

from holofit.batch import BatchSettings, SchedulerError, WorkerLost, journal_path, run_batch
from holofit.batch.backends import DaskBackend, SerialBackend
from holofit.cli import main
from holofit.io.lock import LOCK_NAME, OutputLocked
from tests.batch_helpers import ToyConfig, toy_frame, toy_payload, toy_table

ROOT = Path(__file__).resolve().parents[1]


def _toy_batch_process(out: Path, workers: int, n_frames: int, sleep_s: float) -> subprocess.Popen:
    code = (
        "from tests.batch_helpers import run_toy_batch; "
        f"run_toy_batch({str(out)!r}, {workers}, {n_frames}, {sleep_s})"
    )
    return subprocess.Popen([sys.executable, "-c", code], cwd=ROOT)


def _journal_rows(out: Path) -> int:
    path = journal_path(out)
    return path.read_bytes().count(b"\n") - 1 if path.exists() else 0


def _wait_for(condition, timeout_s: float = 60.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.02)


def _run_toy(out: Path, **options) -> object:
    return run_batch(
        toy_frame, ToyConfig(), range(4), toy_payload, toy_table(out, desc="toy"),
        options=BatchSettings(**({"workers": 0, "progress": False} | options)),
    )


def test_workers_and_resource_tracker_die_with_a_killed_driver(tmp_path):
    out = tmp_path / "out" / "table.csv"
    proc = _toy_batch_process(out, workers=2, n_frames=400, sleep_s=0.2)
    driver = psutil.Process(proc.pid)
    try:
        # both workers have started and are running frames
        _wait_for(lambda: _journal_rows(out) >= 2 and len(driver.children()) >= 3)
        children = driver.children(recursive=True)
        kinds = [" ".join(c.cmdline()) for c in children]
        assert sum("spawn_main" in k for k in kinds) == 2
        assert any("resource_tracker" in k for k in kinds)
        os.kill(proc.pid, signal.SIGKILL)  # the driver alone, not its process group
        proc.wait()
        _, alive = psutil.wait_procs(children, timeout=5)
        assert alive == [], [" ".join(p.cmdline()) for p in alive]
    finally:
        if proc.poll() is None:
            proc.kill()
        for child in psutil.Process().children(recursive=True):
            if child.pid != proc.pid and "spawn_main" in " ".join(child.cmdline()):
                child.kill()


def test_the_parent_watch_alone_ends_an_orphan(tmp_path):
    # without the kernel's parent-death signal (not Linux): the watching thread does it
    code = (
        "import os, sys, time\n"
        "from holofit.batch import lifeline\n"
        "lifeline._kernel_signal_on_parent_death = lambda sig: False\n"
        "parent = os.getpid()\n"
        "if os.fork() == 0:\n"
        "    lifeline.die_with_parent(parent, interval_s=0.05)\n"
        "    print(os.getpid(), flush=True)\n"
        "    time.sleep(60)\n"
        "    os._exit(0)\n"
        "time.sleep(60)\n"
    )
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True,
                            cwd=ROOT)
    orphan = psutil.Process(int(proc.stdout.readline()))
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    try:
        orphan.wait(timeout=3)
    except psutil.TimeoutExpired:
        orphan.kill()
        pytest.fail("the orphan outlived its parent")


def test_a_second_run_into_the_same_folder_is_refused(tmp_path):
    out = tmp_path / "out" / "table.csv"
    first = _toy_batch_process(out, workers=0, n_frames=400, sleep_s=0.05)
    try:
        _wait_for(lambda: _journal_rows(out) >= 1)
        with pytest.raises(OutputLocked, match=f"pid {first.pid}") as info:
            _run_toy(out)
        assert str(out.parent) in str(info.value) and "toy" in str(info.value)
        # nothing of the first run was touched
        assert _journal_rows(out) >= 1 and not out.exists()
        # from the command line: the folder and the holder are named, no traceback
        crops = tmp_path / "crops"
        res = CliRunner().invoke(main, ["prefit", str(_crop_folder(crops)), "-o",
                                        str(out.parent), "-j", "0", "--no-progress"])
        assert res.exit_code == 1, res.output
        assert "another holofit run is writing into this folder" in res.output
        assert f"pid {first.pid}" in res.output and "Traceback" not in res.output
    finally:
        first.kill()
        first.wait()


def test_the_lock_of_a_killed_run_is_taken_over_and_the_run_resumes(tmp_path):
    out = tmp_path / "out" / "table.csv"
    first = _toy_batch_process(out, workers=0, n_frames=4, sleep_s=2.0)
    _wait_for(lambda: (out.parent / LOCK_NAME).exists() and journal_path(out).exists())
    os.kill(first.pid, signal.SIGKILL)
    first.wait()
    summary = _run_toy(out)
    assert any("took over the lock" in n and f"pid {first.pid}" in n for n in summary.notes)
    assert pd.read_csv(out)["frame"].tolist() == [0, 1, 2, 3]
    assert not (out.parent / LOCK_NAME).exists()


class _ClusterLike(SerialBackend):
    """A backend where a dying worker takes down only the calls it held (as on Dask), and
    frame 5 kills every worker that runs it while frame 2, beside it, is lost once too."""

    isolates_lost_workers = True

    def __init__(self) -> None:
        self.runs: list[int] = []

    def submit(self, fn, func, config, frame, payload):
        self.runs.append(frame)
        if frame == 5 or (frame == 2 and self.runs.count(2) == 1):
            return super().submit(_raise, WorkerLost(f"worker died running {frame}"))
        return super().submit(fn, func, config, frame, payload)


def _raise(exc: BaseException) -> None:
    raise exc


def test_a_frame_lost_beside_the_culprit_is_retried_alone_and_succeeds(tmp_path):
    backend = _ClusterLike()
    summary = run_batch(
        toy_frame, ToyConfig(), range(8), toy_payload, toy_table(tmp_path / "t.csv"),
        options=BatchSettings(progress=False), backend=backend,
    )
    table = pd.read_csv(tmp_path / "t.csv")
    assert summary.statuses == {"ok": 7, "error": 1}
    assert table.loc[5, "status"] == "error" and "worker died" in table.loc[5, "message"]
    assert table.loc[2, "status"] == "ok"
    assert backend.runs.count(5) == 2 and backend.runs.count(2) == 2  # each retried once


def _crop_folder(path: Path) -> Path:
    import numpy as np

    from holofit.config import load_instrument
    from tests.conftest import CONFIGS
    from tests.prefit_helpers import make_crops_from_frame

    inst = load_instrument(CONFIGS / "instruments" / "holopy_image0001.toml")
    return make_crops_from_frame(np.ones((40, 40)), (20.0, 20.0), 20, inst, path)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_missing_scheduler_file_is_reported_at_once(tmp_path):
    pytest.importorskip("distributed")
    t0 = time.monotonic()
    with pytest.raises(SchedulerError, match="scheduler file not found"):
        DaskBackend(str(tmp_path / "missing.json"))
    bad = tmp_path / "other.json"
    bad.write_text('{"workers": {}}')
    with pytest.raises(SchedulerError, match="has no 'address' entry"):
        DaskBackend(str(bad))
    assert time.monotonic() - t0 < 5


def test_scheduler_nobody_listens_on_is_reported_at_once():
    pytest.importorskip("distributed")
    address = f"tcp://127.0.0.1:{_free_port()}"
    t0 = time.monotonic()
    with pytest.raises(SchedulerError, match="cannot reach the Dask scheduler at") as info:
        DaskBackend(address)
    assert address in str(info.value) and "refused" in str(info.value).lower()
    assert time.monotonic() - t0 < 5


def test_a_malformed_scheduler_port_is_a_scheduler_error():
    pytest.importorskip("distributed")
    # a ValueError has no strerror: this used to escape as an AttributeError
    with pytest.raises(SchedulerError, match="cannot reach the Dask scheduler at"):
        DaskBackend("tcp://127.0.0.1:notaport")


def test_a_peer_that_accepts_but_never_answers_is_given_up_on():
    pytest.importorskip("distributed")
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen()
    held = []
    threading.Thread(target=lambda: held.append(server.accept()), daemon=True).start()
    try:
        t0 = time.monotonic()
        with pytest.raises(SchedulerError, match="no Dask handshake"):
            DaskBackend(f"tcp://127.0.0.1:{server.getsockname()[1]}", connect_timeout_s=1.0)
        assert time.monotonic() - t0 < 6
    finally:
        server.close()


def test_prefit_cli_names_the_scheduler_problem_without_traceback(tmp_path):
    pytest.importorskip("distributed")
    crops = _crop_folder(tmp_path / "crops")
    for scheduler, words in (
        (str(tmp_path / "missing.json"), "missing.json: Dask scheduler file not found"),
        (f"tcp://127.0.0.1:{_free_port()}", "cannot reach the Dask scheduler"),
    ):
        t0 = time.monotonic()
        res = CliRunner().invoke(main, ["prefit", str(crops), "-o", str(tmp_path / "o"),
                                        "--scheduler", scheduler, "--no-progress"])
        assert res.exit_code == 1 and words in res.output, res.output
        assert res.exception is None or isinstance(res.exception, SystemExit)
        assert time.monotonic() - t0 < 10


def test_killed_prefit_leaves_no_workers(tmp_path):
    # the same with the real command line, `holofit prefit -j 2` killed -9 (~7 s)
    from tests.test_prefit_cli import _crop_folder as simulated_crops
    from tests.test_prefit_cli import _holofit_command

    crops, _ = simulated_crops(tmp_path / "data", 40, size=80, seed=3)
    out = tmp_path / "out"
    proc = subprocess.Popen([*_holofit_command(), "prefit", str(crops), "-o", str(out), "-j", "2",
                             "--no-plot", "--no-progress"])
    driver = psutil.Process(proc.pid)
    try:
        _wait_for(lambda: _journal_rows(out / "prefit.csv") >= 2 and len(driver.children()) >= 3,
                  timeout_s=120)
        children = driver.children(recursive=True)
        assert sum("spawn_main" in " ".join(c.cmdline()) for c in children) == 2
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        _, alive = psutil.wait_procs(children, timeout=5)
        assert alive == [], [" ".join(p.cmdline()) for p in alive]
    finally:
        if proc.poll() is None:
            proc.kill()
