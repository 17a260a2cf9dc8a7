"""Running a run folder's make in tests: the environment, which stages ran, file time stamps."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

#: the tests drive the real make; CI has it
needs_make = pytest.mark.skipif(shutil.which("make") is None, reason="needs GNU make")

#: a stage command as make echoes it, after the HOLOFIT command
_STAGE = re.compile(r" (crop|prefit|library|fit|analyze)\b(.*)$")


def make_env() -> dict[str, str]:
    """The environment of make: this checkout's holofit first, unbuffered output."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(
        p for p in (str(REPO), env.get("PYTHONPATH", "")) if p)
    env["PYTHONUNBUFFERED"] = "1"
    env.pop("MAKEFLAGS", None)
    env.pop("MFLAGS", None)
    return env


def run_make(run: Path, *args: str, timeout: float = 600) -> subprocess.CompletedProcess[str]:
    """``make -C run args...``, output (stdout and stderr together) captured."""
    return subprocess.run(["make", "-C", str(run), *args], stdout=subprocess.PIPE,
                          stderr=subprocess.STDOUT, text=True, env=make_env(), timeout=timeout,
                          check=False)


def holofit_command(run: Path) -> str:
    """The run folder's ``HOLOFIT`` command, as its Makefile sets it."""
    for line in (run / "Makefile").read_text().splitlines():
        if line.startswith("HOLOFIT"):
            return line.split("=", 1)[1].strip()
    raise AssertionError(f"{run}/Makefile sets no HOLOFIT")


def stages_run(output: str, run: Path, command: str | None = None) -> list[tuple[str, str]]:
    """The stage commands make echoed, in order: ``[("crop", options), ("fit initial",
    options), ...]``; a command starts with ``command`` (default: the run folder's HOLOFIT)."""
    command = command or holofit_command(run)
    out = []
    for line in output.replace("\\\n", " ").splitlines():
        m = _STAGE.match(line[len(command):]) if line.startswith(command) else None
        if not m:
            continue
        stage, rest = m.group(1), m.group(2)
        if stage == "fit":
            stage += " initial" if "--pass initial" in rest else " final"
        out.append((stage, rest))
    return out


def names(ran: list[tuple[str, str]]) -> list[str]:
    return [stage for stage, _ in ran]


def mtimes(folder: Path) -> dict[str, int]:
    """Relative path -> modification time (ns) of every file below ``folder``."""
    return {str(p.relative_to(folder)): p.stat().st_mtime_ns
            for p in sorted(folder.rglob("*")) if p.is_file()}
