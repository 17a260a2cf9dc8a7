"""Accuracy of DDA discretisations against exact Lorenz-Mie (homogeneous and coated spheres).

Not a timed benchmark (``bench/run.py`` does not run it): a study that prints, per material,
discretisation and dipoles per wavelength, the hologram error ``1 - R^2`` and the far-field
error ``max |dF| / max |F|`` against the exact solution, and appends JSON lines to a file::

    python bench/study_dda_discretisation.py [--cases a,b] [--variants x,y] [--dpl 10,15,20]
                                            [--out study.jsonl]

Discretisations (``--variants``):

* ``binary-ldr``: centre-inside voxels, LDR (ADDA's defaults; the binary baseline);
* ``binary-fcd``: centre-inside voxels, filtered coupled dipoles;
* ``previous-ldr``: holofit's earlier smooth filling (C2 ramp of half-width 15/16 d,
  Maxwell-Garnett mixing of the Clausius-Mossotti factors), LDR;
* ``fractional-ldr``: the current smooth filling (C2 ramp of half-width d/2, laminate
  anisotropic permittivity of boundary voxels), LDR;
* ``fractional-fcd``: the same with filtered coupled dipoles (the engine's default).

Hologram: 100 x 100 pixels of 0.1 um, particle 8 um above focus, lambda 0.66 um in water,
x polarisation, exact near field on both sides. Far field: 120 directions (Gauss-Legendre in
theta, three azimuths). Dipole size ``d = lambda_medium / (dpl * max |m|)`` (the engine's rule
with ``dipoles_per_wavelength = dpl``); solver tolerance 1e-7.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from holofit.conventions import DetectorGrid, r_squared
from holofit.dda.dipoles import DipoleSystem
from holofit.dda.engine import DDAWave
from holofit.dda.lattice import Lattice
from holofit.dda.voxelize import ramp
from holofit.hologram import calc_hologram
from holofit.optics import Optics
from holofit.particles import Sphere
from holofit.scattering.coated_mie import CoatedSphereWave
from holofit.scattering.theory import Orientation

OPTICS = Optics(0.66, 1.33, 0.0)
GRID = DetectorGrid((100, 100), 0.1)
POSITION = (5.0, 5.0, 8.0)

#: name -> (core radius, outer radius, core index, shell index); core radius 0: homogeneous
CASES = {
    "silica r0.5 (n 1.45)": (0.0, 0.5, 1.0, 1.45),
    "polystyrene r0.5 (n 1.59)": (0.0, 0.5, 1.0, 1.59),
    "n 2.0 r0.4 (m 1.5)": (0.0, 0.4, 1.0, 1.995),
    "TiO2 r0.3 (n 2.74)": (0.0, 0.3, 1.0, 2.74),
    "lossy r0.3 (n 1.5+0.5i)": (0.0, 0.3, 1.0, 1.5 + 0.5j),
    "absorbing r0.2 (n 1.2+2i)": (0.0, 0.2, 1.0, 1.2 + 2.0j),
    "metal r0.2 (n 0.2+4i)": (0.0, 0.2, 1.0, 0.2 + 4.0j),
    "PS core 0.2 + TiO2 shell 0.047": (0.2, 0.247, 1.59, 2.74),
    "silica core 0.15 + metal shell 0.03": (0.15, 0.18, 1.45, 0.2 + 4.0j),
}
#: name -> (filling, ramp half-width in d, laminate boundary voxels, polarizability)
VARIANTS = {
    "binary-ldr": ("binary", 0.0, False, "ldr"),
    "binary-fcd": ("binary", 0.0, False, "fcd"),
    "previous-ldr": ("fractional", 15.0 / 16.0, False, "ldr"),
    "fractional-ldr": ("fractional", 0.5, True, "ldr"),
    "fractional-fcd": ("fractional", 0.5, True, "fcd"),
}


def concentric_lattice(geometry, d: float, filling: str, half_width: float,
                       laminate: bool) -> Lattice:
    """A (coated) sphere on the lattice, with :mod:`holofit.dda.voxelize`'s rules: fractions
    from the signed distances of the two spheres, radial interface normals."""
    core_r, outer_r, n_core, n_shell = geometry
    extent = outer_r + 2 * d
    j = np.arange(int(np.floor(-extent / d - 0.5)) - 1, int(np.ceil(extent / d - 0.5)) + 2)
    jj = np.stack(np.meshgrid(j, j, j, indexing="ij"), -1).reshape(-1, 3)
    p = (jj + 0.5) * d
    r = np.linalg.norm(p, axis=1)
    if filling == "binary":
        f_out, f_core = (r <= outer_r).astype(float), (r <= core_r).astype(float)
    else:
        f_out = ramp((r - outer_r) / d, half_width)
        f_core = ramp((r - core_r) / d, half_width) if core_r > 0 else np.zeros_like(r)
    frac = np.column_stack([f_core, np.maximum(f_out - f_core, 0.0)])
    keep = frac.sum(axis=1) > 0
    jj, frac, p, r = jj[keep], frac[keep], p[keep], r[keep]
    partial = np.any((frac > 0) & (frac < 1), axis=1) | ((frac.sum(1) > 0) & (frac.sum(1) < 1))
    normals = np.where(partial[:, None], p / np.maximum(r, 1e-300)[:, None], 0.0)
    j0 = jj.min(axis=0)
    ijk = jj - j0
    order = np.lexsort((ijk[:, 2], ijk[:, 1], ijk[:, 0]))
    return Lattice(d=d, shape=tuple(int(v) for v in ijk.max(axis=0) + 1),  # type: ignore[arg-type]
                   origin=(j0 + 0.5) * d, ijk=np.ascontiguousarray(ijk[order]),
                   fractions=np.ascontiguousarray(frac[order]), indices=(n_core, n_shell),
                   normals=np.ascontiguousarray(normals[order]) if laminate else None)


def _far_directions() -> np.ndarray:
    mu, _ = np.polynomial.legendre.leggauss(40)
    th, ph = np.arccos(mu), np.radians([0.0, 45.0, 90.0])
    return np.stack([np.outer(np.sin(th), np.cos(ph)), np.outer(np.sin(th), np.sin(ph)),
                     np.outer(np.cos(th), np.ones(3))], -1).reshape(-1, 3)


def exact_reference(geometry) -> tuple[np.ndarray, np.ndarray]:
    """Exact hologram and far-field vectors F(n) (``E = exp(ikr)/(-ikr) F``)."""
    core_r, outer_r, n_core, n_shell = geometry
    wave = CoatedSphereWave(core_r, outer_r, n_core, n_shell, OPTICS)
    k, r = OPTICS.k, 1e4
    n = _far_directions()
    f = wave.field_at(n * r, far_field=True) * (-1j * k * r * np.exp(-1j * k * r))
    return calc_hologram(wave, POSITION, GRID), f


def run(geometry, variant: str, dpl: float, reference) -> dict:
    filling, half_width, laminate, pol = VARIANTS[variant]
    m_max = max(abs(complex(n)) for n in geometry[2:]) / OPTICS.n_medium
    d = OPTICS.wavelength_medium_um / (dpl * m_max)
    lat = concentric_lattice(geometry, d, filling, half_width, laminate)
    system = DipoleSystem(lat, OPTICS.k, OPTICS.n_medium, pol)
    t0 = time.perf_counter()
    sol = system.solve([0.0, 0.0, -1.0], [1.0, 0.0, 0.0], tol=1e-7, maxiter=20000)
    seconds = time.perf_counter() - t0
    wave = DDAWave(Sphere(geometry[1], geometry[3]), OPTICS, Orientation(), sol, np.eye(3))
    holo_ref, f_ref = reference
    f = wave.far_field_amplitude(_far_directions())
    holo = calc_hologram(wave, POSITION, GRID)
    return {"dipoles": lat.n_dipoles, "iterations": sol.iterations, "solve_s": seconds,
            "holo_one_minus_r2": 1.0 - r_squared(holo_ref, holo),
            "far_field_error": float(np.abs(f - f_ref).max() / np.abs(f_ref).max())}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", default=",".join(CASES))
    parser.add_argument("--variants", default=",".join(VARIANTS))
    parser.add_argument("--dpl", default="10,15,20")
    parser.add_argument("--out", default="dda_discretisation_study.jsonl")
    args = parser.parse_args()
    for case in args.cases.split(","):
        reference = exact_reference(CASES[case])
        for dpl in (float(v) for v in args.dpl.split(",")):
            for variant in args.variants.split(","):
                row = {"case": case, "variant": variant, "dpl": dpl,
                       **run(CASES[case], variant, dpl, reference)}
                print(f"{case:36s} {variant:15s} dpl {dpl:4.0f} N {row['dipoles']:7d} "
                      f"it {row['iterations']:5d}  1-R2 {row['holo_one_minus_r2']:.2e}  "
                      f"far field {row['far_field_error']:.4f}", flush=True)
                with open(args.out, "a") as fh:
                    fh.write(json.dumps(row) + "\n")


if __name__ == "__main__":
    main()
