"""Diffusion analysis of fit tables: cleaning, MSDs and correlations, fits, theory.

Entry points: :func:`analyze_table` (a fit-table file to a result) and
:func:`~holofit.analysis.pipeline.analyze_trajectory`; :func:`run_analysis` also writes the
summary files and plots (what ``holofit analyze`` does). What differs between particle models
is in one recipe per model (:mod:`holofit.analysis.recipes`).
"""

from __future__ import annotations

from pathlib import Path

from holofit.analysis.errors import AnalysisError
from holofit.analysis.measurement import Measurement
from holofit.analysis.pipeline import analyze_trajectory
from holofit.analysis.recipes import MODELS
from holofit.analysis.results import AnalysisResult
from holofit.analysis.settings import AnalysisSettings, SettingError
from holofit.analysis.summary import format_report, write_summary
from holofit.analysis.trajectory import Trajectory
from holofit.tables.fit import read_fit_table

__all__ = [
    "MODELS",
    "AnalysisError",
    "AnalysisResult",
    "AnalysisSettings",
    "Measurement",
    "SettingError",
    "Trajectory",
    "analyze_table",
    "analyze_trajectory",
    "format_report",
    "run_analysis",
]


def analyze_table(
    path: str | Path, settings: AnalysisSettings, frame_interval_s: float | None = None
) -> AnalysisResult:
    """Read a fit table (validating it) and analyse it."""
    fit = read_fit_table(path, frame_interval_s)
    traj = Trajectory.from_fit_table(fit, bool(settings.drop_ambiguous))
    return analyze_trajectory(traj, settings)


def run_analysis(
    path: str | Path,
    settings: AnalysisSettings,
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
