"""The README is a front page, and its ten-minute tour works as written.

The tour's shell block (after the ``<!-- tour`` marker) is run line by line in an empty folder
with this environment's ``holofit`` on PATH, as a user would run it: every command must exit 0
and write the files it is known to write. The full tour takes about two minutes on two cores,
so it is a slow test (``make test-all``); ``make test`` runs the same commands on a cut-down
case: 12 frames instead of 40, 2 initial frames, a smaller rod on a coarser lattice (a
particle file written beside the commands), so that its DDA solves and T-matrices cost
seconds, and the per-frame stages in their own process (``-j 0``: no worker processes to
start).
"""

from __future__ import annotations

import os
import shlex
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
MARKER = "<!-- tour"

#: what each tour command writes into its ``-o`` folder; a command new to the tour needs its
#: entry here, so that the test knows what to look for
OUTPUTS: dict[tuple[str, ...], tuple[str, ...]] = {
    ("simulate", "trajectory"): ("trajectory.csv", "truth.csv"),
    ("simulate", "hologram"): ("movie.tif", "background.tif", "truth.csv"),
    ("crop",): ("crops.tif", "crops.csv"),
    ("prefit",): ("prefit.csv",),
    ("library",): ("library.csv",),
    ("fit",): ("initial.csv", "static.json", "fit.csv"),
    ("analyze",): ("summary.csv", "summary.json", "msd.csv"),
}

#: the cut-down tour's particle: the paper's rod at 0.6 of its size, 6 dipoles per wavelength
SMALL_ROD = """[particle]
model = "spherocylinder"
a_um = 0.30
b_um = 0.60
index = 1.495

[dda]
dipoles_per_wavelength = 6
"""


def tour_commands(text: str) -> list[list[str]]:
    """The commands of the first fenced block after the tour marker (continuation lines
    joined, comments dropped), each as its argument list."""
    after = text[text.index(MARKER):]
    fence = after.index("```")
    body = after[fence:].split("\n", 1)[1]
    body = body[:body.index("```")]
    lines = body.replace("\\\n", " ").splitlines()
    return [shlex.split(line, comments=True) for line in lines
            if line.strip() and not line.strip().startswith("#")]


def _subcommand(argv: list[str]) -> tuple[str, ...]:
    return tuple(argv[1:3]) if argv[1] == "simulate" else (argv[1],)


def _out_dir(argv: list[str]) -> str:
    for flag in ("-o", "--out"):
        if flag in argv:
            return argv[argv.index(flag) + 1]
    raise AssertionError(f"tour command without -o: {shlex.join(argv)}")


def cut_down(commands: list[list[str]], particle: str) -> list[list[str]]:
    """The tour's commands on the cut-down case (module docstring)."""
    out = []
    for argv in commands:
        argv = ["12" if prev == "--n-frames" else a for prev, a in zip(["", *argv[:-1]], argv,
                                                                         strict=True)]
        argv = [particle if a == "rod_paper" else a for a in argv]
        if _subcommand(argv) == ("fit",):
            argv += ["--initial-frames", "2"]
        if _subcommand(argv) in (("crop",), ("prefit",), ("library",), ("fit",)):
            argv += ["-j", "0"]
        out.append(argv)
    return out


def _run_tour(commands: list[list[str]], folder: Path) -> dict[str, float]:
    bin_dir = Path(sys.executable).parent
    assert (bin_dir / "holofit").exists(), f"no holofit beside {sys.executable}"
    env = {**os.environ, "PATH": f"{bin_dir}{os.pathsep}{os.environ.get('PATH', '')}",
           "OMP_NUM_THREADS": "1"}
    times = {}
    for argv in commands:
        assert argv[0] == "holofit", f"the tour runs holofit only: {shlex.join(argv)}"
        t0 = time.perf_counter()
        proc = subprocess.run(argv, cwd=folder, env=env, capture_output=True, text=True,
                              timeout=900)
        times[shlex.join(argv[:3])] = time.perf_counter() - t0
        assert proc.returncode == 0, (f"{shlex.join(argv)} exited {proc.returncode}:\n"
                                      f"{proc.stdout[-2000:]}\n{proc.stderr[-3000:]}")
        out = folder / _out_dir(argv)
        missing = [f for f in OUTPUTS[_subcommand(argv)] if not (out / f).is_file()]
        assert not missing, f"{shlex.join(argv)} did not write {missing} in {out}"
    return times


def test_the_readme_is_a_front_page() -> None:
    """At most 400 lines, starting with the two commands the project requires, and a tour."""
    text = README.read_text()
    lines = text.splitlines()
    assert len(lines) <= 400, f"README.md has {len(lines)} lines (at most 400)"
    first = text.split("```", 2)[1]
    assert text.split("```", 1)[0].strip() == "# holofit", "the README starts with the commands"
    assert "make demo" in first and "make test" in first
    assert MARKER in text


def test_the_tour_names_what_every_command_writes() -> None:
    commands = tour_commands(README.read_text())
    assert [_subcommand(c) for c in commands] == list(OUTPUTS), (
        "the tour's commands changed: update OUTPUTS (what each writes)")
    for argv in commands:
        _out_dir(argv)


def test_the_cut_down_tour_runs(tmp_path: Path) -> None:
    (tmp_path / "rod_small.toml").write_text(SMALL_ROD)
    commands = cut_down(tour_commands(README.read_text()), "rod_small.toml")
    _run_tour(commands, tmp_path)


@pytest.mark.slow
def test_the_tour_runs_as_written(tmp_path: Path) -> None:
    times = _run_tour(tour_commands(README.read_text()), tmp_path)
    print({k: round(v, 1) for k, v in times.items()}, f"total {sum(times.values()):.0f} s")
