"""The tables and the report of a field of view's tracks (:mod:`holofit.analysis.tracks`).

``tracks.csv`` has one row per track, analysed or not: its analysis model and the particle
model the fit gave it, its status and reason (and remedy, for one left out), the static
parameters the fit fixed and the sizes the analysis used, each pooled quantity its analysis
measured with its error, its pull against the other tracks of its model and whether it was
pooled, and the physical-consistency numbers. ``pooled.csv`` has one row per (analysis model,
quantity). Both sidecars record each track's model and why (``extra.models``).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pandas as pd

from holofit.analysis.results import AnalysisResult
from holofit.analysis.tracks import POOLED_QUANTITIES, TRACK_STATUSES, TrackResult, TracksResult
from holofit.io.tables import write_table
from holofit.provenance import sidecar

__all__ = ["CHECK_COLUMNS", "check_columns", "format_tracks_report", "model_records",
           "pooled_rows", "track_rows", "write_tracks"]

#: the consistency columns of ``tracks.csv`` (:func:`check_columns`)
CHECK_COLUMNS = ("flagged", "check_failed", "check_threshold_p", "check_min_p",
                 "size_ratio_t", "size_ratio_t_err", "size_z_t", "size_ratio_r",
                 "size_ratio_r_err", "size_z_r")
#: units of the pooled quantities' columns
_UNIT = {"D_t": "um^2/s", "D_par": "um^2/s", "D_perp": "um^2/s", "D_r": "1/s",
         "D_xy": "um^2/s"}


def check_columns(result: AnalysisResult | None) -> dict[str, Any]:
    """A track's consistency numbers (:data:`CHECK_COLUMNS`): whether it is flagged, the
    tests it failed, the per-test threshold and the smallest p-value, and the hydrodynamic /
    optical size ratio with its error and ``z`` from ``D_t`` and ``D_r`` (NaN where not
    tested)."""
    out: dict[str, Any] = dict.fromkeys(CHECK_COLUMNS, math.nan)
    c = result.consistency if result is not None else None
    if c is None:
        return out
    ps = [t.p_value for t in c.tests if math.isfinite(t.p_value)]
    out.update(flagged=c.flagged, check_failed=" ".join(n.replace(" ", "_") for n in c.failed),
               check_threshold_p=c.threshold, check_min_p=min(ps) if ps else math.nan)
    for key, name in (("t", "size D_t"), ("r", "size D_r")):
        t = c.test(name)
        if t is not None and "size_ratio" in t.values:
            out[f"size_ratio_{key}"] = t.values["size_ratio"]
            out[f"size_ratio_{key}_err"] = t.values["size_ratio_err"]
            out[f"size_z_{key}"] = t.statistic
    return out


def _row(t: TrackResult, result: TracksResult) -> dict[str, Any]:
    row: dict[str, Any] = {
        "particle": t.particle, "model": t.model, "particle_model": t.kind,
        "status": t.status, "reason": t.message, "remedy": t.remedy,
        "model_source": t.model_source, "n_frames": t.n_frames, "n_ok": t.n_ok,
        "n_poor_fit": t.n_poor}
    row.update({f"static_{k}": v for k, v in sorted(t.statics.items())})
    sizes = t.result.sizes if t.result is not None else {}
    for name in ("a_um", "b_um"):
        if name in sizes:
            row[name] = sizes[name][0]
    measured = t.result.measured if t.result is not None else {}
    for q in POOLED_QUANTITIES:
        if q not in measured:
            continue
        m, est = measured[q], result.pooled.get((t.model, q))
        row[q], row[f"{q}_err"] = m.value, m.error
        row[f"{q}_pull"] = est.pulls.get(t.particle, math.nan) if est else math.nan
        row[f"{q}_pooled"] = bool(est and t.particle in est.particles)
    row.update(check_columns(t.result))
    return row


def track_rows(result: TracksResult) -> list[dict[str, Any]]:
    """One row per track for ``tracks.csv`` (module docstring), by track id."""
    return [_row(t, result) for t in result.tracks]


def _columns(rows: list[dict[str, Any]]) -> list[str]:
    """The columns of ``tracks.csv``: the track's, the statics of every model, the rest."""
    seen = list(dict.fromkeys(k for r in rows for k in r))
    statics = sorted(k for k in seen if k.startswith("static_"))
    first = seen.index("n_poor_fit") + 1 if "n_poor_fit" in seen else 0
    rest = [k for k in seen if k not in statics]
    return rest[:first] + statics + rest[first:]


def pooled_rows(result: TracksResult) -> list[dict[str, Any]]:
    """One row per (analysis model, quantity) for ``pooled.csv``."""
    return [{"model": e.model, "quantity": e.quantity, "unit": e.unit, "value": e.value,
             "error": e.error, "chi2": e.chi2, "dof": e.dof, "p_value": e.p_value,
             "n_tracks": len(e.particles), "particles": " ".join(map(str, e.particles)),
             "outliers": " ".join(map(str, e.outliers))} for e in result.pooled.values()]


def model_records(result: TracksResult) -> dict[str, dict[str, str]]:
    """Track -> its analysis model, the fit's particle model, why, and its status (the
    sidecars' ``models``)."""
    return {str(t.particle): {"model": t.model, "particle_model": t.kind,
                              "source": t.model_source, "status": t.status}
            for t in result.tracks}


def write_tracks(result: TracksResult, out_dir: str | Path, inputs: list[str | Path]
                 ) -> dict[str, Path]:
    """Write ``tracks.csv`` and ``pooled.csv`` (+ sidecars, atomically; ``pooled.csv`` last)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    cfg = {"pooling": result.pooling.__dict__, "selection": result.selection.summary()}
    extra = {"notes": result.notes, "models": model_records(result)}
    units: dict[str, str] = {
        "particle": "track id", "model": "analysis model (rod, janus, sphere)",
        "particle_model": "the particle model the fit gave the track (its kind)",
        "status": " | ".join(f"{k} ({v})" for k, v in TRACK_STATUSES.items()),
        "static_*": "the static parameters the fit fixed (the model's units)",
        "a_um": "um", "b_um": "um", "*_pull": "1 (sigma, against the other tracks of its model)",
        "*_pooled": "bool", "check_threshold_p": "1", "check_min_p": "1", "size_ratio_t": "1",
        "size_ratio_t_err": "1", "size_z_t": "1 (sigma)", "size_ratio_r": "1",
        "size_ratio_r_err": "1", "size_z_r": "1 (sigma)"}
    for q, unit in _UNIT.items():
        units[q] = units[f"{q}_err"] = unit
    rows = track_rows(result)
    files = {"tracks": write_table(out / "tracks.csv", pd.DataFrame(rows, columns=_columns(rows)),
                                   sidecar(kind="diffusion per track, one row per track",
                                           units=units, config=cfg, inputs=inputs,
                                           extra=extra))}
    files["pooled"] = write_table(
        out / "pooled.csv", pd.DataFrame(pooled_rows(result), columns=[
            "model", "quantity", "unit", "value", "error", "chi2", "dof", "p_value",
            "n_tracks", "particles", "outliers"]),
        sidecar(kind="diffusion pooled over the tracks of each analysis model "
                     "(inverse-variance weighted)",
                units={"value": "unit column", "error": "unit column", "chi2": "1"},
                config=cfg, inputs=inputs, extra=extra))
    return files


def format_tracks_report(result: TracksResult) -> str:
    """A short text report: each track with its model, the tracks left out and why, then
    the pooled values of each model and their consistency."""
    lines = ["tracks:"]
    for t in result.tracks:
        d = t.result.measured.get("D_t") if t.result is not None else None
        dtxt = f"D_t {d.value:.3f} +- {d.error:.3f} um^2/s" if d is not None else ""
        what = t.model + (f" ({t.kind})" if t.kind else "") if t.model else (t.kind or "?")
        statics = ", ".join(f"{k} {v:.4g}" for k, v in sorted(t.statics.items()))
        lines.append(f"  particle {t.particle}: {what}" + (f" [{statics}]" if statics else "")
                     + f", {t.n_ok}/{t.n_frames} ok frames, {t.status}"
                     + (f", {dtxt}" if dtxt else "")
                     + (f" ({t.message})" if t.message and t.result is not None else ""))
    if result.left_out:
        lines.append("left out:")
        lines += [f"  particle {t.particle}: {t.status}: {t.message}"
                  + (f"; remedy: {t.remedy}" if t.remedy else "") for t in result.left_out]
    lines.append("pooled over tracks, each model's apart (inverse-variance weighted):")
    for e in result.pooled.values():
        consistency = (f"chi^2 {e.chi2:.1f} on {e.dof} dof, p {e.p_value:.2g}" if e.dof > 0
                       else "one track")
        lines.append(f"  {e.model:<6} {e.quantity:<7} {e.value:.3f} +- {e.error:.3f} {e.unit} "
                     f"from {len(e.particles)} track(s); {consistency}"
                     + (f"; outliers: {' '.join(map(str, e.outliers))}" if e.outliers else ""))
    listed = tuple(f"particle {t.particle}: " for t in result.left_out)
    lines += [f"note: {n}" for n in result.notes if not n.startswith(listed)]
    return "\n".join(lines)
