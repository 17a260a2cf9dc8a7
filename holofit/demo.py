"""The demo: simulate a short movie of a sphere with known truth, then measure it back.

For now (foundation stage) it simulates with camera noise and checks the exact Lorenz-Mie
model against the noisy frames; later stages extend it to the whole pipeline.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from holofit.config import load_instrument, resolve_config
from holofit.conventions import DetectorGrid, r_squared
from holofit.hologram import calc_hologram
from holofit.io.movie import open_movie
from holofit.models import Sphere
from holofit.scattering.mie import LorenzMie
from holofit.simulate.holograms import simulate_movie

__all__ = ["run_demo"]


def run_demo(out: Path, echo: Callable[[str], None] = print) -> dict[str, float]:
    """Simulate a 5-frame sphere movie and report how well the exact model describes it."""
    inst = load_instrument(resolve_config("paper_100x_oil", "instruments"))
    sphere = Sphere(radius_um=0.5, index=1.59)
    rng = np.random.default_rng(1)
    n = 5
    pos = np.column_stack(
        [7.0 + rng.normal(0, 0.3, n), 7.0 + rng.normal(0, 0.3, n), np.linspace(8, 16, n)]
    )
    shape = (140, 140)
    t0 = time.perf_counter()
    sim = simulate_movie(sphere, inst, pos, shape, alpha=0.9, out_dir=out, seed=3)
    t_sim = time.perf_counter() - t0
    echo(f"simulated {n} frames of a {2 * sphere.radius_um:g} um PS sphere -> {sim.movie}")
    grid = DetectorGrid(shape, inst.pixel_size_um)
    wave = LorenzMie().solve(sphere, inst.optics)
    with open_movie(sim.movie) as movie, open_movie(sim.background) as bg:
        background = np.median(np.stack(list(bg)), axis=0).astype(float)
        r2 = []
        for k, frame in enumerate(movie):
            data = frame / background
            data /= data.mean()
            model = calc_hologram(wave, pos[k], grid, alpha=0.9)
            r2.append(r_squared(data, model))
            echo(
                f"  frame {k}: x={pos[k, 0]:.3f} y={pos[k, 1]:.3f} z={pos[k, 2]:.2f} um"
                f"   R^2(model vs noisy frame) = {r2[-1]:.4f}"
            )
    t1 = time.perf_counter()
    for _ in range(50):
        calc_hologram(wave, pos[0], grid)
    t_holo = (time.perf_counter() - t1) / 50
    echo(f"exact Lorenz-Mie hologram 140x140: {t_holo * 1e3:.2f} ms; simulation {t_sim:.2f} s")
    return {"r2_min": float(min(r2)), "hologram_s": t_holo}
