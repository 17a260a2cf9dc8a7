"""Temporaries of killed writers are removed by the next writer; a live writer's never are.

The writers are real processes killed with SIGKILL (nothing of theirs runs after it), among
them ``holofit crop`` itself, stopped at a known point: its movie is a folder of frames whose
fourth frame is a named pipe, so the crop blocks on it with its output stack half written.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import tifffile
from click.testing import CliRunner

from holofit.cli import main
from holofit.io.atomic import create_temporary, remove_stale_temporaries
from holofit.io.tables import write_table
from holofit.io.tiffstack import TiffStackWriter, write_tiff_stack
from tests.test_crop_synthetic import ring_pattern

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}

pytestmark = pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs POSIX")


def _parts(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.endswith(".part"))


def _wait_for(predicate, proc: subprocess.Popen, timeout_s: float = 60.0) -> None:
    t0 = time.monotonic()
    while not predicate():
        if proc.poll() is not None:
            out, err = proc.communicate()
            raise AssertionError(f"process ended early ({proc.returncode}): {out}{err}")
        if time.monotonic() - t0 > timeout_s:
            proc.kill()
            raise AssertionError("timed out")
        time.sleep(0.02)


def _kill9(proc: subprocess.Popen) -> None:
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    assert proc.returncode == -signal.SIGKILL


WRITER = """
import sys
import numpy as np
from holofit.io.tiffstack import TiffStackWriter
with TiffStackWriter(sys.argv[1]) as w:
    w.write(np.zeros((64, 64), np.float32))
    print("ready", flush=True)
    sys.stdin.readline()
    w.write(np.ones((64, 64), np.float32))
"""


def _start_writer(target: Path) -> subprocess.Popen:
    proc = subprocess.Popen([sys.executable, "-c", WRITER, str(target)], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV)
    assert proc.stdout.readline().strip() == "ready", proc.stderr.read()
    return proc


def test_kill_9_during_crop_leaves_nothing_after_a_rerun(tmp_path):
    shape = (120, 130)
    rng = np.random.default_rng(1)
    frames = [rng.poisson(ring_pattern(shape, 64.2 + k, 58.7) * 120).astype(np.uint8)
              for k in range(5)]
    movie = tmp_path / "movie"
    movie.mkdir()
    for k, frame in enumerate(frames):
        if k != 3:
            tifffile.imwrite(movie / f"frame{k}.tif", frame)
    os.mkfifo(movie / "frame3.tif")  # the crop blocks here, its stack half written
    tifffile.imwrite(tmp_path / "bg.tif", np.full(shape, 120, np.uint8))
    out = tmp_path / "out"
    command = [sys.executable, "-m", "holofit.cli", "crop", str(movie), "-b",
               str(tmp_path / "bg.tif"), "-i", "paper_60x_water", "-o", str(out), "--size", "64",
               "--no-plot", "--keep-saturated"]  # fmt: skip
    # (--keep-saturated: the saturation search reads sampled frames before the stack is
    # begun, and would block on the fifo there instead of halfway through the stack)
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=ENV)
    _wait_for(lambda: out.exists() and any(n.startswith(".crops.tif.") for n in _parts(out)),
              proc)
    _kill9(proc)
    left = _parts(out)
    assert len(left) == 1 and left[0].startswith(".crops.tif.holofit-")
    assert not (out / "crops.tif").exists() and not (out / "crops.csv").exists()

    (movie / "frame3.tif").unlink()
    tifffile.imwrite(movie / "frame3.tif", frames[3])
    done = CliRunner().invoke(main, command[3:])  # the rerun, in this process
    assert done.exit_code == 0, done.output
    assert _parts(out) == []
    assert not any(p.name.startswith(".") for p in out.iterdir())
    table = pd.read_csv(out / "crops.csv")
    assert table["status"].tolist() == ["ok"] * 5
    np.testing.assert_allclose(table["x_px"], 64.2 + np.arange(5), atol=0.2)


def test_a_live_writers_temporary_is_never_removed(tmp_path):
    target = tmp_path / "stack.tif"
    live = _start_writer(target)
    theirs = _parts(tmp_path)
    assert len(theirs) == 1
    # another writer of the same file, and a sweep, while the first is alive
    write_tiff_stack(target, [np.full((8, 8), 2.0, np.float32)])
    assert remove_stale_temporaries(target) == []
    assert _parts(tmp_path) == theirs
    live.communicate("go\n", timeout=60)
    assert live.returncode == 0
    assert _parts(tmp_path) == []
    np.testing.assert_array_equal(tifffile.imread(target), [np.zeros((64, 64)), np.ones((64, 64))])


def test_a_killed_writers_temporary_goes_with_the_next_write(tmp_path):
    target = tmp_path / "stack.tif"
    other = tmp_path / "other.tif"
    killed = _start_writer(target)
    bystander = _start_writer(other)  # alive, writing another file
    _kill9(killed)
    stale = [n for n in _parts(tmp_path) if n.startswith(".stack.tif.")]
    assert len(stale) == 1
    write_tiff_stack(target, [np.zeros((8, 8), np.float32)])
    left = _parts(tmp_path)
    assert stale[0] not in left
    assert len(left) == 1 and left[0].startswith(".other.tif.")  # not ours to judge
    _kill9(bystander)
    # a table is written through the same mechanism
    write_table(other, pd.DataFrame({"a": [1]}))
    assert _parts(tmp_path) == []


def test_what_the_sweep_keeps_and_removes(tmp_path):
    target = tmp_path / "crops.tif"
    host_pid = create_temporary(target)
    tmp, fd = host_pid
    name = tmp.name
    host = name.split("-")[1]
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True).stdout.strip()
    files = {
        # unlocked, written by a process that no longer exists: a leftover
        f".crops.tif.holofit-{host}-{dead}-abcd1234.part": True,
        # unlocked but its process is alive (this one): kept
        f".crops.tif.holofit-{host}-{os.getpid()}-abcd1234.part": False,
        # an older holofit's leftover (no lock, no pid): removed once old enough
        ".crops.tif.zz9_zz9z.part": True,
        ".crops.tif.yy8_yy8y.part": False,  # recent: kept
        # other files are never touched
        ".crops.tif.json.holofit-x-1-abcd1234.part": False,
        "crops.tif.holofit-x-1-abcd1234.part": False,
        ".crops.tif.notours.part": False,
        ".crops.tif.holofit-x-1-abcd1234.part.bak": False,
    }
    for file in files:
        (tmp_path / file).write_bytes(b"x" * 100)
    old = time.time() - 3600
    os.utime(tmp_path / ".crops.tif.zz9_zz9z.part", (old, old))
    removed = {p.name for p in remove_stale_temporaries(target)}
    assert removed == {f for f, gone in files.items() if gone}
    assert (tmp_path / name).exists()  # locked by this process: a live writer
    os.close(fd)
    assert {p.name for p in remove_stale_temporaries(target)} == set()  # our pid is alive
    tmp.unlink()


def test_writer_cleans_up_after_an_exception(tmp_path):
    target = tmp_path / "stack.tif"
    with pytest.raises(ValueError):
        with TiffStackWriter(target) as writer:
            writer.write(np.zeros((4, 4)))
            writer.write(np.zeros((5, 5)))
    assert list(tmp_path.iterdir()) == []
