"""Issue 36's field-of-view scenes through the crop stage, against the simulated truth.

Two scenes, each 512 x 512 pixels and 200 frames on the paper's 60x water instrument
(``configs/instruments/paper_60x_water.toml``), made with holofit's own
:func:`holofit.simulate.field_of_view.simulate_field_of_view` (fields superposed at the camera,
8-bit camera noise); the rods' holograms come from their DDA T-matrices (exact to the solver's
precision at every orientation, one build per rod shape):

``rods_spheres``
    two paper rods (``rod_paper``) and two 1 um polystyrene spheres (``sphere_ps_1um``),
    Brownian (the paper's rod coefficients, Stokes-Einstein spheres); sphere 2 drifts past
    rod 0 at a closest approach under 3 um;
``crossing_rods``
    two rods of the user-described size (a 0.3, b 1.0 um, silica) drifting toward each other
    on nearly the same line, crossing near frame 150.

Measured per particle (truth particle <- the track whose detections lie nearest it): the
fraction of its frames in which it is found (a crop row, ``ok`` or ``edge``, of its track
within 0.5 um of it) among the frames where it is at least 3 um (x-y) from every other
particle, and in all frames; identity swaps (rows of a track nearer another particle than
its own); the rows marked ``overlap`` where another particle's hologram is within reach; and
the crop's reports of tracks lost next to another hologram (``track_losses``).

Usage: ``python bench/detection_scenes.py OUT.json [WORKDIR [FRAMES [SIZE]]]`` (defaults:
a temporary folder, 200 frames, 512 pixels); movies in ``WORKDIR`` are reused. Writes one
flat JSON object.
"""

from __future__ import annotations

import dataclasses
import json
import math
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from holofit.analysis.hydrodynamics import sphere_diffusion
from holofit.config import Instrument, load_instrument, load_particle, resolve_config
from holofit.crop import CropConfig, run_crop
from holofit.simulate.brownian import BrownianParameters, simulate_trajectory
from holofit.simulate.field_of_view import ParticleInView, simulate_field_of_view
from holofit.simulate.holograms import SimulatedMovie

#: the paper's rod coefficients (um^2/s, 1/s)
ROD_D = (0.307, 0.293, 0.311)
#: a particle counts as found within this distance of a row of its track, um
FOUND_UM = 0.5
#: ... in the frames where it is at least this far (x-y) from every other particle, um
APART_UM = 3.0


def _trajectory(n: int, start: tuple[float, float, float], d: tuple[float, float, float],
                drift: tuple[float, float, float], seed: int,
                orientation: tuple[float, float, float] | None = None) -> pd.DataFrame:
    params = BrownianParameters(n_frames=n, frame_interval_s=0.01, d_par_um2_s=d[0],
                                d_perp_um2_s=d[1], d_r_s=d[2], drift_um_s=drift,
                                start_position_um=start, start_orientation=orientation)
    return simulate_trajectory(params, seed=seed).truth


def scene_particles(name: str, n: int, size_px: int, inst: Instrument) -> list[ParticleInView]:
    """The particles of scene ``name`` (module docstring), ``n`` frames, positions scaled to a
    ``size_px`` frame (the 512-px layout shrunk)."""
    scale = size_px * inst.pixel_size_um / 90.47  # 512 px at 0.1767 um
    rod = load_particle(resolve_config("rod_paper", "particles"))
    sphere = load_particle(resolve_config("sphere_ps_1um", "particles"))
    ds = sphere_diffusion(sphere.model.radius_um, 21.0)
    d_sphere = (ds["D_t"], ds["D_t"], ds["D_r"])
    duration = n * 0.01  # s

    def at(x: float, y: float, z: float) -> tuple[float, float, float]:
        return (x * scale, y * scale, z)

    def moving(dx_um: float) -> tuple[float, float, float]:
        """The drift that moves a particle by ``dx_um`` (512-px layout) over the movie."""
        return (dx_um * scale / duration, 0.0, 0.0)

    if name == "rods_spheres":
        specs = [  # model, theory config, start, D, drift (um/s), seed, start orientation
            (rod.model, rod, at(30.0, 32.0, 12.0), ROD_D, (0.0, 0.0, 0.0), 1, (0.3, 1.1, 0.0)),
            (rod.model, rod, at(66.0, 62.0, 14.0), ROD_D, (0.0, 0.0, 0.0), 2, (1.2, 0.6, 0.0)),
            (sphere.model, sphere, at(68.0, 22.0, 11.0), d_sphere, (0.0, 0.0, 0.0), 3, None),
            (sphere.model, sphere, at(40.0, 33.5, 14.0), d_sphere, moving(-20.0), 4, None),
        ]
    elif name == "crossing_rods":
        thin = dataclasses.replace(rod.model, a_um=0.3, b_um=1.0)
        specs = [
            (thin, rod, at(36.0, 45.0, 12.0), ROD_D, moving(12.0), 5, (0.2, 1.0, 0.0)),
            (thin, rod, at(54.0, 45.8, 13.0), ROD_D, moving(-12.0), 6, (1.9, 0.7, 0.0)),
        ]
    else:
        raise ValueError(f"unknown scene {name!r}")
    theories: dict[Any, Any] = {}
    particles = []
    for model, cfg, start, d, drift, seed, orient in specs:
        key = (model.kind, *model.parameters().items())
        if key not in theories:
            theory = cfg.theory(fixed_lattice_for=inst.optics)
            if model.anisotropic:
                theory.tmatrix(model, inst.optics)
            theories[key] = theory
        truth = _trajectory(n, start, d, drift, seed, orient)
        particles.append(ParticleInView(
            model, truth[["x_um", "y_um", "z_um"]].to_numpy(),
            truth[["psi_rad", "theta_rad", "phi_rad"]].to_numpy(), theory=theories[key]))
    return particles


def simulated(name: str, n: int, size_px: int, folder: Path, inst: Instrument) -> SimulatedMovie:
    """Scene ``name`` filmed into ``folder`` (reused if there with ``n`` frames)."""
    movie, background, truth = (folder / f for f in ("movie.tif", "background.tif", "truth.csv"))
    if movie.exists() and truth.exists():
        table = pd.read_csv(truth)
        if table["frame"].nunique() == n:
            return SimulatedMovie(movie, background, truth, table)
    particles = scene_particles(name, n, size_px, inst)
    return simulate_field_of_view(particles, inst, (size_px, size_px), out_dir=folder,
                                  seed=7)


def score_scene(frames: pd.DataFrame, truth: pd.DataFrame, pixel_um: float,
                losses: list[dict[str, Any]]) -> dict[str, Any]:
    """The measures of the module docstring for one scene's crop table."""
    out: dict[str, Any] = {}
    ok = frames[frames["status"].isin(["ok", "edge"])]
    ids = sorted(truth["particle"].unique())
    pos = {p: truth[truth["particle"] == p].set_index("frame")[["x_um", "y_um"]]
           for p in ids}
    n = truth["frame"].nunique()
    # nearest truth particle of every row
    nearest, dist = [], []
    for r in ok.itertuples():
        d = {p: math.hypot(pos[p].at[r.frame, "x_um"] - r.x_um,
                           pos[p].at[r.frame, "y_um"] - r.y_um) for p in ids}
        best = min(d, key=d.get)
        nearest.append(best)
        dist.append(d[best])
    ok = ok.assign(truth=nearest, dist_um=dist)
    owner = {int(t): int(g["truth"].mode().iloc[0]) for t, g in ok.groupby("particle")}
    swapped = ok[(ok["truth"] != ok["particle"].map(owner)) & (ok["dist_um"] < FOUND_UM)]
    out["tracks"] = int(frames["particle"].nunique())
    out["rows"] = len(frames)
    out["identity_swap_rows"] = len(swapped)
    out["overlap_rows"] = int(frames["overlap"].astype(str).str.lower().isin(["true"]).sum())
    out["track_losses"] = len(losses)
    for p in ids:
        others = [q for q in ids if q != p]
        sep = np.min([np.hypot(*(pos[p].to_numpy() - pos[q].to_numpy()).T) for q in others],
                     axis=0)
        apart = sep >= APART_UM
        mine = ok[(ok["truth"] == p) & (ok["dist_um"] < FOUND_UM)
                  & (ok["particle"].map(owner) == p)]
        found = np.zeros(n, bool)
        found[mine["frame"].to_numpy(dtype=int)] = True
        out[f"p{p}_frames_apart"] = int(apart.sum())
        out[f"p{p}_found_apart"] = round(float(found[apart].mean()) if apart.any() else 1.0, 4)
        out[f"p{p}_found_all"] = round(float(found.mean()), 4)
        out[f"p{p}_closest_um"] = round(float(sep.min()), 3)
        out[f"p{p}_tracks"] = int(ok[ok["truth"] == p]["particle"].nunique())
        out[f"p{p}_rms_um"] = round(float(np.sqrt(np.mean(mine["dist_um"] ** 2))), 4) if len(
            mine) else math.nan
    return out


def run(out_json: Path, work: Path, n: int, size_px: int) -> dict[str, Any]:
    inst = load_instrument(resolve_config("paper_60x_water", "instruments"))
    result: dict[str, Any] = {"frames": n, "size_px": size_px, "instrument": inst.name}
    for name in ("rods_spheres", "crossing_rods"):
        t0 = time.time()
        sim = simulated(name, n, size_px, work / name / "sim", inst)
        t1 = time.time()
        crop = run_crop(sim.movie, sim.background, inst, work / name / "crop",
                        CropConfig(plot=False))
        t2 = time.time()
        side = json.loads(crop.table.with_name(crop.table.name + ".json").read_text())
        losses = side["track_losses"]
        scores = score_scene(crop.frames, sim.truth, inst.pixel_size_um, losses)
        result.update({f"{name}_{k}": v for k, v in scores.items()})
        result[f"{name}_simulate_s"] = round(t1 - t0, 1)
        result[f"{name}_crop_s"] = round(t2 - t1, 1)
        result[f"{name}_warnings"] = " | ".join(crop.warnings)
        result[f"{name}_losses"] = json.dumps(losses)
    out_json.write_text(json.dumps(result, indent=1) + "\n")
    return result


if __name__ == "__main__":
    out = Path(sys.argv[1])
    work = Path(sys.argv[2]) if len(sys.argv) > 2 else Path(tempfile.mkdtemp())
    frames = int(sys.argv[3]) if len(sys.argv) > 3 else 200
    size = int(sys.argv[4]) if len(sys.argv) > 4 else 512
    print(json.dumps(run(out, work, frames, size), indent=1))
