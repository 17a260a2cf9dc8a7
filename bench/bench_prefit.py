"""Prefit speed: one frame on one core from the automatic start, and a batch on 2 workers.

Synthetic 8-bit holograms of spheres (a 0.5-1 um, n 1.45-1.6, z 5-30 um) with the paper's 60x
water set-up (0.1767 um pixels), 140x140 crops whose centre is 0.5 px off, as the crop stage
gives them. The estimator's table is built once per process (timed separately as
``prefit_table_build_s``); the per-frame time includes everything else: radial profile,
table search, profile refinement, screening of ambiguous starts, the full fit and its
statistics.

Non-spherical particles (``prefit_rod_*``, issue target ``prefit_rod_frame_s`` <= 0.15): the
paper's rod (a 0.501, b 1.079 um, n 1.495) through the 60x water set-up with its objective
(NA 1.2), 20 frames at random orientations, z 8-16 um, the crop stage's centre within half a
pixel, holograms from the final pass's T-matrix (kept in ``bench/.cache/``, built once),
8-bit camera noise. Timed: the seed fit (``SphereFitSettings(seed_only=True)``: x, y, z, alpha) and,
on the same frames, today's full sphere fit (``prefit_rod_frame_full_s``), with their
evaluations, position errors against the truth and ``ok`` fractions; and, in the same run,
the sphere prefit of ``prefit_frame_140px_s`` and ``prefit_frame_lens_140px_s`` (20 frames) as
``prefit_rod_reference_sphere_*``: the comparison under whatever else the machine runs.

The cost of the objective lens in a fit: ``prefit_frame_140px_s`` is the ideal model (no lens)
on ideal holograms; ``prefit_frame_lens_140px_s`` the same frames (same particles and noise)
made and fitted through the set-up's objective (NA 1.20, :mod:`holofit.scattering.lens`), and
``prefit_frame_fit_na_140px_s`` with the NA fitted too (a scan over NA, then the full fit);
``prefit_table_build_lens_140px_s`` is the estimator's table of lens profiles. The 390 px case
(pylorenzmie, no NA) and the batch use the ideal model.
"""

from __future__ import annotations

import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

from holofit.batch import BatchSettings
from holofit.camera import Camera
from holofit.config import load_instrument, resolve_config
from holofit.conventions import DetectorGrid
from holofit.hologram import calc_hologram
from holofit.io import write_table
from holofit.io.tiffstack import write_tiff_stack
from holofit.particles import Sphere
from holofit.prefit.estimate import profile_table
from holofit.prefit.sphere import SphereFitSettings, fit_sphere_crop
from holofit.prefit.stage import run_prefit
from holofit.provenance import sidecar
from holofit.scattering.mie import MieWave


def _frames(inst, n, size, seed=0):
    """n noisy normalised crops with the crop-stage centre; yields (crop, corner, centre, truth).

    The holograms are made with ``inst.optics`` (through its objective if it has an NA)."""
    px = inst.pixel_size_um
    rng = np.random.default_rng(seed)
    cam = Camera(background_counts=0.47 * 255)
    corner = (200, 300)
    grid = DetectorGrid((size, size), px, corner)
    for _ in range(n):
        a, m, z = rng.uniform(0.5, 1.0), rng.uniform(1.45, 1.6), rng.uniform(5, 30)
        r = corner[0] + size / 2 - 0.5 + rng.uniform(-0.5, 0.5)
        c = corner[1] + size / 2 - 0.5 + rng.uniform(-0.5, 0.5)
        holo = calc_hologram(MieWave(Sphere(a, m), inst.optics), (c * px, r * px, z), grid)
        raw = cam.expose(holo, rng)
        crop = raw / cam.background_counts
        crop[raw >= 255] = np.nan
        centre = ((c + rng.uniform(-0.5, 0.5)) * px, (r + rng.uniform(-0.5, 0.5)) * px)
        yield crop, corner, centre, (c * px, r * px, z, a, m)


def _one_core(inst, size, n, opts=None):
    opts = opts or SphereFitSettings()
    t0 = time.perf_counter()
    n_bins = size // 2 - 1
    search = opts.search.for_crop(n_bins * inst.pixel_size_um, inst.optics.wavelength_medium_um)
    profile_table(inst.optics, inst.pixel_size_um, n_bins, search)
    t_table = time.perf_counter() - t0
    times, evals = [], []
    for crop, corner, centre, _ in _frames(inst, n, size):
        t0 = time.perf_counter()
        fit = fit_sphere_crop(crop, corner, centre, inst.optics, inst.pixel_size_um, opts)
        times.append(time.perf_counter() - t0)
        evals.append(fit.n_eval)
    return t_table, statistics.median(times), statistics.median(evals)


def bench_prefit_frame() -> dict[str, float]:
    lens = load_instrument(resolve_config("paper_60x_water", "instruments"))
    assert lens.optics.numerical_aperture == 1.2
    ideal = lens.with_numerical_aperture(None)
    t_table, t_frame, n_eval = _one_core(ideal, 140, 30)
    t_table_lens, t_lens, n_eval_lens = _one_core(lens, 140, 30)
    _, t_fit_na, n_eval_fit_na = _one_core(lens, 140, 10, SphereFitSettings(fit_na=True))
    pyl = load_instrument(resolve_config("pylorenzmie", "instruments"))
    t_table_390, t_390, _ = _one_core(pyl, 390, 5)
    return {
        "prefit_frame_140px_s": t_frame,
        "prefit_frame_140px_evaluations": float(n_eval),
        "prefit_table_build_140px_s": t_table,
        "prefit_frame_lens_140px_s": t_lens,
        "prefit_frame_lens_140px_evaluations": float(n_eval_lens),
        "prefit_table_build_lens_140px_s": t_table_lens,
        "prefit_frame_fit_na_140px_s": t_fit_na,
        "prefit_frame_fit_na_140px_evaluations": float(n_eval_fit_na),
        "prefit_frame_390px_s": t_390,
        "prefit_table_build_390px_s": t_table_390,
    }


def bench_prefit_batch() -> dict[str, float]:
    inst = load_instrument(resolve_config("paper_60x_water", "instruments"))
    inst = inst.with_numerical_aperture(None)
    n = 150
    with tempfile.TemporaryDirectory() as tmp:
        crops_dir = Path(tmp) / "crops"
        crops, rows = [], []
        for k, (crop, corner, centre, _) in enumerate(_frames(inst, n, 140, seed=1)):
            crops.append(crop.astype(np.float32))
            px = inst.pixel_size_um
            rows.append(
                {
                    "frame": k,
                    "status": "ok",
                    "message": "",
                    "x_px": centre[0] / px,
                    "x_um": centre[0],
                    "y_um": centre[1],
                    "y_px": centre[1] / px,
                    "corner_row": corner[0],
                    "corner_col": corner[1],
                }
            )
        write_tiff_stack(crops_dir / "crops.tif", crops)
        write_table(
            crops_dir / "crops.csv",
            pd.DataFrame(rows),
            sidecar(kind="crop table (benchmark)", config={"instrument": inst.as_dict()}),
        )
        t0 = time.perf_counter()
        res = run_prefit(
            crops_dir,
            Path(tmp) / "out",
            batch=BatchSettings(workers=2, progress=False),
            plot=False,
        )
        wall = time.perf_counter() - t0
        assert res.summary.statuses.get("ok") == n, res.summary.statuses
    return {"prefit_frames_per_s_2workers": n / wall, "prefit_batch_150_frames_2workers_s": wall}


def _rod_frames(n: int = 20, seed: int = 0):
    """The rod frames of the module docstring: (crop, corner, centre, truth position)."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from fit_cases import CASES_SETUP, use_tmatrix

    from holofit.config import load_particle
    from holofit.holomodel.parameters import particle_with, static_values
    from holofit.scattering.theory import Orientation

    inst_name, part_name, truth, _ = CASES_SETUP["rod"]
    inst = load_instrument(resolve_config(inst_name, "instruments"))
    cfg = load_particle(resolve_config(part_name, "particles"))
    model = particle_with(cfg.model, dict(static_values(truth)))
    theory = cfg.with_fixed_lattice(inst.optics).theory()
    cache = Path(__file__).resolve().parent / ".cache"
    cache.mkdir(exist_ok=True)
    use_tmatrix(theory, model, inst, cache / "rod_final_tmatrix.npz")
    px = inst.pixel_size_um
    rng = np.random.default_rng(seed)
    cam = Camera(background_counts=120.0)
    frames = []
    for _ in range(n):
        corner = (200, 300)
        r = corner[0] + 70 - 0.5 + rng.uniform(-0.5, 0.5)
        c = corner[1] + 70 - 0.5 + rng.uniform(-0.5, 0.5)
        pos = (c * px, r * px, rng.uniform(8.0, 16.0))
        o = Orientation(rng.uniform(0, 2 * np.pi), np.arccos(rng.uniform(-1, 1)))
        wave = theory.solve(model, inst.optics, o)
        holo = calc_hologram(wave, pos, DetectorGrid((140, 140), px, corner), 0.9)
        crop = cam.expose(holo, rng) / 120.0
        centre = ((c + rng.uniform(-0.5, 0.5)) * px, (r + rng.uniform(-0.5, 0.5)) * px)
        frames.append((crop, corner, centre, pos))
    return inst, frames


def bench_prefit_rod() -> dict[str, float]:
    inst, frames = _rod_frames()
    profile_table(inst.optics, inst.pixel_size_um, 69,
                  SphereFitSettings().search.for_crop(69 * inst.pixel_size_um,
                                               inst.optics.wavelength_medium_um))
    out: dict[str, float] = {}
    for label, opts in (("", SphereFitSettings(seed_only=True)), ("_full", SphereFitSettings())):
        times, evals, errs, ok = [], [], [], 0
        for crop, corner, centre, pos in frames:
            t0 = time.perf_counter()
            fit = fit_sphere_crop(crop, corner, centre, inst.optics, inst.pixel_size_um, opts)
            times.append(time.perf_counter() - t0)
            evals.append(fit.n_eval)
            errs.append([fit.values[k] - v for k, v in zip(("x_um", "y_um", "z_um"), pos,
                                                            strict=True)])
            ok += fit.status == "ok"
        e = np.asarray(errs)
        out[f"prefit_rod_frame{label}_s"] = statistics.median(times)
        out[f"prefit_rod_frame{label}_evaluations"] = float(statistics.median(evals))
        out[f"prefit_rod{label}_xy_rms_nm"] = 1e3 * float(np.sqrt(np.mean(e[:, :2] ** 2)))
        out[f"prefit_rod{label}_z_rms_nm"] = 1e3 * float(np.sqrt(np.mean(e[:, 2] ** 2)))
        out[f"prefit_rod{label}_ok_fraction"] = ok / len(frames)
    # the sphere's prefit on the same core in the same run (the load of the moment shared)
    _, out["prefit_rod_reference_sphere_140px_s"], _ = _one_core(
        inst.with_numerical_aperture(None), 140, 20)
    _, out["prefit_rod_reference_sphere_lens_140px_s"], _ = _one_core(inst, 140, 20)
    return out


BENCHMARKS = {"prefit_frame": bench_prefit_frame, "prefit_batch": bench_prefit_batch,
              "prefit_rod": bench_prefit_rod}
