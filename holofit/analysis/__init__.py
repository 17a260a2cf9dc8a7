"""Diffusion analysis of fit tables: cleaning, MSDs and correlations, fits, theory.

Entry points: :func:`analyze_table` (a fit-table file to a result) and
:func:`~holofit.analysis.pipeline.analyze_trajectory`; :func:`run_analysis` also writes the
summary files and plots (what ``holofit analyze`` does). What differs between particle models
is in one recipe per model (:mod:`holofit.analysis.recipes`).
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from holofit.analysis.errors import AnalysisError
from holofit.analysis.measurement import Measurement
from holofit.analysis.pipeline import analyze_trajectory
from holofit.analysis.recipes import MODELS
from holofit.analysis.results import AnalysisResult
from holofit.analysis.settings import AnalysisConfig, SettingError
from holofit.analysis.summary import format_report, write_summary
from holofit.analysis.tracks import (
    TrackPooling,
    TracksResult,
    analyze_tracks,
    format_tracks_report,
    n_tracks,
    write_tracks,
)
from holofit.analysis.trajectory import Trajectory
from holofit.io.tables import write_table
from holofit.provenance import sidecar
from holofit.tables.fit import read_fit_table

__all__ = [
    "MODELS",
    "AnalysisConfig",
    "AnalysisError",
    "AnalysisResult",
    "Measurement",
    "SettingError",
    "TrackPooling",
    "TracksResult",
    "Trajectory",
    "analyze_table",
    "analyze_tracks",
    "analyze_trajectory",
    "format_report",
    "format_tracks_report",
    "n_tracks",
    "run_analysis",
    "run_track_analysis",
]


def analyze_table(
    path: str | Path, settings: AnalysisConfig, frame_interval_s: float | None = None
) -> AnalysisResult:
    """Read a fit table (validating it) and analyse it."""
    fit = read_fit_table(path, frame_interval_s)
    traj = Trajectory.from_fit_table(fit, bool(settings.drop_ambiguous))
    return analyze_trajectory(traj, settings)


def run_analysis(
    path: str | Path,
    settings: AnalysisConfig,
    out_dir: str | Path,
    *,
    plots: bool = True,
    frame_interval_s: float | None = None,
) -> tuple[AnalysisResult, dict[str, Path]]:
    """Analyse a fit table and write the PNG plots, ``msd.csv`` and ``summary.json``/``.csv``
    (``summary.csv`` last: make waits for it, so a run interrupted while drawing is rerun)."""
    result = analyze_table(path, settings, frame_interval_s)
    pngs: list[Path] = []
    if plots:
        from holofit.analysis.plots import write_plots

        Path(out_dir).mkdir(parents=True, exist_ok=True)
        pngs = list(write_plots(result, out_dir))
    files = write_summary(result, out_dir, inputs=[path])
    for p in pngs:
        files[p.stem + "_png"] = p
    return result, files


def run_track_analysis(
    path: str | Path,
    settings: AnalysisConfig,
    out_dir: str | Path,
    *,
    plots: bool = True,
    frame_interval_s: float | None = None,
    pooling: TrackPooling | None = None,
) -> tuple[TracksResult, dict[str, Path]]:
    """Analyse every track of a multi-particle fit table (:mod:`holofit.analysis.tracks`).

    Writes ``particle_<id>/`` (each analysed track's summary, MSDs and plots, as
    :func:`run_analysis` writes them), ``tracks.csv``, ``pooled.csv``, ``tracks.png`` and
    ``track_msds.png``, and last ``summary.csv``: every analysed track's summary rows with a
    ``particle`` column (make waits for it).
    """
    out = Path(out_dir)
    result = analyze_tracks(path, settings, pooling=pooling, frame_interval_s=frame_interval_s)
    files: dict[str, Path] = {}
    rows = []
    for t in result.tracks:
        if t.result is None:
            continue
        sub = out / f"particle_{t.particle}"
        if plots:
            from holofit.analysis.plots import write_plots

            sub.mkdir(parents=True, exist_ok=True)
            write_plots(t.result, sub)
        write_summary(t.result, sub, inputs=[path])
        rows += [{"particle": t.particle, "track_status": t.status, **r} for r in t.result.rows]
    files.update(write_tracks(result, out, inputs=[path]))
    if plots:
        from holofit.analysis.track_plots import write_track_plots

        for png in write_track_plots(result, out):
            files[png.stem + "_png"] = png
    files["summary_csv"] = write_table(
        out / "summary.csv", pd.DataFrame(rows),
        sidecar(kind="diffusion analysis summary, one block per track",
                config={"settings": settings.__dict__}, inputs=[path],
                extra={"notes": result.notes}))
    return result, files
