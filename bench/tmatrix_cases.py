"""One T-matrix benchmark case per process (``python bench/tmatrix_cases.py CASE DIR``).

``tmatrix_build_<particle>_s`` is the build of the engine ``auto`` gives the particle (the
paper's rod and Janus particle: the exact T-matrix, ``holofit.scattering.axisym``; best of
three on one BLAS thread, after a warm-up build), with ``tmatrix_rebuild_<particle>_s``, a
fit's build of a new size at its fixed discretisation (what the initial pass pays per trial
size or index). The DDA's builds (``dda_tmatrix_build_<particle>_s``) write
``DIR/<particle>.npz``; the orientation cases load it (a worker's situation: the final pass of
a DDA fit starts from a saved T-matrix). Each case prints one JSON line. Numba's compiled
kernels are loaded by a tiny warm-up first (a one-time, per-installation cost).
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np
from dda_cases import GRID, OPTICS, POS, _peak_mb
from threadpoolctl import threadpool_limits

from holofit.dda import interaction
from holofit.dda.engine import BuiltinDDA
from holofit.dda.tmatrix_io import load_tmatrix, save_tmatrix
from holofit.engines.select import select_engine
from holofit.hologram import calc_hologram
from holofit.holomodel.parameters import particle_with, static_values
from holofit.particles import JanusSphere, Spherocylinder
from holofit.scattering.theory import Orientation

#: the paper's particles (rod: a, b; Janus: core radius, cap thickness; water, 660 nm)
PARTICLES = {
    "rod": Spherocylinder(0.501, 1.079, 1.495),
    "janus": JanusSphere(0.443, 0.047, 1.581, 2.74),
}
#: the engine's defaults (filtered coupled dipoles, laminate voxels, 10 dipoles per wavelength)
SETTINGS: dict[str, str] = {}


def _warm_up() -> None:
    eng = BuiltinDDA(dipole_size_um=0.1, **SETTINGS)
    model = Spherocylinder(0.15, 0.3, 1.5)
    eng.tmatrix(model, OPTICS)
    wave = eng.solve(model, OPTICS, Orientation(0.1, 0.2))
    calc_hologram(wave, POS, GRID)
    wave.rotation_derivative([1.0, 0.0, 0.0]).field_on_detector(POS, GRID)
    eng.solve_direct(model, OPTICS, Orientation(0.1, 0.2))
    interaction.clear_cache()


def build(name: str, folder: Path, tag: str | None = None, **settings: float) -> dict[str, float]:
    """Build the particle's T-matrix from scratch (empty caches) and save it as ``tag``."""
    engine = BuiltinDDA(**SETTINGS, **settings)
    tag = tag or name
    t0, c0 = time.perf_counter(), time.process_time()
    tm = engine.tmatrix(PARTICLES[name], OPTICS)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    path = save_tmatrix(tm, folder / f"{tag}.npz")
    p = tm.provenance
    return {
        f"dda_tmatrix_build_{tag}_s": wall,
        f"dda_tmatrix_build_{tag}_cpu_s": cpu,
        f"dda_tmatrix_build_{tag}_peak_rss_mb": _peak_mb(),
        f"tmatrix_{tag}_order": float(p["order"]),
        f"tmatrix_{tag}_truncation_estimate": float(p["truncation_estimate"]),
        f"tmatrix_{tag}_validation_far_field_err": float(p["validation_far_field_error"]),
        f"tmatrix_{tag}_solves": float(p["n_solves"]),
        f"tmatrix_{tag}_iterations": float(p["iterations_total"]),
        f"tmatrix_{tag}_symmetry_ops": float(p["symmetry_operations"]),
        f"tmatrix_{tag}_dipoles": float(p["n_dipoles"]),
        f"tmatrix_{tag}_file_mb": path.stat().st_size / 2**20,
    }


def auto_build(name: str, folder: Path, repeat: int = 3) -> dict[str, float]:
    """The T-matrix of the engine ``auto`` picks for the particle (its own order search, a
    fresh engine each time): best and median of ``repeat`` builds on one BLAS thread after a
    warm-up build; then a fit's rebuild of a 2 nm larger particle at the discretisation fixed
    at this one (``fix_discretisation``: no order search)."""
    model = PARTICLES[name]
    with threadpool_limits(1):
        engine = select_engine(model)
        engine.tmatrix(model, OPTICS)  # warm-up: compiled kernels, quadratures
        walls, cpus = [], []
        for _ in range(repeat):
            engine = select_engine(model)
            t0, c0 = time.perf_counter(), time.process_time()
            tm = engine.tmatrix(model, OPTICS)
            walls.append(time.perf_counter() - t0)
            cpus.append(time.process_time() - c0)
        fit_engine = select_engine(model)
        fit_engine.fix_discretisation(model, OPTICS)
        first, value = next(iter(static_values(model)))
        bigger = particle_with(model, {first: float(value) + 0.002})
        t0 = time.perf_counter()
        fit_engine.tmatrix(bigger, OPTICS)
        rebuild = time.perf_counter() - t0
    p = tm.provenance
    return {
        f"tmatrix_build_{name}_s": float(np.min(walls)),
        f"tmatrix_build_{name}_median_s": float(np.median(walls)),
        f"tmatrix_build_{name}_cpu_s": float(np.min(cpus)),
        f"tmatrix_rebuild_{name}_s": rebuild,
        f"tmatrix_{name}_is_exact_engine": float(engine.name == "exact"),
        f"tmatrix_{name}_is_ebcm": float(p.get("method") == "ebcm"),
        f"tmatrix_{name}_order": float(p["order"]),
        f"tmatrix_{name}_truncation_estimate": float(p["truncation_estimate"]),
    }


def _median(fn, repeat: int, stats: dict[str, float] | None = None,
            name: str = "") -> float:
    """Median wall time of ``fn(i)``; with ``stats``, also its best (``name_min_s``) and median
    CPU time (``name_cpu_s``): on a shared machine the median includes waiting for a core."""
    times, cpu = [], []
    for i in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        fn(i)
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    if stats is not None:
        stats[f"{name}_min_s"] = float(np.min(times))
        stats[f"{name}_cpu_s"] = float(np.median(cpu))
    return float(np.median(times))


def orientation(name: str, folder: Path, direct_repeat: int = 3) -> dict[str, float]:
    """A new orientation + 140 x 140 hologram from a loaded T-matrix, against direct solves."""
    model = PARTICLES[name]
    t0 = time.perf_counter()
    tm = load_tmatrix(folder / f"{name}.npz")
    out = {f"tmatrix_load_{name}_s": time.perf_counter() - t0}
    engine = BuiltinDDA(**SETTINGS)
    engine.use_tmatrix(model, OPTICS, tm, source=str(folder / f"{name}.npz"))
    rng = np.random.default_rng(1)
    oris = [Orientation(*rng.uniform(0, 2 * np.pi, 3)) for _ in range(40)]

    def new_orientation(i: int) -> None:
        calc_hologram(engine.solve(model, OPTICS, oris[i]), POS, GRID)

    out[f"dda_{name}_orientation_tmatrix_s"] = _median(
        new_orientation, len(oris), out, f"dda_{name}_orientation_tmatrix")
    axes = (np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]))
    xs, ys = (c.ravel() for c in GRID.coordinates())

    def with_jacobian(i: int) -> None:
        """The field and its derivatives for two rotation axes (a fit's Jacobian columns)."""
        wave = engine.solve(model, OPTICS, oris[i])
        wave.field_and_rotation_derivatives(POS, xs, ys, axes)

    out[f"dda_{name}_orientation_jacobian_tmatrix_s"] = _median(
        with_jacobian, len(oris), out, f"dda_{name}_orientation_jacobian_tmatrix")
    wave = engine.solve(model, OPTICS, oris[0])
    out[f"dda_{name}_position_update_tmatrix_s"] = _median(
        lambda i: calc_hologram(wave, (7.0 + 0.013 * i, 6.9, 12.0), GRID), 20, out,
        f"dda_{name}_position_update_tmatrix")
    # direct solves of the same lattice (the engine's default tolerance, warm starts)
    direct = BuiltinDDA(**SETTINGS)

    def cold(i: int) -> None:
        calc_hologram(direct.solve_direct(model, OPTICS, oris[10 + 3 * i]), POS, GRID)

    out[f"dda_{name}_orientation_direct_s"] = _median(cold, direct_repeat, out,
                                                      f"dda_{name}_orientation_direct")
    base = oris[0].as_tuple()

    def warm(i: int) -> None:
        o = Orientation(base[0], base[1] + 0.002 * (i + 1), base[2])
        calc_hologram(direct.solve_direct(model, OPTICS, o), POS, GRID)

    direct.solve_direct(model, OPTICS, oris[0])
    out[f"dda_{name}_small_rotation_direct_s"] = _median(warm, direct_repeat, out,
                                                         f"dda_{name}_small_rotation_direct")
    return out


CASES = {
    "rod_auto_build": lambda d: auto_build("rod", d),
    "janus_auto_build": lambda d: auto_build("janus", d),
    "rod_build": lambda d: build("rod", d),
    "janus_build": lambda d: build("janus", d),
    "janus_build_d24nm": lambda d: build("janus", d, "janus_d24nm", dipole_size_um=0.024),
    "rod_orientation": lambda d: orientation("rod", d),
    "janus_orientation": lambda d: orientation("janus", d, direct_repeat=2),
}

if __name__ == "__main__":
    _warm_up()
    print(json.dumps(CASES[sys.argv[1]](Path(sys.argv[2]))))
