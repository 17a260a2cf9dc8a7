"""The demo: the whole pipeline on a built-in synthetic movie with known truth.

``holofit demo`` (``make demo``) simulates the paper's silica rod (a 501 nm, b 1079 nm, n 1.495)
diffusing and sedimenting (0.9 um/s) in water at 21 C, filmed at 100 frames/s through the
paper's 60x water-immersion set-up with 8-bit camera noise, and runs all five stages on it
exactly as the command line does: crop, Lorenz-Mie prefit, orientation library, DDA fit (an
initial pass with every parameter free on the first frames, then a final pass with the sizes and
index fixed, served from the rod's T-matrix) and the diffusion analysis. It prints what each
stage recovered against the truth and against the spherocylinder prediction. ``holofit demo
--particle sphere`` runs the shorter sphere demo (:mod:`holofit.demo_sphere`).
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd

from holofit.analysis import AnalysisSettings, run_analysis
from holofit.analysis.hydrodynamics import spherocylinder_diffusion
from holofit.batch import BatchOptions
from holofit.config import ParticleConfig, load_instrument, load_particle, resolve_config
from holofit.crop import run_crop
from holofit.demo_sphere import run_sphere_demo
from holofit.fit.stage import run_fit
from holofit.library.stage import run_library
from holofit.models import Spherocylinder
from holofit.prefit import run_prefit
from holofit.simulate.brownian import BrownianParameters
from holofit.simulate.scenarios import diffusing_movie
from holofit.status import FITTABLE_CROP_STATUSES, OK, POOR_FIT

__all__ = ["DEMO_PARTICLES", "run_demo", "run_rod_demo"]

DEMO_PARTICLES = ("rod", "sphere")
TEMPERATURE_C = 21.0
#: the paper's rod and its measured motion (table 1): D_par, D_perp in um^2/s, D_r in 1/s
ROD = Spherocylinder(0.501, 1.079, 1.495)
ROD_D_PAR, ROD_D_PERP, ROD_D_R = 0.307, 0.293, 0.311
SEDIMENTATION_UM_S = 0.9


def run_demo(out: str | Path, particle: str = "rod", echo: Callable[[str], None] = print,
             workers: int = 2, n_frames: int | None = None) -> dict[str, float]:
    """Run the demo of ``particle`` (``rod`` or ``sphere``); returns its headline numbers."""
    if particle not in DEMO_PARTICLES:
        raise ValueError(f"demo particle must be one of {', '.join(DEMO_PARTICLES)}")
    if particle == "sphere":
        kw = {} if n_frames is None else {"n_frames": n_frames}
        return run_sphere_demo(Path(out), echo=echo, workers=workers, **kw)
    return run_rod_demo(out, echo=echo, workers=workers,
                        **({} if n_frames is None else {"n_frames": n_frames}))


def _timed(echo: Callable[[str], None], label: str, t0: float) -> float:
    dt = time.perf_counter() - t0
    echo(f"   ({label}: {dt:.0f} s)")
    return dt


def run_rod_demo(out: str | Path, echo: Callable[[str], None] = print, workers: int = 2,
                 n_frames: int = 150, initial_frames: int = 8) -> dict[str, float]:
    """The rod demo (see the module docstring).

    Returns
    -------
    dict
        Truth and recovered values: static parameters, rms errors of the final fit, the
        diffusion coefficients with their errors, and the wall time of each stage.
    """
    out = Path(out)
    t_start = time.perf_counter()
    inst = load_instrument(resolve_config("paper_60x_water", "instruments"))
    config = load_particle(resolve_config("rod_paper", "particles"))
    truth_config = ParticleConfig(ROD, config.settings, config.path)
    batch = BatchOptions(workers=workers, progress=False)
    times: dict[str, float] = {}
    echo(f"holofit demo: the paper's silica rod (a {ROD.a_um * 1e3:.0f} nm, b "
         f"{ROD.b_um * 1e3:.0f} nm, n {ROD.index:g}) diffusing (D_par {ROD_D_PAR}, D_perp "
         f"{ROD_D_PERP} um^2/s, D_r {ROD_D_R} 1/s) and sinking {SEDIMENTATION_UM_S} um/s in "
         f"water at {TEMPERATURE_C:g} C; {n_frames} frames at {inst.frame_rate_hz:g} frames/s "
         f"through {inst.name} (NA {inst.extra.get('numerical_aperture', '-')}), 8-bit noise")

    t0 = time.perf_counter()
    dynamics = BrownianParameters(
        n_frames=n_frames, frame_interval_s=1.0 / inst.frame_rate_hz, d_par_um2_s=ROD_D_PAR,
        d_perp_um2_s=ROD_D_PERP, d_r_s=ROD_D_R, drift_um_s=(0.0, 0.0, -SEDIMENTATION_UM_S),
        start_position_um=(17.0, 17.0, 15.0))
    sim = diffusing_movie(truth_config, inst, dynamics, out, frame_shape=(192, 192), seed=7)
    truth = sim.trajectory.truth.set_index("frame")
    echo(f"1. simulate: {sim.movie.movie}")
    times["simulate_s"] = _timed(echo, "simulate", t0)

    t0 = time.perf_counter()
    crop = run_crop(sim.movie.movie, sim.movie.background, inst, out / "crop", size=140)
    table = pd.read_csv(crop.table).set_index("frame")
    found = table["status"].isin(FITTABLE_CROP_STATUSES)
    err = np.hypot(table["x_um"] - truth["x_um"], table["y_um"] - truth["y_um"])[found]
    echo(f"2. crop: hologram found in {int(found.sum())}/{n_frames} frames, centre off the "
         f"rod's centre by {1e3 * np.median(err):.0f} nm (median)")
    times["crop_s"] = _timed(echo, "crop", t0)

    t0 = time.perf_counter()
    pre = run_prefit(out / "crop", out / "prefit", batch=batch)
    p = pd.read_csv(pre.table).set_index("frame")
    dz = (p["z_um"] - truth["z_um"]).dropna()
    echo(f"3. prefit (a sphere's model of a rod: a start, not a measurement): "
         f"{int(p['status'].isin([OK, POOR_FIT]).sum())}/{n_frames} converged, z off by "
         f"{1e3 * dz.median():+.0f} nm (median), sphere radius {p['radius_um'].median():.3f} um")
    times["prefit_s"] = _timed(echo, "prefit", t0)

    t0 = time.perf_counter()
    lib = run_library(out / "crop", out / "prefit", config, out / "library", batch=batch)
    lt = pd.read_csv(lib.table).set_index("frame")
    u_true = _axis(truth["theta_rad"], truth["psi_rad"])
    best = _axis(lt["c1_theta_rad"], lt["c1_psi_rad"])
    ang = _angle(best, u_true.loc[lt.index].to_numpy(), head_tail=True)
    echo(f"4. library: best candidate within {np.median(ang):.1f} deg of the truth (median; "
         f"grid step 10 deg)")
    times["library_s"] = _timed(echo, "library", t0)

    t0 = time.perf_counter()
    run = run_fit(out / "crop", out / "prefit", out / "library", config, out / "fit",
                  initial_frames=initial_frames, batch=batch)
    times["fit_s"] = _timed(echo, "fit", t0)
    static = json.loads(run.static.read_text())["values"]
    fit = pd.read_csv(run.final).set_index("frame")
    ok = fit["status"] == OK
    f = fit[ok]
    tr = truth.loc[f.index]
    rms = {k: 1e3 * float(np.sqrt(np.mean((f[k] - tr[k]) ** 2))) for k in
           ("x_um", "y_um", "z_um")}
    axis_err = _angle(f[["ux", "uy", "uz"]].to_numpy(),
                      _axis(tr["theta_rad"], tr["psi_rad"]).to_numpy(), head_tail=True)
    echo(f"5. fit, initial pass ({initial_frames} frames, everything free): a "
         f"{static['a_um'] * 1e3:.1f} nm (truth {ROD.a_um * 1e3:.0f}), b "
         f"{static['b_um'] * 1e3:.1f} nm (truth {ROD.b_um * 1e3:.0f}), n {static['n']:.4f} "
         f"(truth {ROD.index:g}); the config started at a 500, b 1000 nm")
    echo(f"   final pass: {int(ok.sum())}/{n_frames} frames ok, rms error x {rms['x_um']:.1f}, "
         f"y {rms['y_um']:.1f}, z {rms['z_um']:.1f} nm, axis {_rms(axis_err):.2f} deg; "
         f"{int(fit['ambiguous'].fillna(0).sum())} frame(s) flagged ambiguous")

    t0 = time.perf_counter()
    settings = AnalysisSettings(model="rod", temperature_c=TEMPERATURE_C)
    result, _ = run_analysis(run.final, settings, out / "analysis")
    times["analyze_s"] = _timed(echo, "analyze", t0)
    theory = spherocylinder_diffusion(ROD.a_um, ROD.b_um, TEMPERATURE_C)
    truth_d = {"D_par": ROD_D_PAR, "D_perp": ROD_D_PERP,
               "D_t": (ROD_D_PAR + 2 * ROD_D_PERP) / 3, "D_r": ROD_D_R}
    echo("6. analyze: measured against the truth of the simulation and the spherocylinder "
         "prediction")
    m = result.measured
    for key, unit in (("D_par", "um^2/s"), ("D_perp", "um^2/s"), ("D_t", "um^2/s"),
                      ("D_r", "1/s")):
        pred = theory.get(key)
        extra = f", spherocylinder {pred:.3f}" if pred is not None else ""
        below, above = m[key].sides()
        echo(f"   {key:<7} {m[key].value:.3f} -{below:.3f} +{above:.3f} {unit} (truth "
             f"{truth_d[key]:.3f}{extra}; {m[key].pull(truth_d[key]):+.1f} sigma)")
    for key in ("eps_par", "eps_perp", "eps_r"):
        if m[key].upper_limit:
            echo(f"   {key:<7} < {m[key].value:.2g} {m[key].unit} (95 % upper limit: the MSD "
                 "intercept is not resolved from zero)")
        else:
            echo(f"   {key:<7} {m[key].value:.2f} +- {m[key].error:.2f} {m[key].unit}")
    total = time.perf_counter() - t_start
    echo(f"Outputs in {out}/ (plots: prefit/prefit.png, fit/fit.png, fit/frames_final/, "
         f"analysis/*.png); total {total:.0f} s on {workers} worker(s).")
    return {"a_um": float(static["a_um"]), "b_um": float(static["b_um"]),
            "n": float(static["n"]), "ok_fraction": float(ok.mean()),
            **{f"rms_{k}_nm": v for k, v in rms.items()}, "axis_rms_deg": _rms(axis_err),
            **{f"{k}_value": m[k].value for k in truth_d}, **{f"{k}_error": m[k].error
                                                              for k in truth_d},
            **{f"{k}_truth": v for k, v in truth_d.items()}, **times, "total_s": total}


def _axis(theta: pd.Series, psi: pd.Series) -> pd.DataFrame:
    st = np.sin(theta)
    return pd.DataFrame({"ux": st * np.cos(psi), "uy": st * np.sin(psi), "uz": np.cos(theta)})


def _angle(a: np.ndarray, b: np.ndarray, head_tail: bool) -> np.ndarray:
    dot = np.sum(np.asarray(a, float) * np.asarray(b, float), axis=1)
    if head_tail:
        dot = np.abs(dot)
    return np.degrees(np.arccos(np.clip(dot, -1.0, 1.0)))


def _rms(values: np.ndarray) -> float:
    return float(math.sqrt(np.mean(np.square(values)))) if len(values) else math.nan
