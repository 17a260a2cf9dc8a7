"""The aberration term's cost in the lens, timed by CPU time: ``bench_lens``'s
``lens_aberration`` cases (a Mie sphere at a new height every call, the DDA rod at a new position
every call; ideal and aberrated calls alternated), each call timed by ``time.process_time``
rather than the wall clock, so that a machine whose cores are shared by other busy processes
(where a 1.8 ms call is preempted for 10-20 ms at random and ``make bench``'s wall-time medians
of the DDA rod range from 0.1 to 17) still measures the ratio.

    python bench/lens_aberration_cpu.py [--pairs N]

Prints the medians and their ratios (target <= 1.2; docs/validation/aberration.md section 5).
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_lens as bl

from holofit.dda.engine import BuiltinDDA
from holofit.hologram import calc_hologram
from holofit.particles import Sphere, Spherocylinder
from holofit.scattering.mie import LorenzMie
from holofit.scattering.theory import Orientation


def _paired(fa, fb, n: int) -> tuple[float, float]:
    ta, tb = [], []
    for i in range(n):
        t = time.process_time()
        fa(i)
        ta.append(time.process_time() - t)
        t = time.process_time()
        fb(i)
        tb.append(time.process_time() - t)
    return float(np.median(ta)), float(np.median(tb))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", type=int, default=300, help="alternated pairs per case")
    args = parser.parse_args()
    sphere = Sphere(0.5, 1.59)
    ideal = LorenzMie().solve(sphere, bl.LENS)
    ab = LorenzMie().solve(sphere, replace(bl.LENS, aberration=bl.ABERRATION))
    a, b = _paired(lambda i: calc_hologram(ideal, (7, 7, 10 + 1e-4 * i), bl.GRID, 0.8),
                   lambda i: calc_hologram(ab, (7, 7, 10 + 1e-4 * i), bl.GRID, 0.8),
                   args.pairs)
    print(f"Mie lens hologram: ideal {a * 1e3:.3f} ms, aberrated {b * 1e3:.3f} ms, "
          f"ratio {b / a:.3f}")
    model = Spherocylinder(0.5, 1.0, 1.495)
    orientation = Orientation(np.radians(80), np.radians(20))
    engine = BuiltinDDA(dipole_size_um=0.0433341407)
    rod = engine.solve(model, bl.LENS, orientation)
    rod_ab = engine.solve(model, replace(bl.LENS, aberration=bl.ABERRATION), orientation)

    def pos(i: int) -> tuple[float, float, float]:
        return (7 + 0.013 * i, 6.9 + 0.007 * i, 12 + 0.011 * i)

    a, b = _paired(lambda i: calc_hologram(rod, pos(i), bl.GRID),
                   lambda i: calc_hologram(rod_ab, pos(i), bl.GRID), args.pairs)
    print(f"DDA rod lens hologram: ideal {a * 1e3:.3f} ms, aberrated {b * 1e3:.3f} ms, "
          f"ratio {b / a:.3f}")


if __name__ == "__main__":
    main()
