"""The DDA's model error by filling rule and dipole size, against exact solutions (issue 37,
item 4): the plane-cut filling (``fractional``, the default) against the C2 ramp it replaced
(``ramp``), and the flat-ended cylinder's convergence in the dipole size.

Usage: ``python bench/study_dda_filling.py [--parts compare cylinder]
[--out bench/results/exact/dda_filling.json]``; prints a line per solve and writes one JSON
object.

Error: ``max |F_DDA - F_exact| / max |F_exact|`` of the far-field amplitude over 200 random
directions, for the plane wave of the orientation (psi 30, theta 45, phi 23 deg), x
polarisation; solver tolerance 1e-7. References (their own accuracy in brackets): Lorenz-Mie
and coated-sphere Mie (1e-8), holofit's exact T-matrix for the spheroid (EBCM order 28, 1e-10),
the rod (EBCM order 26, 3-7e-4 against the long-double EBCM), the cylinder (EBCM order 34, ~2e-5
against the long-double EBCM and pytmatrixc) and the Janus particle (imbedding order 28,
~5e-4).

* ``compare``: each particle at 10 and 20 dipoles per wavelength with both fillings; the
  spheres at seven radii 0.40-0.52 um (mean and largest error), as one radius alone can be
  lucky on the lattice;
* ``cylinder``: the cylinder (radius 0.5, half-length 1.0 um, n 1.495 in water) at 10, 14, 20,
  28 and 40 dipoles per wavelength, the plane-cut filling (and the ramp up to 28), with the
  voxelised volumes.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from holofit.dda.engine import BuiltinDDA
from holofit.dda.settings import DDASettings
from holofit.optics import Optics
from holofit.particles import (
    CoatedSphere,
    Cylinder,
    JanusSphere,
    ParticleModel,
    Sphere,
    Spherocylinder,
    Spheroid,
)
from holofit.scattering.axisym import build_exact_tmatrix
from holofit.scattering.theory import Orientation
from holofit.scattering.tmatrix_wave import TMatrixWave

OPTICS = Optics(0.660, 1.33)
ORIENTATION = Orientation(np.pi / 6, np.pi / 4, 0.4)
CYLINDER = Cylinder(0.5, 1.0, 1.495)
#: name -> (model, exact order or None for the builder's default)
PARTICLES: dict[str, tuple[ParticleModel, int | None]] = {
    "rod": (Spherocylinder(0.501, 1.079, 1.495), None),
    "spheroid": (Spheroid(0.5, 1.0, 1.495), 28),
    "cylinder": (CYLINDER, 34),
    "janus": (JanusSphere(0.443, 0.047, 1.581, 2.74), 28),
    "coated": (CoatedSphere(0.443, 0.047, 1.581, 2.74), None),
}
SPHERE_RADII = np.linspace(0.40, 0.52, 7)
SPHERE_INDICES = {"silica": 1.45, "polystyrene": 1.59}


def _directions() -> np.ndarray:
    d = np.random.default_rng(3).normal(size=(200, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def _exact(model: ParticleModel, order: int | None) -> np.ndarray:
    tm = build_exact_tmatrix(model, OPTICS, order=order, max_seconds=120.0)
    return TMatrixWave(model, OPTICS, ORIENTATION, tm).far_field_amplitude(_directions())


def dda_error(model: ParticleModel, reference: np.ndarray, dpl: float, filling: str
              ) -> dict[str, float]:
    """The DDA's far-field error against ``reference``, with its dipoles and volume."""
    settings = DDASettings(dipoles_per_wavelength=dpl, filling=filling, tolerance=1e-7)
    engine = BuiltinDDA(settings)
    t0 = time.perf_counter()
    wave = engine.solve_direct(model, OPTICS, ORIENTATION)
    f = wave.far_field_amplitude(_directions())
    lattice = engine.lattice(model, OPTICS)
    return {"dpl": dpl, "filling": filling, "dipoles": float(lattice.n_dipoles),
            "volume_um3": float(lattice.occupied_volume_um3().sum()),
            "error": float(np.abs(f - reference).max() / np.abs(reference).max()),
            "seconds": time.perf_counter() - t0}


def compare() -> dict[str, list[dict]]:
    """Both fillings at 10 and 20 dipoles per wavelength (module docstring)."""
    out: dict[str, list[dict]] = {}
    for name, (model, order) in PARTICLES.items():
        ref = _exact(model, order)
        rows = [dda_error(model, ref, dpl, fill) for dpl in (10.0, 20.0)
                for fill in ("ramp", "fractional")]
        for r in rows:
            print(f"{name:10s} dpl {r['dpl']:4.0f} {r['filling']:10s} {r['error']:.2e}", flush=True)
        out[name] = rows
    for label, n in SPHERE_INDICES.items():
        rows = []
        for dpl in (10.0, 20.0):
            for fill in ("ramp", "fractional"):
                errs = [dda_error(Sphere(r, n), _exact(Sphere(r, n), None), dpl, fill)["error"]
                        for r in SPHERE_RADII]
                rows.append({"dpl": dpl, "filling": fill, "error_mean": float(np.mean(errs)),
                             "error_max": float(np.max(errs))})
                print(f"sphere {label:10s} dpl {dpl:4.0f} {fill:10s} mean {np.mean(errs):.2e} "
                      f"max {np.max(errs):.2e}", flush=True)
        out[f"sphere_{label}"] = rows
    return out


def cylinder_curve() -> list[dict]:
    """The cylinder's error against the dipole size (module docstring)."""
    ref = _exact(CYLINDER, PARTICLES["cylinder"][1])
    exact_volume = np.pi * CYLINDER.radius_um**2 * 2 * CYLINDER.half_length_um
    rows = []
    for dpl in (10.0, 14.0, 20.0, 28.0, 40.0):
        for fill in ("fractional", "ramp"):
            if fill == "ramp" and dpl > 28:
                continue
            r = dda_error(CYLINDER, ref, dpl, fill)
            r["volume_error"] = r["volume_um3"] / exact_volume - 1
            print(f"cylinder dpl {dpl:4.0f} {fill:10s} N {r['dipoles']:8.0f} error "
                  f"{r['error']:.2e} volume {r['volume_error']:+.1e} ({r['seconds']:.0f} s)",
                  flush=True)
            rows.append(r)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--parts", nargs="*", default=["compare", "cylinder"])
    ap.add_argument("--out", type=Path,
                    default=Path(__file__).resolve().parent / "results" / "exact"
                    / "dda_filling.json")
    args = ap.parse_args()
    out: dict[str, object] = {}
    if "cylinder" in args.parts:
        out["cylinder"] = cylinder_curve()
    if "compare" in args.parts:
        out["compare"] = compare()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(out) + "\n")


if __name__ == "__main__":
    main()
