"""Calibration of the analysis's error bars: pulls over many simulated trajectories.

For each particle (rod, Janus sphere, sphere), each trajectory length and each noise level, the
script simulates independent Brownian trajectories with known truth
(:func:`holofit.simulate.brownian.propagate_rigid_body` plus Gaussian localisation and angular
noise), analyses each with the default settings of ``holofit analyze``
(:func:`holofit.analysis.pipeline.analyze_trajectory`) and collects the pulls
``(measured - truth) / reported error``. Calibrated errors give pulls of mean 0 and standard
deviation 1; over ``n`` trajectories the sample mean has a standard error ``1 / sqrt(n)`` and
the sample standard deviation ``1 / sqrt(2 (n - 1))``.

Usage::

    python bench/calibration.py [--seeds 200] [--lengths 30 150 300 1000 2000]
                                [--out bench/results/calibration]

It writes ``calibration.csv`` (one row per particle, noise, length, quantity) and
``calibration.png`` (pull mean and s.d. against length) in ``--out``, and prints the table.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from holofit.analysis.hydrodynamics import sphere_diffusion
from holofit.analysis.pipeline import analyze_trajectory
from holofit.analysis.settings import AnalysisSettings
from holofit.analysis.trajectory import Trajectory
from holofit.conventions import rotation_from_vector
from holofit.simulate.brownian import BrownianParameters, propagate_rigid_body

#: the replicate's temperature, C
T_C = 21.0
#: the paper's rod (bench/replicate.py), um^2/s and 1/s; sedimenting at 0.9 um/s
ROD = {"d_par": 0.307, "d_perp": 0.293, "d_r": 0.311, "drift": (0.0, 0.0, -0.9)}
#: the paper's Janus sphere (hydrodynamic radius 524 nm) and a sphere of the same size
_SPH = sphere_diffusion(0.524, T_C)
JANUS = {"d_par": float(_SPH["D_t"]), "d_perp": float(_SPH["D_t"]), "d_r": float(_SPH["D_r"]),
         "drift": (0.0, 0.0, 0.0)}
#: noise levels: what the fits reach on the replicate, and the paper's real data
NOISE = {"replicate": (0.002, math.radians(0.2)), "paper": (0.035, math.radians(1.5))}
FRAME_INTERVAL_S = 0.01
MODELS = ("rod", "janus", "sphere")
QUANTITIES = {"rod": ("D_par", "D_perp", "D_t", "D_r"), "janus": ("D_t", "D_r"),
              "sphere": ("D_t",)}


@dataclass
class Case:
    """One particle, noise level and trajectory length."""

    model: str
    noise: str
    n_frames: int


def truth_of(model: str) -> dict[str, float]:
    """True values of the quantities a model measures."""
    p = ROD if model == "rod" else JANUS
    return {"D_par": p["d_par"], "D_perp": p["d_perp"],
            "D_t": (p["d_par"] + 2 * p["d_perp"]) / 3, "D_r": p["d_r"]}


def simulate(case: Case, seed: int) -> Trajectory:
    """A simulated measured trajectory (positions with noise, axis with angular noise)."""
    p = ROD if case.model == "rod" else JANUS
    eps, eps_r = NOISE[case.noise]
    rng = np.random.default_rng(seed)
    params = BrownianParameters(case.n_frames, FRAME_INTERVAL_S, p["d_par"], p["d_perp"],
                                p["d_r"], drift_um_s=p["drift"])
    pos, rot = propagate_rigid_body(params, rng)
    pos = pos + eps * rng.standard_normal(pos.shape)
    w = rng.standard_normal((case.n_frames, 3)) * (eps_r / math.sqrt(2.0))
    w[:, 2] = 0.0  # a spin about the axis does not move it
    axis = np.einsum("nij,nj->ni", rot, rotation_from_vector(w)[:, :, 2])
    return Trajectory.from_arrays(pos, None if case.model == "sphere" else axis,
                                  FRAME_INTERVAL_S, source=f"seed {seed}")


def run_case(case: Case, seeds: int) -> dict[str, dict[str, np.ndarray]]:
    """Values, errors and pulls (:meth:`holofit.analysis.measurement.Measurement.pull`: the
    error on the side of the truth) of each quantity over ``seeds`` trajectories (NaN where
    the analysis failed)."""
    keys = QUANTITIES[case.model]
    truth = truth_of(case.model)
    out = {k: {"value": np.full(seeds, np.nan), "error": np.full(seeds, np.nan),
               "pull": np.full(seeds, np.nan)} for k in keys}
    settings = AnalysisSettings(case.model, temperature_c=T_C)
    for s in range(seeds):
        traj = simulate(case, 100_000 * MODELS.index(case.model) + 10 * case.n_frames + s)
        try:
            res = analyze_trajectory(traj, settings)
        except ValueError as exc:  # an AnalysisError: counted as a failure
            print(f"  {case}: seed {s}: {exc}", file=sys.stderr)
            continue
        for k in keys:
            m = res.measured[k]
            out[k]["value"][s] = m.value
            out[k]["error"][s] = m.error
            out[k]["pull"][s] = m.pull(truth[k])
    return out


def summarise(case: Case, data: dict[str, dict[str, np.ndarray]]) -> list[dict]:
    """Pull statistics per quantity."""
    truth = truth_of(case.model)
    rows = []
    for k, d in data.items():
        ok = np.isfinite(d["pull"])
        pull = d["pull"][ok]
        n = int(ok.sum())
        rows.append({
            "model": case.model, "noise": case.noise, "frames": case.n_frames,
            "quantity": k, "n": n, "failed": int(ok.size - n),
            "pull_mean": float(np.mean(pull)) if n else math.nan,
            "pull_sd": float(np.std(pull, ddof=1)) if n > 1 else math.nan,
            "pull_median": float(np.median(pull)) if n else math.nan,
            "bias_rel": float(np.mean(d["value"][ok]) / truth[k] - 1) if n else math.nan,
            "rel_error": float(np.median(d["error"][ok]) / truth[k]) if n else math.nan,
            "scatter_rel": float(np.std(d["value"][ok], ddof=1) / truth[k]) if n > 1 else
            math.nan,
        })
    return rows


def fmt_row(r: dict) -> str:
    return (f"{r['model']:<7}{r['noise']:<10}{r['frames']:>6}  {r['quantity']:<7}"
            f"{r['n']:>5}{r['failed']:>4}  mean {r['pull_mean']:+6.2f}  sd {r['pull_sd']:5.2f}"
            f"  bias {100 * r['bias_rel']:+6.1f} %  err {100 * r['rel_error']:6.1f} %"
            f"  scatter {100 * r['scatter_rel']:6.1f} %")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=200)
    ap.add_argument("--lengths", type=int, nargs="+", default=[30, 150, 300, 1000, 2000])
    ap.add_argument("--models", nargs="+", default=["rod", "janus", "sphere"])
    ap.add_argument("--noises", nargs="+", default=list(NOISE))
    ap.add_argument("--out", type=Path, default=Path("bench/results/calibration"))
    args = ap.parse_args(argv)
    rows = []
    for noise in args.noises:
        for model in args.models:
            for n in args.lengths:
                case = Case(model, noise, n)
                t0 = time.perf_counter()
                rows += (new := summarise(case, run_case(case, args.seeds)))
                for r in new:
                    print(fmt_row(r), flush=True)
                print(f"  ({time.perf_counter() - t0:.0f} s)", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
