"""Accuracy of the DDA polarisability prescriptions against exact Lorenz-Mie spheres.

``python bench/polarizability_vs_mie.py [--out FILE.json]`` solves spheres of several sizes and
indices (the rod's n = 1.495, the paper's sphere n = 1.585, high indices 2.0 and 2.74) with
the built-in DDA at its default dipole size (10 dipoles per wavelength in the particle) and
each prescription:

- ``fcd``: filtered coupled dipoles with the filtered interaction (the engine's default),
  incidence-independent;
- ``ldr``: lattice dispersion relation (ADDA's default), S term of the incident wave;
- ``ldr_avg``: LDR with S averaged over directions and polarisations (1/5), incidence-
  independent: the one a T-matrix needs;
- ``cm``: Clausius-Mossotti (with the radiative reaction term), incidence-independent.

Each sphere is solved for light along a lattice axis (LDR's S = 0) and along a cube diagonal
(S up to 1/3), and compared with Lorenz-Mie (:mod:`holofit.scattering.mie`): hologram
``1 - R^2`` and ``max|dE|/max|E|`` on a 140 x 140 camera of 0.1 um pixels 12 um (and 5 um)
below the sphere, far-field amplitudes over 400 random directions, and the extinction cross
section. Prints a table and writes the numbers as JSON (not a benchmark: no timings).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from holofit.conventions import DetectorGrid, r_squared
from holofit.dda.engine import BuiltinDDA
from holofit.hologram import calc_hologram
from holofit.optics import Optics
from holofit.particles import Sphere
from holofit.scattering.mie import LorenzMie, cross_sections
from holofit.scattering.theory import Orientation

OPTICS = Optics(0.66, 1.33, 0.0)
GRID = DetectorGrid((140, 140), 0.1)
SPHERES = [Sphere(0.45, 1.495), Sphere(0.75, 1.495), Sphere(0.45, 1.585), Sphere(0.3, 2.0),
           Sphere(0.45, 2.0), Sphere(0.25, 2.74)]
ORIENTATIONS = {"axis": Orientation(), "diagonal": Orientation(np.pi / 4,
                                                                np.arccos(1 / np.sqrt(3)))}
KINDS = ("fcd", "ldr", "ldr_avg", "cm")


def compare(sphere: Sphere, kind: str, orientation: Orientation) -> dict[str, float]:
    mie = LorenzMie().solve(sphere, OPTICS)
    wave = BuiltinDDA(polarizability=kind, tolerance=1e-8).solve(sphere, OPTICS, orientation)
    out: dict[str, float] = {"dipoles": float(wave.lattice.n_dipoles)}
    for z in (12.0, 5.0):
        pos = (7.0, 7.0, z)
        e_m = mie.field_on_detector(pos, GRID)
        e_d = wave.field_on_detector(pos, GRID)
        scale = max(np.abs(e).max() for e in e_m)
        out[f"field_err_z{z:g}"] = max(np.abs(a - b).max() for a, b in zip(e_d, e_m,
                                                                          strict=True)) / scale
        out[f"holo_1mR2_z{z:g}"] = 1.0 - r_squared(calc_hologram(mie, pos, GRID),
                                                   calc_hologram(wave, pos, GRID))
    dirs = np.random.default_rng(0).normal(size=(400, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    pts = dirs * 1e4
    f_m = mie.field_at(pts, far_field=True)
    f_d = wave.field_at(pts, far_field=True)
    out["farfield_err"] = float(np.abs(f_d - f_m).max() / np.abs(f_m).max())
    k = OPTICS.k
    fwd = wave.far_field_amplitude(np.array([[0.0, 0.0, -1.0]]))[0]
    c_ext = 4 * np.pi / k**2 * float(np.real(np.dot(OPTICS.polarization, fwd)))
    c_mie = cross_sections(complex(sphere.index) / OPTICS.n_medium, sphere.radius_um,
                           k).extinction_um2
    out["cext_rel_err"] = (c_ext - c_mie) / c_mie
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    rows = []
    for sphere in SPHERES:
        for oname, ori in ORIENTATIONS.items():
            for kind in KINDS:
                res = compare(sphere, kind, ori)
                row = {"radius_um": sphere.radius_um, "index": float(np.real(sphere.index)),
                       "light": oname, "polarizability": kind, **res}
                rows.append(row)
                print(f"a={sphere.radius_um:.2f} n={row['index']:.3f} {oname:8s} {kind:7s} "
                      f"N={int(res['dipoles']):6d}  1-R2(z12)={res['holo_1mR2_z12']:.2e} "
                      f"1-R2(z5)={res['holo_1mR2_z5']:.2e} dE(z12)={res['field_err_z12']:.2e} "
                      f"far={res['farfield_err']:.2e} Cext={res['cext_rel_err']:+.2e}",
                      flush=True)
    if args.out:
        args.out.write_text(json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main()
