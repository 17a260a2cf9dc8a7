"""The demo: the whole pipeline on a built-in synthetic movie with known truth.

``holofit demo`` (``make demo``) simulates the paper's silica rod (a 501 nm, b 1079 nm, n 1.495)
diffusing and sedimenting (0.9 um/s) in water at 21 C, filmed at 100 frames/s through the
paper's 60x water-immersion set-up with 8-bit camera noise, and runs all five stages on it
exactly as the command line does: crop, Lorenz-Mie prefit, orientation library, DDA fit (an
initial pass with every parameter free on frames spread over the movie, then a final pass with
the sizes and index fixed, served from the rod's T-matrix) and the diffusion analysis. It prints
what each stage recovered against the truth and against the spherocylinder prediction.
``holofit demo --particle sphere`` runs the shorter sphere demo (:mod:`holofit.demo.sphere`).
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from holofit.analysis import AnalysisConfig, run_analysis
from holofit.analysis.hydrodynamics import spherocylinder_diffusion
from holofit.batch import BatchSettings
from holofit.config import (
    Instrument,
    ParticleConfig,
    load_instrument,
    load_particle,
    resolve_config,
)
from holofit.crop import CropConfig, run_crop
from holofit.demo.sphere import run_sphere_demo
from holofit.fit.stage import FitConfig, run_fit
from holofit.library.stage import run_library
from holofit.particles import Spherocylinder
from holofit.prefit import run_prefit
from holofit.prefit.sphere import SphereFitSettings
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


@dataclass
class _Demo:
    """What the demo's steps share: where outputs go, the truth, the set-up and the timings."""

    out: Path
    echo: Callable[[str], None]
    n_frames: int
    truth: pd.DataFrame = field(default_factory=pd.DataFrame)
    times: dict[str, float] = field(default_factory=dict)
    final_table: Path | None = None

    def timed(self, label: str, t0: float) -> None:
        self.times[f"{label}_s"] = _timed(self.echo, label, t0)


def run_rod_demo(out: str | Path, echo: Callable[[str], None] = print, workers: int = 2,
                 n_frames: int = 500, initial_frames: int = 8) -> dict[str, float]:
    """The rod demo (see the module docstring).

    Returns
    -------
    dict
        Truth and recovered values: static parameters, rms errors of the final fit, the
        diffusion coefficients with their errors, and the wall time of each stage.
    """
    t_start = time.perf_counter()
    demo = _Demo(Path(out), echo, n_frames)
    inst = load_instrument(resolve_config("paper_60x_water", "instruments"))
    config = load_particle(resolve_config("rod_paper", "particles"))
    batch = BatchSettings(workers=workers, progress=False)
    echo(f"holofit demo: the paper's silica rod (a {ROD.a_um * 1e3:.0f} nm, b "
         f"{ROD.b_um * 1e3:.0f} nm, n {ROD.index:g}) diffusing (D_par {ROD_D_PAR}, D_perp "
         f"{ROD_D_PERP} um^2/s, D_r {ROD_D_R} 1/s) and sinking {SEDIMENTATION_UM_S} um/s in "
         f"water at {TEMPERATURE_C:g} C; {n_frames} frames at {inst.frame_rate_hz:g} frames/s "
         f"through {inst.name} (NA {inst.extra.get('numerical_aperture', '-')}), 8-bit noise")
    _simulate_and_crop(demo, inst, ParticleConfig(ROD, config.settings, config.path))
    _prefit_and_library(demo, config, batch)
    static, ok, rms, axis_err = _fit(demo, config, batch, initial_frames)
    truth_d, m = _analyze(demo)
    total = time.perf_counter() - t_start
    echo(f"Outputs in {demo.out}/ (plots: prefit/prefit.png, fit/fit.png, fit/frames_final/, "
         f"analysis/*.png); total {total:.0f} s on {workers} worker(s).")
    return {"a_um": float(static["a_um"]), "b_um": float(static["b_um"]),
            "n": float(static["n"]), "ok_fraction": float(ok.mean()),
            **{f"rms_{k}_nm": v for k, v in rms.items()}, "axis_rms_deg": _rms(axis_err),
            **{f"{k}_value": m[k].value for k in truth_d}, **{f"{k}_error": m[k].error
                                                              for k in truth_d},
            **{f"{k}_truth": v for k, v in truth_d.items()}, **demo.times, "total_s": total}


def _simulate_and_crop(demo: _Demo, inst: Instrument, truth_config: ParticleConfig) -> None:
    """Steps 1 and 2: the movie with known truth, and its crops."""
    t0 = time.perf_counter()
    if inst.frame_rate_hz is None:
        raise ValueError(f"instrument {inst.name} has no frame_rate_hz: the demo needs one")
    dynamics = BrownianParameters(
        n_frames=demo.n_frames, frame_interval_s=1.0 / inst.frame_rate_hz,
        d_par_um2_s=ROD_D_PAR, d_perp_um2_s=ROD_D_PERP, d_r_s=ROD_D_R,
        drift_um_s=(0.0, 0.0, -SEDIMENTATION_UM_S), start_position_um=(17.0, 17.0, 15.0))
    sim = diffusing_movie(truth_config, inst, dynamics, demo.out, frame_shape=(192, 192), seed=7)
    demo.truth = truth = sim.trajectory.truth.set_index("frame")
    assert sim.movie.movie is not None  # written: an output folder is given
    demo.echo(f"1. simulate: {sim.movie.movie}")
    demo.timed("simulate", t0)

    t0 = time.perf_counter()
    crop = run_crop(sim.movie.movie, sim.movie.background, inst, demo.out / "crop",
                    CropConfig(size=140))
    table = pd.read_csv(crop.table).set_index("frame")
    found = table["status"].isin(FITTABLE_CROP_STATUSES)
    err = np.hypot(table["x_um"] - truth["x_um"], table["y_um"] - truth["y_um"])[found]
    demo.echo(f"2. crop: hologram found in {int(found.sum())}/{demo.n_frames} frames, centre "
              f"off the rod's centre by {1e3 * np.median(err):.0f} nm (median)")
    demo.timed("crop", t0)


def _prefit_and_library(demo: _Demo, config: ParticleConfig, batch: BatchSettings) -> None:
    """Steps 3 and 4: the Lorenz-Mie prefit and the orientation library."""
    out, truth = demo.out, demo.truth
    t0 = time.perf_counter()
    # a rod's prefit only seeds x, y, z and alpha (holofit init sets --seed-only for it)
    pre = run_prefit(out / "crop", out / "prefit", batch=batch,
                     fit=SphereFitSettings(seed_only=True))
    p = pd.read_csv(pre.table).set_index("frame")
    dz = (p["z_um"] - truth["z_um"]).dropna()
    demo.echo(f"3. prefit (a sphere's model of a rod, seed only: a start, not a measurement): "
              f"{int(p['status'].isin([OK, POOR_FIT]).sum())}/{demo.n_frames} converged, z off "
              f"by {1e3 * dz.median():+.0f} nm (median), sphere radius "
              f"{p['radius_um'].median():.3f} um")
    demo.timed("prefit", t0)

    t0 = time.perf_counter()
    lib = run_library(out / "crop", out / "prefit", config, out / "library", batch=batch)
    lt = pd.read_csv(lib.table).set_index("frame")
    u_true = _axis(truth["theta_rad"], truth["psi_rad"])
    best = _axis(lt["c1_theta_rad"], lt["c1_psi_rad"])
    ang = _angle(best, u_true.loc[lt.index].to_numpy(), head_tail=True)
    demo.echo(f"4. library: best candidate within {np.median(ang):.1f} deg of the truth "
              f"(median; grid step 10 deg)")
    demo.timed("library", t0)


def _fit(demo: _Demo, config: ParticleConfig, batch: BatchSettings, initial_frames: int
         ) -> tuple[dict, pd.Series, dict[str, float], np.ndarray]:
    """Step 5: both DDA passes; the static parameters, the ok mask and the final-pass errors."""
    out = demo.out
    t0 = time.perf_counter()
    run = run_fit(out / "crop", out / "prefit", out / "library", out / "fit",
                  FitConfig(config, initial_frames=initial_frames), batch=batch)
    demo.timed("fit", t0)
    if run.static is None or run.final is None:
        raise RuntimeError(f"the fit in {out / 'fit'} wrote no static parameters or final table")
    static = json.loads(run.static.read_text())["values"]
    fit = pd.read_csv(run.final).set_index("frame")
    ok = fit["status"] == OK
    f = fit[ok]
    tr = demo.truth.loc[f.index]
    rms = {k: 1e3 * float(np.sqrt(np.mean((f[k] - tr[k]) ** 2))) for k in
           ("x_um", "y_um", "z_um")}
    axis_err = _angle(f[["ux", "uy", "uz"]].to_numpy(),
                      _axis(tr["theta_rad"], tr["psi_rad"]).to_numpy(), head_tail=True)
    demo.echo(f"5. fit, initial pass ({initial_frames} frames, everything free): a "
              f"{static['a_um'] * 1e3:.1f} nm (truth {ROD.a_um * 1e3:.0f}), b "
              f"{static['b_um'] * 1e3:.1f} nm (truth {ROD.b_um * 1e3:.0f}), n "
              f"{static['n']:.4f} (truth {ROD.index:g}); the config started at a 500, b 1000 nm")
    demo.echo(f"   final pass: {int(ok.sum())}/{demo.n_frames} frames ok, rms error x "
              f"{rms['x_um']:.1f}, y {rms['y_um']:.1f}, z {rms['z_um']:.1f} nm, axis "
              f"{_rms(axis_err):.2f} deg; {int(fit['ambiguous'].fillna(0).sum())} frame(s) "
              "flagged ambiguous")
    demo.final_table = run.final
    return static, ok, rms, axis_err


def _analyze(demo: _Demo) -> tuple[dict[str, float], dict]:
    """Step 6: the diffusion analysis against the truth and the spherocylinder prediction."""
    echo = demo.echo
    t0 = time.perf_counter()
    settings = AnalysisConfig(model="rod", temperature_c=TEMPERATURE_C)
    assert demo.final_table is not None  # set by the fit step, which runs first
    result = run_analysis(demo.final_table, settings, demo.out / "analysis").result
    assert result is not None
    demo.timed("analyze", t0)
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
    return truth_d, m


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
