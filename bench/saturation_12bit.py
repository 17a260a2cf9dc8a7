"""Issue 36, item 4 (part): a 12-bit camera's movie in 16-bit TIFFs, the instrument saying
``bit_depth = 16``, through crop and prefit, against the simulated truth.

A 1 um polystyrene sphere (radius 0.5 um, n 1.59) at z = 12 um on the paper's 60x water
instrument, 256 x 256 pixels, a 12-bit camera whose background sits at BACKGROUND counts so
that the bright central fringes clip at 4095 (several hundred pixels a frame); the frames
are stored as uint16. The crop runs twice: by default (the pile-up at 4095 is found in the
data, masked and reported: :mod:`holofit.crop.saturation`) and with ``mask_saturated=False``
(every pixel used, as before). Each crop folder is prefitted (Lorenz-Mie, automatic starts)
and the mean fitted radius and index are compared with the truth in units of the per-frame
uncertainty the prefit reports and of the frames' scatter.

Usage: ``python bench/saturation_12bit.py OUT.json [WORKDIR [FRAMES]]``; one flat JSON object.
"""

from __future__ import annotations

import json
import sys
import tempfile
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from holofit.camera import Camera
from holofit.config import load_instrument, resolve_config
from holofit.crop import CropConfig, run_crop
from holofit.particles import Sphere
from holofit.prefit.stage import run_prefit
from holofit.simulate.field_of_view import ParticleInView, simulate_field_of_view

BACKGROUND = 2500.0
TRUTH = {"radius_um": 0.5, "n": 1.59}


def _summary(table: pd.DataFrame, prefix: str) -> dict[str, Any]:
    ok = table[table["status"] == "ok"]
    out: dict[str, Any] = {f"{prefix}_ok_frames": len(ok)}
    for col, true in TRUTH.items():
        v = ok[col].to_numpy(dtype=float)
        err = ok.get(f"d_{col}")
        sigma = float(np.median(err)) if err is not None and len(ok) else float("nan")
        out[f"{prefix}_{col}_mean"] = round(float(v.mean()), 5)
        out[f"{prefix}_{col}_sd"] = round(float(v.std(ddof=1)), 5) if len(v) > 1 else None
        out[f"{prefix}_{col}_sigma"] = round(sigma, 5)
        out[f"{prefix}_{col}_pull"] = round(float((v.mean() - true) / sigma), 2)
        out[f"{prefix}_{col}_within_2sigma"] = bool(abs(v.mean() - true) <= 2 * sigma)
    return out


def run(out_json: Path, work: Path, n: int) -> dict[str, Any]:
    inst = load_instrument(resolve_config("paper_60x_water", "instruments"))
    px = inst.pixel_size_um
    rng = np.random.default_rng(3)
    pos = np.column_stack([128.3 * px + 0.02 * np.cumsum(rng.normal(size=n)),
                           127.6 * px + 0.02 * np.cumsum(rng.normal(size=n)), np.full(n, 12.0)])
    camera = Camera(bit_depth=12, background_counts=BACKGROUND)
    sim = simulate_field_of_view([ParticleInView(Sphere(0.5, 1.59), pos)], inst, (256, 256),
                                 camera=camera, out_dir=work / "sim", seed=4)
    import tifffile

    movie = tifffile.imread(sim.movie)
    result: dict[str, Any] = {"frames": n, "dtype": str(movie.dtype),
                              "background_counts": BACKGROUND,
                              "pixels_at_4095_per_frame": float((movie == 4095).sum() / n)}
    inst16 = replace(inst, bit_depth=16)
    for prefix, mask in (("masked", True), ("unmasked", False)):
        crop = run_crop(sim.movie, sim.background, inst16, work / f"crop_{prefix}",
                        CropConfig(size=140, plot=False, mask_saturated=mask))
        result[f"{prefix}_crop_warnings"] = " | ".join(crop.warnings)
        result[f"{prefix}_masked_px_per_row"] = float(crop.frames["n_masked"].mean())
        prefit = run_prefit(crop.out_dir, work / f"prefit_{prefix}", plot=False)
        result.update(_summary(pd.read_csv(prefit.table), prefix))
    out_json.write_text(json.dumps(result, indent=1) + "\n")
    return result


if __name__ == "__main__":
    out = Path(sys.argv[1])
    work = Path(sys.argv[2]) if len(sys.argv) > 2 else Path(tempfile.mkdtemp())
    frames = int(sys.argv[3]) if len(sys.argv) > 3 else 10
    print(json.dumps(run(out, work, frames), indent=1))
