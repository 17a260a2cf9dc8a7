"""The output-folder lock: one writer per folder, a clear refusal, harmless after SIGKILL."""

from __future__ import annotations

import errno
import json
import os
import signal
import subprocess
import sys

import pytest

from holofit.io import lock as lockmod
from holofit.io.lock import LOCK_NAME, OutputLocked, output_lock

HOLD = (
    "import sys, time\n"
    "from holofit.io.lock import output_lock\n"
    "with output_lock(sys.argv[1], stage='prefit'):\n"
    "    print('locked', flush=True)\n"
    "    time.sleep(60)\n"
)


@pytest.fixture
def holder(tmp_path):
    """Another process holding the lock of ``tmp_path / 'out'``; yields (folder, process)."""
    folder = tmp_path / "out"
    proc = subprocess.Popen(
        [sys.executable, "-c", HOLD, str(folder)], stdout=subprocess.PIPE, text=True
    )
    assert proc.stdout.readline().strip() == "locked"
    yield folder, proc
    if proc.poll() is None:
        proc.kill()
    proc.wait()


def test_a_second_writer_is_refused_with_the_folder_and_the_holder_named(holder):
    folder, proc = holder
    with pytest.raises(OutputLocked) as info:
        with output_lock(folder, stage="prefit"):
            pass
    msg = str(info.value)
    assert str(folder) in msg and f"pid {proc.pid}" in msg and "prefit" in msg
    assert "another holofit run is writing into this folder" in msg
    assert info.value.holder.pid == proc.pid
    assert info.value.holder.command  # the holder's command line, for the user to find it


def test_the_lock_of_a_killed_run_is_taken_over_with_a_note(holder):
    folder, proc = holder
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert (folder / LOCK_NAME).exists()  # left behind, but harmless
    with output_lock(folder, stage="fit") as lock:
        assert lock.previous is not None and lock.previous.pid == proc.pid
        assert "took over the lock" in lock.note and f"pid {proc.pid}" in lock.note
        doc = json.loads((folder / LOCK_NAME).read_text())
        assert doc["pid"] == os.getpid() and doc["stage"] == "fit"
    assert not (folder / LOCK_NAME).exists()  # a clean exit removes the file


def test_released_lock_can_be_taken_again_and_nests_in_one_process(tmp_path):
    with output_lock(tmp_path, stage="prefit") as outer:
        assert outer.note is None and outer.locked
        with output_lock(tmp_path, stage="prefit") as inner:  # the runner inside a stage
            assert inner is outer
        assert (tmp_path / LOCK_NAME).exists()  # still held by the outer block
    assert not (tmp_path / LOCK_NAME).exists()
    with output_lock(tmp_path, stage="prefit") as again:
        assert again.previous is None


def test_a_file_system_without_locks_runs_unlocked_with_a_note(tmp_path, monkeypatch):
    def no_locks(fd, op):
        raise OSError(errno.ENOLCK, "No locks available")

    monkeypatch.setattr(lockmod.fcntl, "flock", no_locks)
    with output_lock(tmp_path, stage="prefit") as lock:
        assert not lock.locked and "supports no file locks" in lock.note
