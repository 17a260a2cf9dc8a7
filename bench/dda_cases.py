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
from holofit.optics import Optics
from holofit.particles import JanusSphere, Sphere, Spherocylinder
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
    """A sphere r = 0.95 um, n = 1.585, d = 0.034 um (56^3 box, 91k dipoles binary, 96k smooth)."""
    engine = BuiltinDDA(dipole_size_um=0.034)
    wave, t_first = _first(engine, Sphere(0.95, 1.585), Orientation())
    return {"dda_sphere92k_first_s": t_first,
            "dda_sphere92k_first_iterations": engine.last_iterations,
            "dda_sphere92k_dipoles": wave.lattice.n_dipoles,
            "dda_sphere92k_peak_rss_mb": _peak_mb()}


# -- the matrix-vector product, side by side with ADDA --------------------------------------

#: the paper's rod and Janus particle at the default dipole size, and ADDA's 56^3 sphere
MATVEC_PARTICLES = {
    "sphere92k": (Sphere(0.95, 1.585), 0.034, "binary"),
    "rod": (Spherocylinder(0.501, 1.079, 1.495), None, "fractional"),
    "janus": (JanusSphere(0.443, 0.047, 1.581, 2.74), None, "fractional"),
}
MATVEC_REPEATS = 5
MATVEC_BATCH = 10


def _matvec_cpu_ms(system, batch: int = MATVEC_BATCH, repeats: int = MATVEC_REPEATS) -> float:
    """Median over ``repeats`` batches of the mean CPU time of one product, ms (ADDA reports
    processor time too)."""
    n = system.lattice.n_dipoles
    rng = np.random.default_rng(0)
    v = rng.normal(size=3 * n) + 1j * rng.normal(size=3 * n)
    alpha = system.alpha([0.0, 0.0, -1.0], [1.0, 0.0, 0.0])
    w = np.ascontiguousarray(np.sqrt(alpha if alpha.ndim == 2 else alpha[:, None] * np.ones(3)))
    out = np.empty_like(v)
    system._matvec(v, w, out)  # compile / warm caches
    times = []
    for _ in range(repeats):
        t0 = time.process_time()
        for _ in range(batch):
            system._matvec(v, w, out)
        times.append((time.process_time() - t0) / batch)
    return 1e3 * float(np.median(times))


def _adda_binary() -> str | None:
    import os
    import shutil

    env = os.environ.get("HOLOFIT_ADDA", "")
    if env:
        return env if os.access(env, os.X_OK) else None
    return shutil.which("adda")


def _adda_matvec_ms(binary: str, lattice, n_rel: float, workdir) -> float:
    """ADDA's mean processor time per matrix-vector product on the same dipoles, ms.

    One solve (``-sym enf``: the binary sphere is symmetric, so ADDA solves one polarisation),
    nothing else computed; the log's 'matvec products' time over the number of products.
    """
    import re
    import subprocess

    from holofit.io.shapefile import write_shape_file

    geom = write_shape_file(workdir / "shape.geom", lattice.ijk)
    out = workdir / "run"
    lam = OPTICS.wavelength_medium_um
    cmd = [binary, "-shape", "read", str(geom), "-size", repr(lattice.shape[0] * lattice.d),
           "-lambda", repr(lam), "-m", repr(n_rel), "0", "-sym", "enf", "-scat_matr", "none",
           "-dir", str(out)]
    subprocess.run(cmd, check=True, capture_output=True, cwd=workdir)
    log = (out / "log").read_text()
    count = int(re.search(r"Total number of matrix-vector products:\s*(\d+)", log).group(1))
    seconds = float(re.search(r"\n\s+matvec products:\s*([0-9.eE+-]+)", log).group(1))
    for path in sorted(out.iterdir(), reverse=True):
        path.unlink()
    out.rmdir()
    return 1e3 * seconds / count


def matvec() -> dict[str, float]:
    """Time per matrix-vector product (double and single precision), and ADDA's on the same
    sphere, interleaved in the same run (medians of three rounds)."""
    import tempfile
    from pathlib import Path

    from holofit.dda.dipoles import DipoleSystem
    from holofit.dda.settings import DDASettings
    from holofit.dda.voxelize import voxelize

    out: dict[str, float] = {}
    systems = {}
    for name, (model, d, filling) in MATVEC_PARTICLES.items():
        d = d or DDASettings().dipole_size_for(model, OPTICS)
        lat = voxelize(model, d, filling)
        out[f"dda_matvec_{name}_dipoles"] = lat.n_dipoles
        for precision, dtype in (("", np.complex128), ("_single", np.complex64)):
            systems[name + precision] = DipoleSystem(lat, OPTICS.k, OPTICS.n_medium,
                                                     dtype=dtype)
    binary = _adda_binary()
    if binary is None:
        print("    adda_matvec_sphere92k_ms skipped: no ADDA binary (HOLOFIT_ADDA or adda on "
              "PATH)", file=sys.stderr)
    rounds: dict[str, list[float]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(3):
            for key, system in systems.items():
                rounds.setdefault(f"dda_matvec_{key}_ms", []).append(_matvec_cpu_ms(system))
            if binary is not None:
                sphere = systems["sphere92k"]
                rounds.setdefault("adda_matvec_sphere92k_ms", []).append(_adda_matvec_ms(
                    binary, sphere.lattice, 1.585 / OPTICS.n_medium, Path(tmp)))
    out.update({key: float(np.median(v)) for key, v in rounds.items()})
    if "adda_matvec_sphere92k_ms" in out:
        adda = out["adda_matvec_sphere92k_ms"]
        out["dda_matvec_sphere92k_over_adda"] = out["dda_matvec_sphere92k_ms"] / adda
        out["dda_matvec_sphere92k_single_over_adda"] = out["dda_matvec_sphere92k_single_ms"] / adda
    return out


def _adda_iterations(binary: str, lattice, n_rel: tuple[float, ...], orient_deg, workdir
                     ) -> int:
    """QMR iterations ADDA needs for its X polarisation on these dipoles (default tolerance)."""
    import re
    import subprocess

    from holofit.io.shapefile import write_shape_file

    ijk, domain = lattice.binary_dipoles()
    geom = write_shape_file(workdir / "shape.geom", ijk, domain if len(n_rel) > 1 else None)
    out = workdir / "run_it"
    m_args = [v for n in n_rel for v in (repr(n), "0")]
    cmd = [binary, "-shape", "read", str(geom), "-size", repr(lattice.shape[0] * lattice.d),
           "-lambda", repr(OPTICS.wavelength_medium_um), "-m", *m_args,
           "-orient", *(repr(float(a)) for a in orient_deg), "-sym", "no", "-scat_matr", "none",
           "-dir", str(out)]
    subprocess.run(cmd, check=True, capture_output=True, cwd=workdir)
    log = (out / "log").read_text()
    x_part = log.split("calc X")[1]
    count = len(re.findall(r"^RE_(\d+)", x_part, flags=re.M)) - 1
    for path in sorted(out.iterdir(), reverse=True):
        path.unlink()
    out.rmdir()
    return count


def solve() -> dict[str, float]:
    """Where a solve's time goes (built-in engine), and iterations next to ADDA's.

    The paper's rod and Janus particle, binary voxels at the default dipole size (so that ADDA
    gets the very same dipoles), light along the particle axis and tilted (ADDA's
    ``-orient 30 60 0``, the same rotation here), X polarisation, default tolerance.
    """
    import tempfile
    from pathlib import Path

    from holofit.conventions import euler_zyz
    from holofit.dda.dipoles import DipoleSystem
    from holofit.dda.settings import DDASettings
    from holofit.dda.voxelize import voxelize

    binary = _adda_binary()
    if binary is None:
        print("    adda_*_iterations skipped: no ADDA binary (HOLOFIT_ADDA or adda on PATH)",
              file=sys.stderr)
    out: dict[str, float] = {}
    particles = {"rod": MATVEC_PARTICLES["rod"][0], "janus": MATVEC_PARTICLES["janus"][0]}
    with tempfile.TemporaryDirectory() as tmp:
        for name, model in particles.items():
            d = DDASettings().dipole_size_for(model, OPTICS)
            lat = voxelize(model, d, "binary")
            # ADDA's problem: scaled into the medium (k of the medium, relative indices)
            n_rel = tuple(complex(n).real / OPTICS.n_medium for n in lat.indices)
            system = DipoleSystem(lat, OPTICS.k, OPTICS.n_medium)
            for tag, orient in (("axial", (0.0, 0.0, 0.0)), ("tilted", (30.0, 60.0, 0.0))):
                rot = euler_zyz(*np.radians(orient))
                a_p, e_p = rot.T @ [0.0, 0.0, 1.0], rot.T @ [1.0, 0.0, 0.0]
                system.solve(a_p, e_p)  # warm (numba, FFTW plans)
                sols = [system.solve(a_p, e_p) for _ in range(3)]
                sol = sols[int(np.argmin([s.timings["total"] for s in sols]))]
                key = f"dda_solve_{name}_{tag}"
                out[f"{key}_iterations"] = sol.iterations
                for part, seconds in sol.timings.items():
                    out[f"{key}_{part}_ms"] = 1e3 * seconds
                out[f"{key}_krylov_per_iteration_ms"] = (1e3 * sol.timings["krylov"]
                                                         / max(sol.iterations, 1))
                out[f"{key}_matvec_per_iteration_ms"] = (1e3 * sol.timings["matvec"]
                                                         / max(sol.iterations, 1))
                if binary is not None:
                    out[f"adda_solve_{name}_{tag}_iterations"] = _adda_iterations(
                        binary, lat, n_rel, orient, Path(tmp))
    return out


def precision() -> dict[str, float]:
    """Single- vs double-precision convolution on the paper's rod and Janus holograms.

    Both engines solve the same lattice at the default tolerance; reported: 1 - R^2 between
    the two holograms, and how far a position fit of the single-precision model moves from the
    truth when it fits the double-precision hologram (nm).
    """
    from scipy.optimize import least_squares

    from holofit.conventions import r_squared

    out: dict[str, float] = {}
    grid = DetectorGrid((100, 100), 0.1)
    truth = np.array([5.0, 5.0, 10.0])
    particles = {"rod": (MATVEC_PARTICLES["rod"][0], Orientation(0.4, 1.0, 0.2)),
                 "janus": (MATVEC_PARTICLES["janus"][0], Orientation(0.3, 0.8, 0.0))}
    for name, (model, orientation) in particles.items():
        double = BuiltinDDA().solve(model, OPTICS, orientation)
        single = BuiltinDDA(precision="single").solve(model, OPTICS, orientation)
        h_d = calc_hologram(double, truth, grid)
        h_s = calc_hologram(single, truth, grid)
        out[f"dda_single_vs_double_{name}_one_minus_r2"] = 1.0 - r_squared(h_d, h_s)
        def residual(p, wave=single, target=h_d):
            return (calc_hologram(wave, p, grid) - target).ravel()

        fit = least_squares(residual, truth, x_scale=0.01, xtol=1e-12, ftol=1e-14, gtol=1e-14)
        for axis, delta in zip("xyz", fit.x - truth, strict=True):
            out[f"dda_single_vs_double_{name}_fit_d{axis}_nm"] = 1e3 * abs(float(delta))
    return out


CASES = {"rod": rod, "janus": janus, "janus_tilted": janus_tilted, "sphere92k": sphere92k,
         "matvec": matvec, "solve": solve, "precision": precision}

if __name__ == "__main__":
    _warm_up()
    print(json.dumps(CASES[sys.argv[1]]()))
