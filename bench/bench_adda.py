"""The ADDA adapter against the built-in DDA engine: time per hologram, and agreement.

Skipped (empty result, reason printed) when no ADDA binary is found (``HOLOFIT_ADDA`` or
``adda`` on PATH). Same particles, same machine, same dipoles (binary filling, the dipole size
of the 10-dipoles-per-wavelength rule), a 140 x 140 detector of 0.1 um pixels 12 um from focus.

Reported per particle (rod, Janus):

* ``adda_<p>_holo_s``: one hologram through the adapter (shape and pairs files, one ADDA run,
  reading ``ampl_scatgrid``); any change of orientation *or position* costs this again;
* ``adda_<p>_holo_cpu_s``: its CPU time (this process and the ADDA child; less sensitive to
  other load on a shared machine than wall time);
* ``adda_<p>_process_s``: the wall time spent inside the ADDA process;
* ``builtin_<p>_new_orientation_s``: the built-in engine, new orientation (solve + exact
  near-field hologram), warm engine (cached interaction FFT, warm start);
* ``builtin_<p>_new_orientation_cpu_s``: its CPU time (all threads);
* ``builtin_<p>_cold_s``: the same from a fresh engine (voxelisation and FFT set-up included);
* ``builtin_<p>_far_field_holo_s``: built-in, new orientation, far-field mode (like ADDA);
* ``builtin_<p>_new_position_s``: built-in, a new position of a solved particle;
* ``adda_vs_builtin_<case>_one_minus_r2``: 1 - R^2 between the adapter's hologram and the
  built-in far-field hologram (Janus theta = 0 and pi, tilted rod).
"""

from __future__ import annotations

import resource
import statistics
import time
import warnings

import numpy as np

from holofit.conventions import DetectorGrid, r_squared
from holofit.hologram import calc_hologram
from holofit.optics import Optics
from holofit.particles import JanusSphere, Spherocylinder
from holofit.scattering.theory import Orientation

OPTICS = Optics(0.66, 1.33, 0.0)
GRID = DetectorGrid((140, 140), 0.1)
POSITION = (7.0, 7.0, 12.0)
PARTICLES = {
    "rod": Spherocylinder(0.5, 1.0, 1.495),
    "janus": JanusSphere(0.439, 0.05, 1.59, 2.7),
}
ORIENTATIONS = [Orientation(0.5, 1.0, 0.3), Orientation(0.6, 1.05, 0.3), Orientation(0.7, 1.1, 0.3)]


def _cpu() -> float:
    """CPU seconds of this process and its finished children (ADDA runs), all threads."""
    own = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def _builtin_timings(name: str, model) -> dict[str, float]:
    from holofit.dda.engine import BuiltinDDA

    out: dict[str, float] = {}
    engine = BuiltinDDA(filling="binary")
    t0 = time.perf_counter()
    calc_hologram(engine.solve(model, OPTICS, ORIENTATIONS[0]), POSITION, GRID)
    out[f"builtin_{name}_cold_s"] = time.perf_counter() - t0
    warm, far, warm_cpu = [], [], []
    for o in ORIENTATIONS[1:]:
        c0 = _cpu()
        t0 = time.perf_counter()
        wave = engine.solve(model, OPTICS, o)
        t1 = time.perf_counter()
        calc_hologram(wave, POSITION, GRID)
        t2 = time.perf_counter()
        warm_cpu.append(_cpu() - c0)
        calc_hologram(wave, POSITION, GRID, far_field=True)
        t3 = time.perf_counter()
        warm.append(t2 - t0)
        far.append((t1 - t0) + (t3 - t2))
    out[f"builtin_{name}_new_orientation_s"] = statistics.median(warm)
    out[f"builtin_{name}_new_orientation_cpu_s"] = statistics.median(warm_cpu)
    out[f"builtin_{name}_far_field_holo_s"] = statistics.median(far)
    wave = engine.solve(model, OPTICS, ORIENTATIONS[0])
    calc_hologram(wave, POSITION, GRID)
    moves = []
    for z in np.linspace(11.5, 12.5, 5):
        t0 = time.perf_counter()
        calc_hologram(wave, (7.0, 7.0, float(z)), GRID)
        moves.append(time.perf_counter() - t0)
    out[f"builtin_{name}_new_position_s"] = statistics.median(moves)
    return out


def bench_adda() -> dict[str, float]:
    from holofit.dda import adda as ae
    from holofit.dda.engine import BuiltinDDA

    try:
        engine = ae.AddaEngine()
    except ae.AddaNotFoundError as exc:
        print(f"    skipped: {exc}")
        return {}
    warnings.simplefilter("ignore", ae.AddaFarFieldWarning)
    print(f"    {engine.version.banner} at {engine.binary}")
    # compile the built-in engine's numba kernels outside the timings
    small = Spherocylinder(0.1, 0.2, 1.45)
    calc_hologram(BuiltinDDA().solve(small, OPTICS, ORIENTATIONS[0]), POSITION, GRID)
    out: dict[str, float] = {}
    for name, model in PARTICLES.items():
        adda_t, proc_t, cpu_t = [], [], []
        for o in ORIENTATIONS:
            wave = engine.solve(model, OPTICS, o)
            c0 = _cpu()
            t0 = time.perf_counter()
            calc_hologram(wave, POSITION, GRID)
            adda_t.append(time.perf_counter() - t0)
            cpu_t.append(_cpu() - c0)
            proc_t.append(wave.last_run.seconds)
        out[f"adda_{name}_holo_s"] = statistics.median(adda_t)
        out[f"adda_{name}_holo_cpu_s"] = statistics.median(cpu_t)
        out[f"adda_{name}_process_s"] = statistics.median(proc_t)
        out[f"adda_{name}_n_dipoles"] = float(wave.geometry.n_dipoles)

        out.update(_builtin_timings(name, model))

    cases = {
        "janus_theta0": (PARTICLES["janus"], Orientation(0.4, 0.0, 0.0)),
        "janus_thetapi": (PARTICLES["janus"], Orientation(0.4, np.pi, 0.0)),
        "rod_tilted": (PARTICLES["rod"], Orientation(0.5, 1.0, 0.3)),
    }
    builtin = BuiltinDDA(filling="binary")
    for case, (model, o) in cases.items():
        h_adda = calc_hologram(engine.solve(model, OPTICS, o), POSITION, GRID)
        h_builtin = calc_hologram(builtin.solve(model, OPTICS, o), POSITION, GRID,
                                  far_field=True)
        out[f"adda_vs_builtin_{case}_one_minus_r2"] = 1.0 - r_squared(h_builtin, h_adda)
    return out


BENCHMARKS = {"adda": bench_adda}
