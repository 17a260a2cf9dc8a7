"""Running ADDA: the command line, the subprocess, and reading what ADDA said."""

from __future__ import annotations

import math
import re
import shlex
import subprocess
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from holofit.dda.adda.errors import AddaConvergenceError, AddaError
from holofit.dda.adda.files import AddaGeometry
from holofit.optics import Optics

__all__ = ["AddaResult", "adda_command", "check_adda_output", "run_adda"]

_MAXITER_RE = re.compile(r"haven't converged in (\d+) iterations", re.IGNORECASE)


@dataclass
class AddaResult:
    """One ADDA run: what was asked, what ADDA said, what it computed.

    Attributes
    ----------
    command : list of str
        The command line (file names relative to ``workdir``).
    returncode : int
    stdout, stderr : str
    seconds : float
        Wall time of the ADDA process.
    workdir : Path or None
        Where it ran (deleted afterwards unless the engine keeps files).
    ampl : ndarray or None
        ``[S1, S2, S3, S4]`` per requested direction.
    cross_sections : dict
        ``{"X": {"Cext": ...}, "Y": {...}}`` from ``CrossSec-X/Y``, um^2.
    log : str
        ADDA's log file.
    warnings : list of str
        ADDA's non-fatal ``WARNING`` messages.
    """

    command: list[str]
    returncode: int
    stdout: str
    stderr: str
    seconds: float
    workdir: Path | None = None
    ampl: NDArray[np.complex128] | None = None
    cross_sections: dict[str, dict[str, float]] = field(default_factory=dict)
    log: str = ""
    warnings: list[str] = field(default_factory=list)


def _messages(text: str, kind: str, continued: bool = True) -> list[str]:
    """ADDA's ``ERROR:`` or ``WARNING:`` messages in ``text``.

    ADDA wraps long messages; with ``continued`` the unprefixed lines that follow a message are
    joined to it (stderr carries nothing else).
    """
    out: list[str] = []
    for line in text.splitlines():
        stripped = line.strip()
        if not stripped:
            continue
        if re.match(r"(ERROR|WARNING|INFO):", stripped):
            # other kinds are kept as "" so that their continuation lines are not misattributed
            out.append(stripped if stripped.startswith(kind + ":") else "")
        elif continued and out and out[-1]:
            out[-1] += " " + stripped
    return [m for m in out if m]


def check_adda_output(command: list[str], returncode: int, stdout: str, stderr: str) -> list[str]:
    """Raise if an ADDA run failed; return its non-fatal warnings.

    A run fails if it exits non-zero, prints an ``ERROR`` (on stderr or stdout), or reports
    that the solver did not converge within ``-maxiter`` (ADDA only warns about that and exits
    0). The exception carries ADDA's message and the command line.

    Raises
    ------
    AddaError, AddaConvergenceError
    """
    cmd = shlex.join(command)
    errors = _messages(stderr, "ERROR") + _messages(stdout, "ERROR", continued=False)
    if returncode != 0 or errors:
        said = "; ".join(errors) if errors else (stderr.strip() or stdout.strip())[-2000:]
        status = f"exited with status {returncode}" if returncode != 0 else "reported an error"
        raise AddaError(f"ADDA {status}: {said or '(no message)'}\ncommand: {cmd}")
    found = _messages(stderr, "WARNING") + _messages(stdout, "WARNING", continued=False)
    for message in found:
        if _MAXITER_RE.search(message):
            raise AddaConvergenceError(
                f"ADDA did not converge: {message} (raise max_iterations or the tolerance)\n"
                f"command: {cmd}"
            )
    return found


def run_adda(binary: str | Path, args: list[str], workdir: Path,
             timeout_s: float | None = None) -> AddaResult:
    """Run ``binary args`` in ``workdir`` and check the outcome (:func:`check_adda_output`)."""
    command = [str(binary), *args]
    t0 = time.perf_counter()
    try:
        proc = subprocess.run(command, cwd=workdir, capture_output=True, text=True,
                              timeout=timeout_s, stdin=subprocess.DEVNULL)
    except subprocess.TimeoutExpired as exc:
        raise AddaError(f"ADDA did not finish within {timeout_s} s\ncommand: "
                        f"{shlex.join(command)}") from exc
    except OSError as exc:
        raise AddaError(f"could not start ADDA: {exc}\ncommand: {shlex.join(command)}") from exc
    seconds = time.perf_counter() - t0
    found = check_adda_output(command, proc.returncode, proc.stdout, proc.stderr)
    return AddaResult(command=command, returncode=proc.returncode, stdout=proc.stdout,
                      stderr=proc.stderr, seconds=seconds, workdir=workdir, warnings=found)


def adda_command(
    geometry: AddaGeometry,
    optics: Optics,
    orient_deg: tuple[float, float, float],
    shape_file: str,
    pairs_file: str,
    out_dir: str,
    tolerance: float,
    max_iterations: int,
    polarizability: str = "ldr",
) -> list[str]:
    """ADDA's arguments for one evaluation (see ``adda/README.md`` for why each is there)."""
    n_med = optics.n_medium
    m_args: list[str] = []
    for n in geometry.indices:
        m = complex(n) / n_med
        m_args += [repr(m.real), repr(m.imag)]
    return [
        "-shape", "read", shape_file,
        "-size", repr(geometry.size_um),
        "-m", *m_args,
        "-lambda", repr(optics.wavelength_medium_um),
        "-orient", *(repr(float(a)) for a in orient_deg),
        "-pol", polarizability,
        # filtered coupled dipoles are a polarisability *and* an interaction (both engines)
        "-int", "fcd" if polarizability == "fcd" else "poi",
        "-scat", "dr",
        "-iter", "qmr",
        "-eps", repr(-math.log10(tolerance)),
        "-maxiter", str(int(max_iterations)),
        "-scat_matr", "ampl",
        "-store_scat_grid",
        "-scat_grid_inp", pairs_file,
        "-dir", out_dir,
    ]
