"""Diffusion-analysis speed: a 2000-frame rod trajectory (the paper's run length)."""

from __future__ import annotations

import tempfile
from pathlib import Path

from timing import median_time

from holofit.analysis import AnalysisConfig, Trajectory, analyze_trajectory, run_analysis
from holofit.simulate.brownian import BrownianParameters, MeasurementNoise, simulate_trajectory
from holofit.studies.diffusion import PAPER_ROD
from holofit.tables.fit import validate_fit_table, write_fit_table


def _rod(n_frames: int = 2000):
    r = PAPER_ROD
    params = BrownianParameters(n_frames, 0.01, r["d_par"], r["d_perp"], r["d_r"])
    noise = MeasurementNoise(r["eps_um"], None, r["eps_r"], r["flip"], r["mirror"],
                             fail_fraction=0.01, missing_fraction=0.01)
    return params, noise


def bench_analysis() -> dict[str, float]:
    params, noise = _rod()
    static = {"a_um": 0.501, "b_um": 1.079}
    sim = simulate_trajectory(params, noise, seed=0, static=static)
    settings = AnalysisConfig("rod")

    def analyse() -> None:
        # validation of the table, cleaning, all lag statistics, fits with errors, the two
        # D_est sensitivity reruns and the predictions: everything but writing files
        traj = Trajectory.from_fit_table(validate_fit_table(sim.table))
        analyze_trajectory(traj, settings)

    t_analyse = median_time(analyse, repeat=10)
    t_sim = median_time(lambda: simulate_trajectory(params, noise, seed=1, static=static),
                        repeat=5)
    with tempfile.TemporaryDirectory() as tmp:
        table = Path(tmp) / "fit.csv"
        write_fit_table(table, sim.table)
        t_files = median_time(
            lambda: run_analysis(table, settings, Path(tmp) / "out", plots=True), repeat=3,
            warmup=1,
        )
    return {
        "analyze_2000_frames_s": t_analyse,
        "analyze_2000_frames_with_files_and_plots_s": t_files,
        "simulate_trajectory_2000_frames_s": t_sim,
    }


BENCHMARKS = {"analysis": bench_analysis}
