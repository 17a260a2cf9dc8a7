"""Issue 22's field-of-view study: five spheres of three sizes, with known truth, through crop
(tracks), prefit (the Lorenz-Mie fit, keyed by particle and frame), the fit stage for the
tracks that overlap another (final pass with each track's prefit sizes, then the refit of
overlapping frames with the neighbour's field) and the per-track analysis.

The scene (``holofit.simulate.field_of_view``, fields superposed at the camera, camera noise):
spheres of radius 0.4, 0.5 and 0.6 um (polystyrene and silica) diffusing in water at 21 C
(Stokes-Einstein D), 100 frames/s through the paper's 100x oil objective; particles 0 and 1
start 2.8 um apart (their holograms overlap in a 64-pixel crop); particle 3 leaves the field
of view at frame N/2 and particle 4 enters at frame N/3 (each is far outside the frame the rest
of the time).

Measured: the tracks found and whether each holds one true particle (no identity swap), the
x/y rms error against the truth on frames marked overlapping and not, and each track's D_t
against the truth (within 2 sigma?). Writes one JSON line.

Usage: ``python bench/study_field_of_view.py N_FRAMES OUT.jsonl [WORKDIR [WORKERS
[--simulate-only | FIRST]]]``; the movie in ``WORKDIR/sim`` is reused by a later run with the
same ``N_FRAMES``; ``FIRST``: study only the first FIRST frames of it.
"""

from __future__ import annotations

import itertools
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

from holofit.analysis.settings import AnalysisConfig
from holofit.analysis.tracks import analyze_tracks
from holofit.batch import BatchSettings
from holofit.config import Instrument, load_instrument, load_particle, resolve_config
from holofit.crop import CropConfig, run_crop
from holofit.crop.tracks import LinkSettings
from holofit.fit.config import FitConfig
from holofit.fit.stage import run_fit
from holofit.particles import Sphere
from holofit.prefit.stage import run_prefit
from holofit.simulate.field_of_view import ParticleInView, simulate_field_of_view
from holofit.simulate.holograms import SimulatedMovie

KB = 1.380649e-23
T = 294.15
ETA = 0.978e-3  # water at 21 C, Pa s
SHAPE = (300, 420)
SIZE = 64
#: frames a track may go undetected (``--memory``): the close pair of this scene comes within
#: 0.8 um, closer than the centre finder resolves (~2 um), for up to ~45 frames in a row
MEMORY = 60


def stokes_einstein_um2_s(radius_um: float) -> float:
    return KB * T / (6 * math.pi * ETA * radius_um * 1e-6) * 1e12


def scene(n: int, rng: np.random.Generator) -> tuple[list[ParticleInView], list[float]]:
    dt = 0.01
    specs = [  # radius, index, start (x, y, z), frames in view
        (0.5, 1.59, (9.0, 9.0, 10.0), None),
        (0.4, 1.59, (11.8, 9.0, 11.0), None),
        (0.6, 1.45, (24.0, 22.0, 12.0), None),
        (0.5, 1.59, (36.0, 9.0, 10.0), (0, n // 2)),
        (0.4, 1.59, (36.0, 24.0, 11.0), (n // 3, n)),
    ]
    particles, d_true = [], []
    for a, index, (x, y, z), span in specs:
        d = stokes_einstein_um2_s(a)
        steps = rng.normal(0, math.sqrt(2 * d * dt), (n, 3))
        steps[0] = 0
        pos = np.array([x, y, z]) + np.cumsum(steps, axis=0)
        if span is not None:
            out = np.ones(n, bool)
            out[span[0]:span[1]] = False
            pos[out, 0] = -200.0  # out of the field of view
        particles.append(ParticleInView(Sphere(a, index), pos))
        d_true.append(d)
    return particles, d_true


def _simulated(particles: list[ParticleInView], inst: Instrument, folder: Path,
               workers: int = 1) -> SimulatedMovie:
    """The scene's movie: simulated once into ``folder`` and reused by a later run with the
    same number of frames (500 frames take 10-25 min on one shared core). With several
    workers, blocks of frames are simulated in parallel (each block's camera noise has its
    own seed) and joined."""
    n = len(particles[0].positions_um)
    movie, background, truth = (folder / f for f in ("movie.tif", "background.tif", "truth.csv"))
    if movie.exists() and background.exists() and truth.exists():
        table = pd.read_csv(truth)
        if table["frame"].nunique() == n:
            return SimulatedMovie(movie, background, truth, table)
    if workers <= 1:
        return simulate_field_of_view(particles, inst, SHAPE, out_dir=folder, seed=5)
    from concurrent.futures import ProcessPoolExecutor

    import tifffile

    from holofit.io.tiffstack import TiffStackWriter

    edges = np.linspace(0, n, min(workers, n) + 1).astype(int)
    jobs = [([ParticleInView(p.model, np.asarray(p.positions_um)[a:b]) for p in particles],
             inst, folder / f"block_{k}", 5 + k)
            for k, (a, b) in enumerate(itertools.pairwise(edges))]
    with ProcessPoolExecutor(len(jobs)) as pool:
        parts = list(pool.map(_simulate_block, jobs))
    tables = []
    with TiffStackWriter(movie, {"holofit": "simulated field of view"}) as writer:
        for a, part in zip(edges[:-1], parts, strict=True):
            for frame in tifffile.imread(part.movie).reshape(-1, *SHAPE):
                writer.write(frame)
            tables.append(part.truth.assign(frame=part.truth["frame"] + a))
    parts[0].background.replace(background)
    table = pd.concat(tables, ignore_index=True)
    table.to_csv(truth, index=False)
    return SimulatedMovie(movie, background, truth, table)


def _simulate_block(job: tuple) -> SimulatedMovie:
    particles, inst, folder, seed = job
    return simulate_field_of_view(particles, inst, SHAPE, out_dir=folder, seed=seed)


def _fit_overlapping(work: Path, prefit: Path, frames: pd.DataFrame, workers: int
                     ) -> tuple[pd.DataFrame, dict]:
    """The table the study measures: the prefit's rows, except for tracks with overlapping
    frames, which go through the fit stage (final pass, then the refit of overlapping frames
    with the neighbour's field, :mod:`holofit.fit.per_track`). Each such track's static
    parameters (radius, index) are the median of its prefit rows that are ``ok`` and do not
    overlap (all its prefit rows if there are none): not the truth."""
    pre = pd.read_csv(prefit)
    marked = frames["overlap"].astype(str).str.lower().eq("true")
    pair = sorted(int(p) for p in frames.loc[marked, "particle"].unique())
    if not pair:
        return pre, {"tracks": []}
    cfg = load_particle(resolve_config("sphere_ps_1um", "particles"))
    flags = pre.merge(frames[["particle", "frame", "overlap"]], on=["particle", "frame"])
    clean = flags["overlap"].astype(str).str.lower().ne("true") & flags["status"].eq("ok")
    statics: dict[str, dict] = {}
    entries: dict[str, dict] = {}
    for p in pair:
        rows = flags[(flags["particle"] == p) & clean]
        source = "ok, not overlapping" if len(rows) else "all (none ok and apart)"
        rows = rows if len(rows) else flags[flags["particle"] == p]
        values = {"radius_um": float(rows["radius_um"].median()),
                  "n": float(rows["n"].median())}
        entries[str(p)] = {"model": "sphere", "status": "fitted", "values": values}
        statics[str(p)] = {**values, "from_prefit_rows": source, "n_rows": len(rows)}
    (work / "fit").mkdir(parents=True, exist_ok=True)
    static = work / "fit" / "static_from_prefit.json"
    static.write_text(json.dumps({"particle_model": "sphere", "tracks": entries}))
    run = run_fit(
        work / "crop",
        prefit,
        None,
        work / "fit",
        FitConfig(cfg, plot=False, passes="final", particles=tuple(pair), static=static),
        batch=BatchSettings(workers=workers, progress=False),
    )
    fit = pd.read_csv(run.final)
    keep = [c for c in pre.columns if c in fit.columns]
    table = pd.concat([pre[~pre["particle"].isin(pair)][keep], fit[keep]], ignore_index=True)
    return table, {"tracks": pair, "statics": statics, "notes": run.notes}


def _say(text: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {text}", flush=True)


def _times(path: Path) -> dict:
    """The prefit's seconds per crop (mean, median, max) by status, and its set-up."""
    t = pd.read_csv(path)
    out = {
        str(k): [float(g.mean()), float(g.median()), float(g.max()), len(g)]
        for k, g in t.groupby("status")["fit_time_s"]
    }
    out["setup_s_total"] = float(t["setup_time_s"].sum()) if "setup_time_s" in t else math.nan
    return out


def _first_frames(sim: SimulatedMovie, m: int, folder: Path) -> SimulatedMovie:
    """The first ``m`` frames of a simulated movie (and its truth), in ``folder``."""
    import tifffile

    from holofit.io.tiffstack import TiffStackWriter

    folder.mkdir(parents=True, exist_ok=True)
    with TiffStackWriter(folder / "movie.tif", {"holofit": "simulated field of view"}) as w:
        for frame in tifffile.imread(sim.movie, key=range(m)).reshape(-1, *SHAPE):
            w.write(frame)
    truth = sim.truth[sim.truth["frame"] < m].reset_index(drop=True)
    truth.to_csv(folder / "truth.csv", index=False)
    return SimulatedMovie(folder / "movie.tif", sim.background, folder / "truth.csv", truth)


def main(n: int, out_path: Path, work: Path, workers: int = 2, first: int | None = None) -> dict:
    inst = load_instrument(resolve_config("paper_100x_oil", "instruments"))
    rng = np.random.default_rng(22)
    particles, d_true = scene(n, rng)
    t0 = time.perf_counter()
    sim = _simulated(particles, inst, work / "sim", workers)
    if first is not None and first < n:
        sim = _first_frames(sim, first, work / f"sim_first_{first}")
    t_sim = time.perf_counter() - t0
    t0 = time.perf_counter()
    crop = run_crop(sim.movie, sim.background, inst, work / "crop",
                    CropConfig(size=SIZE, plot=False, link=LinkSettings(memory=MEMORY)),
                    batch=BatchSettings(workers=workers, progress=False))
    t_crop = time.perf_counter() - t0
    _say(f"crop {t_crop:.0f} s: {crop.counts}, tracks {sorted(crop.frames['particle'].unique())}")
    t0 = time.perf_counter()
    pre = run_prefit(
        work / "crop",
        work / "prefit",
        plot=False,
        batch=BatchSettings(workers=workers, progress=False),
    )
    t_prefit = time.perf_counter() - t0
    _say(f"prefit {t_prefit:.0f} s: {pre.summary.statuses}")
    t0 = time.perf_counter()
    try:
        table, fit_note = _fit_overlapping(work, pre.table, crop.frames, workers)
    except Exception as exc:  # the study still reports the prefit's numbers
        table, fit_note = pd.read_csv(pre.table), {"tracks": [], "error": repr(exc)}
    t_fit = time.perf_counter() - t0
    _say(f"fit stage {t_fit:.0f} s: {fit_note}")
    truth = sim.truth
    frames = crop.frames
    # which true particle each track holds, frame by frame
    owners: dict[int, set[int]] = {}
    for row in frames[frames["status"].isin(["ok", "edge"])].itertuples():
        here = truth[truth["frame"] == row.frame]
        d = np.hypot(here["x_px"] - row.x_px, here["y_px"] - row.y_px).to_numpy()
        owners.setdefault(int(row.particle), set()).add(
            int(here["particle"].iloc[int(np.argmin(d))]) if d.min() < 3 else -1
        )
    # a swap: a track holding two true particles; frames whose centre is > 3 px from every
    # true one (a pair closer than the finder resolves, found as one centre between them) are
    # counted apart
    real = {p: o - {-1} for p, o in owners.items()}
    swaps = {p: sorted(o) for p, o in real.items() if len(o) != 1}
    mapping = {p: next(iter(o)) for p, o in real.items() if len(o) == 1}
    off = frames[frames["status"].isin(["ok", "edge"])].copy()
    off_truth = {}
    for row in off.itertuples():
        here = truth[truth["frame"] == row.frame]
        if np.hypot(here["x_px"] - row.x_px, here["y_px"] - row.y_px).min() >= 3:
            off_truth.setdefault(str(row.particle), []).append(int(row.frame))
    both = table.merge(frames[["particle", "frame", "overlap"]], on=["particle", "frame"])
    both["truth"] = both["particle"].map(mapping)
    both = both.merge(
        truth.rename(columns={"particle": "truth"}), on=["truth", "frame"], suffixes=("", "_true")
    )
    ok = both[both["status"] == "ok"]
    err = np.hypot(ok["x_um"] - ok["x_um_true"], ok["y_um"] - ok["y_um_true"]) * 1e3 / math.sqrt(2)

    def rms(mask: pd.Series) -> float:
        v = err[mask.to_numpy()]
        return float(np.sqrt(np.mean(v**2))) if len(v) else math.nan

    overlap = ok["overlap"].astype(str).str.lower().eq("true")
    combined = work / "combined.csv"
    table.to_csv(combined, index=False)
    d_rows: list[dict] = []
    try:
        analysed = analyze_tracks(
            combined, AnalysisConfig(model="sphere"), frame_interval_s=0.01
        ).tracks
    except Exception as exc:
        analysed, d_rows = [], [{"error": repr(exc)}]
    for t in analysed:
        if t.result is None or "D_t" not in t.result.measured:
            d_rows.append({"particle": t.particle, "status": t.status, "message": t.message})
            continue
        m = t.result.measured["D_t"]
        truth_d = d_true[mapping[t.particle]] if t.particle in mapping else math.nan
        d_rows.append(
            {
                "particle": t.particle,
                "truth_particle": mapping.get(t.particle),
                "D_t": m.value,
                "err": m.error,
                "D_true": truth_d,
                "pull": (m.value - truth_d) / m.error if m.error else math.nan,
            }
        )
    result = {
        "study": "field_of_view_five_spheres",
        "n_frames": len(sim.truth["frame"].unique()),
        "simulated_frames": n,
        "frame_shape": list(SHAPE),
        "crop_size": SIZE,
        "tracks_found": sorted(int(p) for p in frames["particle"].unique()),
        "true_particles_tracked": sorted(set(mapping.values())),
        "identity_swaps": swaps,
        "frames_off_every_particle": {p: [len(v), v[:5], v[-5:]] for p, v in off_truth.items()},
        "link_memory": MEMORY,
        "track_spans": {
            str(p): [int(g["frame"].min()), int(g["frame"].max())]
            for p, g in frames.groupby("particle")
        },
        "crop_status": crop.counts,
        "warnings": crop.warnings,
        "prefit_status": pre.summary.statuses,
        "xy_rms_nm_no_overlap": rms(~overlap),
        "xy_rms_nm_overlap": rms(overlap),
        "n_ok_no_overlap": int((~overlap).sum()),
        "n_ok_overlap": int(overlap.sum()),
        "n_overlap_rows": int(frames["overlap"].astype(str).str.lower().eq("true").sum()),
        "D": d_rows,
        "all_D_within_2_sigma": all(abs(r.get("pull", 99)) <= 2 for r in d_rows),
        "xy_rms_nm_per_track": {
            str(p): {
                "apart": rms(~overlap & (ok["particle"] == p)),
                "overlap": rms(overlap & (ok["particle"] == p)),
            }
            for p in sorted(ok["particle"].unique())
        },
        "status_of_overlap_rows": both.loc[
            both["overlap"].astype(str).str.lower().eq("true"), "status"
        ]
        .value_counts()
        .to_dict(),
        "prefit_fit_time_s": _times(pre.table),
        "fit_stage": fit_note,
        "fit_status": table.loc[table["particle"].isin(fit_note.get("tracks", [])), "status"]
        .value_counts()
        .to_dict(),
        "seconds": {"simulate": t_sim, "crop": t_crop, "prefit": t_prefit, "fit": t_fit},
    }
    with out_path.open("a") as fh:
        fh.write(json.dumps(result, default=str) + "\n")
    return result


if __name__ == "__main__":
    n_frames = int(sys.argv[1]) if len(sys.argv) > 1 else 200
    target = Path(sys.argv[2]) if len(sys.argv) > 2 else Path("field_of_view.jsonl")
    workdir = Path(sys.argv[3]) if len(sys.argv) > 3 else Path("fov_study")
    n_workers = int(sys.argv[4]) if len(sys.argv) > 4 else 2
    if len(sys.argv) > 5 and sys.argv[5] == "--simulate-only":
        _simulated(
            scene(n_frames, np.random.default_rng(22))[0],
            load_instrument(resolve_config("paper_100x_oil", "instruments")),
            workdir / "sim",
        )
        raise SystemExit(0)
    first_m = int(sys.argv[5]) if len(sys.argv) > 5 else None
    print(json.dumps(main(n_frames, target, workdir, n_workers, first_m), indent=1, default=str))
