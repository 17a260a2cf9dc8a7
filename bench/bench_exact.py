"""Exact T-matrices of bodies of revolution (holofit.scattering.axisym): build times and the
errors against the references.

Usage: ``python bench/bench_exact.py [--references]`` prints one flat JSON object (with
``--references``, only the comparisons with the independent references below; ``make bench``
runs it through ``bench/run.py`` as the group ``exact``). Keys carry the prefix ``exact_``
(the DDA's T-matrix benchmark owns ``tmatrix_build_rod_s``). Times are the best of three
builds on one thread, after one warm-up build (compiled kernels loaded); errors are relative to
the largest amplitude or value.

References independent of the engine (``tests/exact_references.py``): the rod against the
extended-precision (long double) EBCM of ``tests/ebcm_reference.py`` at orders 70 and 74 (their
difference is its stated accuracy), the spheroid and the cylinder against pytmatrixc
(Mishchenko's EBCM Fortran; the spheroid's own accuracy is its ``ddelt``, 1e-8, while it stops
the cylinder at order 29, ~3e-5 short of convergence), the cylinder also against the
long-double EBCM at order 48 (its change from 44: ~4e-6); each in the far field and in the
camera plane of the
60x water objective (the reference's far field imaged by holofit's lens code, which the exact
engine's image shares). The long-double builds are kept in ``bench/.cache``.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from holofit.conventions import DetectorGrid
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
#: orders of the extended-precision EBCM references (tests/ebcm_reference.py): the rod's far
#: field changes by ~3e-5 from order 66 to 70, the cylinder's by ~4e-6 from 44 to 48 (their
#: convergence is algebraic: the rod's by ~1e-4 from 50 to 54)
ROD_REFERENCE_ORDERS = (70, 74)
CYLINDER_REFERENCE_ORDER = 48
#: the camera plane of the paper's 60x water objective (NA 1.2), 12 um from focus
CAMERA_OPTICS = Optics(0.660, 1.33, 0.0, 1.2)
CAMERA_GRID = DetectorGrid((100, 100), 0.1767)
CAMERA_POSITION = (50 * 0.1767, 50 * 0.1767, 12.0)
REFERENCE_ORIENTATIONS = (Orientation(0.5, 0.3, 0.0), Orientation(-1.1, 1.0, 0.2),
                          Orientation(2.0, 1.5, 0.0), Orientation(0.9, 2.4, 0.7))
CACHE = Path(__file__).resolve().parent / ".cache"


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


def _wave_errors(model, tm, amplitude, optics: Optics) -> tuple[float, float]:
    """Largest far-field and camera-plane field differences of the exact T-matrix ``tm`` from
    a reference's far field (``tests/exact_references.py``), over the reference
    orientations, each relative to the largest value."""
    from holofit.scattering.recorded_field import recorded_field_on_detector
    from tests.exact_references import FarFieldWave

    rng = np.random.default_rng(5)
    dirs = rng.normal(size=(150, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    far, cam = 0.0, 0.0
    for o in REFERENCE_ORIENTATIONS:
        ref = FarFieldWave(model, optics, o, amplitude)
        ours = TMatrixWave(model, optics, o, tm)
        fr = ref.far_field_amplitude(dirs)
        far = max(far, float(np.abs(ours.far_field_amplitude(dirs) - fr).max()
                             / np.abs(fr).max()))
        er = np.stack(recorded_field_on_detector(ref, CAMERA_POSITION, CAMERA_GRID, False))
        eo = np.stack(recorded_field_on_detector(ours, CAMERA_POSITION, CAMERA_GRID, False))
        cam = max(cam, float(np.abs(eo - er).max() / np.abs(er).max()))
    return far, cam


def bench_references(tms: dict) -> dict[str, float]:
    """The exact engine's default builds against independent references (module
    docstring): far field and the camera-plane field through the 60x water objective."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from tests.exact_references import FarFieldWave, ld_ebcm_amplitude, pytmatrix_amplitude

    out: dict[str, float] = {}
    optics = CAMERA_OPTICS
    lo, hi = ROD_REFERENCE_ORDERS
    rod_hi = ld_ebcm_amplitude(ROD, optics, hi, cache=CACHE)
    rod_lo = ld_ebcm_amplitude(ROD, optics, lo, cache=CACHE)
    far, cam = _wave_errors(ROD, tms["rod"], rod_hi, optics)
    out[f"exact_rod_far_field_vs_ld_ebcm{hi}"] = far
    out[f"exact_rod_camera_field_vs_ld_ebcm{hi}"] = cam
    # the reference's own accuracy: its change between the two orders
    rng = np.random.default_rng(5)
    dirs = rng.normal(size=(150, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    change = 0.0
    for o in REFERENCE_ORIENTATIONS:
        a = FarFieldWave(ROD, optics, o, rod_hi).far_field_amplitude(dirs)
        b = FarFieldWave(ROD, optics, o, rod_lo).far_field_amplitude(dirs)
        change = max(change, float(np.abs(a - b).max() / np.abs(a).max()))
    out[f"exact_rod_ld_ebcm_order_change_{lo}_{hi}"] = change
    for name, model in (("spheroid", SPHEROID), ("cylinder", CYLINDER)):
        far, cam = _wave_errors(model, tms[name], pytmatrix_amplitude(model, optics), optics)
        out[f"exact_{name}_far_field_vs_pytmatrix"] = far
        out[f"exact_{name}_camera_field_vs_pytmatrix"] = cam
    cyl = ld_ebcm_amplitude(CYLINDER, optics, CYLINDER_REFERENCE_ORDER, cache=CACHE)
    far, cam = _wave_errors(CYLINDER, tms["cylinder"], cyl, optics)
    out[f"exact_cylinder_far_field_vs_ld_ebcm{CYLINDER_REFERENCE_ORDER}"] = far
    out[f"exact_cylinder_camera_field_vs_ld_ebcm{CYLINDER_REFERENCE_ORDER}"] = cam
    # the two cylinder references against each other: their own spread
    spread = 0.0
    pyt = pytmatrix_amplitude(CYLINDER, optics)
    for o in REFERENCE_ORIENTATIONS:
        a = FarFieldWave(CYLINDER, optics, o, cyl).far_field_amplitude(dirs)
        b = FarFieldWave(CYLINDER, optics, o, pyt).far_field_amplitude(dirs)
        spread = max(spread, float(np.abs(b - a).max() / np.abs(a).max()))
    out[f"exact_cylinder_pytmatrix_vs_ld_ebcm{CYLINDER_REFERENCE_ORDER}_far_field"] = spread
    return out


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
            out[f"exact_{name}_solve_order"] = float(p.get("solve_order", p["order"]))
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
        out.update(bench_references(tms))
        if dda:
            for name, model in (("rod", ROD), ("spheroid", SPHEROID), ("cylinder", CYLINDER),
                                ("janus", JANUS)):
                out[f"exact_dda_default_rule_vs_exact_{name}_far_field"] = _dda_error(
                    model, tms[name])
    return out


BENCHMARKS = {"exact": bench_exact}


def references_only() -> dict[str, float]:
    """:func:`bench_references` alone, on the default builds (``--references``)."""
    with threadpool_limits(limits=1):
        tms = {name: build_exact_tmatrix(model, OPTICS)
               for name, model in (("rod", ROD), ("spheroid", SPHEROID), ("cylinder", CYLINDER))}
        return bench_references(tms)


if __name__ == "__main__":
    if "--references" in sys.argv[1:]:
        print(json.dumps(references_only(), indent=1, sort_keys=True))
    else:
        print(json.dumps(bench_exact(), indent=1, sort_keys=True))
