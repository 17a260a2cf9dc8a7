"""Lorenz-Mie hologram speed."""

from __future__ import annotations

from timing import median_time

from holofit.conventions import DetectorGrid
from holofit.hologram import calc_hologram
from holofit.optics import Optics
from holofit.particles import Sphere
from holofit.scattering.mie import LorenzMie


def bench_mie() -> dict[str, float]:
    optics = Optics(0.66, 1.33, 0.0)
    grid = DetectorGrid((140, 140), 0.1)
    wave = LorenzMie().solve(Sphere(0.5, 1.59), optics)
    t_holo = median_time(lambda: calc_hologram(wave, (7.0, 7.0, 10.0), grid, 0.8), repeat=100)
    t_solve = median_time(lambda: LorenzMie().solve(Sphere(0.5, 1.59), optics), repeat=100)
    big = DetectorGrid((1024, 1280), 0.1)
    t_big = median_time(lambda: calc_hologram(wave, (60.0, 50.0, 10.0), big, 0.8), repeat=5)
    return {
        "mie_holo_140px_s": t_holo,
        "mie_solve_s": t_solve,
        "mie_holo_1024x1280_s": t_big,
    }


BENCHMARKS = {"mie": bench_mie}
