"""Validation of the whole pipeline on synthetic movies with known truth (not part of `make bench`).

    python bench/validate_fit.py rod   --frames 200 --workers 2 --out /tmp/val_rod
    python bench/validate_fit.py janus --frames 200 --workers 2 --out /tmp/val_janus

Simulates the paper's particle diffusing (Beard & Schlick rotation, anisotropic translation,
the rod sedimenting at 0.9 um/s) as an 8-bit movie with camera noise through the paper's
instrument, then runs crop -> prefit -> library -> fit (initial pass on the first frames, final
pass on all) exactly as the command line does, and compares every frame with the truth:
fraction of ok frames, static parameters of the initial pass, rms errors of x, y, z and the axis
of the final pass, and wrong-branch frames (axis more than 10 deg off) that are not flagged
(neither ambiguous nor non-ok). Optionally (``--analyze``) runs ``holofit analyze`` and compares
D with the truth. Writes ``report.json`` and ``report.md`` to the output folder and prints them.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import pandas as pd
from truth_compare import compare_with_truth

from holofit.analysis import AnalysisConfig, run_analysis
from holofit.analysis.hydrodynamics import sphere_diffusion, spherocylinder_diffusion
from holofit.batch import BatchSettings
from holofit.config import ParticleConfig, load_instrument, load_particle, resolve_config
from holofit.crop import CropConfig, run_crop
from holofit.fit.config import FitConfig
from holofit.fit.stage import run_fit
from holofit.holomodel.parameters import static_values
from holofit.library.stage import run_library
from holofit.particles import JanusSphere, Spherocylinder
from holofit.prefit import run_prefit
from holofit.simulate.brownian import BrownianParameters
from holofit.simulate.scenarios import diffusing_movie

CASES = {
    # the paper's rod: a 501 nm, b 1079 nm, n 1.495; measured D_par 0.307, D_perp 0.293 um^2/s,
    # D_r 0.311 1/s; sedimenting 0.9 um/s; 60x water
    "rod": dict(instrument="paper_60x_water", particle="rod_paper",
                truth=Spherocylinder(0.501, 1.079, 1.495), d_par=0.307, d_perp=0.293,
                d_r=0.311, drift=(0.0, 0.0, -0.9), z0=16.0, model="rod"),
    # the paper's Janus particle: core 443 nm, cap 47 nm, n 1.581 / 2.74; D from a 524 nm
    # hydrodynamic radius at 21 C; 100x oil
    "janus": dict(instrument="paper_100x_oil", particle="janus_paper",
                  truth=JanusSphere(0.443, 0.047, 1.581, 2.74), d_par=None, d_perp=None,
                  d_r=None, drift=(0.0, 0.0, 0.0), z0=12.0, model="janus"),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("case", choices=sorted(CASES))
    ap.add_argument("--frames", type=int, default=200)
    ap.add_argument("--initial-frames", type=int, default=50)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--analyze", action="store_true")
    args = ap.parse_args()
    case = CASES[args.case]
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    inst = load_instrument(resolve_config(case["instrument"], "instruments"))
    cfg = load_particle(resolve_config(case["particle"], "particles"))
    truth_model = case["truth"]
    times: dict[str, float] = {}

    if case["d_r"] is None:  # Janus: a sphere of 524 nm hydrodynamic radius at 21 C
        th = sphere_diffusion(0.524, 21.0)
        d_par = d_perp = float(th["D_t"])
        d_r = float(th["D_r"])
    else:
        d_par, d_perp, d_r = case["d_par"], case["d_perp"], case["d_r"]
    params = BrownianParameters(
        n_frames=args.frames, frame_interval_s=1.0 / inst.frame_rate_hz, d_par_um2_s=d_par,
        d_perp_um2_s=d_perp, d_r_s=d_r, drift_um_s=case["drift"],
        start_position_um=(22.0, 22.0, case["z0"]))
    t0 = time.perf_counter()
    movie = diffusing_movie(ParticleConfig(truth_model, cfg.settings, cfg.path), inst, params,
                            out, seed=args.seed)
    times["simulate_s"] = time.perf_counter() - t0
    sim = movie.movie
    truth = movie.trajectory.truth
    batch = BatchSettings(workers=args.workers, progress=False)
    t0 = time.perf_counter()
    run_crop(sim.movie, sim.background, inst, out / "crop", CropConfig(size=140, plot=False))
    times["crop_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    run_prefit(out / "crop", out / "prefit", batch=batch)
    times["prefit_s"] = time.perf_counter() - t0
    # the library is made with the particle config's sizes (what a user has before the fit)
    t0 = time.perf_counter()
    run_library(out / "crop", out / "prefit", cfg, out / "library", batch=batch)
    times["library_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    run = run_fit(
        out / "crop",
        out / "prefit",
        out / "library",
        out / "fit",
        FitConfig(cfg, initial_frames=args.initial_frames),
        batch=batch,
    )
    times["fit_s"] = time.perf_counter() - t0
    report: dict[str, object] = {
        "case": args.case,
        "frames": args.frames,
        "seed": args.seed,
        "times": times,
    }

    static = json.loads(run.static.read_text())
    true_static = dict(static_values(truth_model))
    report["static"] = {
        k: {
            "fitted": static["values"][k],
            "truth": v,
            "error": static["values"][k] - v,
            "spread": static["spread"][k],
        }
        for k, v in true_static.items()
    }
    fit = pd.read_csv(run.final).set_index("frame")
    report.update(
        compare_with_truth(
            fit, truth.set_index("frame"), head_tail_symmetric=truth_model.head_tail_symmetric
        )
    )
    if args.analyze:
        settings = AnalysisConfig(model=case["model"], temperature_c=21.0)
        result = run_analysis(run.final, settings, out / "analysis").result
        report["analysis"] = {
            k: {"value": m.value, "error": m.error, "unit": m.unit}
            for k, m in result.measured.items()
        }
        report["analysis_truth"] = {"D_par": d_par, "D_perp": d_perp, "D_r": d_r}
        if args.case == "rod":
            report["theory_spherocylinder"] = {
                k: float(v)
                for k, v in spherocylinder_diffusion(0.501, 1.079, 21.0).items()
                if k in ("D_t", "D_r")
            }
    text = json.dumps(report, indent=2, default=float)
    (out / "report.json").write_text(text + "\n")
    lines = [
        f"# validation: {args.case}, {args.frames} frames, seed {args.seed}",
        "",
        "```",
        text,
        "```",
    ]
    (out / "report.md").write_text("\n".join(lines) + "\n")
    print(text)


if __name__ == "__main__":
    main()
