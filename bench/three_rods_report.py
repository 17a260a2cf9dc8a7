"""The accuracy of a three-rod field of view run by ``bench/pipeline_cases.py 3 --out-dir DIR``
(``python bench/three_rods_report.py DIR``): prints JSON.

Issue target (field of view): every track fitted through the DDA fit, axis rms <= 0.5 deg on
frames without overlap. Reported per track (each track is the rod whose truth lies nearest its
first ``ok`` frame): the statuses of its rows, the axis and x/y rms of its ``ok`` rows whose
crop no other hologram overlaps, and its diffusion coefficients (``holofit analyze --model
rod``: D_par, D_perp, D_r) against the scene's truth, with their pulls. Works on a run that is
still going: tracks whose final pass is complete (``fit/particle_N/fit.csv``) are reported.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

from holofit.analysis import AnalysisConfig, run_analysis

#: the scene's truth (bench/pipeline_cases.py: the paper's measured coefficients)
TRUTH_D = {"D_par": 0.307, "D_perp": 0.293, "D_r": 0.311}


def _axes(theta: np.ndarray, psi: np.ndarray) -> np.ndarray:
    st = np.sin(theta)
    return np.stack([st * np.cos(psi), st * np.sin(psi), np.cos(theta)], axis=1)


def _track(root: Path, p: int, rows: pd.DataFrame, truth: pd.DataFrame,
           crops: pd.DataFrame) -> dict[str, float | str]:
    out: dict[str, float | str] = {"rows": len(rows)}
    out.update({f"status_{k}": int(v) for k, v in rows["status"].value_counts().items()})
    ok = rows[rows["status"] == "ok"]
    if ok.empty:
        return out
    first = ok.iloc[0]
    at = truth[truth["frame"] == first["frame"]]
    rod = int(at.iloc[int(np.argmin(np.hypot(at["x_um"] - first["x_um"],
                                             at["y_um"] - first["y_um"])))]["particle"])
    out["truth_rod"] = rod
    mine = crops[crops["particle"] == p].set_index("frame")
    over = mine["overlap"].astype(str).str.lower().isin(["true", "1"]) if (
        "overlap" in mine.columns) else pd.Series(False, index=mine.index)
    clean = ok[~over.reindex(ok["frame"]).fillna(False).to_numpy()]
    out["ok_rows_without_overlap"] = len(clean)
    t = truth[truth["particle"] == rod].set_index("frame").loc[clean["frame"]]
    u = clean[["ux", "uy", "uz"]].to_numpy()
    u_true = _axes(t["theta_rad"].to_numpy(), t["psi_rad"].to_numpy())
    axis = np.degrees(np.arccos(np.clip(np.abs((u * u_true).sum(1)), 0, 1)))
    dx = 1e3 * (clean["x_um"].to_numpy() - t["x_um"].to_numpy())
    dy = 1e3 * (clean["y_um"].to_numpy() - t["y_um"].to_numpy())
    out.update(axis_rms_deg=float(np.sqrt(np.mean(axis ** 2))), axis_max_deg=float(axis.max()),
               x_rms_nm=float(np.sqrt(np.mean(dx ** 2))),
               y_rms_nm=float(np.sqrt(np.mean(dy ** 2))))
    for name in ("a_um", "b_um", "n"):
        if name in ok.columns:
            out[name] = float(ok[name].median())
    return out


def _diffusion(table: Path, out_dir: Path) -> dict[str, float]:
    """One track's D's from ``holofit analyze --model rod`` (its own fit table)."""
    result = run_analysis(table, AnalysisConfig(model="rod", temperature_c=21.0), out_dir,
                          plots=False).result
    got: dict[str, float] = {}
    for row in result.rows:
        q = row.get("quantity")
        if q in TRUTH_D:
            v, e = float(row["measured"]), float(row["measured_err"])
            got[q], got[f"{q}_err"] = v, e
            got[f"{q}_pull"] = (v - TRUTH_D[q]) / e if e > 0 else math.nan
    return got


def report(root: Path) -> dict[str, dict[str, float | str]]:
    truth = pd.read_csv(root / "movie" / "truth.csv")
    crops = pd.read_csv(root / "crop" / "crops.csv")
    combined = root / "fit" / "fit.csv"
    tables: dict[int, tuple[pd.DataFrame, Path]] = {}
    if combined.exists():
        fit = pd.read_csv(combined)
        for p, rows in fit.groupby("particle"):
            path = root / "fit" / f"particle_{p}" / "fit.csv"
            tables[int(p)] = (rows.reset_index(drop=True), path)
    else:  # still running: the tracks whose final pass is complete
        for path in sorted((root / "fit").glob("particle_*/fit.csv")):
            p = int(path.parent.name.split("_")[1])
            tables[p] = (pd.read_csv(path), path)
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        for p, (rows, path) in sorted(tables.items()):
            out[str(p)] = _track(root, p, rows, truth, crops)
            try:
                out[str(p)].update(_diffusion(path, Path(tmp) / str(p)))
            except Exception as exc:  # a short or broken track: say why, report the rest
                out[str(p)]["analysis_error"] = f"{type(exc).__name__}: {exc}"
    return out


if __name__ == "__main__":
    parser = argparse.ArgumentParser()
    parser.add_argument("run_dir", type=Path)
    args = parser.parse_args()
    json.dump(report(args.run_dir), sys.stdout, indent=1)
    print()
