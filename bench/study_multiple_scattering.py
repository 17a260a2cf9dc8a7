"""How much multiple scattering between two particles changes their hologram.

holofit's field-of-view model superposes the particles' scattered fields at the camera and
neglects the field that one particle scatters onto the other (:mod:`holofit.simulate.field_of_view`
and the overlap model of the fit). This study measures what that neglect costs: two 1 um
polystyrene spheres in water at separations d (centre to centre), side by side (``x``, the
default) or one above the other (``z``), 12 um above the focal plane, filmed by the paper's 60x
water set-up (ideal model: no lens), exact (the cluster engine's solution, every order of
scattering between the spheres) against the sum of the two
single-sphere Lorenz-Mie fields. Reported per d: the rms hologram difference, relative to the rms
of the hologram's modulation and in units of the 8-bit camera's noise (s.d. 0.012 of the
background, :func:`holofit.simulate.holograms.default_camera`), and 1 - R^2 of the
superposition as a fit of the exact hologram.

Run: ``python bench/study_multiple_scattering.py`` (about a minute per separation on one core).
"""

from __future__ import annotations

import json
import sys
import time

import numpy as np

from holofit.config import load_instrument, resolve_config
from holofit.conventions import hologram_intensity, pixel_centres
from holofit.optics import Optics
from holofit.particles import Sphere
from holofit.scattering.cluster import SphereSumWave, solve_cluster
from holofit.scattering.mie import MieWave
from holofit.scattering.recorded_field import recorded_field
from holofit.scattering.theory import Orientation

RADIUS_UM, INDEX, HEIGHT_UM = 0.5, 1.59, 12.0
NOISE_SD = 0.012  # the 8-bit camera's noise at the background level (relative)


def compare(d_um: float, axis: str = "x", size_px: int = 160) -> dict[str, float | str]:
    inst = load_instrument(resolve_config("paper_60x_water", "instruments"))
    optics = Optics(inst.optics.wavelength_um, inst.optics.n_medium,
                    inst.optics.polarization_rad)  # the ideal model: no lens
    xs, ys = pixel_centres((size_px, size_px), inst.pixel_size_um)
    xs, ys = xs.ravel(), ys.ravel()
    centre = np.array([size_px / 2 * inst.pixel_size_um, size_px / 2 * inst.pixel_size_um,
                       HEIGHT_UM])
    step = {"x": (1.0, 0.0, 0.0), "z": (0.0, 0.0, 1.0), "xz": (0.7071, 0.0, 0.7071)}[axis]
    offsets = np.array([[-d_um / 2 * v for v in step], [d_um / 2 * v for v in step]])
    t0 = time.perf_counter()
    sol = solve_cluster(offsets, [RADIUS_UM] * 2, [INDEX] * 2, optics)
    exact_wave = SphereSumWave(sol, optics, Orientation(0.0, 0.0, 0.0))
    ex, ey = recorded_field(exact_wave, centre, xs, ys)
    solve_s = time.perf_counter() - t0
    sx = sy = 0
    for off in offsets:
        fx, fy = recorded_field(MieWave(Sphere(RADIUS_UM, INDEX), optics), centre + off, xs, ys)
        sx, sy = sx + fx, sy + fy
    pol = optics.polarization_rad
    h_exact = hologram_intensity(ex, ey, pol)
    h_sum = hologram_intensity(sx, sy, pol)
    diff = h_exact - h_sum
    mod = h_exact - np.mean(h_exact)
    return {
        "d_um": d_um,
        "axis": axis,
        "rms_difference": float(np.sqrt(np.mean(diff**2))),
        "relative_to_modulation": float(np.sqrt(np.mean(diff**2) / np.mean(mod**2))),
        "in_noise_sd": float(np.sqrt(np.mean(diff**2)) / NOISE_SD),
        "one_minus_r2": float(np.sum(diff**2) / np.sum(mod**2)),
        "max_abs_difference": float(np.max(np.abs(diff))),
        "solve_s": solve_s,
    }


def main(argv: list[str]) -> None:
    """``[x|z|xz] d1 d2 ...``: side by side (x, the default), one above the other (z), or at
    45 degrees (xz)."""
    axis = argv.pop(0) if argv and argv[0] in ("x", "z", "xz") else "x"
    seps = [float(a) for a in argv] or [1.5, 2.0, 3.0, 4.0]
    for d in seps:
        print(json.dumps(compare(d, axis)), flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
