"""The built-in DDA of a dimer against the exact superposition T-matrix as the dipoles shrink.

Usage: ``python bench/study_dimer_dda_convergence.py [--dpl 5 7 10 14 20] [--out FILE.json]``.

Two touching polystyrene spheres (radii 0.35 um, n 1.59) in water at 660 nm, one orientation
(psi 0.4, theta 1.0, phi 0.3), the hologram on 140 x 140 pixels of 0.1 um 12 um from focus
(the ideal model). For each dipoles-per-wavelength value (the engine's default rule is 10) the
DDA (filtered coupled dipoles, laminate voxels, tolerance 1e-8) is solved directly and
compared with the cluster engine: the field error ``max|dE| / max|E|`` on the camera, the
hologram's ``1 - R^2`` against the exact one (the discretisation study's measure) and the
extinction error. Prints a table and one JSON line; ``tests/test_cluster_dda.py`` asserts the
convergence on a coarser ladder.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from holofit.conventions import DetectorGrid
from holofit.dda.engine import BuiltinDDA
from holofit.hologram import calc_hologram
from holofit.optics import Optics
from holofit.particles import Dimer
from holofit.scattering.cluster import ClusterEngine
from holofit.scattering.theory import Orientation

OPTICS = Optics(0.66, 1.33, 0.0)
GRID = DetectorGrid((140, 140), 0.1)
POS = (7.0, 7.0, 12.0)
MODEL = Dimer(0.35, 0.35, 0.0, 1.59, 1.59)
ORIENTATION = Orientation(0.4, 1.0, 0.3)


def compare(dpl: float, model: Dimer = MODEL) -> dict[str, float]:
    """Errors of the DDA at ``dpl`` dipoles per wavelength against the cluster engine."""
    exact = ClusterEngine().solve(model, OPTICS, ORIENTATION)
    engine = BuiltinDDA(dipoles_per_wavelength=dpl, tolerance=1e-8)
    t0 = time.perf_counter()
    wave = engine.solve_direct(model, OPTICS, ORIENTATION)
    solve_s = time.perf_counter() - t0
    e_ref = np.stack(exact.field_on_detector(POS, GRID))
    e_dda = np.stack(wave.field_on_detector(POS, GRID))
    h_ref = calc_hologram(exact, POS, GRID)
    h_dda = calc_hologram(wave, POS, GRID)
    r2 = 1.0 - np.sum((h_dda - h_ref) ** 2) / np.sum((h_ref - h_ref.mean()) ** 2)
    fwd = np.array([[0.0, 0.0, -1.0]])
    pol = OPTICS.polarization
    c_ref = float(np.real(exact.far_field_amplitude(fwd)[0] @ pol))
    c_dda = float(np.real(wave.far_field_amplitude(fwd)[0] @ pol))
    d = engine.settings.dipole_size_for(model, OPTICS)
    return {"dpl": dpl, "d_um": d, "dipoles": float(wave.solution.lattice.n_dipoles),
            "field_error": float(np.abs(e_dda - e_ref).max() / np.abs(e_ref).max()),
            "one_minus_r2": float(1.0 - r2),
            "extinction_error": abs(c_dda - c_ref) / abs(c_ref), "solve_s": solve_s}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--dpl", type=float, nargs="*", default=[5, 7, 10, 14, 20])
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    rows = []
    print("| dpl | d (nm) | dipoles | max|dE|/max|E| | 1 - R^2 | C_ext error | solve (s) |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for dpl in args.dpl:
        r = compare(dpl)
        rows.append(r)
        print(f"| {dpl:g} | {1e3 * r['d_um']:.1f} | {r['dipoles']:.0f} | "
              f"{r['field_error']:.2e} | {r['one_minus_r2']:.2e} | "
              f"{r['extinction_error']:.2e} | {r['solve_s']:.1f} |", flush=True)
    text = json.dumps({"model": "dimer 0.35 + 0.35 um, n 1.59, touching", "rows": rows})
    if args.out:
        args.out.write_text(text + "\n")
    print(text)


if __name__ == "__main__":
    main()
