"""The cluster engine's benchmark cases, one per process (``python bench/cluster_cases.py
CASE``): prints one JSON line.

* ``build``: the superposition T-matrix of two touching 0.53 um polystyrene spheres in water
  (660 nm): the first build in a process (``cluster_tmatrix_build_dimer_s``; the compiled
  kernels warmed up on another particle first, the order-dependent Gaunt tables not) and a
  rebuild for a new gap with the same orders (``..._rebuild_s``: what a fit of the sizes pays
  per geometry). Target: <= 1 s.
* ``orientation``: that dimer's hologram at a new orientation, 140 x 140 pixels 12 um from
  focus (``dda_dimer_orientation_cluster_s``, median of 40; the DDA's ``dda_*_orientation_*``
  cases use the same pixels, optics and height). Target: <= 0.01 s.
* ``fit``: one 200 x 200 crop of a dimer (HoloPy's dimer2011 particle: 0.6857 and 0.6964 um
  touching spheres, n 1.6026; its instrument, lens NA 1.4) made by the cluster engine with
  8-bit camera noise, fitted with the sizes fixed: the library's candidate orientations
  (all starts) from a start 30 nm / 250 nm off, then the frame fit
  (``fit_dimer_crop_cluster_s``, library scores and fit together; the library's one-time tilt
  solves apart in ``library_dimer_cluster_setup_s``). Target: <= 2 s. A 200 x 200 crop of
  real dimer data is not in the repository (dimer2011 is 100 x 100; see ``realdata``).
* ``realdata``: HoloPy's dimer2011 (100 x 100, the real data) through the stages (crop, prefit,
  library, initial-pass fit with the gap fixed at 0, one frame), engine ``cluster``
  (``fit_dimer2011_cluster_*``); ``realdata_dda`` the same with ``--engine builtin``.
"""

from __future__ import annotations

import dataclasses
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from holofit.camera import Camera
from holofit.config import load_instrument, load_particle, resolve_config
from holofit.conventions import DetectorGrid
from holofit.fit.frame import fit_frame
from holofit.fit.problem import FrameProblem
from holofit.fit.settings import FrameFitSettings
from holofit.fit.task import free_parameters
from holofit.hologram import calc_hologram
from holofit.library.polar import polar_grid, sample_crop
from holofit.library.search import OrientationLibrary, pick_candidates, tilt_grid
from holofit.optics import Optics
from holofit.particles import Dimer
from holofit.scattering.cluster import ClusterEngine
from holofit.scattering.theory import Orientation

ROOT = Path(__file__).resolve().parents[1]
OPTICS = Optics(0.66, 1.33, 0.0)
GRID = DetectorGrid((140, 140), 0.1)
POS = (7.0, 7.0, 12.0)
DIMER = Dimer(0.53, 0.53, 0.0, 1.59, 1.59)


def _warm_up() -> None:
    """Load the compiled kernels (multipole, Legendre, Wigner) on another particle."""
    th = ClusterEngine()
    wave = th.solve(Dimer(0.1, 0.12, 0.0, 1.5, 1.5), OPTICS, Orientation(0.1, 0.2))
    calc_hologram(wave, POS, GRID)
    wave.rotation_derivative([1.0, 0.0, 0.0]).field_on_detector(POS, GRID)


def build() -> dict[str, float]:
    _warm_up()
    th = ClusterEngine()
    t0, c0 = time.perf_counter(), time.process_time()
    sol = th.solution(DIMER, OPTICS)
    first = time.perf_counter() - t0
    first_cpu = time.process_time() - c0
    t0 = time.perf_counter()
    th.solution(DIMER.replace(gap_um=0.01), OPTICS)
    again = time.perf_counter() - t0
    return {"cluster_tmatrix_build_dimer_s": first, "cluster_tmatrix_build_dimer_cpu_s": first_cpu,
            "cluster_tmatrix_build_dimer_rebuild_s": again,
            "cluster_tmatrix_dimer_order": float(sol.tmatrix.order),
            "cluster_tmatrix_dimer_sphere_order": float(max(sol.orders))}


def orientation() -> dict[str, float]:
    _warm_up()
    th = ClusterEngine()
    th.solution(DIMER, OPTICS)
    rng = np.random.default_rng(1)
    oris = [Orientation(*rng.uniform(0, 2 * np.pi, 3)) for _ in range(40)]
    times, cpu = [], []
    for o in oris:
        t0, c0 = time.perf_counter(), time.process_time()
        calc_hologram(th.solve(DIMER, OPTICS, o), POS, GRID)
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return {"dda_dimer_orientation_cluster_s": float(np.median(times)),
            "dda_dimer_orientation_cluster_min_s": float(np.min(times)),
            "dda_dimer_orientation_cluster_cpu_s": float(np.median(cpu))}


#: the synthetic crop's truth
TRUTH_ORIENTATION = Orientation(0.7, 1.1, 0.0)
TRUTH_ALPHA = 0.85
START_OFFSET_UM = (0.03, -0.02, 0.25)


def fit(ideal: bool = False) -> dict[str, float]:
    """The synthetic 200 x 200 crop, through the instrument's lens (NA 1.4) or, with
    ``ideal``, without it in both the crop and the model (``fit_dimer_crop_ideal_cluster_*``)."""
    _warm_up()
    inst = load_instrument(resolve_config("holopy_dimer2011", "instruments"))
    if ideal:
        inst = dataclasses.replace(inst, extra={k: v for k, v in inst.extra.items()
                                                if k != "numerical_aperture"})
    tag = "fit_dimer_crop_ideal_cluster" if ideal else "fit_dimer_crop_cluster"
    cfg = load_particle(resolve_config("dimer_holopy2011", "particles"))
    model = cfg.model
    th = cfg.theory()
    px = inst.pixel_size_um
    crop_n = 200
    grid = DetectorGrid((crop_n, crop_n), px, (50, 80))
    pos = ((80 + 100.3) * px, (50 + 99.6) * px, 15.0)
    holo = calc_hologram(th.solve(model, inst.optics, TRUTH_ORIENTATION), pos, grid,
                         TRUTH_ALPHA)
    cam = Camera(background_counts=120.0)
    crop = cam.expose(holo, np.random.default_rng(0)) / 120.0
    start = tuple(p + d for p, d in zip(pos, START_OFFSET_UM, strict=True))
    out: dict[str, float] = {}
    t0 = time.perf_counter()
    lib = OrientationLibrary(th, model, inst.optics, tilt_grid(model, math.radians(10)))
    lib.solve_all()
    out[f"library_{tag.removeprefix('fit_')}_setup_s"] = time.perf_counter() - t0
    t0, c0 = time.perf_counter(), time.process_time()
    pg = polar_grid(start[:2], (crop_n // 2 - 1) * px, px, 128)
    d, w = sample_crop(crop, grid.corner, px, pg)
    scores = lib.scores(pg, d, w, start, 0.8)
    cands = pick_candidates(scores, lib.tilts, pg.phi, model, 4, math.radians(20))
    res = fit_frame(
        FrameProblem(
            crop,
            grid.corner,
            px,
            th,
            model,
            inst.optics,
            free_parameters(model, "final"),
            settings=FrameFitSettings(),
            seed=0,
        ),
        start,
        0.8,
        cands,
    )
    out[f"{tag}_s"] = time.perf_counter() - t0
    out[f"{tag}_cpu_s"] = time.process_time() - c0
    out[f"{tag}_ok"] = float(res.status == "ok")
    out[f"{tag}_r2"] = float(res.r2)
    out[f"{tag}_evaluations"] = float(res.n_eval)
    out[f"{tag}_starts"] = float(len(cands))
    err = math.sqrt(
        sum((res.values[k] - v) ** 2 for k, v in zip(("x_um", "y_um", "z_um"), pos, strict=True))
    )
    out[f"{tag}_position_error_nm"] = 1e3 * err
    o = TRUTH_ORIENTATION
    ut = np.array(
        [
            math.sin(o.theta) * math.cos(o.psi),
            math.sin(o.theta) * math.sin(o.psi),
            math.cos(o.theta),
        ]
    )
    u = np.array([res.values["ux"], res.values["uy"], res.values["uz"]])
    cos = abs(float(u @ ut) / float(np.linalg.norm(u)))
    out[f"{tag}_axis_error_deg"] = math.degrees(math.acos(min(1.0, cos)))
    return out


def realdata(engine: str) -> dict[str, float]:
    import pandas as pd

    from holofit.batch import BatchSettings
    from holofit.crop import CropConfig, run_crop
    from holofit.fit.config import FitConfig
    from holofit.fit.stage import run_fit
    from holofit.library.stage import run_library
    from holofit.prefit.stage import run_prefit

    serial = BatchSettings(workers=0, progress=False)
    inst = load_instrument(resolve_config("holopy_dimer2011", "instruments"))
    particle = load_particle(resolve_config("dimer_holopy2011", "particles"))
    out: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        crops = root / "crops"
        run_crop(ROOT / "tests" / "data" / "holopy" / "dimer2011.tif", None, inst, crops,
                 CropConfig(normalized=True, size=100, plot=False))
        run_prefit(crops, root / "prefit", batch=serial, plot=False)
        t0 = time.perf_counter()
        run_library(
            crops,
            root / "prefit",
            particle,
            root / "library",
            batch=serial,
            plot=False,
            engine=engine,
        )
        out[f"library_dimer2011_{engine}_s"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        run_fit(
            crops,
            root / "prefit",
            root / "library",
            root / "fit",
            FitConfig(
                particle,
                passes="initial",
                initial_frames=1,
                fixed=("gap_um",),
                plot=False,
                engine=engine,
            ),
            batch=serial,
        )
        out[f"fit_dimer2011_{engine}_stage_s"] = time.perf_counter() - t0
        row = pd.read_csv(root / "fit" / "initial.csv").iloc[0].to_dict()
    for key in (
        "fit_time_s",
        "r2",
        "chi2_red",
        "x_um",
        "y_um",
        "z_um",
        "radius1_um",
        "radius2_um",
        "n1",
        "n2",
        "alpha",
        "theta_rad",
        "psi_rad",
    ):
        if key in row:
            out[f"fit_dimer2011_{engine}_{key}"] = float(row[key])
    out[f"fit_dimer2011_{engine}_ok"] = float(row["status"] == "ok")
    return out


CASES = {
    "build": build,
    "orientation": orientation,
    "fit": fit,
    "fit_ideal": lambda: fit(ideal=True),
    "realdata": lambda: realdata("cluster"),
    "realdata_dda": lambda: realdata("builtin"),
}

if __name__ == "__main__":
    print(json.dumps(CASES[sys.argv[1]]()))
