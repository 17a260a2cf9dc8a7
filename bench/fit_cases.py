"""One library/fit benchmark case per process (``python bench/fit_cases.py CASE``): prints JSON.

The paper's rod (a 0.501, b 1.079 um, n 1.495; 60x water, NA 1.2) and Janus particle (core
0.443 um, cap 0.047 um, n 1.581 / 2.74; 100x oil, NA 1.4), 140 x 140 crops, 12 um from focus,
8-bit camera noise, known truth. The "prefit" start is the truth moved by (30, -20, 250) nm and
alpha 0.85 (what a sphere fit of a rod gives, roughly); the library runs at that start.

Every case uses the paper's instrument with its objective lens (the default) and, as
``<particle>_ideal``, the ideal model without the lens. Reported per case: the library's
one-time tilt solves (``library_<p>_setup_s``), the
library per frame (``library_<p>_frame_s``), the final pass per frame (static parameters fixed:
``fit_<p>_frame_final_s``) and the initial pass (static parameters free from the config's
values: ``fit_<p>_frame_initial_s``), the final pass with direct solves
(``fit_<p>_frame_final_direct_s``) and from the particle's T-matrix (``fit_<p>_frame_final_s``,
the build timed apart), with their solves and hologram evaluations, and the
errors against the truth.
"""

from __future__ import annotations

import dataclasses
import json
import math
import sys
import time

import numpy as np

from holofit.camera import Camera
from holofit.config import load_instrument, load_particle, resolve_config
from holofit.conventions import DetectorGrid
from holofit.fit.frame import FrameFitOptions, fit_frame
from holofit.fit.stage import _free
from holofit.fitting.parameters import particle_with, static_values
from holofit.hologram import calc_hologram
from holofit.library.polar import polar_grid, sample_crop
from holofit.library.search import OrientationLibrary, pick_candidates, tilt_grid
from holofit.models import JanusSphere, Spherocylinder
from holofit.scattering.theory import Orientation

CASES_SETUP = {
    "rod": ("paper_60x_water", "rod_paper", Spherocylinder(0.501, 1.079, 1.495),
            Orientation(0.6, 1.0)),
    "janus": ("paper_100x_oil", "janus_paper", JanusSphere(0.443, 0.047, 1.581, 2.74),
              Orientation(0.6, 1.0)),
}


def run(case: str, with_tmatrix: bool = True) -> dict[str, float]:
    """``case`` is a particle (``rod``, ``janus``: the paper's instrument, objective lens
    included) or ``<particle>_ideal`` (no lens in the model: the focal-plane field itself)."""
    ideal = case.endswith("_ideal")
    name = case.removesuffix("_ideal")
    inst_name, part_name, truth_model, truth_o = CASES_SETUP[name]
    inst = load_instrument(resolve_config(inst_name, "instruments"))
    if ideal:
        inst = dataclasses.replace(inst, extra={k: v for k, v in inst.extra.items()
                                                if k != "numerical_aperture"})
        name = case
    cfg = load_particle(resolve_config(part_name, "particles"))
    px = inst.pixel_size_um
    grid = DetectorGrid((140, 140), px, (100, 200))
    pos = ((200 + 70.3) * px, (100 + 69.6) * px, 12.0)
    truth_theory = cfg.theory()
    wave = truth_theory.solve(truth_model, inst.optics, truth_o)
    holo = calc_hologram(wave, pos, grid, 0.9)
    cam = Camera(background_counts=120.0)
    crop = cam.expose(holo, np.random.default_rng(0)) / 120.0
    start = (pos[0] + 0.03, pos[1] - 0.02, pos[2] + 0.25)
    out: dict[str, float] = {}

    # the library at the truth's static parameters (as after the initial pass)
    fixed_model = particle_with(cfg.model, dict(static_values(truth_model)))
    cfg = cfg.with_fixed_lattice(inst.optics)
    theory = cfg.theory()
    lib = OrientationLibrary(theory, fixed_model, inst.optics,
                             tilt_grid(fixed_model, math.radians(10)))
    t0 = time.perf_counter()
    lib.solve_all()
    out[f"library_{name}_setup_s"] = time.perf_counter() - t0
    out[f"library_{name}_setup_solves"] = float(lib.n_solves)
    pg = polar_grid(start[:2], 69 * px, px, 128)
    d, w = sample_crop(crop, grid.corner, px, pg)
    t0 = time.perf_counter()
    scores = lib.scores(pg, d, w, start, 0.85)
    cands = pick_candidates(scores, lib.tilts, pg.phi, fixed_model, 4, math.radians(20))
    out[f"library_{name}_first_frame_s"] = time.perf_counter() - t0
    # a movie: the particle sinks 9 nm per frame (the paper's rod, 0.9 um/s at 100 frames/s),
    # so neighbouring frames share the library's fields at nearly the same height
    t0 = time.perf_counter()
    n_movie = 40
    for k in range(1, n_movie + 1):
        here = (start[0], start[1], start[2] - 0.009 * k)
        sc = lib.scores(pg, d, w, here, 0.85)
        pick_candidates(sc, lib.tilts, pg.phi, fixed_model, 4, math.radians(20))
    out[f"library_{name}_frame_s"] = (time.perf_counter() - t0) / n_movie

    def fit(pass_name, model, label):
        t0 = time.perf_counter()
        res = fit_frame(crop, grid.corner, px, theory, model, inst.optics, start, 0.85, cands,
                        _free(model, pass_name), FrameFitOptions(), seed=0)
        out[f"fit_{name}_frame_{label}_s"] = time.perf_counter() - t0
        return res

    runs = [("final", fixed_model, "final_direct"), ("initial", cfg.model, "initial")]
    if with_tmatrix:
        runs.append(("final", fixed_model, "final"))
    for pass_name, model, label in runs:
        if label == "final":
            t0 = time.perf_counter()
            theory.tmatrix(fixed_model, inst.optics)
            out[f"tmatrix_build_{name}_in_fit_s"] = time.perf_counter() - t0
        res = fit(pass_name, model, label)
        pass_name = label
        out[f"fit_{name}_frame_{pass_name}_evaluations"] = float(res.n_eval)
        out[f"fit_{name}_frame_{pass_name}_solves"] = float(res.extra["n_solves"])
        out[f"fit_{name}_frame_{pass_name}_ok"] = float(res.status == "ok")
        err = math.sqrt(sum((res.values[k] - v) ** 2 for k, v in
                            zip(("x_um", "y_um", "z_um"), pos, strict=True)))
        out[f"fit_{name}_frame_{pass_name}_position_error_nm"] = 1e3 * err
        u = np.array([res.values["ux"], res.values["uy"], res.values["uz"]])
        ut = np.array([math.sin(truth_o.theta) * math.cos(truth_o.psi),
                       math.sin(truth_o.theta) * math.sin(truth_o.psi), math.cos(truth_o.theta)])
        dot = abs(float(u @ ut)) if name == "rod" else float(u @ ut)
        out[f"fit_{name}_frame_{pass_name}_axis_error_deg"] = math.degrees(
            math.acos(min(1.0, dot)))
    return out


if __name__ == "__main__":
    print(json.dumps(run(sys.argv[1])))
