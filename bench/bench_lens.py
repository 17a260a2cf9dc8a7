"""Holograms through the objective lens (holofit.scattering.lens) against the ideal model.

Each lens number has its ideal counterpart measured in the same run (same grid, particle and
positions), and the ratio is reported:

* Mie, 140 x 140 pixels: the ideal exact near-field hologram (``mie_holo_ideal_140px_s``, the
  same case as ``mie_holo_140px_s``) against the lens hologram at NA 1.2 with a new height at
  every call (``mie_holo_lens_140px_s``: radial tables rebuilt each time, the cost inside a fit),
  a lateral move only (``..._lateral_...``), and a new NA (``..._new_na_...``: new Bessel tables);
* the built-in DDA rod of ``dda_cases.py`` (capsule a = 0.5, b = 1.0 um): the plane-grid position
  update (new x, y, z each call, as ``dda_rod_position_update_s``) against the lens hologram at
  the same positions (``dda_rod_lens_140px_s``); the very first lens hologram (new Bessel
  tables); and the first hologram of each new solve, ideal and lens (``..._new_wave_...``);
* Mie on a full 1024 x 1280 frame;
* the aberrated objective (:mod:`holofit.aberration`, spherical aberration (-2.5, 0.6) rad) against
  the ideal one, same run, calls alternated: the Mie and DDA rod lens holograms with a new height
  at every call (``lens_aberration_mie_140px_s`` against ``lens_ideal_pupil_mie_140px_s``, their
  ratio ``lens_aberration_cost_ratio``; ``..._dda_rod_...`` likewise), and the exact derivatives
  with respect to both coefficients in one pass against one hologram
  (``lens_aberration_derivatives_over_hologram_ratio``, Mie).
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
from timing import median_time

from holofit.aberration import Aberration
from holofit.conventions import DetectorGrid
from holofit.dda.engine import BuiltinDDA
from holofit.hologram import calc_hologram
from holofit.optics import Optics
from holofit.particles import Sphere, Spherocylinder
from holofit.scattering.lens import lens_image
from holofit.scattering.mie import LorenzMie
from holofit.scattering.theory import Orientation

GRID = DetectorGrid((140, 140), 0.1)
IDEAL = Optics(0.66, 1.33, 0.0)
LENS = Optics(0.66, 1.33, 0.0, numerical_aperture=1.2)


def _paired(fa, fb, repeat: int) -> tuple[float, float]:
    """Median times of ``fa()`` and ``fb()`` called alternately (same machine conditions)."""
    for _ in range(2):
        fa()
        fb()
    ta, tb = [], []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fa()
        t1 = time.perf_counter()
        fb()
        t2 = time.perf_counter()
        ta.append(t1 - t0)
        tb.append(t2 - t1)
    return float(np.median(ta)), float(np.median(tb))


def _positions(start: tuple[float, float, float], step: tuple[float, float, float]):
    """A new position at every call (as a fit's iterations)."""
    i = 0

    def nxt() -> tuple[float, float, float]:
        nonlocal i
        i += 1
        return tuple(a + b * i for a, b in zip(start, step, strict=True))

    return nxt


def bench_lens_mie() -> dict[str, float]:
    ideal = LorenzMie().solve(Sphere(0.5, 1.59), IDEAL)
    lens = LorenzMie().solve(Sphere(0.5, 1.59), LENS)
    pos = _positions((7.0, 7.0, 10.0), (0.0, 0.0, 1e-4))
    t_ideal, t_lens = _paired(lambda: calc_hologram(ideal, (7.0, 7.0, 10.0), GRID, 0.8),
                              lambda: calc_hologram(lens, pos(), GRID, 0.8), repeat=200)
    out = {"mie_holo_ideal_140px_s": t_ideal, "mie_holo_lens_140px_s": t_lens}
    pos = _positions((7.0, 7.0, 10.0), (1e-3, -1e-3, 0.0))
    out["mie_holo_lens_lateral_140px_s"] = median_time(
        lambda: calc_hologram(lens, pos(), GRID, 0.8), repeat=100)
    na = iter(1.2 + 1e-4 * np.arange(1000))
    out["mie_holo_lens_new_na_140px_s"] = median_time(
        lambda: calc_hologram(LorenzMie().solve(Sphere(0.5, 1.59), Optics(
            0.66, 1.33, 0.0, numerical_aperture=next(na))), (7.0, 7.0, 10.0), GRID, 0.8),
        repeat=30)
    out["mie_lens_over_ideal_ratio"] = (out["mie_holo_lens_140px_s"]
                                        / out["mie_holo_ideal_140px_s"])
    big = DetectorGrid((1024, 1280), 0.1)
    out["mie_holo_ideal_1024x1280_s"] = median_time(
        lambda: calc_hologram(ideal, (60.0, 50.0, 10.0), big, 0.8), repeat=5)
    pos = _positions((60.0, 50.0, 10.0), (0.0, 0.0, 1e-4))
    out["mie_holo_lens_1024x1280_s"] = median_time(lambda: calc_hologram(lens, pos(), big, 0.8),
                                                   repeat=5)
    return out


def bench_lens_dda() -> dict[str, float]:
    model = Spherocylinder(0.5, 1.0, 1.495)
    orientation = Orientation(np.radians(80), np.radians(20))
    ideal = BuiltinDDA(dipole_size_um=0.0433341407).solve(model, IDEAL, orientation)
    engine = BuiltinDDA(dipole_size_um=0.0433341407)
    lens = engine.solve(model, LENS, orientation)
    lens.expansion  # noqa: B018 - the multipole expansion is shared by both models
    t0 = time.perf_counter()
    calc_hologram(lens, (7.0, 7.0, 12.0), GRID)
    first = time.perf_counter() - t0
    step = (0.013, 0.007, 0.011)
    pos_ideal = _positions((7.0, 6.9, 12.0), step)
    pos_lens = _positions((7.0, 6.9, 12.0), step)
    t_ideal, t_lens = _paired(lambda: calc_hologram(ideal, pos_ideal(), GRID),
                              lambda: calc_hologram(lens, pos_lens(), GRID), repeat=40)
    out = {"dda_rod_ideal_position_update_s": t_ideal, "dda_rod_lens_140px_s": t_lens}
    pos = _positions((7.0, 6.9, 12.0), (0.013, 0.007, 0.0))
    out["dda_rod_lens_lateral_140px_s"] = median_time(lambda: calc_hologram(lens, pos(), GRID),
                                                      repeat=20)
    out["dda_rod_lens_first_s"] = first
    # the first hologram of a new solve (new orientation: a new far field, new pupil modes and
    # tables; the multipole expansion, needed by both models, included), solve excluded
    for name, optics, engine_ in (("ideal", IDEAL, BuiltinDDA(dipole_size_um=0.0433341407)),
                                  ("lens", LENS, engine)):
        times = []
        for i in range(5):
            wave = engine_.solve(model, optics, Orientation(np.radians(80), np.radians(21 + i)))
            t0 = time.perf_counter()
            calc_hologram(wave, (7.0, 7.0, 12.0), GRID)
            times.append(time.perf_counter() - t0)
        out[f"dda_rod_{name}_new_wave_hologram_s"] = float(np.median(times))
    out["dda_rod_lens_over_ideal_ratio"] = (out["dda_rod_lens_140px_s"]
                                            / out["dda_rod_ideal_position_update_s"])
    return out


ABERRATION = Aberration((-2.5, 0.6))


def bench_lens_aberration() -> dict[str, float]:
    out: dict[str, float] = {}
    sphere = Sphere(0.5, 1.59)
    ideal = LorenzMie().solve(sphere, LENS)
    aberrated = LorenzMie().solve(sphere, replace(LENS, aberration=ABERRATION))
    pos_a = _positions((7.0, 7.0, 10.0), (0.0, 0.0, 1e-4))
    pos_b = _positions((7.0, 7.0, 10.0), (0.0, 0.0, 1e-4))
    t_ideal, t_ab = _paired(lambda: calc_hologram(ideal, pos_a(), GRID, 0.8),
                            lambda: calc_hologram(aberrated, pos_b(), GRID, 0.8), repeat=200)
    out["lens_ideal_pupil_mie_140px_s"] = t_ideal
    out["lens_aberration_mie_140px_s"] = t_ab
    out["lens_aberration_cost_ratio"] = t_ab / t_ideal
    x, y = GRID.coordinates()
    image = lens_image(aberrated)
    pos_c = _positions((7.0, 7.0, 10.0), (0.0, 0.0, 1e-4))
    pos_d = _positions((7.0, 7.0, 10.0), (0.0, 0.0, 1e-4))
    t_holo, t_deriv = _paired(
        lambda: calc_hologram(aberrated, pos_c(), GRID, 0.8),
        lambda: image.field_derivatives(pos_d(), x, y, ("sa4_rad", "sa6_rad")), repeat=100)
    out["lens_aberration_derivatives_mie_140px_s"] = t_deriv
    out["lens_aberration_derivatives_over_hologram_ratio"] = t_deriv / t_holo
    model = Spherocylinder(0.5, 1.0, 1.495)
    orientation = Orientation(np.radians(80), np.radians(20))
    engine = BuiltinDDA(dipole_size_um=0.0433341407)
    rod = engine.solve(model, LENS, orientation)
    rod_ab = engine.solve(model, replace(LENS, aberration=ABERRATION), orientation)
    step = (0.013, 0.007, 0.011)
    pos_e = _positions((7.0, 6.9, 12.0), step)
    pos_f = _positions((7.0, 6.9, 12.0), step)
    t_ideal, t_ab = _paired(lambda: calc_hologram(rod, pos_e(), GRID),
                            lambda: calc_hologram(rod_ab, pos_f(), GRID), repeat=40)
    out["lens_ideal_pupil_dda_rod_140px_s"] = t_ideal
    out["lens_aberration_dda_rod_140px_s"] = t_ab
    out["lens_aberration_dda_rod_cost_ratio"] = t_ab / t_ideal
    return out


BENCHMARKS = {"lens_mie": bench_lens_mie, "lens_dda": bench_lens_dda,
              "lens_aberration": bench_lens_aberration}
