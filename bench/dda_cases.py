"""One DDA benchmark case per process (``python bench/dda_cases.py CASE``): prints JSON.

Each case runs in a fresh process so that "empty caches" and peak memory mean what they say.
Numba's compiled kernels are loaded by a tiny warm-up solve first (compilation is a one-time,
per-installation cost, cached on disk).
"""

from __future__ import annotations

import json
import resource
import sys
import time

import numpy as np

from holofit.conventions import DetectorGrid
from holofit.dda import interaction
from holofit.dda.engine import BuiltinDDA
from holofit.hologram import calc_hologram
from holofit.models import JanusSphere, Sphere, Spherocylinder
from holofit.optics import Optics
from holofit.scattering.theory import Orientation

OPTICS = Optics(0.66, 1.33, 0.0)
GRID = DetectorGrid((140, 140), 0.1)
POS = (7.0, 7.0, 12.0)  # 12 um from focus, centred on the 140 x 140 detector


def _warm_up() -> None:
    wave = BuiltinDDA(dipole_size_um=0.1).solve(Sphere(0.3, 1.5), OPTICS, Orientation(0.1, 0.2))
    calc_hologram(wave, (7.0, 7.0, 1.0), GRID)
    calc_hologram(wave, (7.0, 7.0, 12.0), GRID, far_field=True)
    interaction.clear_cache()


def _first(engine: BuiltinDDA, model, orientation):
    t0 = time.perf_counter()
    wave = engine.solve(model, OPTICS, orientation)
    calc_hologram(wave, POS, GRID)
    return wave, time.perf_counter() - t0


def _peak_mb() -> float:
    """Peak resident memory of this process image, MB.

    ``VmHWM`` of /proc (the high-water mark of this process's memory map). ``getrusage``'s
    ``ru_maxrss`` is not used: Linux carries it over from the parent through fork and exec, so
    a child started by a big parent reports the parent's peak.
    """
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def rod() -> dict[str, float]:
    """The ADDA capsule case (a = 0.5, b = 1.0 um, n = 1.495, d = 0.04333 um), tilted."""
    model = Spherocylinder(0.5, 1.0, 1.495)
    engine = BuiltinDDA(dipole_size_um=0.0433341407)
    wave, t_first = _first(engine, model, Orientation(np.radians(30), np.radians(60)))
    out = {"dda_rod_first_s": t_first, "dda_rod_first_iterations": engine.last_iterations,
           "dda_rod_dipoles": wave.lattice.n_dipoles}
    new = Orientation(np.radians(80), np.radians(20))
    t0 = time.perf_counter()
    wave = engine.solve(model, OPTICS, new)
    calc_hologram(wave, POS, GRID)
    out["dda_rod_new_orientation_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    wave = engine.solve(model, OPTICS, Orientation(np.radians(80), np.radians(20.5)))
    calc_hologram(wave, POS, GRID)
    out["dda_rod_small_rotation_s"] = time.perf_counter() - t0
    out["dda_rod_small_rotation_iterations"] = engine.last_iterations
    times = []
    for i in range(20):
        t0 = time.perf_counter()
        calc_hologram(wave, (7.0 + 0.013 * i, 6.9 + 0.007 * i, 12.0 + 0.011 * i), GRID)
        times.append(time.perf_counter() - t0)
    out["dda_rod_position_update_s"] = float(np.median(times))
    times = []
    for i in range(20):
        t0 = time.perf_counter()
        calc_hologram(wave, (7.0 + 0.013 * i, 6.9 + 0.007 * i, 12.0 + 0.011 * i), GRID,
                      far_field=True)
        times.append(time.perf_counter() - t0)
    out["dda_rod_position_update_farfield_s"] = float(np.median(times))
    return out


def janus() -> dict[str, float]:
    """The paper's Janus particle at d = 0.024 um, light along the cap axis (ADDA's case)."""
    model = JanusSphere(0.439, 0.05, 1.59, 2.7)
    engine = BuiltinDDA(dipole_size_um=0.024)
    wave, t_first = _first(engine, model, Orientation(0.0, np.pi))
    return {"dda_janus_first_s": t_first, "dda_janus_first_iterations": engine.last_iterations,
            "dda_janus_dipoles": wave.lattice.n_dipoles, "dda_janus_peak_rss_mb": _peak_mb()}


def janus_tilted() -> dict[str, float]:
    """The same Janus particle tilted by 46 degrees (more iterations)."""
    engine = BuiltinDDA(dipole_size_um=0.024)
    _, t_first = _first(engine, JanusSphere(0.439, 0.05, 1.59, 2.7), Orientation(0.3, 0.8))
    return {"dda_janus_tilted_first_s": t_first,
            "dda_janus_tilted_first_iterations": engine.last_iterations}


def sphere92k() -> dict[str, float]:
    """A sphere r = 0.95 um, n = 1.585, d = 0.034 um (~92k dipoles binary, ~100k fractional)."""
    engine = BuiltinDDA(dipole_size_um=0.034)
    wave, t_first = _first(engine, Sphere(0.95, 1.585), Orientation())
    return {"dda_sphere92k_first_s": t_first,
            "dda_sphere92k_first_iterations": engine.last_iterations,
            "dda_sphere92k_dipoles": wave.lattice.n_dipoles,
            "dda_sphere92k_peak_rss_mb": _peak_mb()}


CASES = {"rod": rod, "janus": janus, "janus_tilted": janus_tilted, "sphere92k": sphere92k}

if __name__ == "__main__":
    _warm_up()
    print(json.dumps(CASES[sys.argv[1]]()))
