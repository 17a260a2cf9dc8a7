"""Issue 36's field of view, end to end, as a user runs it: ``holofit simulate field-of-view``,
``holofit init`` and ``make`` with no option beyond the movie, the instrument and the
population's models, then every number the issue asks for, against the scene's truth.

Scenes (``bench/scenes``): ``mixed_rods_spheres.toml`` (two paper rods and two 1 um PS spheres,
60x water, 512 x 512, 200 frames; a sphere drifts past a rod within about 2.5 um) run with
``-p rod_paper -p sphere_ps_1um``, and ``crossing_small_rods.toml`` (two small rods crossing
within about 2.2 um) run with ``-p rod_small.toml``.

Measured per true particle: the frames in which it is at least ``APART_UM`` (3D) from every
other particle and the fraction of those in which a crop row of its track lies within
``FOUND_UM`` of it (laterally); identity swaps (a track whose rows hold two true particles
in frames where each is ``APART_UM`` from every other; the frames a merged pair's centre lies
nearer the other particle are counted apart);
the model the fit gave its track; each diffusion coefficient of its analysis against the
analysis of its true trajectory (same settings), as a pull in the fit's error; and the frames
in which another particle's hologram reaches into its crop, with how many of them the crop
marked ``overlap`` and the fit modelled or flagged. Writes one JSON line per scene.

Usage: ``python bench/study_mixed_field.py OUT.jsonl WORKDIR [SCENE ...] [--jobs N]``
(default: both scenes; a scene whose ``WORKDIR/<scene>/run`` has finished is measured again,
not rerun: ``make`` does nothing).
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

from holofit.analysis.pipeline import analyze_trajectory
from holofit.analysis.settings import AnalysisConfig
from holofit.analysis.trajectory import Trajectory
from holofit.config import load_particle, resolve_config
from holofit.conventions import axis_from_angles

HERE = Path(__file__).resolve().parent
#: the command line of the environment that runs the study
HOLOFIT = str(Path(sys.executable).parent / "holofit")
SCENES = {
    "mixed_rods_spheres": ("paper_60x_water", ["rod_paper", "sphere_ps_1um"]),
    "crossing_small_rods": ("paper_60x_water", [str(HERE / "scenes" / "rod_small.toml")]),
}
#: a particle counts as apart in a frame when every other is at least this far (3D), um
APART_UM = 3.0
#: a crop row finds a particle when its centre is this close to the true one (lateral), um
FOUND_UM = 1.0
#: analysis kinds of the particle models
_ANALYSIS_MODEL = {"sphere": "sphere", "coated_sphere": "sphere", "spherocylinder": "rod",
                   "cylinder": "rod", "spheroid": "rod", "janus": "janus"}


#: the summary's names of a quantity of the truth's analysis, where they differ (a sphere's
#: translational coefficient is its x-y MSD's)
_SUMMARY_NAMES = {"D_t": ("D_t", "D (x-y MSD)")}


def _say(text: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {text}", flush=True)


def _run(cmd: list[str], log: Path) -> tuple[int, float]:
    t0 = time.perf_counter()
    with log.open("a") as f:
        f.write("$ " + " ".join(cmd) + "\n")
        f.flush()
        rc = subprocess.call(cmd, stdout=f, stderr=subprocess.STDOUT)
    return rc, time.perf_counter() - t0


def _model_kinds(scene_path: Path) -> list[str]:
    import tomllib

    raw = tomllib.loads(scene_path.read_text())
    kinds = []
    for entry in raw["particle"]:
        beside = scene_path.parent / entry["config"]
        cfg = load_particle(beside if beside.is_file()
                            else resolve_config(entry["config"], "particles"))
        kinds.append(cfg.model.kind)
    return kinds


def _apart(truth: pd.DataFrame) -> pd.DataFrame:
    """Per (particle, frame): the 3D and lateral distance to the nearest other particle."""
    rows = []
    for frame, here in truth.groupby("frame"):
        xyz = here[["x_um", "y_um", "z_um"]].to_numpy()
        d3 = np.linalg.norm(xyz[:, None] - xyz[None], axis=-1)
        d2 = np.linalg.norm(xyz[:, None, :2] - xyz[None, :, :2], axis=-1)
        np.fill_diagonal(d3, np.inf)
        np.fill_diagonal(d2, np.inf)
        for i, p in enumerate(here["particle"].to_numpy()):
            rows.append({"particle": int(p), "frame": int(frame), "nearest_um": d3[i].min(),
                         "nearest_lateral_um": d2[i].min()})
    return pd.DataFrame(rows)


def _owners(crops: pd.DataFrame, truth: pd.DataFrame) -> pd.DataFrame:
    """Each crop row's nearest true particle (lateral distance) in its frame."""
    t = {f: g for f, g in truth.groupby("frame")}
    owner, dist = [], []
    for row in crops.itertuples():
        here = t[row.frame]
        d = np.hypot(here["x_um"].to_numpy() - row.x_um, here["y_um"].to_numpy() - row.y_um)
        i = int(np.argmin(d))
        owner.append(int(here["particle"].iloc[i]) if d[i] < FOUND_UM else -1)
        dist.append(float(d[i]))
    return crops.assign(truth=owner, truth_um=dist)


def _truth_analysis(truth: pd.DataFrame, particle: int, model: str, kind_values: dict,
                    dt: float) -> dict:
    one = truth[truth["particle"] == particle].sort_values("frame")
    axis = None
    if model != "sphere":
        axis = axis_from_angles(one["theta_rad"].to_numpy(), one["psi_rad"].to_numpy())
    traj = Trajectory.from_arrays(one[["x_um", "y_um", "z_um"]].to_numpy(), axis, dt,
                                  source=f"truth of particle {particle}")
    res = analyze_trajectory(traj, AnalysisConfig(model=model, **kind_values))
    return {k: (m.value, m.error) for k, m in res.measured.items()}


def measure(name: str, work: Path, kinds: list[str]) -> dict:
    run = work / "run"
    truth = pd.read_csv(work / "sim" / "truth.csv")
    dt = float(np.median(np.diff(np.sort(truth["time_s"].unique())))) \
        if "time_s" in truth else 0.01
    crops = _owners(pd.read_csv(run / "crop" / "crops.csv"), truth)
    apart = _apart(truth)
    found_rows = crops[crops["status"].isin(["ok", "edge"]) & (crops["truth"] >= 0)]
    # identity is defined where the true particles are resolvable (>= APART_UM from every
    # other): a track holding two of them there is a swap; nearer, the finder may merge the
    # pair and the merged centre may lie nearer either (counted apart, not as a swap)
    alone = apart.loc[apart["nearest_um"] >= APART_UM, ["particle", "frame"]].rename(
        columns={"particle": "truth"})
    resolvable = found_rows.merge(alone, on=["truth", "frame"], how="inner")
    holders = resolvable.groupby("particle")["truth"].agg(lambda s: sorted(set(s)))
    swaps = {int(k): v for k, v in holders.items() if len(v) > 1}
    merged_changes = {}
    for k, g in found_rows.groupby("particle"):
        own = holders.get(k, [])
        if int(k) in swaps or len(set(g["truth"])) < 2 or len(own) != 1:
            continue
        other = g[g["truth"] != own[0]]
        merged_changes[int(k)] = {"truth": own[0], "rows_nearer_another": len(other),
                                  "frames": sorted(int(f) for f in other["frame"])}
    track_of = {}
    for p, g in found_rows.groupby("truth"):
        counts = g["particle"].value_counts()
        track_of[int(p)] = [int(t) for t in counts.index]
    fit = pd.read_csv(run / "fit" / "fit.csv") if (run / "fit" / "fit.csv").exists() else None
    tracks = (pd.read_csv(run / "fit" / "tracks.csv")
              if (run / "fit" / "tracks.csv").exists() else None)
    summary = (pd.read_csv(run / "analysis" / "summary.csv")
               if (run / "analysis" / "summary.csv").exists() else None)
    per_particle = []
    for p, kind in enumerate(kinds):
        a = apart[apart["particle"] == p]
        wanted = set(a.loc[a["nearest_um"] >= APART_UM, "frame"])
        got = set(found_rows.loc[found_rows["truth"] == p, "frame"])
        entry: dict = {"particle": p, "kind": kind, "tracks": track_of.get(p, []),
                       "frames_apart": len(wanted),
                       "found_fraction_apart": (len(wanted & got) / len(wanted)
                                                if wanted else math.nan),
                       "closest_um": float(a["nearest_um"].min())}
        near = set(a.loc[a["nearest_lateral_um"] < 6.0, "frame"])
        mine = crops[(crops["truth"] == p) & crops["frame"].isin(near)]
        entry["frames_within_6um_lateral"] = len(near)
        if len(mine):
            entry["overlap_marked"] = int(mine["overlap"].astype(str).str.lower()
                                          .eq("true").sum())
            entry["overlap_rows_found"] = len(mine)
        main = track_of.get(p, [None])[0]
        if main is not None and fit is not None:
            rows = fit[fit["particle"] == main]
            entry["fit_model"] = (sorted(rows["model"].dropna().unique().tolist())
                                  if "model" in rows else None)
            entry["fit_status"] = rows["status"].value_counts().to_dict()
            if len(mine) and "status" in rows:
                near_fit = rows[rows["frame"].isin(near)]
                entry["near_fit_status"] = near_fit["status"].value_counts().to_dict()
        if main is not None and tracks is not None:
            t = tracks[tracks["particle"] == main]
            entry["track_status"] = t.to_dict("records")
        model = _ANALYSIS_MODEL.get(kind, "rod")
        try:
            entry["truth_analysis"] = _truth_analysis(truth, p, model, {}, dt)
        except Exception as exc:  # reported, the study goes on
            entry["truth_analysis"] = {"error": repr(exc)}
        if main is not None and summary is not None and "particle" in summary:
            srow = summary[summary["particle"] == main]
            pulls = {}
            for q, (tv, _te) in entry["truth_analysis"].items() \
                    if isinstance(entry["truth_analysis"], dict) else []:
                names = _SUMMARY_NAMES.get(q, (q,))
                m = (srow[srow["quantity"].isin(names)] if "quantity" in srow
                     else srow.iloc[0:0])
                if not len(m):
                    continue
                v, e = float(m["measured"].iloc[0]), float(m["measured_err"].iloc[0])
                side = "measured_err_below" if tv < v else "measured_err_above"
                if side in m and np.isfinite(m[side].iloc[0]):
                    e = float(m[side].iloc[0])  # the error on the truth's side
                if np.isfinite(e) and e > 0:
                    pulls[q] = {"fit": v, "err": e, "truth": tv, "pull": (v - tv) / e}
            entry["D_pulls"] = pulls
            entry["analysis_model"] = (srow["model"].iloc[0] if "model" in srow and len(srow)
                                       else None)
        per_particle.append(entry)
    return {"study": f"mixed_field_{name}", "identity_swaps": swaps,
            "apart_um": APART_UM, "owner_changes_while_near": merged_changes,
            "tracks": sorted(int(t) for t in crops["particle"].unique()),
            "particles": per_particle}


def main(argv: list[str]) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("work", type=Path)
    ap.add_argument("scenes", nargs="*", default=list(SCENES))
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args(argv)
    for name in args.scenes:
        instrument, models = SCENES[name]
        scene = HERE / "scenes" / f"{name}.toml"
        work = args.work / name
        work.mkdir(parents=True, exist_ok=True)
        log = work / "log.txt"
        result: dict = {"scene": name}
        if not (work / "sim" / "truth.csv").exists():
            rc, t = _run([HOLOFIT, "simulate", "field-of-view", str(scene), "-o",
                          str(work / "sim")], log)
            result["simulate_s"] = t
            if rc:
                raise SystemExit(f"simulate failed, see {log}")
        run = work / "run"
        if not (run / "Makefile").exists():
            cmd = [HOLOFIT, "init", str(run), "--movie", str(work / "sim" / "movie.tif"),
                   "-b", str(work / "sim" / "background.tif"), "-i", instrument]
            for m in models:
                cmd += ["-p", m]
            rc, _ = _run(cmd, log)
            if rc:
                raise SystemExit(f"holofit init failed, see {log}")
        _say(f"{name}: make -C {run} JOBS={args.jobs}")
        rc, t = _run(["make", "-C", str(run), f"JOBS={args.jobs}"], log)
        result |= {"make_rc": rc, "make_s": t}
        _say(f"{name}: make exited {rc} after {t:.0f} s")
        result |= measure(name, work, _model_kinds(scene))
        with args.out.open("a") as f:
            f.write(json.dumps(result, default=str) + "\n")
        _say(json.dumps(result, default=str)[:2000])


if __name__ == "__main__":
    main(sys.argv[1:])
