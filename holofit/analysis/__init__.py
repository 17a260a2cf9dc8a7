"""Diffusion analysis of fit tables: cleaning, MSDs and correlations, fits, theory.

Entry points: :func:`~holofit.analysis.stage.run_analysis` (what ``holofit analyze`` does: a
fit table of one track or many to the summary files and plots),
:func:`~holofit.analysis.stage.analyze_table` (a table of one track to a result) and
:func:`~holofit.analysis.pipeline.analyze_trajectory`. What differs between particle models is
in one recipe per model (:mod:`holofit.analysis.recipes`).
"""

from __future__ import annotations

from holofit.analysis.errors import AnalysisError
from holofit.analysis.measurement import Measurement
from holofit.analysis.pipeline import analyze_trajectory
from holofit.analysis.population import TrackSelection
from holofit.analysis.recipes import MODELS
from holofit.analysis.results import AnalysisResult
from holofit.analysis.settings import AnalysisConfig, SettingError
from holofit.analysis.stage import AnalysisRun, analyze_table, run_analysis
from holofit.analysis.summary import format_report
from holofit.analysis.track_tables import format_tracks_report
from holofit.analysis.tracks import TrackPooling, TracksResult, analyze_tracks, n_tracks
from holofit.analysis.trajectory import Trajectory

__all__ = [
    "MODELS",
    "AnalysisConfig",
    "AnalysisError",
    "AnalysisResult",
    "AnalysisRun",
    "Measurement",
    "SettingError",
    "TrackPooling",
    "TrackSelection",
    "TracksResult",
    "Trajectory",
    "analyze_table",
    "analyze_tracks",
    "analyze_trajectory",
    "format_report",
    "format_tracks_report",
    "n_tracks",
    "run_analysis",
]
