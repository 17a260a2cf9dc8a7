"""Exact T-matrices of bodies of revolution (holofit.scattering.axisym): build times and the
errors against the references.

Usage: ``python bench/bench_exact.py`` prints one flat JSON object (``make bench`` runs it
through ``bench/run.py`` as the group ``exact``). Keys carry the prefix ``exact_`` (the DDA's
T-matrix benchmark owns ``tmatrix_build_rod_s``). Times are the best of three builds on one
thread, after one warm-up build (compiled kernels loaded); errors are relative to the largest
amplitude or value.
"""

from __future__ import annotations

import json
import time

import numpy as np
from threadpoolctl import threadpool_limits

from holofit.optics import Optics
from holofit.particles import CoatedSphere, Cylinder, JanusSphere, Sphere, Spherocylinder, Spheroid
from holofit.scattering.axisym import build_exact_tmatrix
from holofit.scattering.axisym.iitm import integrate_profile
from holofit.scattering.axisym.order import far_field_change
from holofit.scattering.axisym.profiles import CapProfile
from holofit.scattering.coated_mie import coated_coefficients
from holofit.scattering.theory import Orientation
from holofit.scattering.tmatrix_wave import TMatrixWave

OPTICS = Optics(0.660, 1.33)
ROD = Spherocylinder(0.501, 1.079, 1.495)
SPHEROID = Spheroid(0.5, 1.0, 1.495)
CYLINDER = Cylinder(0.5, 1.0, 1.495)
JANUS = JanusSphere(0.443, 0.047, 1.581, 2.74)
#: DESIGN.md section 7: long-double EBCM, x polarisation, psi 30 deg, tilts 0 / 45 / 80 deg
ROD_CEXT = {0: 4.1681, 45: 2.9820, 80: 2.6329}


def _best_build(model, repeats: int = 3, **kw):
    best, tm = float("inf"), None
    for _ in range(repeats):
        t0 = time.perf_counter()
        tm = build_exact_tmatrix(model, OPTICS, **kw)
        best = min(best, time.perf_counter() - t0)
    return best, tm


def _extinction(tm, euler) -> float:
    e = np.array([1.0, 0.0, 0.0])
    c = tm.lab_coefficients(euler, e)
    fwd = tm.expansion(c.vector).far_amplitude(np.array([[0.0, 0.0, -1.0]]))[0]
    return float(4 * np.pi / tm.k**2 * np.imag(e @ fwd))


def _dda_error(model, tm) -> float:
    from holofit.dda.engine import BuiltinDDA
    from holofit.dda.settings import DDASettings

    rng = np.random.default_rng(3)
    dirs = rng.normal(size=(200, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    o = Orientation(np.pi / 6, np.pi / 4, 0.4)
    fd = BuiltinDDA(DDASettings()).solve_direct(model, OPTICS, o).far_field_amplitude(dirs)
    fe = TMatrixWave(model, OPTICS, o, tm).far_field_amplitude(dirs)
    return float(np.abs(fd - fe).max() / np.abs(fe).max())


def bench_exact(dda: bool = True) -> dict[str, float]:
    out: dict[str, float] = {}
    with threadpool_limits(limits=1):
        build_exact_tmatrix(Sphere(0.4, 1.5), OPTICS)  # warm-up: compiled kernels
        build_exact_tmatrix(SPHEROID, OPTICS, order=8)
        build_exact_tmatrix(CoatedSphere(0.3, 0.05, 1.5, 2.0), OPTICS, order=6)
        tms = {}
        for name, model in (("rod", ROD), ("spheroid", SPHEROID), ("cylinder", CYLINDER),
                            ("janus", JANUS)):
            seconds, tm = _best_build(model)
            tms[name] = tm
            p = tm.provenance
            out[f"exact_tmatrix_build_{name}_s"] = seconds
            out[f"exact_{name}_order"] = float(p["order"])
            out[f"exact_{name}_truncation_estimate"] = float(p["truncation_estimate"])
        for tilt, ref in ROD_CEXT.items():
            got = _extinction(tms["rod"], (np.pi / 6, np.radians(tilt), 0.0))
            out[f"exact_rod_cext_{tilt}deg_um2"] = got
            out[f"exact_rod_cext_{tilt}deg_rel_err_vs_long_double_ebcm"] = abs(got - ref) / ref
        # the rod by the other method (invariant imbedding, order 40) against the EBCM's
        iitm = build_exact_tmatrix(ROD, OPTICS, order=40, method="iitm")
        out["exact_rod_iitm40_vs_ebcm_far_field"] = far_field_change(iitm, tms["rod"])
        # layered sphere and the Janus full-shell limit against coated Mie
        L = 14
        k = OPTICS.k
        a, b = coated_coefficients(1.581 / 1.33, 2.74 / 1.33, k * 0.443, k * 0.490, L)
        idx = np.arange(L)
        for name, prof in (("coated", CapProfile(0.443, 0.047, 1.581, 2.74, x_edge=-1.0)),):
            blocks = integrate_profile(prof, L, k, 1.33, [192]).blocks
            err = max(np.abs(-blocks[1, idx, idx] - a).max(),
                      np.abs(-blocks[1, L + idx, L + idx] - b).max())
            out[f"exact_janus_full_shell_vs_coated_mie_{name}"] = float(err)
        tc = build_exact_tmatrix(CoatedSphere(0.443, 0.047, 1.581, 2.74), OPTICS)
        d = np.diag(tc.blocks[0])
        a, b = coated_coefficients(1.581 / 1.33, 2.74 / 1.33, k * 0.443, k * 0.490, tc.order)
        out["exact_coated_sphere_default_build_vs_coated_mie"] = float(
            max(np.abs(d[:tc.order] + a).max(), np.abs(d[tc.order:] + b).max()))
        if dda:
            for name, model in (("rod", ROD), ("spheroid", SPHEROID), ("cylinder", CYLINDER),
                                ("janus", JANUS)):
                out[f"exact_dda_default_rule_vs_exact_{name}_far_field"] = _dda_error(
                    model, tms[name])
    return out


BENCHMARKS = {"exact": bench_exact}


if __name__ == "__main__":
    print(json.dumps(bench_exact(), indent=1, sort_keys=True))
