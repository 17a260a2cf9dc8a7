"""The whole pipeline on a field of view of one rod and of three rods (``python
bench/pipeline_cases.py N_RODS [--frames N]``): prints JSON. Issue target (field of view):
``pipeline_three_rods_s / pipeline_one_rod_s <= 3.3`` (cost linear in the particles).

The paper's rod (a 0.501, b 1.079 um, n 1.495) and its measured motion (D_par 0.307, D_perp
0.293 um^2/s, D_r 0.311 1/s), filmed by the paper's 60x water set-up (100 frames/s, 8-bit
noise), 12-15 um above focus, far enough apart that their holograms do not overlap; the frame
grows with the number of rods (192 x 192 px per rod, side by side). Timed: crop (tracks),
the prefit (seed only), the library and both fit passes (tracked), in this process, one worker;
the rod's T-matrix is built once per run (its time is reported apart and included). Reported
too: the tracks found and the axis and position errors of the final fit's ``ok`` frames
against the truth.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

from holofit.batch import BatchSettings
from holofit.config import load_instrument, load_particle, resolve_config
from holofit.crop import CropConfig, run_crop
from holofit.fit.config import FitConfig
from holofit.fit.stage import run_fit
from holofit.library.stage import run_library
from holofit.prefit import run_prefit
from holofit.prefit.sphere import SphereFitSettings
from holofit.simulate.field_of_view import simulate_field_of_view
from holofit.simulate.scene import load_scene

SCENE = """
instrument = "paper_60x_water"
frames = {frames}
shape = [192, {width}]
seed = 5
{particles}
"""
ROD = """
[[particle]]
config = "rod_paper"
start_um = [{x:.2f}, 9.0, {z:.1f}]
d_par_um2_s = 0.307
d_perp_um2_s = 0.293
d_r_s = 0.311
start_orientation = [{psi:.2f}, 1.1, 0.0]
"""


def run(n_rods: int, frames: int, out_dir: Path | None = None,
        workers: int = 1) -> dict[str, float]:
    """Run the case; in ``out_dir`` (kept, each stage resuming) or in a temporary folder."""
    tag = {1: "one_rod", 3: "three_rods"}.get(n_rods, f"{n_rods}_rods")
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) if out_dir is None else Path(out_dir)
        root.mkdir(parents=True, exist_ok=True)
        pixel_um = load_instrument(resolve_config("paper_60x_water", "instruments")).pixel_size_um
        width = 192 * n_rods
        particles = "".join(ROD.format(x=(96 + 192 * i) * pixel_um, z=12.0 + 1.5 * i,
                                       psi=0.5 + 1.7 * i) for i in range(n_rods))
        (root / "scene.toml").write_text(SCENE.format(frames=frames, width=width,
                                                      particles=particles))
        scene = load_scene(root / "scene.toml")
        sim = simulate_field_of_view(scene.particles, scene.instrument, scene.frame_shape,
                                     seed=scene.seed, out_dir=root / "movie")
        _log("simulation done")
        config = load_particle(resolve_config("rod_paper", "particles"))
        batch = BatchSettings(workers=workers, progress=False)
        out: dict[str, float] = {}
        t_all = time.perf_counter()
        t0 = time.perf_counter()
        run_crop(sim.movie, sim.background, scene.instrument, root / "crop",
                 CropConfig(size=140, plot=False))
        out[f"pipeline_{tag}_crop_s"] = time.perf_counter() - t0
        _log(f"crop done: {time.perf_counter() - t0:.0f} s")
        t0 = time.perf_counter()
        run_prefit(root / "crop", root / "prefit", fit=SphereFitSettings(seed_only=True),
                   batch=batch, plot=False)
        out[f"pipeline_{tag}_prefit_s"] = time.perf_counter() - t0
        _log(f"prefit done: {time.perf_counter() - t0:.0f} s")
        t0 = time.perf_counter()
        run_library(root / "crop", root / "prefit", config, root / "library", batch=batch)
        out[f"pipeline_{tag}_library_s"] = time.perf_counter() - t0
        _log(f"library done: {time.perf_counter() - t0:.0f} s")
        t0 = time.perf_counter()
        run_fit(
            root / "crop",
            root / "prefit",
            root / "library",
            root / "fit",
            FitConfig(config, plot=False),
            batch=batch,
        )
        out[f"pipeline_{tag}_fit_s"] = time.perf_counter() - t0
        _log(f"fit done: {time.perf_counter() - t0:.0f} s")
        out[f"pipeline_{tag}_s"] = time.perf_counter() - t_all
        out.update(_errors(tag, root, sim.truth_table, n_rods))
    return out


def _log(msg: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


def _errors(tag: str, root: Path, truth_path: Path, n_rods: int) -> dict[str, float]:
    fit = pd.read_csv(root / "fit" / "fit.csv")
    truth = pd.read_csv(truth_path)
    if "particle" not in fit.columns:
        fit["particle"] = 0
    ok = fit[fit["status"] == "ok"]
    # each track is the rod whose truth lies nearest its first ok frame
    axis_err, pos_err = [], []
    for _, rows in ok.groupby("particle"):
        first = rows.iloc[0]
        at = truth[truth["frame"] == first["frame"]]
        rod = int(
            at.iloc[
                int(np.argmin(np.hypot(at["x_um"] - first["x_um"], at["y_um"] - first["y_um"])))
            ]["particle"]
        )
        t = truth[truth["particle"] == rod].set_index("frame").loc[rows["frame"]]
        st = np.sin(t["theta_rad"].to_numpy())
        u_true = np.stack(
            [st * np.cos(t["psi_rad"]), st * np.sin(t["psi_rad"]), np.cos(t["theta_rad"])], axis=1
        )
        u = rows[["ux", "uy", "uz"]].to_numpy()
        axis_err += list(np.degrees(np.arccos(np.clip(np.abs((u * u_true).sum(1)), 0, 1))))
        pos_err += list(
            np.hypot(
                rows["x_um"].to_numpy() - t["x_um"].to_numpy(),
                rows["y_um"].to_numpy() - t["y_um"].to_numpy(),
            )
        )
    return {
        f"pipeline_{tag}_tracks": float(fit["particle"].nunique()),
        f"pipeline_{tag}_rows": float(len(fit)),
        f"pipeline_{tag}_ok_rows": float(len(ok)),
        f"pipeline_{tag}_axis_rms_deg": float(math.sqrt(np.mean(np.square(axis_err))))
        if axis_err
        else math.nan,
        f"pipeline_{tag}_xy_rms_nm": 1e3 * float(math.sqrt(np.mean(np.square(pos_err))))
        if pos_err
        else math.nan,
    }


if __name__ == "__main__":
    parser = argparse.ArgumentParser()
    parser.add_argument("n_rods", type=int)
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument(
        "--out-dir",
        type=Path,
        default=None,
        help="keep the run here (stages resume) instead of a temporary folder",
    )
    parser.add_argument("--workers", type=int, default=1)
    args = parser.parse_args()
    print(json.dumps(run(args.n_rods, args.frames, args.out_dir, args.workers)))
