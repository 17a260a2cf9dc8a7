"""The sphere demo (``holofit demo --particle sphere``): a built-in synthetic movie with known
truth through crop, prefit and analyze.

A 1-um polystyrene sphere diffuses in water at 21 C (Stokes-Einstein); its 300-frame movie is
simulated with camera noise on the paper's 100x set-up, then cropped, Lorenz-Mie prefitted and
analysed, exactly as `holofit crop`, `holofit prefit` and `holofit analyze` would do it. The
demo prints how well each stage recovers the truth.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd

from holofit.analysis import AnalysisConfig, format_report, run_analysis
from holofit.analysis.hydrodynamics import sphere_diffusion
from holofit.batch import BatchSettings
from holofit.config import load_instrument, resolve_config
from holofit.crop import CropConfig, run_crop
from holofit.particles import Sphere
from holofit.prefit import run_prefit
from holofit.simulate.brownian import BrownianParameters, simulate_trajectory
from holofit.simulate.holograms import simulate_movie
from holofit.status import FITTABLE_CROP_STATUSES, OK

__all__ = ["run_sphere_demo"]

N_FRAMES = 300
TEMPERATURE_C = 21.0


def run_sphere_demo(out: Path, echo: Callable[[str], None] = print, workers: int = 2,
             n_frames: int = N_FRAMES) -> dict[str, float]:
    """Simulate, crop, prefit and analyse a diffusing sphere; report against the truth.

    Returns
    -------
    dict
        Headline numbers (rms errors of the prefit, measured and true diffusion coefficient).
    """
    out = Path(out)
    t_start = time.perf_counter()
    inst = load_instrument(resolve_config("paper_100x_oil", "instruments"))
    sphere = Sphere(radius_um=0.5, index=1.59)
    theory = sphere_diffusion(sphere.radius_um, TEMPERATURE_C)
    d_true, d_r_true = float(theory["D_t"]), float(theory["D_r"])
    if inst.frame_rate_hz is None:
        raise ValueError(f"instrument {inst.name} has no frame_rate_hz: the demo needs one")
    dt = 1.0 / inst.frame_rate_hz
    params = BrownianParameters(
        n_frames=n_frames, frame_interval_s=dt, d_par_um2_s=d_true, d_perp_um2_s=d_true,
        d_r_s=d_r_true, start_position_um=(13.5, 13.5, 12.0),
    )
    truth = simulate_trajectory(params, seed=7).truth
    pos = truth[["x_um", "y_um", "z_um"]].to_numpy()
    echo(f"holofit demo: a {2 * sphere.radius_um:g}-um polystyrene sphere (n {sphere.index.real:g})"
         f" diffusing in water at {TEMPERATURE_C:g} C, D = {d_true:.4f} um^2/s "
         f"(Stokes-Einstein), {n_frames} frames at {inst.frame_rate_hz:g} frames/s, "
         f"instrument {inst.name}")

    t0 = time.perf_counter()
    sim = simulate_movie(sphere, inst, pos, (256, 256), alpha=0.85, seed=3, out_dir=out / "sim")
    assert sim.movie is not None  # written: out_dir is given
    echo(f"1. simulate: {sim.movie} with 8-bit camera noise ({time.perf_counter() - t0:.1f} s)")

    t0 = time.perf_counter()
    crop = run_crop(sim.movie, sim.background, inst, out / "crop", CropConfig(size=140, plot=True))
    table = pd.read_csv(crop.table)
    found = table["status"].isin(FITTABLE_CROP_STATUSES)
    err_px = np.hypot(table["x_px"] - pos[:, 0] / inst.pixel_size_um,
                      table["y_px"] - pos[:, 1] / inst.pixel_size_um)[found]
    echo(f"2. crop: hologram found in {int(found.sum())}/{n_frames} frames, centre error median "
         f"{np.median(err_px):.3f} px ({time.perf_counter() - t0:.1f} s)")

    t0 = time.perf_counter()
    pre = run_prefit(out / "crop", out / "prefit",
                     batch=BatchSettings(workers=workers, progress=False))
    fit = pd.read_csv(pre.table)
    ok = (fit["status"] == OK).to_numpy()
    rms = {
        "x_nm": 1e3 * np.sqrt(np.mean((fit["x_um"][ok] - pos[ok, 0]) ** 2)),
        "y_nm": 1e3 * np.sqrt(np.mean((fit["y_um"][ok] - pos[ok, 1]) ** 2)),
        "z_nm": 1e3 * np.sqrt(np.mean((fit["z_um"][ok] - pos[ok, 2]) ** 2)),
        "a_nm": 1e3 * np.sqrt(np.mean((fit["radius_um"][ok] - sphere.radius_um) ** 2)),
        "n": float(np.sqrt(np.mean((fit["n"][ok] - sphere.index.real) ** 2))),
    }
    echo(f"3. prefit: {int(ok.sum())}/{n_frames} frames converged from the automatic start; "
         f"rms error x {rms['x_nm']:.1f} nm, y {rms['y_nm']:.1f} nm, z {rms['z_nm']:.1f} nm, "
         f"radius {rms['a_nm']:.1f} nm, index {rms['n']:.4f} "
         f"({time.perf_counter() - t0:.1f} s, {workers} workers)")

    t0 = time.perf_counter()
    settings = AnalysisConfig(model="sphere", temperature_c=TEMPERATURE_C)
    result = run_analysis(pre.table, settings, out / "analysis").result
    assert result is not None
    echo(f"4. analyze ({time.perf_counter() - t0:.1f} s):")
    for line in format_report(result).splitlines():
        echo("   " + line)
    m = _translational_d(result)
    if m is not None:
        below, above = m.sides()
        echo(f"Measured D = {m.value:.4f} -{below:.4f} +{above:.4f} um^2/s against the true "
             f"{d_true:.4f} um^2/s ({m.pull(d_true):+.1f} standard errors). Outputs in {out}/; "
             f"total {time.perf_counter() - t_start:.0f} s.")
    return {**{f"rms_{k}": float(v) for k, v in rms.items()}, "d_true": d_true,
            "d_measured": float(m.value) if m is not None else float("nan")}


def _translational_d(result):
    for name in ("D", "D_t", "D_xy"):
        if name in result.measured:
            return result.measured[name]
    return None
