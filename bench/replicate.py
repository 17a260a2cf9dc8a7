"""The paper's two experiments replicated on synthetic truth (``make replicate``; not a test).

    python bench/replicate.py [--out replicate] [--only rod|janus|dask] [--frames N] [--workers 2]
                              [--engine builtin] [--keep-sim]
                              [--initial-frames K] [--dask-check N]

Each experiment is a movie with known truth made like the paper's data — the rod: 2000 frames
at 100 frames/s through the 60x water set-up, a 501 nm, b 1079 nm, n 1.495, diffusing with the
paper's measured coefficients and sinking 0.9 um/s at 21 C; the Janus particle: 3000 frames
through the 100x oil set-up, core 443 nm, cap 47 nm, n 1.581 / 2.74, diffusing like a sphere of
524 nm hydrodynamic radius — and goes through the whole pipeline as a user runs it (crop ->
prefit -> library -> fit -> analyze, the stages' library functions with their defaults). The
report, ``OUT/report.md``, regenerates the paper's two tables side by side (the paper's measured
value, ours, the simulation's truth, the theory), with the plots (MSDs with fits, orientation
MSD, projection correlation, trajectories, example fit residuals) and the wall time of every
stage. ``--dask-check N`` also fits the rod's first N frames on a local Dask cluster and checks
that the table equals the process pool's. Each experiment writes its own section
(``OUT/rod/section.md``, ``OUT/janus/section.md``, ``OUT/rod/dask_section.md``) and the report
is assembled from those that exist, so ``--only janus`` reruns one experiment and keeps the
other's.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import pickle
import resource
import time
from pathlib import Path

import numpy as np
import pandas as pd
from truth_compare import compare_with_truth

from holofit.analysis import AnalysisConfig, run_analysis
from holofit.analysis.hydrodynamics import sphere_diffusion, spherocylinder_diffusion
from holofit.batch import BatchSettings
from holofit.config import ParticleConfig, load_instrument, load_particle, resolve_config
from holofit.crop import CropConfig, run_crop
from holofit.fit.config import FitConfig
from holofit.fit.stage import run_fit
from holofit.library.stage import run_library
from holofit.particles import JanusSphere, Spherocylinder
from holofit.prefit import run_prefit
from holofit.prefit.sphere import SphereFitSettings
from holofit.simulate.brownian import BrownianParameters
from holofit.simulate.scenarios import diffusing_movie

T_C = 21.0
#: the paper's tables: quantity -> (value, error) as printed
PAPER_ROD = {"a (nm)": (501, 19), "b (nm)": (1079, 72), "n": (1.495, 0.012),
             "D_par (um^2/s)": (0.307, 0.028), "D_perp (um^2/s)": (0.293, 0.025),
             "D_t (um^2/s)": (0.298, 0.026), "D_r (1/s)": (0.311, 0.034),
             "D_par/D_perp": (1.04, 0.05), "eps_par (nm)": (28.3, math.nan),
             "eps_perp (nm)": (35.4, math.nan), "eps_r (deg)": (1.5, math.nan)}
PAPER_JANUS = {"a (nm)": (443, 20), "t (nm)": (47, 8), "n_TiO2": (2.74, 0.23),
               "n_PS": (1.581, 0.046), "a_eff from D_t (nm)": (524, 15),
               "a_eff from D_r (nm)": (523, 6), "eps (nm)": (21.8, math.nan)}


def _cpu_s() -> float:
    """CPU time (user + system) of this process and of its finished children (the stages'
    worker processes): on shared cores the wall time depends on the load, the CPU time much
    less."""
    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(
        resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


def _stage(times: dict[str, float], name: str, fn, *args, **kwargs):
    t0, c0 = time.perf_counter(), _cpu_s()
    result = fn(*args, **kwargs)
    times[name] = time.perf_counter() - t0
    print(f"  {name}: {times[name]:.0f} s wall, {_cpu_s() - c0:.0f} s CPU (load average "
          f"{os.getloadavg()[0]:.1f})", flush=True)
    return result


def _simulated(truth: ParticleConfig, inst, dynamics, out: Path, seed: int, keep: bool):
    """The movie (``diffusing_movie``), or with ``keep`` the one an earlier run of the same
    length and seed left in ``OUT/sim.pkl`` (the engines' comparison fits one movie)."""
    cache = out / "sim.pkl"
    tag = (dynamics.n_frames, seed, repr(truth.model))
    if keep and cache.exists():
        saved_tag, sim = pickle.loads(cache.read_bytes())
        if saved_tag == tag:
            return sim
    sim = diffusing_movie(truth, inst, dynamics, out, frame_shape=(192, 192), seed=seed)
    cache.write_bytes(pickle.dumps((tag, sim)))
    return sim


def _pipeline(out: Path, config: ParticleConfig, truth: ParticleConfig, inst, dynamics, *,
              workers: int, initial_frames: int, model: str, seed: int,
              engine: str | None = None, keep_sim: bool = False) -> dict:
    times: dict[str, float] = {}
    batch = BatchSettings(workers=workers, progress=False)
    sim = _stage(times, "simulate", _simulated, truth, inst, dynamics, out, seed, keep_sim)
    # every stage on the same workers, as a run folder's JOBS gives them (holofit init)
    _stage(times, "crop", run_crop, sim.movie.movie, sim.movie.background, inst, out / "crop",
           CropConfig(size=140), batch=batch)
    # a non-spherical particle's prefit seeds its position only (as `holofit init` sets it)
    prefit_fit = SphereFitSettings(seed_only=config.model.anisotropic)
    _stage(times, "prefit", run_prefit, out / "crop", out / "prefit", batch=batch, fit=prefit_fit)
    _stage(times, "library", run_library, out / "crop", out / "prefit", config,
           out / "library", engine=engine, batch=batch)
    run = _stage(times, "fit", run_fit, out / "crop", out / "prefit", out / "library",
                 out / "fit", FitConfig(config, initial_frames=initial_frames, engine=engine),
                 batch=batch)
    settings = AnalysisConfig(model=model, temperature_c=T_C)
    analysis = _stage(times, "analyze", run_analysis, run.final, settings, out / "analysis")
    result, files = analysis.result, analysis.files
    fit = pd.read_csv(run.final).set_index("frame")
    if "follow_source" in fit:
        print(f"  tracking: {fit['follow_source'].value_counts().to_dict()}, "
              f"{int(fit['follow_jump'].fillna(0).sum())} jump(s), evaluations per frame "
              f"{fit['n_eval'].mean():.1f}; runner-up refit "
              f"{fit['runner_up_refit'].value_counts().to_dict()}; "
              f"statuses {fit['status'].value_counts().to_dict()}", flush=True)
    for note in run.notes:
        print(f"  note: {note}", flush=True)
    tr = sim.trajectory.truth.set_index("frame").loc[fit.index]
    truth_result = _analyse_truth(tr, run.final, settings, out / "analysis_truth")
    static = json.loads(run.static.read_text())
    score = compare_with_truth(fit, tr, head_tail_symmetric=truth.model.head_tail_symmetric)
    cont = json.loads(Path(str(run.final) + ".json").read_text()).get("continuity")
    near_focus = (tr["z_um"] < NEAR_FOCUS_UM).to_numpy()
    ok = (fit["status"] == "ok").to_numpy()
    score["near_focus"] = {"frames": int(near_focus.sum()), "ok": int((ok & near_focus).sum()),
                           "ok_elsewhere": float(ok[~near_focus].mean())
                           if (~near_focus).any() else None}
    return {"times": times, "continuity": cont, "result": result, "static": static, "score": score,
            "final": run.final, "files": files, "truth_result": truth_result}


#: frames closer than this to the focal plane (true height, um) are counted apart
NEAR_FOCUS_UM = 3.0


def _analyse_truth(truth: pd.DataFrame, final: Path, settings: AnalysisConfig, out: Path):
    """The same analysis on the simulation's true trajectory at the fitted frames: what the
    movie's length allows, separated from what the fits add."""
    table = truth.reset_index()[["frame", "time_s", "x_um", "y_um", "z_um", "psi_rad",
                                 "theta_rad", "phi_rad"]].copy()
    table["status"] = "ok"
    out.mkdir(parents=True, exist_ok=True)
    path = out / "truth_as_fit.csv"
    table.to_csv(path, index=False)
    sidecar = json.loads(Path(str(final) + ".json").read_text())
    Path(str(path) + ".json").write_text(json.dumps(sidecar))
    result = run_analysis(path, settings, out).result
    return result


def _fm(m, digits: int = 3) -> str:
    """A measurement: ``v ± e``, ``v -below +above`` where the sides differ by > 10 %, or
    ``< v`` for an upper limit (holofit.analysis.measurement)."""
    if m.upper_limit:
        return f"< {m.value:.{digits}f}"
    below, above = m.sides()
    if math.isfinite(below) and math.isfinite(above) and abs(above - below) > 0.1 * m.error:
        return f"{m.value:.{digits}f} -{below:.{digits}f} +{above:.{digits}f}"
    return _fmt(m.value, m.error, digits)


def _fmt(v: float, e: float = math.nan, digits: int = 3) -> str:
    if not math.isfinite(v):
        return "--"
    return f"{v:.{digits}f}" + (f" ± {e:.{digits}f}" if math.isfinite(e) else "")


def rod(out: Path, frames: int, workers: int, initial_frames: int,
        seed: int, engine: str | None = None,
        keep_sim: bool = False) -> tuple[list[str], dict]:
    inst = load_instrument(resolve_config("paper_60x_water", "instruments"))
    config = load_particle(resolve_config("rod_paper", "particles"))
    truth_model = Spherocylinder(0.501, 1.079, 1.495)
    truth = ParticleConfig(truth_model, config.settings, config.path)
    d_par, d_perp, d_r = 0.307, 0.293, 0.311
    dyn = BrownianParameters(frames, 1 / inst.frame_rate_hz, d_par, d_perp, d_r,
                             drift_um_s=(0.0, 0.0, -0.9), start_position_um=(17.0, 17.0, 20.0))
    r = _pipeline(out, config, truth, inst, dyn, workers=workers,
                  initial_frames=initial_frames, model="rod", seed=seed, engine=engine,
                  keep_sim=keep_sim)
    m, st = r["result"].measured, r["static"]
    t = _truth_column(r)
    pred = spherocylinder_diffusion(0.501, 1.079, T_C)
    sp = r["result"].predictions
    rows = [
        ("a (nm)", _fmt(1e3 * st["values"]["a_um"], 1e3 * st["spread"]["a_um"], 1), "501", "--"),
        ("b (nm)", _fmt(1e3 * st["values"]["b_um"], 1e3 * st["spread"]["b_um"], 1), "1079", "--"),
        ("n", _fmt(st["values"]["n"], st["spread"]["n"], 4), "1.495", "--"),
        ("D_par (um^2/s)", _fm(m["D_par"]), t("D_par"), f"{d_par}",
         _fmt(sp["cyl D_par"][0].value) + " (cylinder)" if "cyl D_par" in sp else "--"),
        ("D_perp (um^2/s)", _fm(m["D_perp"]), t("D_perp"),
         f"{d_perp}",
         _fmt(sp["cyl D_perp"][0].value) + " (cylinder)" if "cyl D_perp" in sp else "--"),
        ("D_t (um^2/s)", _fm(m["D_t"]), t("D_t"),
         f"{(d_par + 2 * d_perp) / 3:.3f}",
         _fmt(pred["D_t"]) + " (spherocylinder)"),
        ("D_r (1/s)", _fm(m["D_r"]), t("D_r"), f"{d_r}",
         _fmt(pred["D_r"]) + " (spherocylinder)"),
        ("D_par/D_perp", _fm(m["D_par/D_perp"]),
         t("D_par/D_perp"), f"{d_par / d_perp:.3f}", "--"),
        ("eps_par (nm)", _fm(m["eps_par"], 1), "--", "--"),
        ("eps_perp (nm)", _fm(m["eps_perp"], 1), "--", "--"),
        ("eps_r (deg)", _fm(m["eps_r"], 2), "--", "--"),
    ]
    pulls = {k: m[k].pull(v) for k, v in
             (("D_par", d_par), ("D_perp", d_perp), ("D_t", (d_par + 2 * d_perp) / 3),
              ("D_r", d_r))}
    return _table("Rod (the paper's table 1)", rows, PAPER_ROD, r, pulls), r


def janus(out: Path, frames: int, workers: int, initial_frames: int,
          seed: int, engine: str | None = None,
        keep_sim: bool = False) -> tuple[list[str], dict]:
    inst = load_instrument(resolve_config("paper_100x_oil", "instruments"))
    config = load_particle(resolve_config("janus_paper", "particles"))
    truth_model = JanusSphere(0.443, 0.047, 1.581, 2.74)
    truth = ParticleConfig(truth_model, config.settings, config.path)
    d = sphere_diffusion(0.524, T_C)
    dyn = BrownianParameters(frames, 1 / inst.frame_rate_hz, float(d["D_t"]), float(d["D_t"]),
                             float(d["D_r"]), start_position_um=(10.2, 10.2, 12.0))
    r = _pipeline(out, config, truth, inst, dyn, workers=workers,
                  initial_frames=initial_frames, model="janus", seed=seed, engine=engine,
                  keep_sim=keep_sim)
    m, st = r["result"].measured, r["static"]
    t = _truth_column(r)
    rows = [
        ("a (nm)", _fmt(1e3 * st["values"]["radius_um"], 1e3 * st["spread"]["radius_um"], 1),
         "443", "--"),
        ("t (nm)", _fmt(1e3 * st["values"]["cap_thickness_um"],
                        1e3 * st["spread"]["cap_thickness_um"], 1), "47", "--"),
        ("n_TiO2", _fmt(st["values"]["n_cap"], st["spread"]["n_cap"], 3), "2.74", "--"),
        ("n_PS", _fmt(st["values"]["n_core"], st["spread"]["n_core"], 4), "1.581", "--"),
        ("a_eff from D_t (nm)", _fm(m["a_eff_t"], 0),
         t("a_eff_t", 0), "524", "--"),
        ("a_eff from D_r (nm)", _fm(m["a_eff_r"], 0),
         t("a_eff_r", 0), "524", "--"),
        ("eps (nm)", _fm(m["eps"], 1), "--", "--"),
    ]
    pulls = {"a_eff_t": m["a_eff_t"].pull(524), "a_eff_r": m["a_eff_r"].pull(524)}
    return _table("Janus particle (the paper's table 2)", rows, PAPER_JANUS, r, pulls), r


def _truth_column(r: dict):
    """Format a quantity of the analysis of the true trajectory (``--`` where it has none)."""
    measured = r["truth_result"].measured

    def cell(key: str, digits: int = 3) -> str:
        m = measured.get(key)
        return _fm(m, digits) if m is not None else "--"
    return cell


def _table(title: str, rows, paper: dict, r: dict, pulls: dict) -> list[str]:
    lines = [f"## {title}", "", "| quantity | paper (measured) | holofit (this movie) | "
             "true trajectory, same analysis | truth | theory |",
             "| --- | --- | --- | --- | --- | --- |"]
    for row in rows:
        q, ours, *rest = row
        from_truth, truth, theory = rest if len(rest) == 3 else ("--", *rest)
        pv, pe = paper.get(q, (math.nan, math.nan))
        lines.append(f"| {q} | {_fmt(pv, pe, 3 if pv < 10 else 0)} | {ours} | {from_truth} | "
                     f"{truth} | {theory} |")
    lines += ["", "Pulls against the truth (measured − truth) / error: "
              + ", ".join(f"{k} {v:+.2f}" for k, v in pulls.items()), "",
              _score_line(r["score"]), "", _continuity_line(r.get("continuity")), "",
              "Wall time (s): " + ", ".join(f"{k} {v:.0f}" for k, v in r["times"].items())
              + f"; total {sum(r['times'].values()):.0f}.", ""]
    notes = list(r["result"].notes)
    if notes:
        lines += ["The analysis's notes:", ""] + [f"- {n}" for n in notes] + [""]
    return lines


def _reported(sc: dict) -> str:
    """The axis error the fits report, against the one measured."""
    if sc.get("axis_sigma_rms_deg") is None:
        return ""
    return (f" (the fits' own error {sc['axis_sigma_rms_deg']:.2f} deg rms; mean (error / "
            f"reported)^2 {sc['axis_chi2_mean']:.2f}, 1 at the noise floor)")


def _score_line(sc: dict) -> str:
    """The final pass against the truth, in words."""
    rms = sc["rms_nm"]
    text = (f"Frames: {sc['statuses']}; ambiguous {sc['ambiguous_frames']}. The final fit "
            f"against the truth (ok frames): rms x {rms['x_um']:.1f}, y {rms['y_um']:.1f}, "
            f"z {rms['z_um']:.1f} nm; axis {sc['axis_rms_deg']:.2f} deg rms off the wrong "
            f"branch{_reported(sc)}; {sc['wrong_branch_frames']} frame(s) on the wrong branch "
            f"(axis > 10 deg off), {sc['wrong_branch_unflagged']} of them not flagged ambiguous")
    if sc["psi_rms_deg"] is not None:
        text += (f"; azimuth psi {sc['psi_rms_deg']:.2f} deg rms over the "
                 f"{sc['psi_frames']} frames with |sin theta| > 0.3")
    nf = sc.get("near_focus")
    if nf and nf["frames"]:
        text += (f". Within {NEAR_FOCUS_UM:g} um of the focal plane (true z; {nf['frames']} "
                 f"frames) {nf['ok']} are ok; elsewhere {100 * nf['ok_elsewhere']:.1f} % are ok")
    return text + "."


def _continuity_line(cont: dict | None) -> str:
    """What the continuity sweeps did (from fit.csv's sidecar)."""
    if not cont:
        return "Continuity sweeps: not run."
    return (f"Continuity sweeps (holofit.fit.continuity): {cont['sweeps']} sweep(s), "
            f"{cont['refitted']} refit(s), {cont['replaced']} row(s) replaced by a better fit "
            f"from a neighbour's orientation, {cont['flagged']} flagged poor_fit (reduced chi2 "
            f"bar {cont['chi2_bar']:.3f}).")


def dask_check(out: Path, n: int) -> list[str]:
    """The rod's final pass over its first ``n`` frames on a local Dask cluster vs processes."""
    config = load_particle(resolve_config("rod_paper", "particles"))
    tables = {}
    for name, opts in (("processes", BatchSettings(workers=2, progress=False)),
                       ("dask", BatchSettings(workers=2, dask_local=True, progress=False))):
        config_final = FitConfig(config, passes="final", static=out / "fit" / "static.json",
                                 frames=tuple(range(n)), plot=False)
        run = run_fit(out / "crop", out / "prefit", out / "library", out / f"fit_{name}",
                      config_final, batch=opts)
        tables[name] = pd.read_csv(run.final).drop(columns=["fit_time_s"])
    a, b = tables["processes"], tables["dask"]
    numeric = [c for c in a.columns if pd.api.types.is_float_dtype(a[c])]
    others = [c for c in a.columns if c not in numeric]
    same_labels = a[others].equals(b[others])
    diff = {
        c: float(
            np.nanmax(
                np.abs(a[c].to_numpy() - b[c].to_numpy()) / np.maximum(1.0, np.abs(a[c].to_numpy()))
            )
        )
        for c in numeric
        if not a[c].equals(b[c])
    }
    worst = max(diff, key=diff.get) if diff else None
    if same_labels and not diff:
        verdict = "the tables are identical"
    elif same_labels and diff[worst] < 1e-5:
        verdict = (
            f"statuses and flags identical; {len(diff)} numeric column(s) differ "
            f"in the last digits (largest: {worst}, {diff[worst]:.1e}; "
            "floating-point summation order)"
        )
    else:
        verdict = "the tables DIFFER: " + (
            "statuses or flags differ" if not same_labels else f"{worst} by {diff[worst]:.2e}"
        )
    return [
        "## The distributed path",
        "",
        f"The rod's final pass over frames 0-{n - 1} on a local Dask cluster (2 workers) and "
        f"on the process pool (timing columns aside): {verdict}.",
        "",
    ]


#: the report's parts, in order: one file each, so that one experiment can be rerun alone
SECTIONS = (
    ("rod", "rod/section.md"),
    ("janus", "janus/section.md"),
    ("dask", "rod/dask_section.md"),
)


def _write_report(out: Path) -> str:
    """``OUT/report.md`` from the sections that exist."""
    lines = [
        "# holofit replicates the paper on synthetic truth",
        "",
        "Generated by `make replicate` (bench/replicate.py). Each movie has known truth; the "
        "pipeline runs with its defaults, as a user runs it.",
        "",
    ]
    for _, rel in SECTIONS:
        if (out / rel).exists():
            lines.append((out / rel).read_text())
    text = "\n".join(lines)
    (out / "report.md").write_text(text)
    return text


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--out", type=Path, default=Path("replicate"))
    ap.add_argument(
        "--only",
        choices=("rod", "janus", "dask"),
        help="one experiment (its section of the report is replaced, the others "
        "kept), or only the Dask check on an earlier rod run",
    )
    ap.add_argument("--frames", type=int, default=None, help="override the movie length")
    ap.add_argument(
        "--initial-frames",
        type=int,
        default=None,
        help="override the initial pass's frames (rod 100, Janus 10)",
    )
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--engine", default=None,
                    help="the library's and the fit's engine (default: auto; builtin: the DDA)")
    ap.add_argument("--keep-sim", action="store_true",
                    help="reuse the movie of an earlier run of the same length and seed")
    ap.add_argument("--dask-check", type=int, default=0)
    ap.add_argument("--seed", type=int, default=11, help="the simulation's random seed")
    args = ap.parse_args()
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    # the Janus initial pass fits every static parameter with direct DDA solves (15-35 solves,
    # ~25 s a frame on one core from a seed, against ~3 s for the rod), so it takes 10 frames
    for name, fn, n, k in (("rod", rod, 2000, 100), ("janus", janus, 3000, 10)):
        if args.only and args.only != name:
            continue
        print(f"{name}:", flush=True)
        part, _ = fn(
            out / name, args.frames or n, args.workers, args.initial_frames or k, args.seed,
            args.engine, args.keep_sim,
        )
        lines = list(part)
        lines[2:2] = [
            f"Simulation seed {args.seed}, {args.frames or n} frames, the initial pass "
            f"on {args.initial_frames or k} of them (spread over the movie where the "
            "particle has a T-matrix: holofit.fit.seeded).",
            "",
        ]
        for png in ("msd.png", "orientation.png", "trajectory.png"):
            if (out / name / "analysis" / png).exists():
                lines.append(f"![{name} {png}]({name}/analysis/{png})")
        pictures = sorted((out / name / "fit" / "frames_final").glob("*.png"))[:2]
        lines += [f"![{name} fit residuals]({p.relative_to(out)})" for p in pictures] + [""]
        (out / name / "section.md").write_text("\n".join(lines) + "\n")
        _write_report(out)
    if args.dask_check and args.only in (None, "rod", "dask"):
        (out / "rod" / "dask_section.md").write_text(
            "\n".join(dask_check(out / "rod", args.dask_check)) + "\n"
        )
    print(_write_report(out))


if __name__ == "__main__":
    main()
