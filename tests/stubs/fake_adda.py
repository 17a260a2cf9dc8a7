#!/usr/bin/env python3
"""A stand-in for the ADDA executable, for holofit's tests (no code of ADDA; written from the
conventions in tests/data/adda/README_reference.md).

It understands the command line that holofit's ADDA engine passes and, in the default mode
``born``, writes ``ampl_scatgrid`` for the *first Born approximation* of the dipole set (each
dipole polarised by the incident field alone, Clausius-Mossotti polarisability), computed
entirely in ADDA's own conventions: light along ADDA's +z, ``-orient`` zyz active rotation about
the dipole-box centre, phase origin at the box centre, Bohren & Huffman amplitude-matrix basis.
The tests compare what holofit makes of that file with the same Born sum done in holofit's lab
frame, so every seam (frames, orientation, phase origin, row order, polarisation) is checked
without ADDA.

Environment variables:
    FAKE_ADDA_MODE     born (default) | exit | error | maxiter | warn | shuffle | noampl
    FAKE_ADDA_VERSION  first line printed by ``-V`` (default ``ADDA v.1.5.0-alpha3 (stub)``)
    FAKE_ADDA_CALLS    file to which each invocation appends one JSON line {argv, cwd}
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import numpy as np


def options(argv: list[str]) -> dict[str, list[str]]:
    out: dict[str, list[str]] = {}
    key = None
    for arg in argv:
        if arg.startswith("-") and len(arg) > 1 and not _is_number(arg):
            key = arg[1:]
            out[key] = []
        elif key is not None:
            out[key].append(arg)
    return out


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def read_shape(path: Path) -> tuple[np.ndarray, np.ndarray]:
    rows = []
    for line in path.read_text().splitlines():
        text = line.split("#", 1)[0].strip()
        if not text or text.lower().startswith("nmat"):
            continue
        parts = [int(v) for v in text.split()]
        rows.append(parts + [1] * (4 - len(parts)))
    arr = np.array(rows)
    return arr[:, :3], arr[:, 3]


def read_pairs(path: Path) -> tuple[np.ndarray, np.ndarray]:
    lines = path.read_text().splitlines()
    assert lines[0].strip() == "global_type=pairs", lines[0]
    n = int(lines[1].split("=")[1])
    assert lines[2].strip() == "pairs="
    vals = np.array([[float(v) for v in line.split()] for line in lines[3 : 3 + n]])
    return vals[:, 0], vals[:, 1]


def rz(t: float) -> np.ndarray:
    c, s = np.cos(t), np.sin(t)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def ry(t: float) -> np.ndarray:
    c, s = np.cos(t), np.sin(t)
    return np.array([[c, 0, s], [0, 1.0, 0], [-s, 0, c]])


def born_ampl(opts: dict[str, list[str]], cwd: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    ijk, dom = read_shape(cwd / opts["shape"][1])
    lo, hi = ijk.min(axis=0), ijk.max(axis=0)
    box = hi - lo + 1
    d = float(opts["size"][0]) / box[0]
    r_p = (ijk - lo - (box - 1) / 2.0) * d
    a, b, g = (np.radians(float(v)) for v in opts.get("orient", ["0", "0", "0"]))
    r = r_p @ (rz(a) @ ry(b) @ rz(g)).T
    m_vals = [float(v) for v in opts["m"]]
    m = np.array(m_vals[0::2]) + 1j * np.array(m_vals[1::2])
    alpha_dom = 3 * d**3 / (4 * np.pi) * (m**2 - 1) / (m**2 + 2)
    alpha = alpha_dom[dom - 1]
    k = 2 * np.pi / float(opts["lambda"][0])
    theta, phi = read_pairs(cwd / opts["scat_grid_inp"][0])
    th, ph = np.radians(theta), np.radians(phi)
    n = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], axis=1)
    # sum_j alpha_j exp(i k (z_j - n.r_j)): incident phase at the dipole, radiated phase
    s = np.exp(1j * k * (r[:, 2][None, :] - n @ r.T)) @ alpha
    fields = []
    for e in (np.array([1.0, 0, 0]), np.array([0, 1.0, 0])):
        e_perp = e[None, :] - n * (n @ e)[:, None]
        fields.append(-1j * k**3 * e_perp * s[:, None])
    fx, fy = fields
    e_th = np.stack([np.cos(th) * np.cos(ph), np.cos(th) * np.sin(ph), -np.sin(th)], axis=1)
    e_per = -np.stack([-np.sin(ph), np.cos(ph), 0 * ph], axis=1)
    c, sn = np.cos(ph), np.sin(ph)
    fxt, fyt = (fx * e_th).sum(1), (fy * e_th).sum(1)
    fxp, fyp = (fx * e_per).sum(1), (fy * e_per).sum(1)
    s1 = sn * fxp - c * fyp
    s2 = c * fxt + sn * fyt
    s3 = sn * fxt - c * fyt
    s4 = c * fxp + sn * fyp
    return theta, phi, np.stack([s1, s2, s3, s4], axis=1)


def write_outputs(out: Path, theta: np.ndarray, phi: np.ndarray, amp: np.ndarray) -> None:
    out.mkdir(parents=True, exist_ok=False)
    lines = ["theta phi s1.r s1.i s2.r s2.i s3.r s3.i s4.r s4.i"]
    for t, p, row in zip(theta, phi, amp, strict=True):
        vals = " ".join(f"{v:.10E}" for z in row for v in (z.real, z.imag))
        lines.append(f"{t:.2f} {p:.2f} {vals}")
    (out / "ampl_scatgrid").write_text("\n".join(lines) + "\n")
    for pol in ("X", "Y"):
        (out / f"CrossSec-{pol}").write_text("Cext\t= 1.0\nQext\t= 1.0\n")
    (out / "log").write_text("stand-in ADDA log\n")


def main() -> int:
    argv = sys.argv[1:]
    calls = os.environ.get("FAKE_ADDA_CALLS")
    if calls:
        with open(calls, "a") as fh:
            fh.write(json.dumps({"argv": argv, "cwd": os.getcwd()}) + "\n")
    if argv == ["-V"]:
        print(os.environ.get("FAKE_ADDA_VERSION", "ADDA v.1.5.0-alpha3 (stub)"))
        print("Sequential version")
        return 0
    mode = os.environ.get("FAKE_ADDA_MODE", "born")
    if mode == "exit":
        sys.stderr.write("stand-in crashed: out of memory\n")
        return 3
    if mode == "error":
        sys.stderr.write("ERROR: (../make_particle.c:1061) Failed to open file 'shape.dat'\n")
        return 0
    if mode == "noampl":
        return 0
    opts = options(argv)
    cwd = Path.cwd()
    theta, phi, amp = born_ampl(opts, cwd)
    order = np.arange(theta.size)[::-1] if mode == "shuffle" else np.arange(theta.size)
    write_outputs(cwd / opts["dir"][0], theta[order], phi[order], amp[order])
    if mode == "maxiter":
        for _ in range(2):
            sys.stderr.write(
                "WARNING: (../iterative.c:1630) Iterations haven't converged in 3 iterations.\n"
                "Further calculated scattering quantities may be less accurate.\n"
            )
    if mode == "warn":
        sys.stderr.write("WARNING: (../param.c:2100) a harmless stand-in warning\n")
    print("all data is saved in '" + opts["dir"][0] + "'")
    return 0


if __name__ == "__main__":
    sys.exit(main())
