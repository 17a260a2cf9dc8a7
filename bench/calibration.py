"""Calibration of the analysis's error bars: pulls over many simulated trajectories.

For each particle (the paper's rod, sedimenting; the paper's Janus sphere; a sphere of the same
size), each trajectory length and each noise level (what the fits reach on the replicate, 2 nm
and 0.2 deg; the paper's real data, 35 nm and 1.5 deg), the script simulates independent
Brownian trajectories with known truth, analyses each with the default settings of
``holofit analyze`` and collects the pulls ``(measured - truth) / error``
(:func:`holofit.studies.diffusion.calibration_case`). Calibrated errors give pulls of mean 0
and standard deviation 1; over ``n`` trajectories the sample mean has a standard error
``1 / sqrt(n)`` and the sample s.d. ``1 / sqrt(2 (n - 1))``.

Usage::

    python bench/calibration.py [--seeds 200] [--lengths 30 150 300 1000 2000]
                                [--models rod janus sphere] [--noises replicate paper]
                                [--out bench/results/calibration] [--first-seed 0]

Writes ``calibration.csv`` (one row per model, noise, length and quantity; the table of the
README's analysis section) and ``calibration.png`` (pull mean and s.d. against length) in
``--out``, and prints the table as it goes.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import pandas as pd

from holofit.studies.diffusion import (
    CALIBRATION_NOISE,
    CALIBRATION_QUANTITIES,
    calibration_case,
    pull_bounds,
)


def fmt_row(r: dict) -> str:
    """One line of the printed table."""
    return (f"{r['model']:<7}{r['noise']:<10}{r['frames']:>6}  {r['quantity']:<7}"
            f"{r['n']:>5}{r['failed']:>4}  mean {r['pull_mean']:+6.2f}  sd {r['pull_sd']:5.2f}"
            f"  |pull|<=1 {100 * r['within_1_sigma']:5.1f} %  bias {100 * r['bias_rel']:+6.1f} %"
            f"  err {100 * r['rel_error']:6.1f} %  scatter {100 * r['scatter_rel']:6.1f} %")


def plot(table: pd.DataFrame, path: Path) -> None:
    """Pull mean and s.d. against trajectory length, one line per model and quantity."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    noises = list(dict.fromkeys(table["noise"]))
    fig, axes = plt.subplots(2, len(noises), figsize=(5.5 * len(noises), 7), squeeze=False,
                             sharex=True)
    for j, noise in enumerate(noises):
        sub = table[table["noise"] == noise]
        for (model, q), g in sub.groupby(["model", "quantity"], sort=False):
            g = g.sort_values("frames")
            label = f"{model} {q}"
            axes[0, j].errorbar(g["frames"], g["pull_mean"], g["pull_mean_se"], marker="o",
                                ms=3, capsize=2, label=label)
            axes[1, j].errorbar(g["frames"], g["pull_sd"], g["pull_sd_se"], marker="o", ms=3,
                                capsize=2, label=label)
        eps, eps_r = CALIBRATION_NOISE[noise]
        axes[0, j].set_title(f"noise '{noise}': {1e3 * eps:g} nm, {eps_r * 57.2958:.2g} deg")
        axes[0, j].axhspan(-0.15, 0.15, color="0.9")
        axes[1, j].axhspan(0.9, 1.1, color="0.9")
        axes[0, j].axhline(0, color="k", lw=0.5)
        axes[1, j].axhline(1, color="k", lw=0.5)
        axes[0, j].set_ylabel("pull mean")
        axes[1, j].set_ylabel("pull s.d.")
        axes[1, j].set_xlabel("trajectory length (frames)")
        axes[1, j].set_xscale("log")
    axes[0, -1].legend(fontsize=7, ncol=2)
    fig.suptitle("pulls (measured - truth) / error; grey: the target band")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=200)
    ap.add_argument("--lengths", type=int, nargs="+", default=[30, 150, 300, 1000, 2000])
    ap.add_argument("--models", nargs="+", default=list(CALIBRATION_QUANTITIES))
    ap.add_argument("--noises", nargs="+", default=list(CALIBRATION_NOISE))
    ap.add_argument("--out", type=Path, default=Path("bench/results/calibration"))
    ap.add_argument("--first-seed", type=int, default=0,
                    help="offset of the seeds (fresh trajectories for a rerun of a case)")
    ap.add_argument("--merge", type=Path, nargs="+", default=None, metavar="CSV",
                    help="no study: merge these calibration.csv files (e.g. one per noise "
                         "level, run apart; a later file's row replaces an earlier one's) "
                         "into --out's table and plot")
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    rows = []
    t_all = time.perf_counter()
    if args.merge:
        merged = pd.concat([pd.read_csv(p) for p in args.merge])  # a later file's row wins
        rows = merged.drop_duplicates(["model", "noise", "frames", "quantity"],
                                      keep="last").to_dict("records")
        args.seeds = int(min(r["n"] for r in rows))
    for noise in [] if args.merge else args.noises:
        for model in args.models:
            for n in args.lengths:
                t0 = time.perf_counter()
                for summary in calibration_case(model, noise, n, args.seeds,
                                                  args.first_seed).values():
                    rows.append(summary.row())
                    print(fmt_row(rows[-1]), flush=True)
                print(f"  ({time.perf_counter() - t0:.0f} s)", flush=True)
    table = pd.DataFrame(rows)
    mean_bound, (sd_lo, sd_hi) = pull_bounds(args.seeds)
    table["meets_target"] = ((table["pull_mean"].abs() <= 0.15)
                             & table["pull_sd"].between(0.9, 1.1))
    table["within_seed_bounds"] = ((table["pull_mean"].abs() <= mean_bound)
                                   & table["pull_sd"].between(sd_lo, sd_hi))
    tmp = args.out / "calibration.csv.tmp"
    table.to_csv(tmp, index=False, float_format="%.4g")
    tmp.replace(args.out / "calibration.csv")
    plot(table, args.out / "calibration.png")
    print(f"{int(table['meets_target'].sum())} of {len(table)} rows meet the target "
          f"(|mean| <= 0.15, s.d. in [0.9, 1.1]); {int(table['within_seed_bounds'].sum())} are "
          f"within it widened by 3 standard errors of {args.seeds} seeds "
          f"(|mean| <= {mean_bound:.2f}, s.d. in [{sd_lo:.2f}, {sd_hi:.2f}]); "
          f"{time.perf_counter() - t_all:.0f} s; wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
