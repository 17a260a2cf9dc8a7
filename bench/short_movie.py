"""A short Janus movie through ``holofit init`` + ``make``, timed stage by stage (issue #26's
"short movies are dominated by set-up"; not a test).

    python bench/short_movie.py [--out short_movie] [--frames 24] [--jobs N] [--z 8]
                                [--engine NAME] [--fit-opts '...'] [--json FILE]

The paper's Janus particle (core 443 nm, cap 47 nm, n 1.581 / 2.74; the fit starts from the
shipped ``janus_paper`` config) diffusing like a sphere of 524 nm hydrodynamic radius at
``--z`` um above the focal plane of the 100x oil set-up (``paper_100x_oil``), filmed for
``--frames`` frames. The run folder is made by ``holofit init`` with its defaults (``--engine``
is its ``--engine``: ``builtin`` for the DDA, where ``auto`` gives the particle its exact
T-matrix) and each Makefile target is run in turn (``make crop``, ``prefit``, ``library``,
``fit-initial``, ``fit``, ``analyze``; ``JOBS`` empty = every CPU unless ``--jobs``), so each
stage's wall time is its own. Prints the stage times (wall, and the CPU time of all the
stage's processes: on shared cores the wall time depends on the load, the CPU time much
less), the fit stage's notes (T-matrix build), and the final table against the truth (x, y, z
rms in nm, axis rms in deg, wrong-branch frames); ``--json`` writes them as one flat JSON
object.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import shlex
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
from truth_compare import compare_with_truth

from holofit.analysis.hydrodynamics import sphere_diffusion
from holofit.config import ParticleConfig, load_instrument, load_particle, resolve_config
from holofit.particles import JanusSphere
from holofit.simulate.brownian import BrownianParameters
from holofit.simulate.scenarios import diffusing_movie

T_C = 21.0
STAGES = ("crop", "prefit", "library", "fit-initial", "fit", "analyze")


def simulate(out: Path, frames: int, z_um: float, seed: int) -> Path:
    """The movie (``OUT/sim/movie.tif``, ``background.tif``, ``truth.csv``)."""
    inst = load_instrument(resolve_config("paper_100x_oil", "instruments"))
    config = load_particle(resolve_config("janus_paper", "particles"))
    truth = ParticleConfig(JanusSphere(0.443, 0.047, 1.581, 2.74), config.settings, config.path)
    d = sphere_diffusion(0.524, T_C)
    dyn = BrownianParameters(frames, 1 / inst.frame_rate_hz, float(d["D_t"]), float(d["D_t"]),
                             float(d["D_r"]), start_position_um=(10.2, 10.2, z_um))
    diffusing_movie(truth, inst, dyn, out, frame_shape=(192, 192), seed=seed)
    return out / "sim"


def _children_cpu() -> float:
    use = resource.getrusage(resource.RUSAGE_CHILDREN)
    return use.ru_utime + use.ru_stime


def run_make(run: Path, target: str, jobs: str | None) -> tuple[float, float, str]:
    """``make -C RUN TARGET``: its wall time, the CPU time of its processes (user + system,
    every worker included) and its output (exits on failure)."""
    cmd = ["make", "-C", str(run), target] + ([f"JOBS={jobs}"] if jobs is not None else [])
    t0, c0 = time.perf_counter(), _children_cpu()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    seconds, cpu = time.perf_counter() - t0, _children_cpu() - c0
    text = proc.stdout + proc.stderr
    if proc.returncode:
        sys.exit(f"make {target} failed after {seconds:.0f} s:\n{text[-3000:]}")
    return seconds, cpu, text


#: the table whose rows are a stage's frames (their ``fit_time_s``: wall time in the worker)
STAGE_TABLES = {"prefit": "prefit/prefit.csv", "library": "library/library.csv",
                "fit": "fit/fit.csv"}


def project(run: Path, times: dict[str, float], frames: int, to: int,
            workers: int) -> dict[str, float]:
    """Each stage's wall time for a movie of ``to`` frames: the per-frame part (the stage
    table's ``fit_time_s`` over ``workers``) scaled, the rest taken as fixed (the library's
    tilts, the T-matrix, start-up); crop and analyze scaled whole and kept, and the initial pass
    kept (its frames do not grow with the movie past a few hundred; the replicate's Janus
    movie fits 10)."""
    out = {}
    for stage, wall in times.items():
        table = STAGE_TABLES.get(stage)
        if stage == "crop":
            out[stage] = wall * to / frames
        elif table is not None and (run / table).exists():
            per = pd.read_csv(run / table)["fit_time_s"].fillna(0.0).to_numpy()
            busy = float(per.sum()) / max(workers, 1)
            out[stage] = max(wall - busy, 0.0) + busy * to / frames
        else:
            out[stage] = wall
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=Path("short_movie"))
    ap.add_argument("--frames", type=int, default=24)
    ap.add_argument("--z", type=float, default=8.0, help="start height above focus, um")
    ap.add_argument("--jobs", default=None, help="make JOBS= (default: the Makefile's)")
    ap.add_argument("--fit-opts", default="", help="holofit init --fit-opts")
    ap.add_argument("--engine", default=None, help="holofit init --engine (default: auto)")
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--project", type=int, default=3000,
                    help="also project the stage times to a movie this long (frames)")
    ap.add_argument("--keep-sim", action="store_true",
                    help="reuse OUT/sim if it exists (same frames, z and seed)")
    args = ap.parse_args()
    out: Path = args.out
    times: dict[str, float] = {}
    t0 = time.perf_counter()
    if not (args.keep_sim and (out / "sim" / "movie.tif").exists()):
        shutil.rmtree(out, ignore_errors=True)
        simulate(out, args.frames, args.z, args.seed)
        print(f"simulate: {time.perf_counter() - t0:.0f} s (not counted)", flush=True)
    sim = out / "sim"
    run = out / "run"
    shutil.rmtree(run, ignore_errors=True)
    holofit = str(Path(sys.executable).with_name("holofit"))
    init = [holofit, "init", str(run), "--movie", str((sim / "movie.tif").resolve()),
            "-b", str((sim / "background.tif").resolve()), "-i", "paper_100x_oil",
            "-p", "janus_paper"]
    if args.fit_opts:
        init += ["--fit-opts", args.fit_opts]
    if args.engine:
        init += ["--engine", args.engine]
    subprocess.run(init, check=True, capture_output=True)
    log = []
    cpu: dict[str, float] = {}
    for stage in STAGES:
        times[stage], cpu[stage], text = run_make(run, stage, args.jobs)
        log.append(text)
        print(f"  {stage}: {times[stage]:.1f} s wall, {cpu[stage]:.1f} s CPU", flush=True)
    total = sum(times.values())
    print(f"total (make): {total:.1f} s = {total / 60:.2f} min wall; CPU "
          f"{sum(cpu.values()):.0f} s (load average now {os.getloadavg()[0]:.1f})", flush=True)
    fit_log = log[STAGES.index("fit")] + log[STAGES.index("fit-initial")]
    for line in fit_log.splitlines():
        if re.search(r"T-matrix|initial pass|chunk|note", line):
            print("  |", line.strip()[:200])
    fit = pd.read_csv(run / "fit" / "fit.csv").set_index("frame")
    truth = pd.read_csv(sim / "truth.csv").set_index("frame").loc[fit.index]
    score = compare_with_truth(fit, truth, head_tail_symmetric=False)
    static = json.loads((run / "fit" / "static.json").read_text())
    rms = score["rms_nm"]
    print(f"final fit vs truth: statuses {score['statuses']}; x/y/z rms "
          f"{rms['x_um']:.2f}/{rms['y_um']:.2f}/{rms['z_um']:.2f} nm; axis "
          f"{score['axis_rms_deg']:.2f} deg; wrong branch {score['wrong_branch_frames']} "
          f"(unflagged {score['wrong_branch_unflagged']})")
    print("static: " + ", ".join(f"{k} {v:.4f}" for k, v in static["values"].items())
          + f" over {static['n_frames']} frame(s) (truth radius 0.443, cap 0.047, "
          "n_core 1.581, n_cap 2.74)")
    projection = project(run, times, args.frames, args.project, int(args.jobs or os.cpu_count()
                                                                     or 1))
    print(f"projected to {args.project} frames (the per-frame cost from the tables' "
          "fit_time_s, the rest of each stage's wall time fixed): " + ", ".join(
              f"{k} {v:.0f} s" for k, v in projection.items())
          + f"; total {sum(projection.values()) / 60:.1f} min")
    if args.json:
        flat = {f"{k.replace('-', '_')}_s": v for k, v in times.items()}
        flat |= {f"{k.replace('-', '_')}_cpu_s": v for k, v in cpu.items()}
        flat |= {f"projected_{k.replace('-', '_')}_s": v for k, v in projection.items()}
        flat |= {"total_s": total, "frames": args.frames, "jobs": args.jobs or "default",
                 "engine": args.engine or "auto",
                 "fit_opts": args.fit_opts, "x_rms_nm": rms["x_um"], "y_rms_nm": rms["y_um"],
                 "z_rms_nm": rms["z_um"], "axis_rms_deg": score["axis_rms_deg"],
                 "wrong_branch": score["wrong_branch_frames"],
                 "ok_frames": int(score["statuses"].get("ok", 0)),
                 **{f"static_{k}": v for k, v in static["values"].items()}}
        args.json.write_text(json.dumps(flat, indent=1))
    print("reproduce: " + " ".join(shlex.quote(a) for a in sys.argv))


if __name__ == "__main__":
    main()
